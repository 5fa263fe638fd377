//! The read model: what the store tells about its batches.
//!
//! Owns: a batch's counts, the lists of batches, and the rows its report is assembled from
//! (partial while the batch runs), with the hash of the batch's settings. Never writes, and never
//! interprets rows into a report (`assay_report::assemble` does).

use assay_model::episode::TaskInfo;
use assay_model::job::{JobKind, ShardState};
use assay_report::rows::{BatchRow, BatchRows, Outcome, ShardRow};
use assay_spec::SpecError;
use rusqlite::OptionalExtension;

use super::shard_state::{CANCELLED, DONE, FAILED, LEASED, QUEUED};
use super::{BatchCounts, Store, role};
use crate::error::CoordError;

/// What the coordinator's reports say built them (`Provenance::assay_version`).
pub const REPORT_GENERATOR: &str = concat!("assay-coordinator ", env!("CARGO_PKG_VERSION"));

impl Store {
    /// The queued shards of a batch (every running batch when `None`) by what they need of a
    /// worker, as `(needs, count)`.
    pub fn queued_needs(
        &self,
        batch_id: Option<&str>,
    ) -> Result<Vec<(Vec<String>, u32)>, CoordError> {
        let mut stmt = self.conn.prepare_cached(
            // The running batches first, then each one's queued shards from `shards_waiting`.
            "SELECT COALESCE(s.needs, json_array(s.role)) AS nd, COUNT(*)
             FROM batches b CROSS JOIN shards s ON s.batch_id = b.id
             WHERE s.state = 'queued' AND b.state = 'running' AND (?1 IS NULL OR b.id = ?1)
             GROUP BY nd ORDER BY nd",
        )?;
        let rows = stmt.query_map([batch_id], |r| {
            Ok((r.get::<_, String>(0)?, r.get::<_, u32>(1)?))
        })?;
        let mut out = Vec::new();
        for row in rows {
            let (needs, n) = row?;
            out.push((serde_json::from_str(&needs)?, n));
        }
        Ok(out)
    }

