//! `assay-coordinator`: one per cluster. Accepts batches, plans them into shards, keeps every
//! state change in its SQLite job store, leases shards to workers by role and capacity, re-queues
//! what expires, retries what fails a bounded number of times, and builds reports. Checks every
//! call's credential against the method it calls (`access`), re-reading rotated credential files.
//!
//! Never links physics, rendering or torch (checked by `tests/forbidden_dependencies.rs`).

pub mod access;
pub mod actor;
pub mod capability;
pub mod config;
pub mod error;
pub mod metrics;
pub mod service;
pub mod store;

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::AtomicU32;
use std::time::Duration;

use assay_proto::v1 as pb;
use tokio::net::TcpListener;
use tokio::sync::{Notify, broadcast, watch};
use tracing::{info, warn};

pub use config::CoordinatorConfig;
pub use error::CoordError;

use crate::actor::StoreHandle;
use crate::service::{CoordinatorService, Shared, WorkerSessionService, now_ms};

/// Serves both services on `listener` until `shutdown` resolves, then tells every worker goodbye
/// (their leases stay in the store, so a restarted coordinator picks them up) and returns. With
/// `metrics`, serves `GET /metrics` (Prometheus) and `GET /healthz` there too.
pub async fn serve(
    config: CoordinatorConfig,
    listener: TcpListener,
    metrics: Option<TcpListener>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), CoordError> {
    std::fs::create_dir_all(&config.artifact_root).map_err(|e| {
        CoordError::InvalidRequest(format!(
            "artifact root {}: {e}",
            config.artifact_root.display()
        ))
    })?;
    let store = StoreHandle::spawn(&config.store_path)?;
    let ttl = config.lease_ttl.as_millis() as i64;
    let (survived, running) = store
        .call(move |s| Ok((s.refresh_leases(now_ms(), ttl)?, s.running_batches()?)))
        .await?;
    info!(store = %config.store_path.display(), running = running.len(), leases = survived, "job store open");

    let (stop_tx, stop_rx) = watch::channel(false);
    let (events, _) = broadcast::channel(1024);
    let shared = Arc::new(Shared {
        store: store.clone(),
        config,
        work: Notify::new(),
        events,
        workers_connected: AtomicU32::new(0),
        capabilities: Default::default(),
        shutdown: stop_rx.clone(),
    });

    // Lease sweeper: expired leases go back to the queue (or fail, out of attempts).
    let sweeper = {
        let shared = shared.clone();
        let mut stop = stop_rx.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(250));
            loop {
                tokio::select! {
                    _ = tick.tick() => {}
                    _ = stop.changed() => return,
                }
                match shared.store.call(|s| s.expire(now_ms(), None)).await {
                    Ok(changed) => {
                        if changed.requeued > 0 {
                            info!(requeued = changed.requeued, "expired leases re-queued");
                        }
                        shared.publish(&changed);
                    }
                    Err(e) => warn!(error = %e, "lease sweep failed"),
                }
            }
        })
    };

    // Telemetry: a zenoh router for the cluster, and batch progress on every change.
    let telemetry = match shared.config.telemetry.clone() {
        Some(endpoint) => match assay_telemetry::open_router(
            &endpoint,
            shared
                .config
                .keyring
                .as_ref()
                .map(|k| k.zenoh_users())
                .as_deref(),
        )
        .await
        {
            Ok(session) => {
                info!(%endpoint, "telemetry router listening");
                Some((
                    session.clone(),
                    tokio::spawn(publish_progress(shared.clone(), session, stop_rx.clone())),
                ))
            }
            Err(e) => {
                warn!(%endpoint, error = %e, "telemetry is off: the router could not start");
                None
            }
        },
        None => None,
    };
    let metrics = metrics.map(|l| {
        info!(addr = ?l.local_addr().ok(), "metrics at /metrics");
        tokio::spawn(serve_metrics(shared.clone(), l, stop_rx.clone()))
    });
    let refresher = shared
        .config
        .keyring
        .clone()
        .filter(|k| k.has_files())
        .map(|k| {
            tokio::spawn(refresh_credentials(
                k,
                shared.config.credentials_refresh,
                stop_rx.clone(),
            ))
        });
    let addr = listener.local_addr().ok();
    let keyring = shared.config.keyring.clone();
    info!(
        addr = ?addr,
        credentials = keyring.as_ref().map_or("none required".into(), |k| k.describe()),
        "coordinator listening"
    );
    // Every call's credential is checked against the method it calls (`access`).
    let server = tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(Duration::from_secs(5)))
        .http2_keepalive_timeout(Some(Duration::from_secs(10)))
        .add_service(access::Guarded::new(
            pb::coordinator_server::CoordinatorServer::new(CoordinatorService {
                shared: shared.clone(),
            })
            .max_decoding_message_size(assay_proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(assay_proto::MAX_MESSAGE_BYTES),
            keyring.clone(),
        ))
        .add_service(access::Guarded::new(
            pb::worker_session_server::WorkerSessionServer::new(WorkerSessionService {
                shared: shared.clone(),
            })
            .max_decoding_message_size(assay_proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(assay_proto::MAX_MESSAGE_BYTES),
            keyring,
        ));
    let mut stop_for_server = stop_rx.clone();
    // Every connection without Nagle's delay: an assignment, a result and its ack are small
    // messages, and with Nagle and delayed ACKs each waited ~40 ms (`assay bench coordinator`:
    // 1,100 shards/s with 50 workers, nearly idle).
    let incoming = tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
    let result = server.serve_with_incoming_shutdown(incoming, async move {
        let _ = stop_for_server.changed().await;
    });
    let trigger = tokio::spawn(async move {
        shutdown.await;
        info!("coordinator shutting down");
        let _ = stop_tx.send(true);
    });
    let out = result.await;
    trigger.abort();
    let _ = sweeper.await;
    if let Some(r) = refresher {
        let _ = r.await;
    }
    if let Some(m) = metrics {
        let _ = m.await;
    }
    if let Some((session, task)) = telemetry {
        let _ = task.await;
        assay_telemetry::close(session).await;
    }
    out.map_err(|e| CoordError::InvalidRequest(format!("server: {e}")))
}

/// Reads the keyring's files every `every` until `stop` changes: a rotated key is accepted, and
/// the old one refused, from the next call on. A failed read keeps the keys and is logged once
/// (not every `every`), until it reads again.
async fn refresh_credentials(
    keyring: Arc<assay_proto::auth::Keyring>,
    every: Duration,
    mut stop: watch::Receiver<bool>,
) {
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut failing: Option<String> = None;
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stop.changed() => return,
        }
        let k = keyring.clone();
        let Ok(read) = tokio::task::spawn_blocking(move || k.reload()).await else {
            return;
        };
        match read {
            Ok(changed) => {
                if changed {
                    info!(credentials = %keyring.describe(), "credentials changed: the new keys are taken, the old refused");
                }
                if failing.take().is_some() {
                    info!("credential files read again");
                }
            }
            Err(e) => {
                if failing.as_deref() != Some(e.as_str()) {
                    warn!(error = %e, "credential files unreadable: the keys read before stay");
                }
                failing = Some(e);
            }
        }
    }
}

