//! The trainer role of a worker: text diversity and world-model fits (`assay_trainer::jobs`).

use std::path::Path;
use std::sync::Mutex;

use assay_core::trainer::TrainerJob;
use assay_proto::v1 as pb;
use assay_trainer::embedders::{Config, Embedders};
use assay_worker_runtime::ShardError;

pub struct TrainerRole {
    embedders: Mutex<Embedders>,
    device: tch::Device,
}

impl TrainerRole {
    /// `config`: the worker's configuration file text (its `[embedders.*]`), if any.
    pub fn new(config: Option<&str>) -> Result<Self, String> {
        let config = match config {
            Some(text) => Config::parse(text)?,
            None => Config::default(),
        };
        let device = assay_trainer::default_device();
        tracing::info!(?device, "trainer role ready");
        Ok(Self {
            embedders: Mutex::new(Embedders::new(config, device)),
            device,
        })
    }

    pub fn run(&self, a: &pb::Assignment, root: &Path) -> Result<String, ShardError> {
        let job: TrainerJob = serde_json::from_str(&a.input_json).map_err(|e| {
            ShardError::permanent(format!(
                "trainer shard {}: the job does not parse: {e}",
                a.shard_id
            ))
        })?;
        let outcome =
            assay_trainer::jobs::run(&job, &a.batch_id, root, &self.embedders, self.device)
                .map_err(|e| ShardError {
                    message: e.message,
                    retryable: e.retryable,
                })?;
        serde_json::to_string(&outcome)
            .map_err(|e| ShardError::permanent(format!("trainer outcome: {e}")))
    }
}
