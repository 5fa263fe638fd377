//! A local cluster of real processes on loopback: a coordinator, sim workers, and a judge and a
//! trainer worker when the batch needs them (`assay eval`, `assay watch`). Each process is the
//! `assay` binary itself (or [`Plan::exe`]) started with `coordinator` or `worker` arguments, its
//! log in the run folder; one that exits is started again a few times ([`LocalCluster::supervise`]).
//!
//! Owns: which processes a plan starts and with what arguments, their supervision and their stop.
//! Never: the batch (the caller submits and follows it) or the terminal (the caller prints
//! [`LocalCluster::description`]).

mod proc;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;

pub use proc::{ChildProc, PARENT_VAR, die_with_parent, wait_for_file};

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
    /// The `assay` binary the cluster's processes run (not a flag: the running executable, unless
    /// a caller that is not `assay` itself — a test — names it).
    #[arg(skip)]
    pub exe: Option<PathBuf>,
}

impl ClusterArgs {
    /// Whether episodes get pictures: the sim workers render, or render workers do.
    pub fn rendering(&self) -> bool {
        self.render_workers > 0 || self.roles.split(',').any(|r| r.trim() == "render")
    }

    /// The plan of a local cluster for a batch with `judges` and `policies`, a trainer when
    /// `training`.
    pub fn plan(
        &self,
        judges: &[String],
        policies: &[String],
        training: bool,
        trainer_capacity: Option<u32>,
        asset_roots: Vec<PathBuf>,
    ) -> Plan {
        Plan {
            exe: self.exe.clone(),
            workers: self.workers,
            capacity: self.capacity,
            roles: self.roles.clone(),
            render_workers: self.render_workers,
            image_size: self.image_size.clone(),
            video: self.video,
            config: self.config.clone(),
            judges: judges.to_vec(),
            judge_capacity: self.judge_capacity,
            training,
            trainer_capacity,
            asset_roots,
            policy_key_envs: crate::docs::policy_key_envs(policies),
        }
    }
}

/// What to start.
pub struct Plan {
    /// The `assay` binary to start (default: this process's own executable).
    pub exe: Option<PathBuf>,
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
    /// The folders the sim, render and trainer workers may read files from (their
    /// `--asset-root`): the folders of the task paths, the run's own `--asset-root` and the
    /// folders of the model files its `--policy` values name (`docs::worker_roots`).
    pub asset_roots: Vec<PathBuf>,
    /// The variables its `--policy` values' `api_key_env` name, which the workers may send
    /// (their `--policy-key-env`, `docs::policy_key_envs`).
    pub policy_key_envs: Vec<String>,
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
    fn start(exe: &Path, name: &str, args: Vec<String>, log: PathBuf) -> anyhow::Result<Self> {
        let proc = ChildProc::spawn(exe, name, &args, &log)?;
        Ok(Self {
            proc,
            args,
            log,
            restarts: 0,
            due: None,
        })
    }
}

/// The running processes; stopped (SIGTERM, then SIGKILL) on [`LocalCluster::stop`] or drop.
/// [`LocalCluster::supervise`] starts again one that exited.
pub struct LocalCluster {
    /// The coordinator's gRPC address (`http://127.0.0.1:PORT`); the same after a restart.
    pub addr: String,
    /// The telemetry endpoint, when on.
    pub telemetry: Option<String>,
    /// One line saying what runs where (`local cluster: coordinator at …`).
    pub description: String,
    exe: PathBuf,
    coordinator: Supervised,
    workers: Vec<Supervised>,
    addr_file: PathBuf,
}

/// What the coordinator announced in its address file.
struct Announced {
    /// `host:port` of its gRPC listener.
    bound: String,
    telemetry: Option<String>,
    metrics: Option<String>,
}

