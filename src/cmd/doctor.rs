//! `assay doctor`: checks what this machine needs to run Assay's roles, and says what to fix
//! (the checks are `assay_run::doctor`'s).

use std::path::PathBuf;
use std::process::ExitCode;

use assay_run::doctor::{Verdict, checks};

#[derive(clap::Args)]
pub struct Args {
    /// Configuration file: its judges' endpoints are checked for reachability.
    #[arg(long, env = "ASSAY_CONFIG")]
    pub config: Option<PathBuf>,
    /// Also check that this coordinator answers (`http://host:7878`).
    #[arg(long)]
    pub coordinator: Option<String>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let checks = checks(a.config.as_deref(), a.coordinator.as_deref());
    let failed = checks.iter().any(|c| c.verdict == Verdict::Fail);
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&checks)?);
    } else {
        for c in &checks {
            let mark = match c.verdict {
                Verdict::Ok => "ok  ",
                Verdict::Warn => "warn",
                Verdict::Fail => "FAIL",
            };
            outln!("{mark} {} ({}): {}", c.name, c.needed_by, c.detail);
            if !c.fix.is_empty() {
                outln!("     fix: {}", c.fix);
            }
        }
        outln!(
            "{}",
            if failed {
                "Some checks failed: the roles named beside them cannot run here until fixed."
            } else {
                "Everything Assay needs is here."
            }
        );
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}
