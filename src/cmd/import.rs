//! `assay import gensim|robogen|bbsea PATH`: a generator's own output → task spec v1 files, with
//! the per-task mapping report (what was mapped, inferred, left out, and why a task was not
//! imported). `assay eval --import PIPELINE PATH` runs the same import before evaluating.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use assay_import::{Import, ImportOptions, Pipeline, import, spec_to_yaml};
use assay_proto::v1 as pb;

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
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let batch = read(a.pipeline, &a.path, a.asset_root.clone())?;
    print!("{}", batch.report());
    if let Some(out) = &a.out {
        let written = write(&batch, out)?;
        println!(
            "wrote {written} task spec(s) and import-report.json to {}",
            out.display()
        );
    }
    let failed = failed(&batch);
    Ok(if batch.specs().is_empty() || (a.strict && failed > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

/// Imports a batch, failing only when nothing under `path` can be read at all.
pub fn read(
    pipeline: Pipeline,
    path: &Path,
    asset_root: Option<PathBuf>,
) -> anyhow::Result<Import> {
    anyhow::ensure!(path.exists(), "{}: no such file or folder", path.display());
    let batch = import(pipeline, path, &ImportOptions { asset_root });
    anyhow::ensure!(
        !batch.tasks.is_empty() || !batch.errors.is_empty(),
        "no {pipeline} tasks found under {}",
        path.display()
    );
    Ok(batch)
}

/// Tasks that could not be imported, and batch-level errors.
pub fn failed(batch: &Import) -> usize {
    batch.tasks.iter().filter(|t| t.spec.is_none()).count() + batch.errors.len()
}

/// Writes every imported spec (`ID.yaml`) and `import-report.json` to `out`.
pub fn write(batch: &Import, out: &Path) -> anyhow::Result<usize> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let specs = batch.specs();
    for spec in &specs {
        let file = out.join(format!("{}.yaml", spec.id));
        std::fs::write(&file, spec_to_yaml(spec))
            .with_context(|| format!("writing {}", file.display()))?;
    }
    let report = out.join("import-report.json");
    std::fs::write(&report, serde_json::to_vec_pretty(batch)?)
        .with_context(|| format!("writing {}", report.display()))?;
    Ok(specs.len())
}

/// The imported specs as task documents for a batch (origin: the source file).
pub fn documents(batch: &Import) -> Vec<pb::TaskDocument> {
    batch
        .specs()
        .into_iter()
        .map(|spec| pb::TaskDocument {
            origin: spec
                .source
                .origin
                .clone()
                .unwrap_or_else(|| spec.id.clone()),
            format: "yaml".into(),
            content: spec_to_yaml(spec),
        })
        .collect()
}
