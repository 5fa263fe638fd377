//! `assay report`: a batch's report bundle (report.json, report.md, report.html, episodes.parquet
//! and the figures) fetched from a coordinator, or written again from a report.json; the bundle is
//! `assay_run::bundle`'s.

use std::path::PathBuf;
use std::process::ExitCode;

use assay_run::bundle::{self, HumanArgs};
use assay_run::client::DEFAULT_COORDINATOR;

#[derive(clap::Args)]
pub struct Args {
    /// The batch whose report the coordinator builds (or --from a report.json).
    #[arg(required_unless_present = "from", conflicts_with = "from")]
    pub batch: Option<String>,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Write report.md and report.html again from this report.json, without a coordinator.
    #[arg(long, value_name = "REPORT_JSON")]
    pub from: Option<PathBuf>,
    /// Folder for report.json, report.md, report.html and the figures (default: beside the
    /// report.json of --from, or `report-BATCH` for a coordinator's batch). A folder holding
    /// another batch's report is refused unless --force.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write into --out even when it holds the report of another batch.
    #[arg(long)]
    pub force: bool,
    /// The artifact store, for the scene views and keyframes in report.html (default: the
    /// `artifacts` folder beside the report, where `assay eval` puts it).
    #[arg(long, env = "ASSAY_ARTIFACTS")]
    pub artifacts: Option<PathBuf>,
    #[command(flatten)]
    pub human: HumanArgs,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let human = a.human.table()?;
    if let Some(from) = &a.from {
        let out = bundle::rewrite(
            from,
            a.out.as_deref(),
            a.artifacts.as_deref(),
            a.force,
            human.as_ref(),
        )?;
        eprintln!(
            "wrote report.json, report.md and report.html in {}",
            out.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let batch = a.batch.clone().unwrap_or_default();
    let (out, final_) = assay_run::rt::block_on(bundle::fetch(
        &a.coordinator,
        &batch,
        a.out.as_deref(),
        a.artifacts.as_deref(),
        a.force,
        human.as_ref(),
    ))?;
    eprintln!(
        "wrote report.json, report.md and report.html in {}{}",
        out.display(),
        if final_ {
            ""
        } else {
            " (partial: the batch is still running)"
        }
    );
    Ok(ExitCode::SUCCESS)
}
