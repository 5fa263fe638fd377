//! `assay-telemetry`: live progress and rates of a cluster on eclipse-zenoh.
//!
//! The coordinator runs a zenoh router; workers and viewers (`assay top`, `assay eval`) connect to
//! it as clients. Nothing is discovered by multicast and gossip is off: by default everything
//! listens and connects on loopback only, and a multi-node cluster names its router's address.
//! Statistics are published with blocking congestion control, so a burst is slowed, not dropped.
//!
//! Key expressions (JSON payloads):
//! - `assay/<cluster>/workers/<worker>/stats` — [`WorkerStats`], every second from every worker.
//! - `assay/<cluster>/batches/<batch>/progress` — [`BatchProgress`], from the coordinator on change.
//!
//! Owns: the key layout, the zenoh configuration and the payload types. Never decides anything:
//! telemetry is for people and dashboards; the job store stays the source of truth.

use serde::{Deserialize, Serialize};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

/// Statistics a worker publishes about itself.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct WorkerStats {
    pub worker: String,
    pub node: String,
    pub roles: Vec<String>,
    pub episodes_done: u64,
    pub episodes_failed: u64,
    /// Episodes judged (judge role).
    #[serde(default)]
    pub judged: u64,
    /// Trainer jobs finished (trainer role: text diversity, world models).
    #[serde(default)]
    pub trained: u64,
    /// Episodes whose pictures this worker drew for a sim worker without a renderer (render
    /// shards).
    #[serde(default)]
    pub rendered: u64,
    /// Pictures and captions the judge role read from a process of its node over shared memory
    /// (iceoryx2), and those it read from the artifact store (drawn on another node, or no
    /// longer kept).
    #[serde(default)]
    pub frames_from_shared_memory: u64,
    #[serde(default)]
    pub frames_from_store: u64,
    /// Leases this worker holds now (shards running).
    pub leases_held: u64,
    /// Leases it may hold at once (its capacity).
    pub lease_capacity: u64,
    pub physics_steps_per_s: f64,
    pub frames_per_s: f64,
    pub uptime_s: f64,
    pub unix_ms: i64,
}

/// A batch's progress as the coordinator sees it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BatchProgress {
    pub batch: String,
    pub name: String,
    pub state: String,
    pub total: u32,
    pub done: u32,
    pub failed: u32,
    pub running: u32,
    pub successes: u32,
    pub workers_connected: u32,
    /// Work that waits for a capability no connected worker offers, one line each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub waiting: Vec<String>,
    /// Its share of the cluster: its priority, the workers holding its shards, its fair share
    /// and what it holds of every lease now (fractions; see the coordinator's `BatchStatus`).
    #[serde(default)]
    pub priority: String,
    #[serde(default)]
    pub workers_holding: u32,
    #[serde(default)]
    pub fair_share: f64,
    #[serde(default)]
    pub holds: f64,
}

#[derive(Debug, thiserror::Error)]
#[error("telemetry: {0}")]
pub struct TelemetryError(String);

fn err(e: impl std::fmt::Display) -> TelemetryError {
    TelemetryError(e.to_string())
}

/// A key-expression chunk from an id: characters zenoh reserves become `_`.
pub fn chunk(id: &str) -> String {
    let s: String = id
        .chars()
        .map(|c| {
            if matches!(c, '/' | '*' | '$' | '#' | '?') || c.is_whitespace() {
                '_'
            } else {
                c
            }
        })
        .collect();
    if s.is_empty() { "_".into() } else { s }
}

pub fn worker_key(cluster: &str, worker: &str) -> String {
    format!("assay/{}/workers/{}/stats", chunk(cluster), chunk(worker))
}

pub fn batch_key(cluster: &str, batch: &str) -> String {
    format!("assay/{}/batches/{}/progress", chunk(cluster), chunk(batch))
}

/// Everything of one cluster.
pub fn cluster_keys(cluster: &str) -> String {
    format!("assay/{}/**", chunk(cluster))
}

fn base_config(mode: &str) -> Result<zenoh::Config, TelemetryError> {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", &format!("\"{mode}\""))
        .map_err(err)?;
    c.insert_json5("scouting/multicast/enabled", "false")
        .map_err(err)?;
    c.insert_json5("scouting/gossip/enabled", "false")
        .map_err(err)?;
    Ok(c)
}

/// The user name the cluster token's holders present to its router; a role key's holders
/// present their role's name (`worker`, `submitter`, `viewer`: `assay_proto::auth::Access`).
pub const ZENOH_USER: &str = "assay";

