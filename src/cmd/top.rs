//! `assay top`: a live view of a cluster from its telemetry (workers' rates, batches' progress).

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use assay_telemetry::{BatchProgress, ClusterSubscriber, WorkerStats};

#[derive(clap::Args)]
pub struct Args {
    /// The cluster's telemetry router (the coordinator's `--telemetry`; `assay eval` prints it).
    #[arg(
        long,
        env = "ASSAY_TELEMETRY_CONNECT",
        default_value = "tcp/127.0.0.1:7447"
    )]
    pub telemetry: String,
    #[arg(long, env = "ASSAY_CLUSTER", default_value = "local")]
    pub cluster: String,
    /// Print every sample as a JSON line instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
}

fn table(
    workers: &BTreeMap<String, WorkerStats>,
    batches: &BTreeMap<String, BatchProgress>,
) -> String {
    let mut out = String::from("\x1b[2J\x1b[H");
    out.push_str(&format!(
        "{:<32} {:>9} {:>7} {:>8} {:>7} {:>7} {:>8} {:>12} {:>9}\n",
        "worker",
        "episodes",
        "failed",
        "rendered",
        "judged",
        "trained",
        "leases",
        "steps/s",
        "frames/s"
    ));
    for w in workers.values() {
        out.push_str(&format!(
            "{:<32} {:>9} {:>7} {:>8} {:>7} {:>7} {:>8} {:>12.0} {:>9.1}\n",
            w.worker,
            w.episodes_done,
            w.episodes_failed,
            w.rendered,
            w.judged,
            w.trained,
            format!("{}/{}", w.leases_held, w.lease_capacity),
            w.physics_steps_per_s,
            w.frames_per_s
        ));
    }
    out.push('\n');
    for b in batches.values() {
        out.push_str(&format!(
            "batch {} {:<10} {}/{} done, {} ok, {} failed, {} running  {}\n  share: {}\n",
            b.batch,
            b.state,
            b.done + b.failed,
            b.total,
            b.successes,
            b.failed,
            b.running,
            b.name,
            crate::print::share_line(&b.priority, b.workers_holding, b.fair_share, b.holds)
        ));
        for w in &b.waiting {
            out.push_str(&format!("  waiting: {w}\n"));
        }
    }
    out
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    assay_run::rt::block_on(async move {
        // Any credential watches: a viewer's key, a submitter's, a worker's or the cluster token.
        use assay_proto::auth::{Access, Credential};
        let login = Credential::from_env(&[Access::Viewer, Access::Submitter, Access::Worker])
            .map_err(anyhow::Error::msg)?
            .map(|c| c.zenoh_login());
        let session = assay_telemetry::open_client(
            &a.telemetry,
            login.as_ref().map(|(u, p)| (*u, p.as_str())),
        )
        .await
        .with_context(|| {
            format!(
                "could not join the telemetry router at {}{}",
                a.telemetry,
                if login.is_none() {
                    " (a cluster with a token admits only its members: set ASSAY_CLUSTER_TOKEN, \
                     ASSAY_VIEWER_TOKEN or another role's key, or its _FILE variant)"
                } else {
                    " (is it running, and is this key the cluster's?)"
                }
            )
        })?;
        let sub = ClusterSubscriber::new(&session, &a.cluster).await?;
        let deadline = a
            .duration
            .map(|d| Instant::now() + Duration::from_secs_f64(d));
        let stop = assay_run::rt::terminated();
        tokio::pin!(stop);
        let (mut workers, mut batches) = (BTreeMap::new(), BTreeMap::new());
        let mut redraw = tokio::time::interval(Duration::from_secs(1));
        loop {
            let left = deadline
                .map(|d| d.saturating_duration_since(Instant::now()))
                .unwrap_or(Duration::from_secs(3600));
            // Ends at its deadline, on a signal, or when stdout's reader has gone (`| head`).
            if left.is_zero() || crate::print::stdout_closed() {
                break;
            }
            tokio::select! {
                s = sub.next() => {
                    let Some((key, v)) = s else { break };
                    if a.json {
                        outln!("{}", serde_json::json!({"key": key, "value": v}));
                    }
                    if key.ends_with("/stats") {
                        if let Ok(w) = serde_json::from_value::<WorkerStats>(v) {
                            workers.insert(w.worker.clone(), w);
                        }
                    } else if let Ok(b) = serde_json::from_value::<BatchProgress>(v) {
                        batches.insert(b.batch.clone(), b);
                    }
                }
                _ = redraw.tick(), if !a.json => out!("{}", table(&workers, &batches)),
                _ = tokio::time::sleep(left) => break,
                _ = &mut stop => break,
            }
        }
        assay_telemetry::close(session).await;
        Ok(ExitCode::SUCCESS)
    })
}
