//! `assay-worker-runtime`: what every worker role shares.
//!
//! Owns the session with the coordinator: connect, register with roles and capacity, receive
//! assignments under leases, heartbeat them, report results (kept until acknowledged, and sent
//! again after a reconnect), reconnect with backoff when the coordinator goes away, and hand
//! leases back on shutdown. Shards run on their own named threads, never on the async executor.
//! Never links physics, rendering or torch itself: roles plug in through [`ShardHandler`].

pub mod artifacts;

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use assay_proto::channel::{ChannelOptions, KeepAlive};
use assay_proto::v1 as pb;
use pb::worker_message::Msg as Out;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tracing::{debug, info, warn};

/// What a role does with one shard. Called on a dedicated thread: blocking is expected.
pub trait ShardHandler: Send + Sync + 'static {
    fn run(&self, assignment: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError>;
}

/// A shard that could not produce an outcome.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{message}")]
pub struct ShardError {
    pub message: String,
    /// False when retrying cannot help (a spec the role cannot build, an unknown policy).
    pub retryable: bool,
}

impl ShardError {
    pub fn permanent(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            retryable: false,
        }
    }
    pub fn retryable(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            retryable: true,
        }
    }
}

/// Called with what the coordinator announced at registration.
pub type RegisteredHook = Arc<dyn Fn(&pb::Registered) + Send + Sync>;

#[derive(Clone)]
pub struct WorkerConfig {
    /// `http://host:port` of the coordinator.
    pub coordinator: String,
    pub worker_id: String,
    pub node_id: String,
    pub roles: Vec<pb::Role>,
    /// What the worker offers beyond its roles (see `Register.capabilities`).
    pub capabilities: Vec<String>,
    pub capacity: u32,
    pub versions: BTreeMap<String, String>,
    /// Longest wait between reconnection attempts.
    pub max_backoff: Duration,
    /// Give up after this long without a coordinator (None: keep trying).
    pub give_up_after: Option<Duration>,
    /// Called after every (re)registration with what the coordinator announced.
    pub on_registered: Option<RegisteredHook>,
    /// The credential sent with every call: the cluster token or a worker key
    /// (`assay_proto::auth`); None: none.
    pub token: Option<assay_proto::auth::Token>,
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("bad coordinator address '{0}': {1}")]
    Address(String, String),
    #[error("no coordinator at {0} for {1:?}")]
    GaveUp(String, Duration),
    /// The coordinator refused this worker (a missing or wrong credential, or one that is not
    /// a worker's): retrying would not help.
    #[error("the coordinator at {0} refused this worker: {1}")]
    Refused(String, String),
}

struct Done {
    lease_id: u64,
    shard_id: u64,
    result: Result<String, ShardError>,
    wall_time_s: f64,
}

