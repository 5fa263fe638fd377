//! `assay validate`: task specs checked exactly as the coordinator's planner checks them.

use std::path::PathBuf;
use std::process::ExitCode;

use assay_run::docs;

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// A folder the tasks may read asset files from, besides the task paths (repeatable;
    /// default: the working folder).
    #[arg(long = "asset-root", value_name = "DIR")]
    pub asset_roots: Vec<PathBuf>,
}

/// Checks documents exactly as the coordinator's planner does (duplicate ids included).
pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let tasks = docs::collect(&a.paths)?;
    let roots = docs::asset_roots(&a.paths, &a.asset_roots)?;
    let (planned, errors) = assay_plan::plan_tasks(&tasks, &roots);
    for e in &errors {
        eprintln!("{e}");
    }
    let bad: std::collections::BTreeSet<_> = errors.iter().map(|e| (&e.origin, &e.task)).collect();
    eprintln!("{} valid, {} invalid", planned.len(), bad.len());
    Ok(if errors.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
