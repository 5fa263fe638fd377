//! The judge role: scores judge shards with the judges of the worker's configuration (the
//! built-in offline judge, or VLMs behind OpenAI-compatible endpoints), on the worker's runtime.
//!
//! Owns: building judges on first use and sharing them between shards, storing transcripts.
//! Never renders and never talks to the coordinator.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use assay_proto::v1 as pb;
use assay_spec::spec::TaskSpec;
use assay_worker_runtime::{ShardError, artifacts};

use crate::io_error;
use crate::telemetry::Counters;

/// The judge role: scores judge shards with the judges of the configuration.
pub(crate) struct JudgeRole {
    pub(crate) config: assay_judge::Config,
    /// Where the configuration came from, for errors.
    pub(crate) origin: String,
    /// Judges are built on first use and shared by the shards (their endpoints hold the
    /// concurrency and rate limits).
    pub(crate) judges: std::sync::Mutex<std::collections::HashMap<String, Arc<assay_judge::Judge>>>,
    pub(crate) runtime: tokio::runtime::Handle,
    pub(crate) worker_id: String,
    pub(crate) counters: Arc<Counters>,
}

impl JudgeRole {
    pub(crate) fn judge(&self, name: &str) -> Result<Arc<assay_judge::Judge>, ShardError> {
        let mut judges = self.judges.lock().expect("judges");
        if let Some(j) = judges.get(name) {
            return Ok(j.clone());
        }
        let cfg = self.config.judge(name).ok_or_else(|| {
            ShardError::permanent(format!(
                "judge '{name}' is not configured on worker {} ({}; configured: {})",
                self.worker_id,
                self.origin,
                self.config.names().join(", ")
            ))
        })?;
        let judge = Arc::new(
            assay_judge::Judge::new(name, &cfg)
                .map_err(|e| ShardError::permanent(e.to_string()))?,
        );
        judges.insert(name.to_owned(), judge.clone());
        Ok(judge)
    }

    pub(crate) fn run(&self, a: &pb::Assignment, root: &Path) -> Result<String, ShardError> {
        let spec: TaskSpec = serde_json::from_str(&a.task_spec_json).map_err(|e| {
            ShardError::permanent(format!(
                "task spec from the coordinator does not parse: {e}"
            ))
        })?;
        let episode: assay_model::episode::EpisodeOutcome = serde_json::from_str(&a.input_json)
            .map_err(|e| {
                ShardError::permanent(format!(
                    "task {}: the episode to judge does not parse: {e}",
                    spec.id
                ))
            })?;
        let judge = self.judge(&a.judge)?;
        let artifacts = assay_judge::Artifacts::new(root, held_on_this_node(&episode));
        let judged = self
            .runtime
            .block_on(judge.judge(
                &episode,
                &spec.description,
                a.judge_repeats,
                a.budget_left_usd,
                &artifacts,
            ))
            .map_err(|e| {
                let msg = format!("task {} seed {}: judge '{}': {e}", spec.id, a.seed, a.judge);
                match e {
                    assay_judge::JudgeError::Permanent(_) => ShardError::permanent(msg),
                    assay_judge::JudgeError::Retryable(_) => ShardError::retryable(msg),
                }
            })?;
        let mut outcome = judged.outcome;
        outcome.transcript = Some(
            artifacts::put(root, "judge", "json", &judged.transcript).map_err(io_error("judge"))?,
        );
        let (shared, stored) = artifacts.reads();
        self.counters
            .frames_shared
            .fetch_add(u64::from(shared), Ordering::Relaxed);
        self.counters
            .frames_stored
            .fetch_add(u64::from(stored), Ordering::Relaxed);
        self.counters.judged.fetch_add(1, Ordering::Relaxed);
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

/// The episode's pictures and caption that a process of this node keeps in memory (the render
/// role that drew them). One process keeps all of an episode's pictures: after one miss the rest
/// are read from the artifact store without asking again.
fn held_on_this_node(
    episode: &assay_model::episode::EpisodeOutcome,
) -> std::collections::HashMap<String, Vec<u8>> {
    let mut held = std::collections::HashMap::new();
    let Some(imagery) = &episode.imagery else {
        return held;
    };
    let keys = imagery
        .views
        .iter()
        .map(|v| v.artifact.as_str())
        .chain(imagery.keyframes.iter().map(|k| k.artifact.as_str()))
        .chain(imagery.caption.as_deref());
    let node = crate::kept::NodeArtifacts::open();
    for key in keys {
        match node.kept(key) {
            Some(bytes) => {
                held.insert(key.to_owned(), bytes);
            }
            None => break,
        }
    }
    held
}