/// Runs the worker until `shutdown` resolves. Then finished results are sent, running leases are
/// handed back to the coordinator, and the function returns.
pub async fn run_worker(
    config: WorkerConfig,
    handler: Arc<dyn ShardHandler>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), WorkerError> {
    let options = ChannelOptions {
        connect_timeout: Some(Duration::from_secs(2)),
        keep_alive: Some(KeepAlive {
            interval: Duration::from_secs(5),
            timeout: Duration::from_secs(10),
        }),
        ..ChannelOptions::default()
    };
    let endpoint = assay_proto::channel::endpoint("coordinator", &config.coordinator, &options)
        .map_err(|e| WorkerError::Address(e.address, e.source.to_string()))?;
    let (done_tx, mut done_rx) = mpsc::channel::<Done>(256);
    // Leases being worked on, and finished results the coordinator has not acknowledged yet.
    let mut running: HashMap<u64, u64> = HashMap::new();
    let mut unacked: BTreeMap<u64, pb::ShardResult> = BTreeMap::new();
    let mut backoff = Duration::from_millis(100);
    let mut alone_since = Instant::now();
    tokio::pin!(shutdown);

    'reconnect: loop {
        let channel = tokio::select! {
            c = endpoint.connect() => c,
            _ = &mut shutdown => return Ok(()),
        };
        let channel = match channel {
            Ok(c) => c,
            Err(e) => {
                if let Some(limit) = config.give_up_after
                    && alone_since.elapsed() > limit
                {
                    return Err(WorkerError::GaveUp(config.coordinator.clone(), limit));
                }
                debug!(error = %e, wait = ?backoff, "coordinator unreachable");
                tokio::select! {
                    _ = tokio::time::sleep(backoff) => {}
                    _ = &mut shutdown => return Ok(()),
                }
                backoff = (backoff * 2).min(config.max_backoff);
                continue;
            }
        };
        let mut client: pb::worker_session_client::WorkerSessionClient<_> =
            assay_proto::channel::client(
                channel,
                config.token.clone(),
                assay_proto::MAX_MESSAGE_BYTES,
            );
        let (out_tx, out_rx) = mpsc::channel::<pb::WorkerMessage>(256);
        let send = |m: Out| pb::WorkerMessage { msg: Some(m) };
        let register = pb::Register {
            worker_id: config.worker_id.clone(),
            node_id: config.node_id.clone(),
            roles: config.roles.iter().map(|r| *r as i32).collect(),
            capabilities: config.capabilities.clone(),
            capacity: config.capacity,
            versions: config.versions.clone().into_iter().collect(),
            held_leases: running.keys().copied().collect(),
        };
        let _ = out_tx.send(send(Out::Register(register))).await;
        let mut inbound = match client.session(ReceiverStream::new(out_rx)).await {
            Ok(r) => r.into_inner(),
            Err(e)
                if matches!(
                    e.code(),
                    tonic::Code::Unauthenticated | tonic::Code::PermissionDenied
                ) =>
            {
                return Err(WorkerError::Refused(
                    config.coordinator.clone(),
                    e.message().to_owned(),
                ));
            }
            Err(e) => {
                warn!(error = %e, "session refused");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(config.max_backoff);
                continue;
            }
        };
        let registered = match inbound.message().await {
            Ok(Some(pb::CoordinatorMessage {
                msg: Some(pb::coordinator_message::Msg::Registered(r)),
            })) => r,
            other => {
                warn!(?other, "coordinator did not confirm registration");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(config.max_backoff);
                continue;
            }
        };
        backoff = Duration::from_millis(100);
        let artifact_root = PathBuf::from(&registered.artifact_root);
        let lost: Vec<u64> = running
            .keys()
            .filter(|id| !registered.kept_leases.contains(id))
            .copied()
            .collect();
        if !lost.is_empty() {
            info!(leases = ?lost, "coordinator no longer grants these leases; their results will not count");
        }
        if let Some(hook) = &config.on_registered {
            hook(&registered);
        }
        info!(worker = %config.worker_id, session = %registered.session_id, kept = registered.kept_leases.len(), "registered");
        // Results finished while we were away.
        for r in unacked.values() {
            let _ = out_tx.send(send(Out::Result(r.clone()))).await;
        }
        let mut heartbeat = tokio::time::interval(Duration::from_millis(u64::from(
            registered.heartbeat_interval_ms.max(100),
        )));
        loop {
            tokio::select! {
                m = inbound.message() => {
                    use pb::coordinator_message::Msg as In;
                    match m {
                        Ok(Some(pb::CoordinatorMessage { msg: Some(In::Assignment(a)) })) => {
                            running.insert(a.lease_id, a.shard_id);
                            spawn_shard(handler.clone(), a, artifact_root.clone(), done_tx.clone());
                        }
                        Ok(Some(pb::CoordinatorMessage { msg: Some(In::Ack(ack)) })) => {
                            unacked.remove(&ack.lease_id);
                            if !ack.accepted {
                                debug!(lease = ack.lease_id, "result not counted (lease no longer current)");
                            }
                        }
                        Ok(Some(pb::CoordinatorMessage { msg: Some(In::Goodbye(g)) })) => {
                            info!(reason = %g.reason, "coordinator said goodbye; reconnecting");
                            alone_since = Instant::now();
                            continue 'reconnect;
                        }
                        Ok(Some(_)) => {}
                        Ok(None) | Err(_) => {
                            warn!("lost the coordinator; reconnecting");
                            alone_since = Instant::now();
                            continue 'reconnect;
                        }
                    }
                }
                Some(d) = done_rx.recv() => {
                    running.remove(&d.lease_id);
                    let m = match d.result {
                        Ok(outcome_json) => {
                            let r = pb::ShardResult { lease_id: d.lease_id, shard_id: d.shard_id, outcome_json, wall_time_s: d.wall_time_s };
                            unacked.insert(d.lease_id, r.clone());
                            Out::Result(r)
                        }
                        Err(e) => Out::Failure(pb::ShardFailure { lease_id: d.lease_id, shard_id: d.shard_id, error: e.message, retryable: e.retryable }),
                    };
                    let _ = out_tx.send(send(m)).await;
                }
                _ = heartbeat.tick() => {
                    if !running.is_empty() {
                        let _ = out_tx.send(send(Out::Heartbeat(pb::Heartbeat { lease_ids: running.keys().copied().collect() }))).await;
                    }
                }
                _ = &mut shutdown => {
                    // Send what finished, hand back what did not, and wait (briefly) for the
                    // coordinator to close the session.
                    while let Ok(d) = done_rx.try_recv() {
                        running.remove(&d.lease_id);
                        if let Ok(outcome_json) = d.result {
                            let _ = out_tx.send(send(Out::Result(pb::ShardResult { lease_id: d.lease_id, shard_id: d.shard_id, outcome_json, wall_time_s: d.wall_time_s }))).await;
                        }
                    }
                    let ids: Vec<u64> = running.keys().copied().collect();
                    info!(leases = ids.len(), "shutting down: handing leases back");
                    let _ = out_tx.send(send(Out::ReturnLeases(pb::ReturnLeases { lease_ids: ids, reason: "worker shutting down".into() }))).await;
                    drop(out_tx);
                    let _ = tokio::time::timeout(Duration::from_secs(3), async {
                        while let Ok(Some(_)) = inbound.message().await {}
                    }).await;
                    return Ok(());
                }
            }
        }
    }
}

fn spawn_shard(
    handler: Arc<dyn ShardHandler>,
    a: pb::Assignment,
    root: PathBuf,
    done: mpsc::Sender<Done>,
) {
    let name = format!("assay-shard-{}", a.lease_id);
    let spawned = std::thread::Builder::new().name(name).spawn(move || {
        let start = Instant::now();
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| handler.run(&a, &root)))
                .unwrap_or_else(|p| {
                    let what = p
                        .downcast_ref::<String>()
                        .cloned()
                        .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                        .unwrap_or_else(|| "unknown panic".into());
                    Err(ShardError::retryable(format!("worker panicked: {what}")))
                });
        let _ = done.blocking_send(Done {
            lease_id: a.lease_id,
            shard_id: a.shard_id,
            result,
            wall_time_s: start.elapsed().as_secs_f64(),
        });
    });
    if let Err(e) = spawned {
        warn!(error = %e, "could not start a shard thread");
    }
}

/// The default worker id: `<node>/<pid>`, stable for the life of the process.
pub fn default_worker_id(node_id: &str) -> String {
    format!("{node_id}/{}", std::process::id())
}