/// `GET /metrics` and `GET /healthz` until `stop` changes.
async fn serve_metrics(
    shared: Arc<Shared>,
    listener: TcpListener,
    mut stop: watch::Receiver<bool>,
) {
    use axum::http::{StatusCode, header};
    use axum::response::IntoResponse;
    let app = axum::Router::new()
        .route(
            "/metrics",
            axum::routing::get(move || {
                let shared = shared.clone();
                async move {
                    let workers = shared
                        .workers_connected
                        .load(std::sync::atomic::Ordering::Relaxed);
                    match shared.store.call(|s| s.metrics()).await {
                        Ok(snapshot) => (
                            StatusCode::OK,
                            [(
                                header::CONTENT_TYPE,
                                "text/plain; version=0.0.4; charset=utf-8",
                            )],
                            snapshot.render(workers),
                        )
                            .into_response(),
                        Err(e) => (StatusCode::SERVICE_UNAVAILABLE, format!("job store: {e}\n"))
                            .into_response(),
                    }
                }
            }),
        )
        .route("/healthz", axum::routing::get(|| async { "ok\n" }));
    let served = axum::serve(listener, app).with_graceful_shutdown(async move {
        let _ = stop.changed().await;
    });
    if let Err(e) = served.await {
        warn!(error = %e, "metrics server stopped");
    }
}

