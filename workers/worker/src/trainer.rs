//! The trainer role of a worker: text diversity and world-model fits (`assay_trainer::jobs`).

use std::path::Path;
use std::sync::Mutex;

use assay_embed::{Config, Embedders};
use assay_model::policy::{Policy, PolicyError, PolicySpec};
use assay_model::proxy::ExternalWorldModel;
use assay_model::trainer::TrainerJob;
use assay_model::world::WorldError;
use assay_proto::v1 as pb;
use assay_worker_runtime::ShardError;

pub struct TrainerRole {
    embedders: Mutex<Embedders>,
    device: tch::Device,
    /// Remote policies ranked by the world-model proxy call their servers on this runtime (set
    /// by [`TrainerRole::on`] once the worker's runtime runs).
    runtime: Option<tokio::runtime::Handle>,
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
            runtime: None,
        })
    }

    /// The role, running its remote policies' calls on `runtime`.
    pub fn on(self, runtime: tokio::runtime::Handle) -> Self {
        Self {
            runtime: Some(runtime),
            ..self
        }
    }

    pub fn run(
        &self,
        a: &pb::Assignment,
        root: &Path,
        counters: &crate::telemetry::Counters,
    ) -> Result<String, ShardError> {
        let job: TrainerJob = serde_json::from_str(&a.input_json).map_err(|e| {
            ShardError::permanent(format!(
                "trainer shard {}: the job does not parse: {e}",
                a.shard_id
            ))
        })?;
        // Policy objects ranked by the world-model proxy act in it: built here as a sim worker
        // builds them.
        let policies = |name: &str| -> Result<Box<dyn Policy>, PolicyError> {
            let spec = PolicySpec::parse(name).map_err(PolicyError::Load)?;
            let runtime = self.runtime.as_ref().ok_or_else(|| {
                PolicyError::Load("the trainer role has no runtime for policy calls".into())
            })?;
            assay_policy::load_with(&spec, root, runtime, crate::diffusion_loader())
        };
        // A lab's world model, served over `assay.v1.WorldModel`, when the proxy names one.
        let world_models = |server: &ExternalWorldModel| {
            let runtime = self.runtime.as_ref().ok_or_else(|| {
                WorldError::Unavailable(
                    "the trainer role has no runtime for world-model calls".into(),
                )
            })?;
            assay_policy::world_model::connect(&server.url, server.timeout_ms, runtime)
        };
        // Clips are read where they are: kept by a render worker of this node, else stored.
        let node = crate::kept::NodeArtifacts::open();
        let read = |key: &str| node.read(root, key, counters);
        let outcome = assay_trainer::jobs::run(
            &job,
            &a.batch_id,
            root,
            &read,
            &self.embedders,
            &policies,
            &world_models,
            self.device,
        )
        .map_err(|e| ShardError {
            message: e.message,
            retryable: e.retryable,
        })?;
        serde_json::to_string(&outcome)
            .map_err(|e| ShardError::permanent(format!("trainer outcome: {e}")))
    }
}