/// The router the coordinator runs, listening on `endpoint` (e.g. `tcp/127.0.0.1:7447`). With
/// `users` (user names and passwords, derived from the cluster's credentials), the router admits
/// only sessions that prove they know one user's password (zenoh's user-password authentication:
/// an HMAC of a fresh nonce, the password never sent); without, it admits anyone who can reach
/// it. The users are read once, when the router opens: a credential rotated later joins
/// telemetry after the coordinator restarts (gRPC takes it at once).
pub async fn open_router(
    endpoint: &str,
    users: Option<&[(&str, String)]>,
) -> Result<zenoh::Session, TelemetryError> {
    let mut c = base_config("router")?;
    c.insert_json5("listen/endpoints", &format!("[\"{endpoint}\"]"))
        .map_err(err)?;
    c.insert_json5("connect/endpoints", "[]").map_err(err)?;
    let Some(users) = users else {
        return zenoh::open(c).await.map_err(err);
    };
    // zenoh reads the accepted users from a file, once, while the session opens: a private file
    // that lives only that long.
    let lines: String = users.iter().map(|(u, p)| format!("{u}:{p}\n")).collect();
    let dict = PrivateFile::create(&lines).map_err(err)?;
    c.insert_json5(
        "transport/auth/usrpwd/dictionary_file",
        &serde_json::to_string(&dict.path.display().to_string()).map_err(err)?,
    )
    .map_err(err)?;
    let session = zenoh::open(c).await.map_err(err);
    drop(dict);
    session
}

/// A client session on the router at `endpoint` (workers, `assay top`, `assay eval`), presenting
/// `login` (user name and password) when the cluster has credentials.
pub async fn open_client(
    endpoint: &str,
    login: Option<(&str, &str)>,
) -> Result<zenoh::Session, TelemetryError> {
    let mut c = base_config("client")?;
    c.insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
        .map_err(err)?;
    c.insert_json5("listen/endpoints", "[]").map_err(err)?;
    if let Some((user, password)) = login {
        c.insert_json5(
            "transport/auth/usrpwd/user",
            &serde_json::to_string(user).map_err(err)?,
        )
        .map_err(err)?;
        c.insert_json5(
            "transport/auth/usrpwd/password",
            &serde_json::to_string(password).map_err(err)?,
        )
        .map_err(err)?;
    }
    zenoh::open(c).await.map_err(err)
}

/// A file only this user can read, removed when dropped.
struct PrivateFile {
    path: std::path::PathBuf,
}

impl PrivateFile {
    fn create(content: &str) -> std::io::Result<Self> {
        use std::io::Write;
        use std::os::unix::fs::OpenOptionsExt;
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!(
            "assay-zenoh-users-{}-{n}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.subsec_nanos())
        ));
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&path)?;
        f.write_all(content.as_bytes())?;
        Ok(Self { path })
    }
}

impl Drop for PrivateFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Publishes JSON values on one key, blocking (not dropping) under congestion.
pub struct JsonPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
}

impl JsonPublisher {
    pub async fn new(session: &zenoh::Session, key: String) -> Result<Self, TelemetryError> {
        let publisher = session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Block)
            .await
            .map_err(err)?;
        Ok(Self { publisher })
    }

    pub async fn put<T: Serialize>(&self, value: &T) -> Result<(), TelemetryError> {
        let json = serde_json::to_vec(value).map_err(err)?;
        self.publisher.put(json).await.map_err(err)
    }
}

/// Everything published in a cluster, as (key, JSON) pairs.
pub struct ClusterSubscriber {
    subscriber:
        zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
}

impl ClusterSubscriber {
    pub async fn new(session: &zenoh::Session, cluster: &str) -> Result<Self, TelemetryError> {
        let subscriber = session
            .declare_subscriber(cluster_keys(cluster))
            .await
            .map_err(err)?;
        Ok(Self { subscriber })
    }

    /// The next sample; `None` once the session closes.
    pub async fn next(&self) -> Option<(String, serde_json::Value)> {
        loop {
            let sample = self.subscriber.recv_async().await.ok()?;
            let key = sample.key_expr().as_str().to_owned();
            if let Ok(v) = serde_json::from_slice(&sample.payload().to_bytes()) {
                return Some((key, v));
            }
        }
    }
}

/// Closes a session, waiting for its tasks (call before the runtime ends).
pub async fn close(session: zenoh::Session) {
    let _ = session.close().await;
}

/// Closes a session from synchronous code.
pub fn close_blocking(session: zenoh::Session) {
    let _ = session.close().wait();
}

