//! A local cluster of real processes on loopback: a coordinator, sim workers, and a judge and a
//! trainer worker when the batch needs them (`assay eval`, `assay watch`).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;

use crate::proc::{ChildProc, wait_for_file};

/// The local cluster's options, shared by `assay eval` and `assay watch` (flattened into both,
/// so their flags, defaults and configuration keys are the same).
#[derive(clap::Args, Debug, Clone)]
#[command(next_help_heading = "Local cluster")]
pub struct ClusterArgs {
    /// Sim worker processes to start.
    #[arg(long, default_value_t = 2)]
    pub workers: u32,
    /// Shards each worker runs at once.
    #[arg(long, default_value_t = 1)]
    pub capacity: u32,
    /// Worker roles: sim,render (pictures of every episode, judging, dynamics diversity) or sim
    /// (physics only, faster; with --render-workers, pictures are drawn by those).
    #[arg(long, default_value = "sim,render")]
    pub roles: String,
    /// Render-only worker processes to start beside the sim workers: they draw the pictures
    /// of episodes that sim-only workers (`--roles sim`) simulated, and the judge reads them
    /// over shared memory.
    #[arg(long, default_value_t = 0)]
    pub render_workers: u32,
    /// Size of rendered views and keyframes, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480")]
    pub image_size: String,
    /// Also a video of every episode (MP4 with ffmpeg installed, else an animated GIF).
    #[arg(long)]
    pub video: bool,
    /// Configuration file (TOML) for the judge and trainer workers (`[judges.<name>]`,
    /// `[embedders.<name>]`).
    #[arg(long, env = "ASSAY_CONFIG")]
    pub config: Option<PathBuf>,
    /// Judge requests in flight at once in the judge worker (shards it runs at once).
    #[arg(long, default_value_t = 4)]
    pub judge_capacity: u32,
    /// No judging (by default rendered episodes are judged by the built-in `offline` judge,
    /// or by the judges given with --judge).
    #[arg(long, conflicts_with = "judges")]
    pub no_judge: bool,
}

/// What to start.
pub struct Plan {
    /// Sim worker processes.
    pub workers: u32,
    /// Shards each sim worker runs at once.
    pub capacity: u32,
    /// Roles of the sim workers (`sim,render` or `sim`).
    pub roles: String,
    /// Render-only worker processes.
    pub render_workers: u32,
    pub image_size: String,
    pub video: bool,
    /// Configuration file passed to the judge and trainer workers.
    pub config: Option<PathBuf>,
    /// Judges; a judge worker is started when there are any.
    pub judges: Vec<String>,
    pub judge_capacity: u32,
    /// Start a trainer worker.
    pub training: bool,
    pub trainer_capacity: Option<u32>,
    /// The folders the sim workers may read asset files from (their `--asset-root`).
    pub asset_roots: Vec<PathBuf>,
}

/// Times a local process is started again after it exits before the run gives up on it.
pub const MAX_RESTARTS: u32 = 3;

/// A process of the cluster with what it takes to start it again.
struct Supervised {
    proc: ChildProc,
    args: Vec<String>,
    log: PathBuf,
    restarts: u32,
    /// When an exited process is due to start again (backoff: 0.5 s, 1 s, 2 s).
    due: Option<Instant>,
}

impl Supervised {
    fn new(proc: ChildProc, args: Vec<String>, log: PathBuf) -> Self {
        Self {
            proc,
            args,
            log,
            restarts: 0,
            due: None,
        }
    }
}

/// The running processes; stopped (SIGTERM, then SIGKILL) on [`LocalCluster::stop`] or drop.
/// [`LocalCluster::supervise`] starts again one that exited.
pub struct LocalCluster {
    /// The coordinator's gRPC address (`http://127.0.0.1:PORT`); the same after a restart.
    pub addr: String,
    /// The telemetry endpoint, when on.
    pub telemetry: Option<String>,
    coordinator: Supervised,
    workers: Vec<Supervised>,
    addr_file: PathBuf,
}

