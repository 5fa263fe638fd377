//! `assay submit`: a batch of task specs sent to a running coordinator.

use std::path::PathBuf;
use std::process::ExitCode;

use assay_run::batch::{BatchArgs, default_name};
use assay_run::client::DEFAULT_COORDINATOR;
use assay_run::docs;

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders (walked for .yaml, .yml, .json).
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = DEFAULT_COORDINATOR)]
    pub coordinator: String,
    #[command(flatten)]
    pub batch: BatchArgs,
    /// Do not run the batch if the same tasks (same content hash) were evaluated on this
    /// coordinator before: record it as skipped, a duplicate of that batch.
    #[arg(long)]
    pub skip_if_evaluated: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let tasks = docs::collect(&a.paths)?;
    let roots = docs::asset_roots(&a.paths, &a.batch.asset_roots)?;
    let mut req = a.batch.request(tasks, &default_name(&a.paths));
    req.asset_roots = docs::root_strings(&roots);
    req.skip_if_evaluated = a.skip_if_evaluated;
    assay_run::rt::block_on(async move {
        let mut c = assay_run::client::connect(&a.coordinator).await?;
        let r = assay_run::client::submit(&mut c, req).await?;
        crate::print::rejected(&r.rejected);
        if !r.duplicate_of.is_empty() {
            eprintln!(
                "skipped {}: the same tasks (content {}) were evaluated in batch {}",
                r.batch_id, r.content_hash, r.duplicate_of
            );
            outln!("{}", r.batch_id);
            return Ok(ExitCode::SUCCESS);
        }
        eprintln!(
            "submitted {}: {} tasks accepted, {} rejected, {} shards",
            r.batch_id,
            r.accepted_tasks,
            r.rejected.len(),
            r.shards
        );
        outln!("{}", r.batch_id);
        Ok(ExitCode::SUCCESS)
    })
}
