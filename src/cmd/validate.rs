use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
}

/// Checks documents exactly as the coordinator's planner does (duplicate ids included).
pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let docs = crate::docs::collect(&a.paths)?;
    let (planned, errors) = assay_coordinator::service::plan_tasks(&docs);
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