/// How often a batch's progress is published, or sent to a `WatchBatch` stream, at most while it
/// changes.
pub(crate) const PROGRESS_EVERY: Duration = Duration::from_millis(200);

/// Publishes a batch's progress on `assay/<cluster>/batches/<batch>/progress` when it changes, at
/// most every [`PROGRESS_EVERY`]: a sample reads the batch's counts (every shard of it), and one
/// per completion took the store thread from leasing — at 20,000 completions a second, most of
/// it. A batch changed since its last sample is published at the next tick; after the event
/// channel lagged (changes were missed), every running batch and every batch last seen running.
async fn publish_progress(
    shared: Arc<Shared>,
    session: zenoh::Session,
    mut stop: watch::Receiver<bool>,
) {
    let mut events = shared.events.subscribe();
    let mut publishers: std::collections::HashMap<String, assay_telemetry::JsonPublisher> =
        Default::default();
    let mut dirty = std::collections::BTreeSet::new();
    // Batches whose last sample said running: their next change must not be missed.
    let mut live = std::collections::BTreeSet::new();
    let mut lagged = false;
    let mut tick = tokio::time::interval(PROGRESS_EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        // Published at a tick; an event between ticks only marks its batch.
        let due = tokio::select! {
            e = events.recv() => {
                match e {
                    Ok(b) => {
                        dirty.insert(b);
                    }
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => lagged = true,
                    Err(_) => return,
                }
                false
            }
            _ = tick.tick() => true,
            _ = stop.changed() => return,
        };
        if !due {
            continue;
        }
        if std::mem::take(&mut lagged) {
            dirty.extend(live.iter().cloned());
            if let Ok(running) = shared.store.call(|s| s.running_batches()).await {
                dirty.extend(running);
            }
        }
        for batch in std::mem::take(&mut dirty) {
            let id = batch.clone();
            let Ok((c, queued)) = shared
                .store
                .call(move |s| Ok((s.counts(&id)?, s.queued_needs(Some(&id))?)))
                .await
            else {
                continue;
            };
            if c.state == store::batch_state::RUNNING {
                live.insert(batch.clone());
            } else {
                live.remove(&batch);
            }
            if !publishers.contains_key(&batch) {
                match assay_telemetry::JsonPublisher::new(
                    &session,
                    assay_telemetry::batch_key(&shared.config.cluster, &batch),
                )
                .await
                {
                    Ok(p) => {
                        publishers.insert(batch.clone(), p);
                    }
                    Err(e) => {
                        warn!(error = %e, "telemetry publisher");
                        continue;
                    }
                }
            }
            let progress = assay_telemetry::BatchProgress {
                batch: c.id.clone(),
                name: c.name.clone(),
                state: c.state.clone(),
                total: c.total,
                done: c.done,
                failed: c.failed,
                running: c.leased,
                successes: c.successes,
                workers_connected: shared
                    .workers_connected
                    .load(std::sync::atomic::Ordering::Relaxed),
                waiting: crate::capability::waiting(&queued, &shared.capabilities.offered()),
                priority: c.share.share.priority.to_string(),
                workers_holding: c.share.workers,
                fair_share: c.share.fair_share,
                holds: c.share.holds,
            };
            if let Err(e) = publishers[&batch].put(&progress).await {
                warn!(error = %e, "telemetry put");
            }
        }
    }
}
