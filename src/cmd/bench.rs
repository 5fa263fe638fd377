//! `assay bench`: the peer reference scene, timed like `shared/bench/peers/peers.py` (one JSON
//! line on stdout), the frame hand-off, and the coordinator at scale; the measurements are
//! `assay_run::bench`'s.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use assay_run::bench;

#[derive(clap::Args)]
pub struct Args {
    /// physics | render | rollout | handoff | coordinator | scaling | churn
    pub measure: String,
    /// `coordinator`, `churn`: fake workers (sessions over loopback gRPC); `scaling`: the most
    /// of them.
    #[arg(long, default_value_t = 1000)]
    pub workers: u32,
    /// `coordinator`: shards in the batch.
    #[arg(long, default_value_t = 100_000)]
    pub shards: u64,
    /// `coordinator`: shards each fake worker holds at once (and the store bench's lease grant).
    #[arg(long, default_value_t = 1)]
    pub capacity: u32,
    /// `scaling`, `churn`: how long each fake episode takes, in milliseconds.
    #[arg(long, default_value_t = 20)]
    pub work_ms: u64,
    /// `churn`: milliseconds between two events (a worker joins or leaves, in turn).
    #[arg(long, default_value_t = 100)]
    pub every_ms: u64,
    /// `churn`: the coordinator's lease TTL, in milliseconds (how long a stalled worker's shard
    /// waits before it runs elsewhere).
    #[arg(long, default_value_t = 2_000)]
    pub lease_ttl_ms: u64,
    /// The scene contract.
    #[arg(long, default_value = "bench/reference-scene.json")]
    pub scene: PathBuf,
    #[arg(long, default_value_t = 5)]
    pub trials: u32,
    /// Timed physics steps per trial (default: the contract's).
    #[arg(long)]
    pub steps: Option<u32>,
    /// Frames per `render` trial.
    #[arg(long, default_value_t = 20)]
    pub frames: u32,
    /// `rollout`: render the contract's 8 frames per episode.
    #[arg(long)]
    pub render: bool,
    /// Image width (default: the contract camera's, 640).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the contract camera's, 480).
    #[arg(long)]
    pub height: Option<u32>,
    /// Also read back a depth image per frame.
    #[arg(long)]
    pub depth: bool,
    /// Also read back a segmentation image per frame.
    #[arg(long)]
    pub seg: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut progress = |line: String| eprintln!("{line}");
    let line = match a.measure.as_str() {
        "coordinator" => bench::coordinator::run(a.workers, a.shards, a.capacity, &mut progress)?,
        "scaling" => bench::coordinator::scaling(
            a.workers,
            a.shards,
            a.capacity,
            Duration::from_millis(a.work_ms),
            &mut progress,
        )?,
        "churn" => bench::churn::run(
            &bench::churn::Churn {
                exe: std::env::current_exe()?,
                workers: a.workers,
                shards: a.shards,
                every: Duration::from_millis(a.every_ms.max(1)),
                work: Duration::from_millis(a.work_ms),
                lease_ttl: Duration::from_millis(a.lease_ttl_ms.max(1)),
            },
            &mut progress,
        )?,
        measure => bench::peers(
            measure,
            &bench::PeerBench {
                scene: a.scene,
                trials: a.trials,
                steps: a.steps,
                frames: a.frames,
                render: a.render,
                width: a.width,
                height: a.height,
                depth: a.depth,
                seg: a.seg,
            },
        )?,
    };
    outln!("{line}");
    Ok(ExitCode::SUCCESS)
}