impl LocalCluster {
    /// Starts the processes, with the job store and logs in `run_dir` (an existing store is
    /// reopened) and the artifact store at `artifacts`.
    pub fn start(plan: &Plan, run_dir: &Path, artifacts: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(run_dir)
            .with_context(|| format!("creating {}", run_dir.display()))?;
        let addr_file = run_dir.join("coordinator.addr");
        let _ = std::fs::remove_file(&addr_file);
        let s = |p: PathBuf| p.display().to_string();
        let mut coordinator_args: Vec<String> = vec![
            "coordinator".into(),
            "--listen".into(),
            "127.0.0.1:0".into(),
            "--store".into(),
            s(run_dir.join("jobs.db")),
            "--artifacts".into(),
            s(artifacts.to_path_buf()),
            "--addr-file".into(),
            s(addr_file.clone()),
            "--metrics-listen".into(),
            "127.0.0.1:0".into(),
        ];
        let coordinator_log = run_dir.join("coordinator.log");
        let mut coordinator = ChildProc::spawn("coordinator", &coordinator_args, &coordinator_log)?;
        let announced = wait_for_file(&addr_file, Duration::from_secs(30), &mut coordinator)?;
        let mut lines = announced.lines().map(str::trim);
        let bound = lines.next().unwrap_or_default().to_owned();
        let addr = format!("http://{bound}");
        // A restarted coordinator listens where the workers and this process look for it.
        coordinator_args[2] = bound;
        let on = |l: Option<&str>| {
            l.filter(|l| !l.is_empty() && *l != "off")
                .map(str::to_owned)
        };
        let telemetry = on(lines.next());
        let metrics = on(lines.next());
        let mut workers = Vec::new();
        // A worker of `roles` drawing pictures at the run's size, named `local/<name>`.
        let drawing = |roles: &str, name: String| -> Vec<String> {
            vec![
                "worker".into(),
                "--coordinator".into(),
                addr.clone(),
                "--roles".into(),
                roles.to_owned(),
                "--image-size".into(),
                plan.image_size.clone(),
                "--capacity".into(),
                plan.capacity.to_string(),
                "--node-id".into(),
                "local".into(),
                "--worker-id".into(),
                format!("local/{name}"),
            ]
        };
        for i in 0..plan.workers.max(1) {
            let mut args = drawing(&plan.roles, format!("worker-{i}"));
            if plan.video {
                args.push("--video".into());
            }
            for r in &plan.asset_roots {
                args.push("--asset-root".into());
                args.push(s(r.clone()));
            }
            let log = run_dir.join(format!("worker-{i}.log"));
            let proc = ChildProc::spawn(&format!("worker {i}"), &args, &log)?;
            workers.push(Supervised::new(proc, args, log));
        }
        let sim_workers = workers.len();
        for i in 0..plan.render_workers {
            let args = drawing("render", format!("render-{i}"));
            let log = run_dir.join(format!("render-{i}.log"));
            let proc = ChildProc::spawn(&format!("render worker {i}"), &args, &log)?;
            workers.push(Supervised::new(proc, args, log));
        }

        if !plan.judges.is_empty() {
            let mut args: Vec<String> = vec![
                "worker".into(),
                "--coordinator".into(),
                addr.clone(),
                "--roles".into(),
                "judge".into(),
                "--capacity".into(),
                plan.judge_capacity.max(1).to_string(),
                "--node-id".into(),
                "local".into(),
                "--worker-id".into(),
                "local/judge-0".into(),
            ];
            if let Some(path) = &plan.config {
                args.push("--config".into());
                args.push(s(path.clone()));
            }
            let log = run_dir.join("judge-0.log");
            let proc = ChildProc::spawn("judge worker", &args, &log)?;
            workers.push(Supervised::new(proc, args, log));
        }
        if plan.training {
            let mut args: Vec<String> = vec![
                "worker".into(),
                "--coordinator".into(),
                addr.clone(),
                "--roles".into(),
                "trainer".into(),
                "--node-id".into(),
                "local".into(),
                "--worker-id".into(),
                "local/trainer-0".into(),
                "--capacity".into(),
                plan.trainer_capacity
                    .unwrap_or_else(|| {
                        std::thread::available_parallelism().map_or(1, |n| n.get() as u32)
                    })
                    .max(1)
                    .to_string(),
            ];
            if let Some(path) = &plan.config {
                args.push("--config".into());
                args.push(s(path.clone()));
            }
            let log = run_dir.join("trainer-0.log");
            let proc = ChildProc::spawn("trainer worker", &args, &log)?;
            workers.push(Supervised::new(proc, args, log));
        }
        eprintln!(
            "local cluster: coordinator at {addr}, {sim_workers} sim workers{}{}{}; metrics at {}; logs in {}",
            match plan.render_workers {
                0 => String::new(),
                n => format!(", {n} render workers"),
            },
            if plan.judges.is_empty() {
                String::new()
            } else {
                format!(", a judge worker ({})", plan.judges.join(", "))
            },
            if plan.training {
                ", a trainer worker"
            } else {
                ""
            },
            metrics
                .as_deref()
                .map_or_else(|| "(off)".into(), |m| format!("http://{m}/metrics")),
            run_dir.display()
        );
        Ok(Self {
            addr,
            telemetry,
            coordinator: Supervised::new(coordinator, coordinator_args, coordinator_log),
            workers,
            addr_file,
        })
    }

