//! One module per subcommand.

pub mod agreement;
pub mod bench;
pub mod bench_coordinator;
pub mod cluster;
pub mod coordinator;
#[cfg(feature = "trainer")]
pub mod diversity;
pub mod doctor;
pub mod eval;
pub mod export;
pub mod frames;
pub mod import;
pub mod policy;
pub mod rank;
pub mod report;
pub mod status;
pub mod submit;
pub mod top;
pub mod validate;
#[cfg(feature = "trainer")]
pub mod watch;
pub mod worker;

use std::future::Future;

use assay_proto::v1 as pb;

/// The default coordinator address, also read from ASSAY_COORDINATOR.
pub const DEFAULT_COORDINATOR: &str = "http://127.0.0.1:7878";

/// A multi-threaded runtime for commands that talk to the network.
/// `--resamples`: a count that can make a 95 % interval (or 0 for none).
pub fn resamples(s: &str) -> Result<usize, String> {
    let n: usize = s.parse().map_err(|e| format!("{e}"))?;
    assay_stats::agreement::check_resamples(n)
}

pub fn block_on<F: Future>(f: F) -> F::Output {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("assay-rt")
        .build()
        .expect("tokio runtime")
        .block_on(f)
}

/// A client of the coordinator at `addr`, carrying the cluster token when one is set
/// (`assay_proto::auth`).
pub async fn client(
    addr: &str,
) -> anyhow::Result<pb::coordinator_client::CoordinatorClient<assay_proto::auth::Channel>> {
    let token = assay_proto::auth::Token::from_env().map_err(anyhow::Error::msg)?;
    let options = assay_proto::channel::ChannelOptions {
        connect_timeout: Some(std::time::Duration::from_secs(5)),
        ..Default::default()
    };
    let channel = assay_proto::channel::connect("coordinator", addr, &options).await?;
    Ok(assay_proto::channel::client(
        channel,
        token,
        assay_proto::MAX_MESSAGE_BYTES,
    ))
}

/// Resolves on SIGTERM or Ctrl-C. The handlers are installed when this is called (inside the
/// runtime), not when the future is first polled: a signal that arrives before the future is
/// polled is still caught instead of killing the process.
pub fn terminated() -> impl Future<Output = ()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate()).expect("SIGTERM handler");
    let mut int = signal(SignalKind::interrupt()).expect("SIGINT handler");
    async move {
        tokio::select! {
            _ = term.recv() => {}
            _ = int.recv() => {}
        }
    }
}

pub fn state_name(state: i32) -> &'static str {
    match pb::BatchState::try_from(state).unwrap_or(pb::BatchState::Unspecified) {
        pb::BatchState::Running => "running",
        pb::BatchState::Completed => "completed",
        pb::BatchState::Cancelled => "cancelled",
        pb::BatchState::Skipped => "skipped",
        pb::BatchState::Unspecified => "unknown",
    }
}

/// Prints the task errors a coordinator reported for a submission.
pub fn print_rejected(rejected: &[pb::SpecError]) {
    for e in rejected {
        let task = if e.task_id.is_empty() {
            "<no id>"
        } else {
            &e.task_id
        };
        let path = if e.path.is_empty() {
            "<document>"
        } else {
            &e.path
        };
        eprintln!("invalid task {task} ({}): {path}: {}", e.origin, e.reason);
    }
}

/// This process's CPU time, in seconds (the benchmarks' CPU-time rates).
pub(crate) fn cpu_s() -> f64 {
    use nix::time::{ClockId, clock_gettime};
    let t = clock_gettime(ClockId::CLOCK_PROCESS_CPUTIME_ID).expect("process CPU clock");
    t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9
}
