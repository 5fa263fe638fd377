use std::process::ExitCode;

use assay_proto::v1 as pb;

#[derive(clap::Args)]
pub struct Args {
    /// A batch id; without one, every batch is listed.
    pub batch: Option<String>,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Follow the batch until it finishes.
    #[arg(long)]
    pub watch: bool,
}

#[derive(clap::Args)]
pub struct CancelArgs {
    pub batch: String,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
}

pub fn line(s: &pb::BatchStatus) -> String {
    if !s.duplicate_of.is_empty() {
        return format!(
            "{}  {:<9}  repeats {} (content {})  {}",
            s.batch_id,
            super::state_name(s.state),
            s.duplicate_of,
            s.content_hash.get(..12).unwrap_or(&s.content_hash),
            s.name
        );
    }
    let judged = if s.judge_total > 0 {
        format!(
            "  {}/{} judged (${:.4})",
            s.judge_done + s.judge_failed,
            s.judge_total,
            s.judge_cost_usd
        )
    } else {
        String::new()
    };
    let judged = if s.trainer_total > 0 {
        format!(
            "{judged}  {}/{} trained",
            s.trainer_done + s.trainer_failed,
            s.trainer_total
        )
    } else {
        judged
    };
    // Work no connected worker can take, on lines of their own.
    let waiting: String = s
        .waiting
        .iter()
        .map(|w| format!("\n  waiting: {w}"))
        .collect();
    format!(
        "{}  {:<9}  {}/{} done  {} ok  {} failed  {} running  {} queued  {} cancelled  {} invalid tasks{judged}  {} workers  {}{waiting}",
        s.batch_id,
        super::state_name(s.state),
        s.shards_done + s.shards_failed + s.shards_cancelled,
        s.shards_total,
        s.successes,
        s.shards_failed,
        s.shards_running,
        s.shards_queued,
        s.shards_cancelled,
        s.invalid_tasks,
        s.workers_connected,
        s.name
    )
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    super::block_on(async move {
        let mut c = super::client(&a.coordinator).await?;
        match a.batch {
            None => {
                for b in c
                    .list_batches(pb::ListBatchesRequest {})
                    .await?
                    .into_inner()
                    .batches
                {
                    println!("{}", line(&b));
                }
            }
            Some(id) if a.watch => {
                let mut stream = c
                    .watch_batch(pb::GetBatchRequest { batch_id: id })
                    .await?
                    .into_inner();
                while let Some(s) = stream.message().await? {
                    println!("{}", line(&s));
                }
            }
            Some(id) => println!(
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
    super::block_on(async move {
        let mut c = super::client(&a.coordinator).await?;
        println!(
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