    /// Starts again every process that exited, after a backoff, at most [`MAX_RESTARTS`] times
    /// each: a worker's leases then expire and its shards run again elsewhere or on its
    /// successor; a coordinator comes back on the same address and job store, where the workers
    /// find it again. Returns a line per event (an exit seen, a restart); an error when a
    /// process exited more often than it may restart.
    pub fn supervise(&mut self) -> anyhow::Result<Vec<String>> {
        let mut events = Vec::new();
        let addr_file = self.addr_file.clone();
        for (is_coordinator, p) in std::iter::once((true, &mut self.coordinator))
            .chain(self.workers.iter_mut().map(|w| (false, w)))
        {
            if p.due.is_none() {
                let Ok(Some(status)) = p.proc.child.try_wait() else {
                    continue;
                };
                if p.restarts >= MAX_RESTARTS {
                    anyhow::bail!(
                        "the local {} process exited ({status}) after {} restarts; its log is {}",
                        p.proc.name,
                        p.restarts,
                        p.log.display()
                    );
                }
                let wait = Duration::from_millis(500 << p.restarts);
                events.push(format!(
                    "the local {} process exited ({status}); starting it again in {:.1} s \
                     ({} of {MAX_RESTARTS})",
                    p.proc.name,
                    wait.as_secs_f64(),
                    p.restarts + 1
                ));
                p.due = Some(Instant::now() + wait);
            }
            if p.due.is_some_and(|due| Instant::now() >= due) {
                p.due = None;
                p.restarts += 1;
                if is_coordinator {
                    let _ = std::fs::remove_file(&addr_file);
                }
                let mut proc = ChildProc::respawn(&p.proc.name, &p.args, &p.log)?;
                if is_coordinator {
                    wait_for_file(&addr_file, Duration::from_secs(30), &mut proc)?;
                }
                events.push(format!("the local {} process is running again", proc.name));
                p.proc = proc;
            }
        }
        Ok(events)
    }

    /// Workers first (they hand their leases back), then the coordinator.
    pub fn stop(mut self) {
        for w in &mut self.workers {
            w.proc.stop(Duration::from_secs(5));
        }
        self.coordinator.proc.stop(Duration::from_secs(5));
    }
}
