//! `assay export`: a finished run's results in the formats researchers already read —
//! `lerobot` (a LeRobotDataset v3.0 of its episodes), `tensorboard` (its figures as
//! TensorBoard scalars) and `wandb` (the same figures as a W&B offline run); the formats are
//! `assay_export`'s.

use std::path::PathBuf;
use std::process::ExitCode;

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
    /// Export at a policy interface, as policy-spec arguments
    /// (`space=ee_delta,cameras=image:scene@224+wrist:wrist@224,state=ee_pos+ee_quat+gripper`):
    /// each of its cameras as `observation.images.<name>` (those without a size at --size), its
    /// state parts as `observation.state` and its action space as `action`, read from the
    /// recorded rows at the control rate (--fps 10 at the default time step). Default: the
    /// original interface (the task camera, tool position + holding, tool velocities).
    #[arg(long, value_name = "ARGS")]
    pub interface: Option<String>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.format {
        Format::Lerobot(a) => {
            let options = lerobot::Options {
                size: a.size,
                fps: a.fps,
                policies: a.policies,
                successful_only: a.successful,
                interface: a
                    .interface
                    .as_deref()
                    .map(assay_model::policy::Interface::parse_args)
                    .transpose()
                    .map_err(|e| anyhow::anyhow!("--interface: {e}"))?,
            };
            let specs = assay_run::export::task_specs(&a.run)?;
            let mut drawing = assay_run::export::RunDrawing::default();
            let s = lerobot::export(&a.run, &a.out, &specs, &options, &mut drawing)?;
            for why in &s.skipped {
                eprintln!("left out: {why}");
            }
            outln!(
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
            outln!("{}: {n} scalars", file.display());
            Ok(ExitCode::SUCCESS)
        }
        Format::Wandb(a) => {
            let e = assay_export::wandb::export(&a.run, &a.out, &a.project)?;
            outln!(
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