/// A free TCP port on loopback for a router to listen on.
pub fn free_loopback_endpoint() -> std::io::Result<String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0")?;
    Ok(format!("tcp/127.0.0.1:{}", l.local_addr()?.port()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_become_valid_key_chunks() {
        assert_eq!(
            worker_key("local", "node-a/1234"),
            "assay/local/workers/node-a_1234/stats"
        );
        assert_eq!(chunk("a*b c"), "a_b_c");
        assert_eq!(chunk(""), "_");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_client_receives_what_another_client_publishes_through_the_router() {
        let endpoint = free_loopback_endpoint().unwrap();
        let router = open_router(&endpoint, None).await.unwrap();
        let viewer = open_client(&endpoint, None).await.unwrap();
        let sub = ClusterSubscriber::new(&viewer, "t").await.unwrap();
        let worker = open_client(&endpoint, None).await.unwrap();
        let publisher = JsonPublisher::new(&worker, worker_key("t", "w/1"))
            .await
            .unwrap();
        let stats = WorkerStats {
            worker: "w/1".into(),
            episodes_done: 3,
            ..Default::default()
        };
        // Subscriptions propagate asynchronously: publish until one arrives (bounded).
        let got = tokio::time::timeout(std::time::Duration::from_secs(20), async {
            loop {
                publisher.put(&stats).await.unwrap();
                if let Ok(Some(x)) =
                    tokio::time::timeout(std::time::Duration::from_millis(200), sub.next()).await
                {
                    return x;
                }
            }
        })
        .await
        .expect("a sample within 20 s");
        assert_eq!(got.0, "assay/t/workers/w_1/stats");
        assert_eq!(serde_json::from_value::<WorkerStats>(got.1).unwrap(), stats);
        for s in [worker, viewer, router] {
            close(s).await;
        }
    }

    /// Publishes `stats` until `sub` receives a sample (true) or `within` passes (false).
    async fn delivered(
        publisher: &JsonPublisher,
        sub: &ClusterSubscriber,
        stats: &WorkerStats,
        within: std::time::Duration,
    ) -> bool {
        tokio::time::timeout(within, async {
            loop {
                publisher.put(stats).await.unwrap();
                if let Ok(Some(_)) =
                    tokio::time::timeout(std::time::Duration::from_millis(200), sub.next()).await
                {
                    return;
                }
            }
        })
        .await
        .is_ok()
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_router_with_a_password_admits_only_sessions_that_know_it() {
        let endpoint = free_loopback_endpoint().unwrap();
        let password = "5f1c0ffee-derived-from-the-cluster-token";
        let users_files = || -> Vec<std::path::PathBuf> {
            std::fs::read_dir(std::env::temp_dir())
                .unwrap()
                .filter_map(|e| e.ok())
                .filter(|e| {
                    e.file_name()
                        .to_string_lossy()
                        .starts_with("assay-zenoh-users-")
                })
                .map(|e| e.path())
                .collect()
        };
        let before = users_files();
        // Two users: the cluster token's holders, and a role's (a viewer) with its own password.
        let viewer_password = "the-viewers-own-password";
        let users = [
            (ZENOH_USER, password.to_owned()),
            ("viewer", viewer_password.to_owned()),
        ];
        let router = open_router(&endpoint, Some(&users)).await.unwrap();
        // The users file lived only while the router opened.
        let after: Vec<_> = users_files()
            .into_iter()
            .filter(|p| !before.contains(p))
            .collect();
        assert!(after.is_empty(), "left behind: {after:?}");

        let viewer = open_client(&endpoint, Some(("viewer", viewer_password)))
            .await
            .unwrap();
        let sub = ClusterSubscriber::new(&viewer, "t").await.unwrap();
        let member = open_client(&endpoint, Some((ZENOH_USER, password)))
            .await
            .unwrap();
        let publisher = JsonPublisher::new(&member, worker_key("t", "member"))
            .await
            .unwrap();
        let stats = WorkerStats {
            worker: "member".into(),
            ..Default::default()
        };
        assert!(
            delivered(&publisher, &sub, &stats, std::time::Duration::from_secs(20)).await,
            "a member's sample did not arrive"
        );
        // Without a password, with another, or with one user's password under another's name, a
        // client is not let in: either opening fails, or what it publishes reaches nobody.
        for wrong in [
            None,
            Some((ZENOH_USER, "not-the-password-of-this-cluster")),
            Some(("viewer", password)),
        ] {
            match open_client(&endpoint, wrong).await {
                Err(e) => assert!(
                    !e.to_string().contains(password) && !e.to_string().contains(viewer_password),
                    "{e}"
                ),
                Ok(outsider) => {
                    let p = JsonPublisher::new(&outsider, worker_key("t", "outsider"))
                        .await
                        .unwrap();
                    assert!(
                        !delivered(&p, &sub, &stats, std::time::Duration::from_secs(3)).await,
                        "an outsider ({wrong:?}) published into the cluster"
                    );
                    close(outsider).await;
                }
            }
        }
        for s in [member, viewer, router] {
            close(s).await;
        }
    }
}
