//! `assay import gensim|robogen|bbsea PATH`: a generator's own output → task spec v1 files, with
//! the per-task mapping report (what was mapped, inferred, left out, and why a task was not
//! imported). `assay eval --import PIPELINE PATH` runs the same import before evaluating.

use std::path::PathBuf;
use std::process::ExitCode;

use assay_import::Pipeline;
use assay_run::imports;

#[derive(clap::Args)]
pub struct Args {
    /// The generator: gensim, robogen or bbsea.
    pub pipeline: Pipeline,
    /// The generator's output tree (GenSim: the folder with generated_tasks.json; RoboGen: the
    /// repository root or a folder of task YAMLs; BBSEA: the repository root).
    pub path: PathBuf,
    /// The folder asset paths must stay inside (default: PATH/assets for GenSim and RoboGen,
    /// PATH for BBSEA).
    #[arg(long)]
    pub asset_root: Option<PathBuf>,
    /// Write one spec file per imported task (ID.yaml) and import-report.json here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Exit non-zero if any task could not be imported.
    #[arg(long)]
    pub strict: bool,
    /// Run each imported task's inferred oracle on seeds 0..N in the simulator (here, on this
    /// machine's cores) and say in its mapping report on how many it succeeds, and why it fails
    /// where it does.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub check_oracle: u64,
    /// GenSim: the seeds the task's own reset() lays out, each a layout in the spec (its
    /// scene, goals and plan on that seed): `A..B` ranges and single seeds, comma-separated, or
    /// `none` (every seed starts from seed 0's scene with position jitter). A seed without a
    /// layout is an error of its episode. Default: 0..20,1000000..1000003 (a batch's first 20
    /// seeds and the generalization plan's default held-out seeds).
    #[arg(long, value_name = "SEEDS", value_parser = layout_seeds)]
    pub layout_seeds: Option<Seeds>,
}

/// Seeds as `--layout-seeds` gives them.
#[derive(Debug, Clone)]
pub struct Seeds(pub Vec<u64>);

fn layout_seeds(text: &str) -> Result<Seeds, String> {
    assay_import::parse_seeds(text).map(Seeds)
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut batch = imports::read(
        a.pipeline,
        &a.path,
        a.asset_root.clone(),
        a.layout_seeds.clone().map(|s| s.0),
    )?;
    if a.check_oracle > 0 {
        imports::check_oracles(&mut batch, a.check_oracle);
    }
    out!("{}", batch.report());
    if let Some(out) = &a.out {
        let written = imports::write(&batch, out)?;
        outln!(
            "wrote {written} task spec(s) and import-report.json to {}",
            out.display()
        );
    }
    let failed = imports::failed(&batch);
    Ok(if batch.specs().is_empty() || (a.strict && failed > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}
