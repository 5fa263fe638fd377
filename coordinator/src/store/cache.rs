//! What a lease and a completion read of a batch that never changes once it is submitted, kept
//! in memory: its share settings, its judges' repeats and budget, its clip size, whether it
//! renders or has a plan after its episodes, and its tasks' specs.
//!
//! A batch's row holds its seeds as JSON (100,000 seeds: about 600 KB), and the columns added
//! since the first release come after it, so every read of one of them walked the seeds' chain
//! of overflow pages; a task's spec is kilobytes of overflow pages of its own. A lease read both
//! for every shard it took, and a completion the batch's plans. Read once per batch now.
//!
//! Only what no statement changes after the batch's submission is kept (its state and counts
//! are always read from the file). A batch id is taken again only if the submission that took
//! it was rolled back — a group that failed to commit, after which the store clears the cache
//! ([`Cache::clear`]). A batch is forgotten when it ends ([`Cache::forget`]).
//!
//! Owns: the cached values and reading them on first use. Never: anything that changes.

use std::collections::HashMap;
use std::sync::Arc;

use assay_model::job::Priority;
use rusqlite::{Connection, OptionalExtension};

use super::Share;
use crate::error::CoordError;

/// A submitted batch's settings, as leasing and completion read them.
#[derive(Debug, Clone)]
pub(super) struct BatchInfo {
    pub share: Share,
    pub judge_repeats: u32,
    pub judge_budget_usd: Option<f64>,
    /// The frame size of the clips its world models or policies learn from (None: no clips).
    pub clip_size: Option<i64>,
    /// The policy interface of its clips (a ranking's `config.interface`; empty: the original).
    pub clip_interface: String,
    /// Every episode is rendered.
    pub render: bool,
    /// It has work planned after its episodes (dynamics, ranking or generalization).
    pub planned: bool,
}

#[derive(Debug, Default)]
pub(super) struct Cache {
    batches: HashMap<String, Arc<BatchInfo>>,
    /// A task's spec JSON, by batch and task id.
    specs: HashMap<String, HashMap<String, Arc<str>>>,
}

impl Cache {
    /// Forgets what was read of `batch` (it ended: nothing of it is leased again).
    pub fn forget(&mut self, batch: &str) {
        self.batches.remove(batch);
        self.specs.remove(batch);
    }

    /// Forgets everything (the file changed under the store, e.g. a failed group rolled back).
    pub fn clear(&mut self) {
        self.batches.clear();
        self.specs.clear();
    }

    /// `batch`'s settings, read from `conn` the first time.
    pub fn batch(&mut self, conn: &Connection, batch: &str) -> Result<Arc<BatchInfo>, CoordError> {
        if let Some(info) = self.batches.get(batch) {
            return Ok(info.clone());
        }
        let info = conn
            .prepare_cached(
                "SELECT priority, submitter, max_workers, judge_repeats, judge_budget_usd,
                        COALESCE(json_extract(dynamics_json, '$.config.image_size'),
                                 json_extract(ranking_json, '$.config.world_model.image_size'),
                                 json_extract(generalization_json, '$.config.image_size')),
                        render,
                        dynamics_json IS NOT NULL OR ranking_json IS NOT NULL
                          OR generalization_json IS NOT NULL,
                        COALESCE(json_extract(ranking_json, '$.config.interface'), '')
                 FROM batches WHERE id = ?1",
            )?
            .query_row([batch], |r| {
                Ok(BatchInfo {
                    share: Share {
                        priority: r.get::<_, String>(0)?.parse().unwrap_or(Priority::Normal),
                        submitter: r.get(1)?,
                        max_workers: r.get(2)?,
                    },
                    judge_repeats: r.get(3)?,
                    judge_budget_usd: r.get(4)?,
                    clip_size: r.get(5)?,
                    render: r.get(6)?,
                    planned: r.get(7)?,
                    clip_interface: r.get(8)?,
                })
            })
            .optional()?
            .ok_or_else(|| CoordError::NotFound(format!("batch '{batch}'")))?;
        let info = Arc::new(info);
        self.batches.insert(batch.to_owned(), info.clone());
        Ok(info)
    }

    /// The spec JSON of `task` in `batch` (empty when the task has no row), read from `conn` the
    /// first time.
    pub fn spec(
        &mut self,
        conn: &Connection,
        batch: &str,
        task: &str,
    ) -> Result<Arc<str>, CoordError> {
        if let Some(spec) = self.specs.get(batch).and_then(|t| t.get(task)) {
            return Ok(spec.clone());
        }
        let spec: Arc<str> = conn
            .prepare_cached("SELECT spec_json FROM tasks WHERE batch_id = ?1 AND task_id = ?2")?
            .query_row([batch, task], |r| r.get::<_, String>(0))
            .optional()?
            .unwrap_or_default()
            .into();
        self.specs
            .entry(batch.to_owned())
            .or_default()
            .insert(task.to_owned(), spec.clone());
        Ok(spec)
    }
}
