//! `assay token derive --role worker` / `--service policy`: prints a key derived from the
//! cluster token in `$ASSAY_CLUSTER_TOKEN` (or the file `$ASSAY_CLUSTER_TOKEN_FILE` names), for
//! an operator to hand out. The cluster token is read from the environment only, never from a
//! flag (flags show in `ps`); what is printed is the derived key alone, on one line.

use std::process::ExitCode;

use anyhow::Context;
use assay_proto::auth::{Access, Token};

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: TokenCommand,
}

#[derive(clap::Subcommand)]
pub enum TokenCommand {
    /// Print a role's key (worker, submitter, viewer) or a service's secret (policy,
    /// world-model), derived from the cluster token in the environment.
    Derive {
        /// The role whose key to print: worker (WorkerSession), submitter (submit, cancel and
        /// read), viewer (status, reports, telemetry).
        #[arg(long, conflicts_with = "service", required_unless_present = "service")]
        role: Option<String>,
        /// The service whose secret to print: policy (policy servers), world-model.
        #[arg(long)]
        service: Option<String>,
    },
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let TokenCommand::Derive { role, service } = a.command;
    let token = Token::from_env()
        .map_err(anyhow::Error::msg)?
        .context("no cluster token: set ASSAY_CLUSTER_TOKEN or ASSAY_CLUSTER_TOKEN_FILE")?;
    let key = match (role, service) {
        (Some(role), _) => {
            let access = Access::parse_role(&role)
                .with_context(|| format!("--role {role}: expected worker, submitter or viewer"))?;
            token.role_key(access)
        }
        (None, Some(service)) => {
            anyhow::ensure!(
                matches!(service.as_str(), "policy" | "world-model"),
                "--service {service}: expected policy or world-model"
            );
            token.for_service(&service)
        }
        (None, None) => unreachable!("clap requires --role or --service"),
    };
    outln!("{}", key.expose());
    Ok(ExitCode::SUCCESS)
}
