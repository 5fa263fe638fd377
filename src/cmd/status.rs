//! `assay status` and `assay cancel`: a batch's status (or every batch's), followed until it
//! finishes with `--watch`; cancelling a batch.

use std::process::ExitCode;

use assay_proto::v1 as pb;
use assay_run::client::DEFAULT_COORDINATOR;

use crate::print::status_line as line;

#[derive(clap::Args)]
pub struct Args {
    /// A batch id; without one, every batch is listed.
    pub batch: Option<String>,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Follow the batch until it finishes.
    #[arg(long)]
    pub watch: bool,
}

#[derive(clap::Args)]
pub struct CancelArgs {
    pub batch: String,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = DEFAULT_COORDINATOR)]
    pub coordinator: String,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    assay_run::rt::block_on(async move {
        let mut c = assay_run::client::connect(&a.coordinator).await?;
        match a.batch {
            None => {
                for b in c
                    .list_batches(pb::ListBatchesRequest {})
                    .await?
                    .into_inner()
                    .batches
                {
                    outln!("{}", line(&b));
                }
            }
            Some(id) if a.watch => {
                let mut stream = c
                    .watch_batch(pb::GetBatchRequest { batch_id: id })
                    .await?
                    .into_inner();
                while let Some(s) = stream.message().await? {
                    outln!("{}", line(&s));
                    // `| head`: nothing reads the lines any more.
                    if crate::print::stdout_closed() {
                        break;
                    }
                }
            }
            Some(id) => outln!(
                "{}",
                line(
                    &c.get_batch(pb::GetBatchRequest { batch_id: id })
                        .await?
                        .into_inner()
                )
            ),
        }
        Ok(ExitCode::SUCCESS)
    })
}

pub fn cancel(a: CancelArgs) -> anyhow::Result<ExitCode> {
    assay_run::rt::block_on(async move {
        let mut c = assay_run::client::connect(&a.coordinator).await?;
        outln!(
            "{}",
            line(
                &c.cancel_batch(pb::GetBatchRequest { batch_id: a.batch })
                    .await?
                    .into_inner()
            )
        );
        Ok(ExitCode::SUCCESS)
    })
}
