//! The rows a batch's report is assembled from, as the job store holds them: the batch, its
//! tasks and its shards, each shard with its [`JobKind`] and its outcome decoded once.
//!
//! Owns: the row types, and decoding a stored outcome by the kind of its shard. Never reads a
//! store (the coordinator selects the rows) and never interprets them (that is `assemble`).

use assay_model::episode::{EpisodeOutcome, TaskInfo};
use assay_model::job::{JobKind, ShardState};
use assay_model::proxy::RankingPlan;
use assay_model::quality::JudgeOutcome;
use assay_model::trainer::TrainerOutcome;
use assay_spec::error::SpecError;

/// Everything the store holds that a batch's report is made of.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchRows {
    pub batch: BatchRow,
    /// The batch's tasks, in the order the store gives them (the report's "task order").
    pub tasks: Vec<TaskInfo>,
    /// Every shard of the batch, in the order they were queued.
    pub shards: Vec<ShardRow>,
    /// SHA-256 of the batch's settings as canonical JSON (see `Provenance::config_hash`).
    pub config_hash: String,
}

/// A batch as submitted, and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchRow {
    pub id: String,
    pub name: String,
    /// `running`, `completed`, `cancelled` or `skipped`.
    pub state: String,
    /// The policies it was submitted with (a ladder's learned ones are in its shards).
    pub policies: Vec<String>,
    pub seeds: Vec<u64>,
    /// Tasks it refused, with why.
    pub invalid: Vec<SpecError>,
    pub submitted_ms: i64,
    pub finished_ms: Option<i64>,
    /// Policy ranking, when the batch ranks.
    pub ranking: Option<RankingPlan>,
}

/// One shard.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardRow {
    pub kind: JobKind,
    pub state: ShardState,
    /// Empty for a trainer's shard, which runs no task.
    pub task_id: String,
    pub seed: u64,
    /// Empty for a trainer's shard.
    pub policy: String,
    /// Attempts so far (a lease counts one; a handed-back lease none).
    pub attempts: u32,
    /// A done shard's outcome (`None` while it is open, or when it failed or was cancelled).
    pub outcome: Option<Outcome>,
    /// Why it failed (or, while queued again, why its last attempt did).
    pub error: Option<String>,
    /// The worker that ran it last.
    pub worker: Option<String>,
    /// A judge's shard: the judge.
    pub judge: Option<String>,
    /// The job's name for people ("ladder kitchen @ 10"); `None` for the batch's episodes and
    /// their judging.
    pub job: Option<String>,
    /// The task group of a trainer's shard, of a trained policy's episode and of an imagined
    /// rollout's judging.
    pub group: Option<String>,
}

/// A done shard's outcome, by what the shard does.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Episode(Box<EpisodeOutcome>),
    Judge(Box<JudgeOutcome>),
    Trainer(Box<TrainerOutcome>),
}

impl Outcome {
    /// Decodes the stored outcome JSON of a shard of `kind`.
    pub fn decode(kind: JobKind, json: &str) -> Result<Self, serde_json::Error> {
        Ok(if kind.is_episode() {
            Outcome::Episode(Box::new(serde_json::from_str(json)?))
        } else if kind.is_judging() {
            Outcome::Judge(Box::new(serde_json::from_str(json)?))
        } else {
            Outcome::Trainer(Box::new(serde_json::from_str(json)?))
        })
    }
}

impl ShardRow {
    /// A done episode's outcome.
    pub fn episode(&self) -> Option<&EpisodeOutcome> {
        match &self.outcome {
            Some(Outcome::Episode(o)) => Some(o),
            _ => None,
        }
    }

    /// A done judge shard's outcome.
    pub fn judgement(&self) -> Option<&JudgeOutcome> {
        match &self.outcome {
            Some(Outcome::Judge(o)) => Some(o),
            _ => None,
        }
    }

    /// A done trainer shard's outcome.
    pub fn trained(&self) -> Option<&TrainerOutcome> {
        match &self.outcome {
            Some(Outcome::Trainer(o)) => Some(o),
            _ => None,
        }
    }

    /// Its error, or "" (how the report quotes a failed shard without one).
    pub fn error_text(&self) -> String {
        self.error.clone().unwrap_or_default()
    }
}
