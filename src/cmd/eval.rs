//! `assay eval`: the embedded default. A local cluster (a coordinator, sim workers, a judge and a
//! trainer worker on loopback) runs the batch with live progress, and the report lands in the
//! output folder; the run itself is `assay_run::eval`'s.

use std::process::ExitCode;

use assay_run::eval::{EvalArgs, Outcome};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub eval: EvalArgs,
    /// Exit non-zero if any task was invalid or any episode failed with an error.
    #[arg(long, help_heading = "Output")]
    pub strict: bool,
    /// No progress bar (logs a line per change instead).
    #[arg(long, help_heading = "Output")]
    pub quiet: bool,
}

/// Runs the batch. `resolved` is the run's resolved configuration (`crate::config::resolved`),
/// written to OUT/config.toml once the folder is claimed.
pub fn run(a: Args, resolved: Option<String>) -> anyhow::Result<ExitCode> {
    let out = a.eval.out.clone();
    let mut terminal = crate::progress::Terminal::new(a.quiet);
    let outcome = assay_run::eval::run(a.eval, resolved, &mut terminal)?;
    for line in crate::print::ranking_lines(&outcome.report) {
        outln!("{line}");
    }
    let again = "the report holds what finished; run the same command again to go on from the \
                 job store";
    let Outcome { last, exited, .. } = &outcome;
    if let (Some(why), None) = (exited, last) {
        eprintln!("{why}: {again}");
        return Ok(ExitCode::FAILURE);
    }
    let Some(last) = last else {
        anyhow::bail!("no status from the coordinator");
    };
    eprintln!(
        "{}: {}/{} episodes completed, {} succeeded, {} failed; report in {} (and report.md, report.json)",
        crate::print::state_name(last.state),
        last.shards_done,
        last.shards_total,
        last.successes,
        last.shards_failed,
        out.join("report.html").display()
    );
    if let Some(why) = exited {
        eprintln!("{why}: {again}");
        return Ok(ExitCode::FAILURE);
    }
    Ok(if outcome.succeeded(a.strict) {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
