//! What a worker has done, and its statistics published every second on zenoh.
//!
//! Owns: the counters and the publisher. Never decides anything (the job store is the truth).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// What the worker has done, for telemetry.
#[derive(Default)]
pub struct Counters {
    pub episodes: AtomicU64,
    pub failed: AtomicU64,
    pub running: AtomicU64,
    pub steps: AtomicU64,
    pub frames: AtomicU64,
    pub judged: AtomicU64,
    pub trained: AtomicU64,
    pub rendered: AtomicU64,
    /// Pictures a judge read over shared memory, and from the artifact store.
    pub frames_shared: AtomicU64,
    pub frames_stored: AtomicU64,
}

/// Publishes this worker's statistics every second on `assay/<cluster>/workers/<worker>/stats`,
/// once the coordinator has announced where its telemetry router is.
pub(crate) async fn publish_stats(
    mut announced: tokio::sync::watch::Receiver<Option<(String, String)>>,
    login: Option<(&'static str, String)>,
    counters: Arc<Counters>,
    worker: String,
    node: String,
    roles: Vec<String>,
    capacity: u64,
) {
    let (endpoint, cluster) = loop {
        if let Some((e, c)) = announced.borrow_and_update().clone()
            && !e.is_empty()
        {
            break (e, c);
        }
        if announced.changed().await.is_err() {
            return;
        }
    };
    let login = login.as_ref().map(|(u, p)| (*u, p.as_str()));
    let session = match assay_telemetry::open_client(&endpoint, login).await {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!(%endpoint, error = %e, "telemetry is off for this worker");
            return;
        }
    };
    let publisher = match assay_telemetry::JsonPublisher::new(
        &session,
        assay_telemetry::worker_key(&cluster, &worker),
    )
    .await
    {
        Ok(p) => p,
        Err(e) => {
            tracing::warn!(error = %e, "telemetry publisher");
            return;
        }
    };
    tracing::info!(%endpoint, "publishing telemetry");
    let start = std::time::Instant::now();
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let (mut last, mut last_steps, mut last_frames) = (std::time::Instant::now(), 0u64, 0u64);
    loop {
        tick.tick().await;
        let (steps, frames) = (
            counters.steps.load(Ordering::Relaxed),
            counters.frames.load(Ordering::Relaxed),
        );
        let dt = last.elapsed().as_secs_f64().max(1e-3);
        let stats = assay_telemetry::WorkerStats {
            worker: worker.clone(),
            node: node.clone(),
            roles: roles.clone(),
            episodes_done: counters.episodes.load(Ordering::Relaxed),
            episodes_failed: counters.failed.load(Ordering::Relaxed),
            judged: counters.judged.load(Ordering::Relaxed),
            trained: counters.trained.load(Ordering::Relaxed),
            rendered: counters.rendered.load(Ordering::Relaxed),
            frames_from_shared_memory: counters.frames_shared.load(Ordering::Relaxed),
            frames_from_store: counters.frames_stored.load(Ordering::Relaxed),
            leases_held: counters.running.load(Ordering::Relaxed),
            lease_capacity: capacity,
            physics_steps_per_s: (steps - last_steps) as f64 / dt,
            frames_per_s: (frames - last_frames) as f64 / dt,
            uptime_s: start.elapsed().as_secs_f64(),
            unix_ms: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_millis() as i64)
                .unwrap_or(0),
        };
        (last, last_steps, last_frames) = (std::time::Instant::now(), steps, frames);
        if let Err(e) = publisher.put(&stats).await {
            tracing::warn!(error = %e, "telemetry put");
        }
    }
}