    pub fn counts(&self, batch_id: &str) -> Result<BatchCounts, CoordError> {
        let mut c: BatchCounts = self
            .conn
            .query_row(
                "SELECT id, name, state, submitted_ms, finished_ms, invalid_json, content_hash, duplicate_of FROM batches WHERE id = ?1",
                [batch_id],
                |r| {
                    let invalid: String = r.get(5)?;
                    let invalid: Vec<SpecError> = serde_json::from_str(&invalid).unwrap_or_default();
                    let distinct: std::collections::BTreeSet<_> =
                        invalid.iter().map(|e| (e.origin.clone(), e.task.clone())).collect();
                    Ok(BatchCounts {
                        id: r.get(0)?,
                        name: r.get(1)?,
                        state: r.get(2)?,
                        submitted_ms: r.get(3)?,
                        finished_ms: r.get(4)?,
                        invalid_tasks: distinct.len() as u32,
                        content_hash: r.get(6)?,
                        duplicate_of: r.get(7)?,
                        ..Default::default()
                    })
                },
            )
            .optional()?
            .ok_or_else(|| CoordError::NotFound(format!("batch '{batch_id}'")))?;
        let mut stmt = self.conn.prepare(
            "SELECT state, role, COUNT(*) FROM shards WHERE batch_id = ?1 GROUP BY state, role",
        )?;
        let rows = stmt.query_map([batch_id], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, u32>(2)?,
            ))
        })?;
        for row in rows {
            let (state, shard_role, n) = row?;
            if shard_role == role::TRAINER {
                c.trainer_total += n;
                match state.as_str() {
                    DONE => c.trainer_done = n,
                    FAILED => c.trainer_failed = n,
                    _ => {}
                }
                continue;
            }
            if shard_role == role::JUDGE {
                c.judge_total += n;
                match state.as_str() {
                    DONE => c.judge_done = n,
                    FAILED => c.judge_failed = n,
                    _ => {}
                }
                continue;
            }
            c.total += n;
            match state.as_str() {
                QUEUED => c.queued = n,
                LEASED => c.leased = n,
                DONE => c.done = n,
                FAILED => c.failed = n,
                CANCELLED => c.cancelled = n,
                _ => {}
            }
        }
        c.successes = self.conn.query_row(
            "SELECT COUNT(*) FROM shards WHERE batch_id = ?1 AND role NOT IN ('judge', 'trainer') AND state = 'done'
             AND json_extract(outcome_json, '$.success') = 1",
            [batch_id],
            |r| r.get(0),
        )?;
        c.judge_cost_usd = Self::judge_spent(&self.conn, batch_id)?;
        c.share = super::fair::share(&self.conn, batch_id)?;
        Ok(c)
    }

    /// SHA-256 of a batch's settings as canonical JSON (see `Provenance::config_hash`).
    fn config_hash(&self, batch_id: &str) -> Result<String, CoordError> {
        let settings: serde_json::Value = self.conn.query_row(
            "SELECT json_object('policies', json(policies_json), 'seeds', json(seeds_json),
                    'max_attempts', max_attempts, 'judges', json(judges_json),
                    'judge_repeats', judge_repeats, 'judge_budget_usd', judge_budget_usd,
                    'text_models', json(text_models_json), 'dynamics', json(dynamics_json),
                    'ranking', json(ranking_json), 'generalization', json(generalization_json))
             FROM batches WHERE id = ?1",
            [batch_id],
            |r| {
                let text: String = r.get(0)?;
                Ok(serde_json::from_str(&text).unwrap_or(serde_json::Value::Null))
            },
        )?;
        // serde_json's maps are sorted by key: the same settings give the same text.
        Ok(assay_spec::hash::sha256_hex(
            settings.to_string().as_bytes(),
        ))
    }

    /// The task specs of a batch as it stored them (canonical JSON), by task id, in task order.
    pub fn task_specs(&self, batch_id: &str) -> Result<Vec<(String, String)>, CoordError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT task_id, spec_json FROM tasks WHERE batch_id = ?1 ORDER BY rowid",
        )?;
        let rows = stmt.query_map([batch_id], |r| Ok((r.get(0)?, r.get(1)?)))?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    pub fn batch_ids(&self) -> Result<Vec<String>, CoordError> {
        let mut stmt = self.conn.prepare("SELECT id FROM batches ORDER BY seq")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    /// Batches still running (after a restart, these carry on).
    pub fn running_batches(&self) -> Result<Vec<String>, CoordError> {
        let mut stmt = self
            .conn
            .prepare("SELECT id FROM batches WHERE state = 'running' ORDER BY seq")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    /// What the batch's report is assembled from (`assay_report::assemble::report`): its row,
    /// its tasks and its shards, each shard's outcome decoded once, and its settings' hash.
    pub fn batch_rows(&self, batch_id: &str) -> Result<BatchRows, CoordError> {
        Ok(BatchRows {
            batch: self.batch_row(batch_id)?,
            tasks: self.task_rows(batch_id)?,
            shards: self.shard_rows(batch_id)?,
            config_hash: self.config_hash(batch_id)?,
        })
    }

    fn batch_row(&self, batch_id: &str) -> Result<BatchRow, CoordError> {
        #[allow(clippy::type_complexity)]
        let (name, state, policies, seeds, invalid, submitted, finished, ranking): (String, String, String, String, String, i64, Option<i64>, Option<String>) =
            self.conn
                .query_row(
                    "SELECT name, state, policies_json, seeds_json, invalid_json, submitted_ms, finished_ms, ranking_json FROM batches WHERE id = ?1",
                    [batch_id],
                    |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?, r.get(7)?)),
                )
                .optional()?
                .ok_or_else(|| CoordError::NotFound(format!("batch '{batch_id}'")))?;
        Ok(BatchRow {
            id: batch_id.to_owned(),
            name,
            state,
            policies: serde_json::from_str(&policies)?,
            seeds: serde_json::from_str(&seeds)?,
            invalid: serde_json::from_str(&invalid)?,
            submitted_ms: submitted,
            finished_ms: finished,
            ranking: ranking.map(|p| serde_json::from_str(&p)).transpose()?,
        })
    }

    /// The batch's tasks. No `ORDER BY`: the report's "task order" has always been the order
    /// SQLite gives them in, and it must stay the same for the same store.
    fn task_rows(&self, batch_id: &str) -> Result<Vec<TaskInfo>, CoordError> {
        let mut stmt = self.conn.prepare(
            "SELECT task_id, name, grp, pipeline, origin, spec_hash FROM tasks WHERE batch_id = ?1",
        )?;
        let it = stmt.query_map([batch_id], |r| {
            Ok(TaskInfo {
                id: r.get(0)?,
                name: r.get(1)?,
                group: r.get(2)?,
                pipeline: r.get(3)?,
                origin: r.get(4)?,
                spec_hash: r.get(5)?,
            })
        })?;
        Ok(it.collect::<Result<_, _>>()?)
    }

    /// The batch's shards in queue order, a done shard's outcome decoded by its kind.
    fn shard_rows(&self, batch_id: &str) -> Result<Vec<ShardRow>, CoordError> {
        let mut stmt = self.conn.prepare(
            "SELECT kind, state, task_id, seed, policy, attempts, outcome_json, error, worker, judge, job, grp
             FROM shards WHERE batch_id = ?1 ORDER BY id",
        )?;
        let mut rows = stmt.query([batch_id])?;
        let mut out = Vec::new();
        while let Some(r) = rows.next()? {
            let kind: JobKind = r.get::<_, String>(0)?.parse()?;
            let state: ShardState = r.get::<_, String>(1)?.parse()?;
            let outcome = match (state, r.get::<_, Option<String>>(6)?) {
                (ShardState::Done, Some(json)) => Some(Outcome::decode(kind, &json)?),
                _ => None,
            };
            out.push(ShardRow {
                kind,
                state,
                task_id: r.get(2)?,
                seed: r.get::<_, i64>(3)? as u64,
                policy: r.get(4)?,
                attempts: r.get(5)?,
                outcome,
                error: r.get(7)?,
                worker: r.get(8)?,
                judge: r.get(9)?,
                job: r.get(10)?,
                group: r.get(11)?,
            });
        }
        Ok(out)
    }
}
