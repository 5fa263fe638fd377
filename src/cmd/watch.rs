//! `assay watch DIR`: continuous evaluation. Every batch (a sub-folder of task specs) that lands
//! in DIR is evaluated once it has stopped changing, a repeat is skipped, each evaluated batch
//! gets its marginal text diversity, and a corpus report accumulates; the watch itself is
//! `assay_run::watch`'s.

use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub watch: assay_run::watch::WatchArgs,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut terminal = crate::progress::Terminal::new(true);
    assay_run::watch::run(a.watch, &mut terminal)?;
    Ok(ExitCode::SUCCESS)
}
