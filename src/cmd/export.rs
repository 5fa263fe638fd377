//! `assay export`: a finished run's results in the formats researchers already read —
//! `lerobot` (a LeRobotDataset v3.0 of its episodes), `tensorboard` (its figures as
//! TensorBoard scalars) and `wandb` (the same figures as a W&B offline run); the formats are
//! `assay_export`'s.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use assay_export::lerobot;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub format: Format,
}

#[derive(clap::Subcommand)]
pub enum Format {
    /// A LeRobotDataset v3.0 (parquet + MP4 + meta/) of the run's episodes: camera frames,
    /// tool state, commanded action and the task's instruction per frame, loadable with
    /// `LeRobotDataset(repo_id, root=OUT)`. Needs ffmpeg (H.264).
    Lerobot(LerobotArgs),
    /// The run's figures (success per policy and group, judge scores, diversity against budget,
    /// ranking, generalization) as TensorBoard scalars: one event file in OUT, for
    /// `tensorboard --logdir OUT` or tbparse.
    Tensorboard(TensorboardArgs),
    /// The same figures as a Weights & Biases offline run (config, history, summary):
    /// OUT/offline-run-*/, which `wandb sync OUT/offline-run-*` uploads. Nothing is sent from here.
    Wandb(WandbArgs),
}

#[derive(clap::Args)]
pub struct WandbArgs {
    /// An `assay eval` output folder (report.json; its config.toml becomes the run's config).
    pub run: PathBuf,
    /// Where the offline run's folder goes (created when missing), e.g. your `wandb/` folder.
    pub out: PathBuf,
    /// The W&B project the run belongs to (`wandb sync -p` overrides it).
    #[arg(long, default_value = "assay")]
    pub project: String,
}

#[derive(clap::Args)]
pub struct TensorboardArgs {
    /// An `assay eval` output folder (report.json).
    pub run: PathBuf,
    /// The log folder (created when missing). To compare runs in TensorBoard, give each its own
    /// folder under one log root.
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct LerobotArgs {
    /// An `assay eval` output folder (report.json, artifacts/, run/jobs.db).
    pub run: PathBuf,
    /// A new (or empty) folder for the dataset.
    pub out: PathBuf,
    /// Frames are SIZE x SIZE pixels (even), from the task's first camera.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Frames per second of episode time. A frame's physics steps must be a whole number of
    /// recorded rows (4 steps): at the default time step of 1/240 s, e.g. 5, 10, 15, 20, 30, 60.
    #[arg(long, default_value_t = 10)]
    pub fps: u32,
    /// Only this policy's episodes (repeatable; all policies by default).
    #[arg(long = "policy", value_name = "POLICY")]
    pub policies: Vec<String>,
    /// Only episodes that succeeded (ground truth from the simulator).
    #[arg(long)]
    pub successful: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.format {
        Format::Lerobot(a) => {
            let options = lerobot::Options {
                size: a.size,
                fps: a.fps,
                policies: a.policies,
                successful_only: a.successful,
            };
            let specs = task_specs(&a.run)?;
            let s = lerobot::export(&a.run, &a.out, &specs, &options)?;
            for why in &s.skipped {
                eprintln!("left out: {why}");
            }
            println!(
                "{}: LeRobotDataset {} with {} episodes, {} frames, {} tasks{}",
                a.out.display(),
                lerobot::CODEBASE_VERSION,
                s.episodes,
                s.frames,
                s.tasks,
                if s.skipped.is_empty() {
                    String::new()
                } else {
                    format!(" ({} episodes left out, listed above)", s.skipped.len())
                }
            );
            Ok(ExitCode::SUCCESS)
        }
        Format::Tensorboard(a) => {
            let (file, n) = assay_export::tensorboard::export(&a.run, &a.out)?;
            println!("{}: {n} scalars", file.display());
            Ok(ExitCode::SUCCESS)
        }
        Format::Wandb(a) => {
            let e = assay_export::wandb::export(&a.run, &a.out, &a.project)?;
            println!(
                "{}: W&B offline run {} ({} scalars, {} history steps); upload it with `wandb sync {}`",
                e.dir.display(),
                e.run_id,
                e.scalars,
                e.steps,
                e.dir.display()
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// The task specs of `run` (an `assay eval` folder) as its job store holds them.
fn task_specs(run: &Path) -> anyhow::Result<lerobot::Specs> {
    let marker = run.join(crate::outdir::MARKER);
    let batch_id = serde_json::from_slice::<crate::outdir::Marker>(
        &std::fs::read(&marker)
            .with_context(|| format!("{} is not an `assay eval` output folder", run.display()))?,
    )
    .with_context(|| format!("reading {}", marker.display()))?
    .batch_id
    .with_context(|| format!("{}: the run never submitted its batch", run.display()))?;
    let db = run.join("run").join("jobs.db");
    if !db.is_file() {
        bail!(
            "{} has no job store (run/jobs.db): the task specs come from there",
            run.display()
        );
    }
    let store = assay_coordinator::store::Store::open(&db)
        .map_err(|e| anyhow::anyhow!("{}: {e}", db.display()))?;
    let rows = store
        .task_specs(&batch_id)
        .map_err(|e| anyhow::anyhow!("{}: {e}", db.display()))?;
    Ok(rows
        .into_iter()
        .map(|(id, json)| {
            let spec = serde_json::from_str(&json)
                .map_err(|e| format!("its stored spec does not parse: {e}"));
            (id, spec)
        })
        .collect())
}
