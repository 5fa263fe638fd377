use std::path::PathBuf;
use std::process::ExitCode;

use assay_proto::v1 as pb;

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders (walked for .yaml, .yml, .json).
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    #[command(flatten)]
    pub batch: BatchArgs,
}

#[derive(clap::Args, Clone)]
pub struct BatchArgs {
    /// Seeds 0..N per task and policy.
    #[arg(long, default_value_t = 5)]
    pub seeds: u64,
    /// Explicit seeds (overrides --seeds).
    #[arg(long, value_delimiter = ',')]
    pub seed_list: Vec<u64>,
    /// Policies (oracle, oracle:noise=0.01).
    #[arg(long = "policy", default_value = "oracle")]
    pub policies: Vec<String>,
    /// A name for the batch (shown in reports).
    #[arg(long)]
    pub name: Option<String>,
    /// Attempts per shard before it is recorded as failed (0: coordinator default).
    #[arg(long, default_value_t = 0)]
    pub max_attempts: u32,
    /// Judges that score every rendered episode (names from the judge workers' configuration;
    /// `offline` is built in). Repeat or separate with commas.
    #[arg(long = "judge", value_delimiter = ',')]
    pub judges: Vec<String>,
    /// Times each judge item (scene alignment, completion) is asked.
    #[arg(long, default_value_t = assay_core::quality::DEFAULT_REPEATS)]
    pub judge_repeats: u32,
    /// Stop making judge calls once this batch's judges have spent this many USD (0: no limit).
    #[arg(long, default_value_t = 0.0)]
    pub judge_budget_usd: f64,
}

impl BatchArgs {
    pub fn request(
        &self,
        tasks: Vec<pb::TaskDocument>,
        default_name: &str,
    ) -> pb::SubmitBatchRequest {
        let seeds = if self.seed_list.is_empty() {
            (0..self.seeds).collect()
        } else {
            self.seed_list.clone()
        };
        pb::SubmitBatchRequest {
            name: self.name.clone().unwrap_or_else(|| default_name.to_owned()),
            tasks,
            policies: self
                .policies
                .iter()
                .map(|p| pb::PolicyRef { name: p.clone() })
                .collect(),
            seeds,
            max_attempts: self.max_attempts,
            judges: self.judges.clone(),
            judge_repeats: self.judge_repeats,
            judge_budget_usd: self.judge_budget_usd,
        }
    }
}

pub fn default_name(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(" + ")
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let docs = crate::docs::collect(&a.paths)?;
    let req = a.batch.request(docs, &default_name(&a.paths));
    super::block_on(async move {
        let mut c = super::client(&a.coordinator).await?;
        let r = c.submit_batch(req).await?.into_inner();
        super::print_rejected(&r.rejected);
        eprintln!(
            "submitted {}: {} tasks accepted, {} rejected, {} shards",
            r.batch_id,
            r.accepted_tasks,
            r.rejected.len(),
            r.shards
        );
        println!("{}", r.batch_id);
        Ok(ExitCode::SUCCESS)
    })
}
