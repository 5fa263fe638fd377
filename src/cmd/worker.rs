use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::bail;
use assay_core::spec::TaskSpec;
use assay_proto::v1 as pb;
use assay_worker_runtime::{ShardError, ShardHandler, WorkerConfig, default_worker_id, run_worker};

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Comma-separated roles: sim (render, judge and trainer come with later releases).
    #[arg(long, default_value = "sim", value_delimiter = ',')]
    pub roles: Vec<String>,
    /// Shards run at once.
    #[arg(long, env = "ASSAY_CAPACITY", default_value_t = 1)]
    pub capacity: u32,
    /// Node id (defaults to the host name).
    #[arg(long, env = "ASSAY_NODE_ID")]
    pub node_id: Option<String>,
    /// Worker id (defaults to <node>/<pid>).
    #[arg(long)]
    pub worker_id: Option<String>,
}

/// The sim role behind the worker runtime's trait.
struct SimRole;

impl ShardHandler for SimRole {
    fn run(&self, a: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError> {
        let spec: TaskSpec = serde_json::from_str(&a.task_spec_json).map_err(|e| {
            ShardError::permanent(format!(
                "task spec from the coordinator does not parse: {e}"
            ))
        })?;
        let policy = a
            .policy
            .as_ref()
            .map(|p| p.name.as_str())
            .unwrap_or("oracle");
        let outcome =
            assay_sim::run_episode(&spec, a.seed, policy, artifact_root).map_err(|e| {
                let msg = format!("task {}: {e}", spec.id);
                if e.retryable() {
                    ShardError::retryable(msg)
                } else {
                    ShardError::permanent(msg)
                }
            })?;
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut roles = Vec::new();
    for r in &a.roles {
        match pb::Role::parse(r) {
            Some(pb::Role::Sim) => roles.push(pb::Role::Sim),
            Some(other) => bail!(
                "role '{}' is not available in this build (sim only)",
                other.name()
            ),
            None => bail!("unknown role '{r}' (sim, render, judge, trainer)"),
        }
    }
    let node_id = a.node_id.unwrap_or_else(|| {
        std::fs::read_to_string("/etc/hostname")
            .map(|s| s.trim().to_owned())
            .unwrap_or_else(|_| "local".into())
    });
    let mut versions = assay_sim::versions();
    versions.insert("assay".into(), env!("CARGO_PKG_VERSION").into());
    let config = WorkerConfig {
        coordinator: a.coordinator,
        worker_id: a.worker_id.unwrap_or_else(|| default_worker_id(&node_id)),
        node_id,
        roles,
        capacity: a.capacity.max(1),
        versions,
        max_backoff: Duration::from_secs(2),
        give_up_after: None,
    };
    super::block_on(async move {
        run_worker(config, Arc::new(SimRole), super::terminated()).await?;
        Ok(ExitCode::SUCCESS)
    })
}