impl LocalCluster {
    /// Starts the processes, with the job store and logs in `run_dir` (an existing store is
    /// reopened) and the artifact store at `artifacts`.
    pub fn start(plan: &Plan, run_dir: &Path, artifacts: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(run_dir)
            .with_context(|| format!("creating {}", run_dir.display()))?;
        let exe = match &plan.exe {
            Some(exe) => exe.clone(),
            None => std::env::current_exe().context("locating the assay binary")?,
        };
        let addr_file = run_dir.join("coordinator.addr");
        let _ = std::fs::remove_file(&addr_file);
        let (coordinator, announced) = start_coordinator(&exe, run_dir, artifacts, &addr_file)?;
        let addr = format!("http://{}", announced.bound);
        let workers = start_workers(&exe, plan, &addr, run_dir)?;
        let description = describe(plan, &addr, announced.metrics.as_deref(), run_dir);
        Ok(Self {
            addr,
            telemetry: announced.telemetry,
            description,
            exe,
            coordinator,
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
        let exe = self.exe.clone();
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
                let mut proc = ChildProc::respawn(&exe, &p.proc.name, &p.args, &p.log)?;
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

/// Starts the coordinator on a free loopback port and waits for its address file; a restart
/// listens on the same address (the arguments are rewritten to it).
fn start_coordinator(
    exe: &Path,
    run_dir: &Path,
    artifacts: &Path,
    addr_file: &Path,
) -> anyhow::Result<(Supervised, Announced)> {
    let s = |p: &Path| p.display().to_string();
    let mut args: Vec<String> = vec![
        "coordinator".into(),
        "--listen".into(),
        "127.0.0.1:0".into(),
        "--store".into(),
        s(&run_dir.join("jobs.db")),
        "--artifacts".into(),
        s(artifacts),
        "--addr-file".into(),
        s(addr_file),
        "--metrics-listen".into(),
        "127.0.0.1:0".into(),
    ];
    let log = run_dir.join("coordinator.log");
    let mut proc = ChildProc::spawn(exe, "coordinator", &args, &log)?;
    let announced = wait_for_file(addr_file, Duration::from_secs(30), &mut proc)?;
    let mut lines = announced.lines().map(str::trim);
    let bound = lines.next().unwrap_or_default().to_owned();
    // A restarted coordinator listens where the workers and this process look for it.
    args[2] = bound.clone();
    let on = |l: Option<&str>| {
        l.filter(|l| !l.is_empty() && *l != "off")
            .map(str::to_owned)
    };
    let announced = Announced {
        bound,
        telemetry: on(lines.next()),
        metrics: on(lines.next()),
    };
    let coordinator = Supervised {
        proc,
        args,
        log,
        restarts: 0,
        due: None,
    };
    Ok((coordinator, announced))
}

/// The arguments of a worker process joining `addr` on node `local` as `local/<name>`.
fn worker_args(addr: &str, roles: &str, name: &str) -> Vec<String> {
    vec![
        "worker".into(),
        "--coordinator".into(),
        addr.to_owned(),
        "--roles".into(),
        roles.to_owned(),
        "--node-id".into(),
        "local".into(),
        "--worker-id".into(),
        format!("local/{name}"),
    ]
}

/// The sim workers, render workers, judge worker and trainer worker of `plan`.
fn start_workers(
    exe: &Path,
    plan: &Plan,
    addr: &str,
    run_dir: &Path,
) -> anyhow::Result<Vec<Supervised>> {
    let mut workers = Vec::new();
    let mut start = |name: &str, args: Vec<String>, log: &str| -> anyhow::Result<()> {
        workers.push(Supervised::start(exe, name, args, run_dir.join(log))?);
        Ok(())
    };
    // A worker of `roles` drawing pictures at the run's size.
    let drawing = |roles: &str, name: String| -> Vec<String> {
        let mut args = worker_args(addr, roles, &name);
        args.splice(
            5..5,
            [
                "--image-size".into(),
                plan.image_size.clone(),
                "--capacity".into(),
                plan.capacity.to_string(),
            ],
        );
        args
    };
    // Workers open asset files and policy models below the folders given here only (a worker
    // given none would use its working folder): the task paths' folders, the run's
    // --asset-root and its policies' model folders. They send the keys the run's own policies
    // name, and no other.
    let with_roots = |mut args: Vec<String>| {
        for r in &plan.asset_roots {
            args.push("--asset-root".into());
            args.push(r.display().to_string());
        }
        for var in &plan.policy_key_envs {
            args.push("--policy-key-env".into());
            args.push(var.clone());
        }
        args
    };
    for i in 0..plan.workers.max(1) {
        let mut args = drawing(&plan.roles, format!("worker-{i}"));
        if plan.video {
            args.push("--video".into());
        }
        start(
            &format!("worker {i}"),
            with_roots(args),
            &format!("worker-{i}.log"),
        )?;
    }
    for i in 0..plan.render_workers {
        let args = with_roots(drawing("render", format!("render-{i}")));
        start(
            &format!("render worker {i}"),
            args,
            &format!("render-{i}.log"),
        )?;
    }
    let with_config = |mut args: Vec<String>| {
        if let Some(path) = &plan.config {
            args.push("--config".into());
            args.push(path.display().to_string());
        }
        args
    };
    if !plan.judges.is_empty() {
        let mut args = worker_args(addr, "judge", "judge-0");
        args.splice(
            5..5,
            ["--capacity".into(), plan.judge_capacity.max(1).to_string()],
        );
        start("judge worker", with_config(args), "judge-0.log")?;
    }
    if plan.training {
        let capacity = plan
            .trainer_capacity
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get() as u32))
            .max(1);
        let mut args = worker_args(addr, "trainer", "trainer-0");
        args.extend(["--capacity".into(), capacity.to_string()]);
        // The trainer loads the policies a proxy ranks, as a sim worker does.
        start(
            "trainer worker",
            with_roots(with_config(args)),
            "trainer-0.log",
        )?;
    }
    Ok(workers)
}

/// `local cluster: coordinator at …, N sim workers…; metrics at …; logs in …`.
fn describe(plan: &Plan, addr: &str, metrics: Option<&str>, run_dir: &Path) -> String {
    let sim_workers = plan.workers.max(1);
    format!(
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
        metrics.map_or_else(|| "(off)".into(), |m| format!("http://{m}/metrics")),
        run_dir.display()
    )
}
