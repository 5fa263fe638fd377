//! The job store: batches, tasks and shards in one SQLite file.
//!
//! Every state change of a shard is one SQL statement guarded by its current state and lease id,
//! so a late or duplicate message can never count a shard twice. Time is passed in (`now_ms`), so
//! lease logic is tested without sleeping.

use std::path::Path;

use assay_core::SpecError;
use assay_core::dynamics::DynamicsConfig;
use assay_core::generalization::{
    EvalEpisode, GeneralizationPlan, GeneralizationResults, GroupGeneralization,
    HELD_OUT_VARIATIONS, TRAIN_VARIATIONS,
};
use assay_core::proxy::{
    IMAGINED_JUDGING, ImaginedJudgement, ProxyEpisode, ProxyResult, RankingPlan, RealEpisode,
    ranking_results,
};
use assay_core::quality::{DEFAULT_REPEATS, Item, JudgeOutcome};
use assay_core::quality_report::JudgeRecord;
use assay_core::report::{
    self, EpisodeImagery, EpisodeOutcome, Report, RunInfo, ShardRecord, TaskInfo,
};
use assay_core::trainer::{DiversityResults, TrainerJob, TrainerOutcome};
use rusqlite::{Connection, OptionalExtension, params};

use crate::error::CoordError;

/// States a shard moves through: queued → leased → done | failed | cancelled; an expired or
/// returned lease goes back to queued.
pub mod shard_state {
    pub const QUEUED: &str = "queued";
    pub const LEASED: &str = "leased";
    pub const DONE: &str = "done";
    pub const FAILED: &str = "failed";
    pub const CANCELLED: &str = "cancelled";
}
use shard_state::*;

pub mod batch_state {
    pub const RUNNING: &str = "running";
    pub const COMPLETED: &str = "completed";
    pub const CANCELLED: &str = "cancelled";
    /// Not run: the same tasks were evaluated before (`duplicate_of`).
    pub const SKIPPED: &str = "skipped";
}

const SCHEMA: &str = r#"
PRAGMA journal_mode = WAL;
PRAGMA synchronous = NORMAL;
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS batches (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    name TEXT NOT NULL,
    state TEXT NOT NULL,
    policies_json TEXT NOT NULL,
    seeds_json TEXT NOT NULL,
    max_attempts INTEGER NOT NULL,
    invalid_json TEXT NOT NULL,
    submitted_ms INTEGER NOT NULL,
    finished_ms INTEGER
);
CREATE TABLE IF NOT EXISTS tasks (
    batch_id TEXT NOT NULL,
    task_id TEXT NOT NULL,
    name TEXT NOT NULL,
    grp TEXT NOT NULL,
    pipeline TEXT NOT NULL,
    origin TEXT NOT NULL,
    spec_hash TEXT NOT NULL,
    spec_json TEXT NOT NULL,
    PRIMARY KEY (batch_id, task_id)
);
CREATE TABLE IF NOT EXISTS shards (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    batch_id TEXT NOT NULL,
    task_id TEXT NOT NULL,
    seed INTEGER NOT NULL,
    policy TEXT NOT NULL,
    role TEXT NOT NULL,
    state TEXT NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    lease_id INTEGER,
    lease_worker TEXT,
    lease_expires_ms INTEGER,
    outcome_json TEXT,
    error TEXT,
    wall_time_s REAL,
    worker TEXT
);
CREATE INDEX IF NOT EXISTS shards_by_state ON shards (state, role, id);
CREATE INDEX IF NOT EXISTS shards_by_batch ON shards (batch_id, state);
CREATE UNIQUE INDEX IF NOT EXISTS shards_by_lease ON shards (lease_id);
"#;

/// Columns added after the first release, added to an older store when it is opened.
const ADDED_COLUMNS: &[(&str, &str, &str)] = &[
    ("batches", "judges_json", "TEXT NOT NULL DEFAULT '[]'"),
    ("batches", "judge_repeats", "INTEGER NOT NULL DEFAULT 5"),
    ("batches", "judge_budget_usd", "REAL"),
    // A judge shard: the judge's name and the episode outcome it judges.
    ("shards", "judge", "TEXT"),
    ("shards", "input_json", "TEXT"),
    // Diversity: the embedding models of the batch's text-diversity shard, and its dynamics
    // settings (JSON `{"budgets": [...], "config": DynamicsConfig}`; NULL: none).
    ("batches", "text_models_json", "TEXT NOT NULL DEFAULT '[]'"),
    ("batches", "dynamics_json", "TEXT"),
    // A trainer shard: what it computes ("text", "dynamics GROUP @ BUDGET") and its task group.
    ("shards", "job", "TEXT"),
    ("shards", "grp", "TEXT"),
    // Policy ranking (JSON `assay_core::proxy::RankingPlan`; NULL: none).
    ("batches", "ranking_json", "TEXT"),
    // Generalization (JSON `assay_core::generalization::GeneralizationPlan`; NULL: none).
    ("batches", "generalization_json", "TEXT"),
    // Continuous evaluation: the batch's content hash, and for a skipped batch the batch it
    // repeats.
    ("batches", "content_hash", "TEXT NOT NULL DEFAULT ''"),
    ("batches", "duplicate_of", "TEXT"),
];

/// Shard roles.
pub mod role {
    pub const SIM: &str = "sim";
    pub const JUDGE: &str = "judge";
    pub const TRAINER: &str = "trainer";
}

/// The dynamics part of a batch: episode budgets and world-model settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DynamicsPlan {
    pub budgets: Vec<u32>,
    pub config: DynamicsConfig,
}

/// A task accepted by the planner.
#[derive(Debug, Clone)]
pub struct PlannedTask {
    pub info: TaskInfo,
    pub spec_json: String,
}

/// A batch ready to be stored.
#[derive(Debug, Clone)]
pub struct NewBatch {
    pub name: String,
    pub tasks: Vec<PlannedTask>,
    pub policies: Vec<String>,
    pub seeds: Vec<u64>,
    pub max_attempts: u32,
    pub invalid: Vec<SpecError>,
    pub role: String,
    /// Judges that score every rendered episode (empty: none).
    pub judges: Vec<String>,
    /// Times each judge item is asked (0: the default, 5).
    pub judge_repeats: u32,
    /// USD the batch's judges may spend; None: no limit.
    pub judge_budget_usd: Option<f64>,
    /// SHA-256 of the batch's tasks (see `SubmitBatchResponse.content_hash`).
    pub content_hash: String,
    /// Embedding models for text diversity (empty: none) and the texts per group ("All" last).
    pub text_models: Vec<String>,
    pub text_groups: Vec<(String, Vec<String>)>,
    /// Dynamics diversity (None: none): every episode renders a clip, and each group's world
    /// models are queued once its episodes are finished.
    pub dynamics: Option<DynamicsPlan>,
    /// Policy ranking by the world-model proxy (None: none): every episode renders a clip, and
    /// each group's proxy is queued once its episodes are finished.
    pub ranking: Option<RankingPlan>,
    /// Generalization (None: none): every episode renders a clip; each group's diffusion policy
    /// is trained once its episodes are finished, then run on training and held-out variations.
    pub generalization: Option<GeneralizationPlan>,
}

/// A shard handed to a worker.
#[derive(Debug, Clone, PartialEq)]
pub struct Lease {
    pub lease_id: u64,
    pub shard_id: u64,
    pub batch_id: String,
    pub task_spec_json: String,
    pub seed: u64,
    pub policy: String,
    pub role: String,
    pub attempt: u32,
    /// For a judge shard: the judge, the episode outcome JSON it judges, repeats per item and
    /// what is left of the batch's budget (None: no limit).
    pub judge: Option<JudgeLease>,
    /// For a trainer shard: its job (JSON `assay_core::trainer::TrainerJob`).
    pub trainer_job: Option<String>,
    /// For an episode of a batch that measures dynamics diversity: the clip's frame size.
    pub clip_size: u32,
}

#[derive(Debug, Clone, PartialEq)]
pub struct JudgeLease {
    pub judge: String,
    pub episode_json: String,
    pub repeats: u32,
    pub budget_left_usd: Option<f64>,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct BatchCounts {
    pub id: String,
    pub name: String,
    pub state: String,
    pub total: u32,
    pub queued: u32,
    pub leased: u32,
    pub done: u32,
    pub failed: u32,
    pub cancelled: u32,
    pub successes: u32,
    pub invalid_tasks: u32,
    pub submitted_ms: i64,
    pub finished_ms: Option<i64>,
    /// Judge shards (the counts above are episodes).
    pub judge_total: u32,
    pub judge_done: u32,
    pub judge_failed: u32,
    pub judge_cost_usd: f64,
    /// Trainer shards (text diversity, world models).
    pub trainer_total: u32,
    pub trainer_done: u32,
    pub trainer_failed: u32,
    pub content_hash: String,
    /// A skipped batch: the batch it repeats.
    pub duplicate_of: Option<String>,
}

/// What a state change did, so the caller knows whom to wake.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Changed {
    /// Batches whose counts changed.
    pub batches: Vec<String>,
    /// Shards that went back to the queue.
    pub requeued: u32,
}

pub struct Store {
    conn: Connection,
}

/// id, batch, seed, policy, role, attempts, spec JSON, judge, input JSON, repeats, budget,
/// clip size (of the batch's dynamics or ranking world model).
type QueuedShard = (
    i64,
    String,
    i64,
    String,
    String,
    u32,
    String,
    Option<String>,
    Option<String>,
    u32,
    Option<f64>,
    Option<i64>,
);

impl Store {
    pub fn open(path: &Path) -> Result<Self, CoordError> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        Self::init(conn)
    }

    pub fn open_in_memory() -> Result<Self, CoordError> {
        Self::init(Connection::open_in_memory()?)
    }

    fn init(conn: Connection) -> Result<Self, CoordError> {
        conn.execute_batch(SCHEMA)?;
        for (table, column, decl) in ADDED_COLUMNS {
            let present: bool = conn.query_row(
                &format!("SELECT COUNT(*) FROM pragma_table_info('{table}') WHERE name = ?1"),
                [column],
                |r| r.get::<_, i64>(0).map(|n| n > 0),
            )?;
            if !present {
                conn.execute_batch(&format!("ALTER TABLE {table} ADD COLUMN {column} {decl}"))?;
            }
        }
        Ok(Self { conn })
    }

    /// Opens a group: the store calls until [`Store::commit_group`] share one transaction. Each
    /// call still runs in its own savepoint, so one that fails leaves the others' changes intact.
    pub fn begin_group(&mut self) -> Result<(), CoordError> {
        self.conn.execute_batch("BEGIN IMMEDIATE")?;
        Ok(())
    }

    /// Commits the open group; on failure the whole group is rolled back.
    pub fn commit_group(&mut self) -> Result<(), CoordError> {
        if let Err(e) = self.conn.execute_batch("COMMIT") {
            let _ = self.conn.execute_batch("ROLLBACK");
            return Err(e.into());
        }
        Ok(())
    }

    /// The connection, for tests that need to reach under the store's API.
    #[cfg(test)]
    pub(crate) fn conn(&mut self) -> &mut Connection {
        &mut self.conn
    }

    /// USD the batch's judge shards have spent so far.
    fn judge_spent(conn: &Connection, batch_id: &str) -> Result<f64, CoordError> {
        Ok(conn.query_row(
            "SELECT COALESCE(SUM(json_extract(outcome_json, '$.usage.cost_usd')), 0.0) FROM shards
             WHERE batch_id = ?1 AND role = 'judge' AND state = 'done'",
            [batch_id],
            |r| r.get(0),
        )?)
    }

    fn next_counter(tx: &Connection, key: &str, n: u64) -> Result<u64, CoordError> {
        let cur: Option<i64> = tx
            .prepare_cached("SELECT value FROM meta WHERE key = ?1")?
            .query_row([key], |r| r.get(0))
            .optional()?;
        let first = cur.unwrap_or(1) as u64;
        tx.prepare_cached(
            "INSERT INTO meta (key, value) VALUES (?1, ?2) ON CONFLICT(key) DO UPDATE SET value = excluded.value",
        )?
        .execute(params![key, (first + n) as i64])?;
        Ok(first)
    }

    fn insert_tasks(
        tx: &Connection,
        batch_id: &str,
        tasks: &[PlannedTask],
    ) -> Result<(), CoordError> {
        for t in tasks {
            tx.execute(
                "INSERT INTO tasks (batch_id, task_id, name, grp, pipeline, origin, spec_hash, spec_json)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![batch_id, t.info.id, t.info.name, t.info.group, t.info.pipeline, t.info.origin, t.info.spec_hash, t.spec_json],
            )?;
        }
        Ok(())
    }

    /// The first batch evaluated (running or completed, not itself skipped) with this content
    /// hash, if any.
    pub fn evaluated_with(&self, content_hash: &str) -> Result<Option<String>, CoordError> {
        Ok(self
            .conn
            .query_row(
                "SELECT id FROM batches WHERE content_hash = ?1 AND state IN ('running', 'completed')
                 ORDER BY seq LIMIT 1",
                [content_hash],
                |r| r.get(0),
            )
            .optional()?)
    }

    /// Records `batch` as skipped, a repeat of `duplicate_of`: in the history, with no shards.
    pub fn record_skipped(
        &mut self,
        batch: &NewBatch,
        duplicate_of: &str,
        now_ms: i64,
    ) -> Result<String, CoordError> {
        let tx = self.conn.savepoint()?;
        let seq = Self::next_counter(&tx, "batch_seq", 1)?;
        let id = format!("b{seq:05}-{:x}", now_ms & 0xff_ffff);
        tx.execute(
            "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms,
             finished_ms, content_hash, duplicate_of)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?9, ?10, ?11)",
            params![
                id,
                seq as i64,
                batch.name,
                batch_state::SKIPPED,
                serde_json::to_string(&batch.policies)?,
                serde_json::to_string(&batch.seeds)?,
                batch.max_attempts,
                serde_json::to_string(&batch.invalid)?,
                now_ms,
                batch.content_hash,
                duplicate_of,
            ],
        )?;
        Self::insert_tasks(&tx, &id, &batch.tasks)?;
        tx.commit()?;
        Ok(id)
    }

    /// Stores a batch and plans its shards: seed-major (every task's first seed runs before any
    /// task's second), then policy, then task in submission order.
    pub fn submit(&mut self, batch: &NewBatch, now_ms: i64) -> Result<(String, u32), CoordError> {
        let tx = self.conn.savepoint()?;
        let seq = Self::next_counter(&tx, "batch_seq", 1)?;
        let id = format!("b{seq:05}-{:x}", now_ms & 0xff_ffff);
        tx.execute(
            "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms,
             judges_json, judge_repeats, judge_budget_usd, text_models_json, dynamics_json)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
            params![
                id,
                seq as i64,
                batch.name,
                batch_state::RUNNING,
                serde_json::to_string(&batch.policies)?,
                serde_json::to_string(&batch.seeds)?,
                batch.max_attempts,
                serde_json::to_string(&batch.invalid)?,
                now_ms,
                serde_json::to_string(&batch.judges)?,
                if batch.judge_repeats == 0 { DEFAULT_REPEATS } else { batch.judge_repeats },
                batch.judge_budget_usd,
                serde_json::to_string(&batch.text_models)?,
                batch.dynamics.as_ref().map(serde_json::to_string).transpose()?,
            ],
        )?;
        Self::insert_tasks(&tx, &id, &batch.tasks)?;
        let mut n = 0u32;
        {
            let mut ins = tx.prepare(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
            )?;
            for seed in &batch.seeds {
                for policy in &batch.policies {
                    for t in &batch.tasks {
                        ins.execute(params![
                            id,
                            t.info.id,
                            *seed as i64,
                            policy,
                            batch.role,
                            QUEUED
                        ])?;
                        n += 1;
                    }
                }
            }
        }
        tx.execute(
            "UPDATE batches SET content_hash = ?1 WHERE id = ?2",
            params![batch.content_hash, id],
        )?;
        if let Some(plan) = &batch.ranking {
            tx.execute(
                "UPDATE batches SET ranking_json = ?1 WHERE id = ?2",
                params![serde_json::to_string(plan)?, id],
            )?;
        }
        if let Some(plan) = &batch.generalization {
            tx.execute(
                "UPDATE batches SET generalization_json = ?1 WHERE id = ?2",
                params![serde_json::to_string(plan)?, id],
            )?;
        }
        if !batch.text_models.is_empty() && !batch.tasks.is_empty() {
            let job = TrainerJob::Text {
                models: batch.text_models.clone(),
                groups: batch.text_groups.clone(),
            };
            tx.execute(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, input_json)
                 VALUES (?1, '', 0, '', ?2, ?3, 'text', ?4)",
                params![id, role::TRAINER, QUEUED, serde_json::to_string(&job)?],
            )?;
        }
        tx.commit()?;
        Ok((id, n))
    }

    /// Leases up to `n` queued shards of running batches for one of `roles`.
    pub fn lease(
        &mut self,
        worker: &str,
        roles: &[String],
        n: u32,
        now_ms: i64,
        ttl_ms: i64,
    ) -> Result<Vec<Lease>, CoordError> {
        if n == 0 || roles.is_empty() {
            return Ok(Vec::new());
        }
        let tx = self.conn.savepoint()?;
        let placeholders = roles.iter().map(|_| "?").collect::<Vec<_>>().join(",");
        let sql = format!(
            "SELECT s.id, s.batch_id, s.seed, s.policy, s.role, s.attempts, COALESCE(t.spec_json, ''),
                    s.judge, s.input_json, b.judge_repeats, b.judge_budget_usd,
                    COALESCE(json_extract(b.dynamics_json, '$.config.image_size'),
                             json_extract(b.ranking_json, '$.config.world_model.image_size'),
                             json_extract(b.generalization_json, '$.config.image_size'))
             FROM shards s LEFT JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                           JOIN batches b ON b.id = s.batch_id
             WHERE s.state = 'queued' AND s.role IN ({placeholders})
             ORDER BY s.id LIMIT {n}"
        );
        let rows: Vec<QueuedShard> = {
            let mut stmt = tx.prepare_cached(&sql)?;
            let it = stmt.query_map(rusqlite::params_from_iter(roles.iter()), |r| {
                Ok((
                    r.get(0)?,
                    r.get(1)?,
                    r.get(2)?,
                    r.get(3)?,
                    r.get(4)?,
                    r.get(5)?,
                    r.get(6)?,
                    r.get(7)?,
                    r.get(8)?,
                    r.get(9)?,
                    r.get(10)?,
                    r.get(11)?,
                ))
            })?;
            it.collect::<Result<_, _>>()?
        };
        let first = Self::next_counter(&tx, "lease_seq", rows.len() as u64)?;
        let mut out = Vec::with_capacity(rows.len());
        for (
            k,
            (
                shard_id,
                batch_id,
                seed,
                policy,
                shard_role,
                attempts,
                spec,
                judge,
                input,
                repeats,
                budget,
                dynamics,
            ),
        ) in rows.into_iter().enumerate()
        {
            let trainer_job = if shard_role == role::TRAINER {
                input.clone()
            } else {
                None
            };
            let clip_size = match (dynamics, shard_role.as_str()) {
                (Some(size), r) if r != role::JUDGE && r != role::TRAINER => size as u32,
                _ => 0,
            };
            let judge = match (judge, input) {
                (Some(judge), Some(episode_json)) => Some(JudgeLease {
                    judge,
                    budget_left_usd: match budget {
                        Some(b) => Some(b - Self::judge_spent(&tx, &batch_id)?),
                        None => None,
                    },
                    episode_json,
                    repeats,
                }),
                _ => None,
            };
            let lease_id = first + k as u64;
            tx.prepare_cached(
                "UPDATE shards SET state = 'leased', attempts = attempts + 1, lease_id = ?1, lease_worker = ?2,
                 lease_expires_ms = ?3 WHERE id = ?4 AND state = 'queued'",
            )?
            .execute(params![lease_id as i64, worker, now_ms + ttl_ms, shard_id])?;
            out.push(Lease {
                lease_id,
                shard_id: shard_id as u64,
                batch_id,
                task_spec_json: spec,
                seed: seed as u64,
                policy,
                role: shard_role,
                attempt: attempts + 1,
                judge,
                trainer_job,
                clip_size,
            });
        }
        tx.commit()?;
        Ok(out)
    }

    /// Extends the leases `worker` still holds; returns the ids that are still valid.
    pub fn heartbeat(
        &mut self,
        worker: &str,
        lease_ids: &[u64],
        now_ms: i64,
        ttl_ms: i64,
    ) -> Result<Vec<u64>, CoordError> {
        let tx = self.conn.savepoint()?;
        let mut kept = Vec::new();
        for id in lease_ids {
            let n = tx.execute(
                "UPDATE shards SET lease_expires_ms = ?1 WHERE lease_id = ?2 AND lease_worker = ?3 AND state = 'leased'",
                params![now_ms + ttl_ms, *id as i64, worker],
            )?;
            if n == 1 {
                kept.push(*id);
            }
        }
        tx.commit()?;
        Ok(kept)
    }

    /// Records a finished shard: `outcome_json` is an `EpisodeOutcome` for a sim shard, a
    /// `JudgeOutcome` for a judge shard. Accepted only if `lease_id` is the shard's current lease:
    /// a result from an expired, returned or completed lease is not counted. An outcome that
    /// does not parse counts as a failed attempt. A rendered episode of a batch with judges
    /// queues one judge shard per judge, in the same transaction, so the batch cannot look
    /// finished in between.
    pub fn complete(
        &mut self,
        worker: &str,
        lease_id: u64,
        shard_id: u64,
        outcome_json: &str,
        wall_time_s: f64,
        now_ms: i64,
    ) -> Result<(bool, Changed), CoordError> {
        let tx = self.conn.savepoint()?;
        let current: Option<(String, String, String, i64, String)> = tx
            .prepare_cached(
                "SELECT s.role, s.batch_id, s.task_id, s.seed, s.policy FROM shards s
                 WHERE s.id = ?1 AND s.lease_id = ?2 AND s.state = 'leased'",
            )?
            .query_row(params![shard_id as i64, lease_id as i64], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?))
            })
            .optional()?;
        let Some((shard_role, batch, task, seed, policy)) = current else {
            return Ok((false, Changed::default()));
        };
        // What to queue after it: judge shards for a rendered episode of a judged batch.
        let judges: Vec<String> = match shard_role.as_str() {
            role::JUDGE => match serde_json::from_str::<JudgeOutcome>(outcome_json) {
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable judge outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
            role::TRAINER => match serde_json::from_str::<TrainerOutcome>(outcome_json) {
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable trainer outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
            _ => match serde_json::from_str::<EpisodeOutcome>(outcome_json) {
                Ok(o) if o.imagery.is_some() => {
                    let judges: String = tx.query_row(
                        "SELECT judges_json FROM batches WHERE id = ?1",
                        [&batch],
                        |r| r.get(0),
                    )?;
                    serde_json::from_str(&judges)?
                }
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
        };
        tx.prepare_cached(
            "UPDATE shards SET state = 'done', outcome_json = ?1, wall_time_s = ?2, worker = ?3, error = NULL,
             lease_expires_ms = NULL WHERE id = ?4 AND lease_id = ?5 AND state = 'leased'",
        )?
        .execute(params![outcome_json, wall_time_s, worker, shard_id as i64, lease_id as i64])?;
        for judge in &judges {
            tx.execute(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, judge, input_json)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![batch, task, seed, policy, role::JUDGE, QUEUED, judge, outcome_json],
            )?;
        }
        let mut queued = judges.len() as u32;
        if shard_role == role::TRAINER {
            match serde_json::from_str::<TrainerOutcome>(outcome_json) {
                Ok(TrainerOutcome::Diffusion { group, model, .. }) => {
                    queued += Self::queue_generalization_episodes(&tx, &batch, &group, &model)?;
                }
                Ok(TrainerOutcome::Proxy { result }) => {
                    queued += Self::queue_imagined_judging(&tx, &batch, &result)?;
                }
                _ => {}
            }
        }
        Self::finish_if_done(&tx, &batch, now_ms)?;
        tx.commit()?;
        Ok((
            true,
            Changed {
                batches: vec![batch],
                requeued: queued,
            },
        ))
    }

    /// Records a failed attempt: re-queued while attempts remain and the error is retryable,
    /// failed with its error otherwise.
    pub fn fail(
        &mut self,
        lease_id: u64,
        shard_id: u64,
        error: &str,
        retryable: bool,
        now_ms: i64,
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let row: Option<(String, u32, u32)> = tx
            .query_row(
                "SELECT s.batch_id, s.attempts, b.max_attempts FROM shards s JOIN batches b ON b.id = s.batch_id
                 WHERE s.id = ?1 AND s.lease_id = ?2 AND s.state = 'leased'",
                params![shard_id as i64, lease_id as i64],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()?;
        let mut changed = Changed::default();
        if let Some((batch, attempts, max)) = row {
            if retryable && attempts < max {
                tx.execute(
                    "UPDATE shards SET state = 'queued', error = ?1, lease_worker = NULL, lease_expires_ms = NULL WHERE id = ?2",
                    params![error, shard_id as i64],
                )?;
                changed.requeued = 1;
            } else {
                let msg = if retryable {
                    format!("{error} (after {attempts} attempts)")
                } else {
                    error.to_owned()
                };
                tx.execute(
                    "UPDATE shards SET state = 'failed', error = ?1, lease_expires_ms = NULL WHERE id = ?2",
                    params![msg, shard_id as i64],
                )?;
                Self::finish_if_done(&tx, &batch, now_ms)?;
            }
            changed.batches.push(batch);
        }
        tx.commit()?;
        Ok(changed)
    }

    /// A worker hands leases back (graceful shutdown): they are re-queued and the attempt is not
    /// counted against the shard.
    pub fn return_leases(
        &mut self,
        worker: &str,
        lease_ids: &[u64],
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let mut changed = Changed::default();
        for id in lease_ids {
            let batch: Option<String> = tx
                .query_row(
                    "UPDATE shards SET state = 'queued', attempts = attempts - 1, lease_worker = NULL, lease_expires_ms = NULL
                     WHERE lease_id = ?1 AND lease_worker = ?2 AND state = 'leased' RETURNING batch_id",
                    params![*id as i64, worker],
                    |r| r.get(0),
                )
                .optional()?;
            if let Some(b) = batch {
                changed.requeued += 1;
                changed.batches.push(b);
            }
        }
        tx.commit()?;
        Ok(changed)
    }

    /// Ends every lease whose deadline passed (or, with `worker`, the given leases of that worker:
    /// its session broke). Each counts as an attempt; a shard out of attempts fails.
    pub fn expire(
        &mut self,
        now_ms: i64,
        worker: Option<(&str, &[u64])>,
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let sql_owned;
        let rows: Vec<(i64, String, u32, u32, Option<String>)> = {
            let (sql, args): (&str, Vec<rusqlite::types::Value>) = match worker {
                None => (
                    "SELECT s.id, s.batch_id, s.attempts, b.max_attempts, s.lease_worker FROM shards s JOIN batches b ON b.id = s.batch_id
                     WHERE s.state = 'leased' AND s.lease_expires_ms < ?1",
                    vec![now_ms.into()],
                ),
                Some((w, ids)) => {
                    let list = ids.iter().map(u64::to_string).collect::<Vec<_>>().join(",");
                    sql_owned = format!(
                        "SELECT s.id, s.batch_id, s.attempts, b.max_attempts, s.lease_worker FROM shards s JOIN batches b ON b.id = s.batch_id
                         WHERE s.state = 'leased' AND s.lease_worker = ?1 AND s.lease_id IN ({list})"
                    );
                    (sql_owned.as_str(), vec![w.to_owned().into()])
                }
            };
            let mut stmt = tx.prepare(sql)?;
            let it = stmt.query_map(rusqlite::params_from_iter(args), |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?))
            })?;
            it.collect::<Result<_, _>>()?
        };
        let mut changed = Changed::default();
        for (id, batch, attempts, max, lease_worker) in rows {
            let why = match worker {
                None => format!(
                    "lease expired: worker {} stopped heartbeating",
                    lease_worker.unwrap_or_default()
                ),
                Some((w, _)) => format!("worker {w} disconnected while running the shard"),
            };
            if attempts < max {
                tx.execute(
                    "UPDATE shards SET state = 'queued', error = ?1, lease_worker = NULL, lease_expires_ms = NULL WHERE id = ?2",
                    params![why, id],
                )?;
                changed.requeued += 1;
            } else {
                tx.execute(
                    "UPDATE shards SET state = 'failed', error = ?1, lease_expires_ms = NULL WHERE id = ?2",
                    params![format!("{why} (after {attempts} attempts)"), id],
                )?;
                Self::finish_if_done(&tx, &batch, now_ms)?;
            }
            if !changed.batches.contains(&batch) {
                changed.batches.push(batch);
            }
        }
        tx.commit()?;
        Ok(changed)
    }

    /// After a restart: give every surviving lease a fresh deadline, so workers have time to
    /// reconnect and claim them before they expire. Returns how many leases survived.
    pub fn refresh_leases(&mut self, now_ms: i64, ttl_ms: i64) -> Result<usize, CoordError> {
        Ok(self.conn.execute(
            "UPDATE shards SET lease_expires_ms = ?1 WHERE state = 'leased'",
            [now_ms + ttl_ms],
        )?)
    }

    /// A worker (re)registers saying which leases it still runs. Those it still holds are kept;
    /// any other lease recorded for it (assigned while the coordinator went down, never
    /// received) goes back to the queue without counting an attempt.
    pub fn reconcile(
        &mut self,
        worker: &str,
        running: &[u64],
    ) -> Result<(Vec<u64>, Changed), CoordError> {
        let recorded: Vec<u64> = {
            let mut stmt = self.conn.prepare(
                "SELECT lease_id FROM shards WHERE lease_worker = ?1 AND state = 'leased'",
            )?;
            let ids = stmt
                .query_map([worker], |r| r.get::<_, i64>(0))?
                .collect::<Result<Vec<_>, _>>()?;
            ids.into_iter().map(|i| i as u64).collect()
        };
        let (kept, unknown): (Vec<u64>, Vec<u64>) =
            recorded.into_iter().partition(|id| running.contains(id));
        let changed = self.return_leases(worker, &unknown)?;
        Ok((kept, changed))
    }

    pub fn cancel(&mut self, batch_id: &str, now_ms: i64) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        Self::require_batch(&tx, batch_id)?;
        tx.execute(
            "UPDATE shards SET state = 'cancelled', error = 'cancelled', lease_expires_ms = NULL
             WHERE batch_id = ?1 AND state IN ('queued', 'leased')",
            [batch_id],
        )?;
        tx.execute(
            "UPDATE batches SET state = ?1, finished_ms = COALESCE(finished_ms, ?2) WHERE id = ?3 AND state = ?4",
            params![batch_state::CANCELLED, now_ms, batch_id, batch_state::RUNNING],
        )?;
        tx.commit()?;
        Ok(Changed {
            batches: vec![batch_id.to_owned()],
            requeued: 0,
        })
    }

    /// A batch with no shards (every task invalid) is complete as soon as it is stored.
    pub fn finish_if_empty(&mut self, batch_id: &str, now_ms: i64) -> Result<(), CoordError> {
        Self::finish_if_done(&self.conn, batch_id, now_ms)
    }

    fn require_batch(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let exists = conn
            .prepare("SELECT 1 FROM batches WHERE id = ?1")?
            .exists([batch_id])?;
        if exists {
            Ok(())
        } else {
            Err(CoordError::NotFound(format!("batch '{batch_id}'")))
        }
    }

    fn finish_if_done(conn: &Connection, batch_id: &str, now_ms: i64) -> Result<(), CoordError> {
        Self::queue_dynamics(conn, batch_id)?;
        Self::queue_proxy(conn, batch_id)?;
        Self::queue_diffusion(conn, batch_id)?;
        // EXISTS, not COUNT: this runs on every completion, and counting the open shards made
        // each one O(open shards) — quadratic over a batch (`assay bench coordinator` found it).
        let open: bool = conn
            .prepare_cached(
                "SELECT EXISTS (SELECT 1 FROM shards WHERE batch_id = ?1 AND state IN ('queued', 'leased'))",
            )?
            .query_row([batch_id], |r| r.get(0))?;
        if !open {
            conn.execute(
                "UPDATE batches SET state = ?1, finished_ms = ?2 WHERE id = ?3 AND state = ?4",
                params![
                    batch_state::COMPLETED,
                    now_ms,
                    batch_id,
                    batch_state::RUNNING
                ],
            )?;
        }
        Ok(())
    }

    /// The plan in `column` of a running batch (None: the batch is not running or has none).
    fn running_plan<T: serde::de::DeserializeOwned>(
        conn: &Connection,
        batch_id: &str,
        column: &str,
    ) -> Result<Option<T>, CoordError> {
        let row: Option<(String, Option<String>)> = conn
            .prepare_cached(&format!(
                "SELECT state, {column} FROM batches WHERE id = ?1"
            ))?
            .query_row([batch_id], |r| Ok((r.get(0)?, r.get(1)?)))
            .optional()?;
        match row {
            Some((state, Some(plan))) if state == batch_state::RUNNING => {
                Ok(Some(serde_json::from_str(&plan)?))
            }
            _ => Ok(None),
        }
    }

    /// The batch's task groups in task order.
    fn groups(conn: &Connection, batch_id: &str) -> Result<Vec<String>, CoordError> {
        let mut stmt = conn.prepare(
            "SELECT grp FROM tasks WHERE batch_id = ?1 GROUP BY grp ORDER BY MIN(rowid)",
        )?;
        let groups = stmt
            .query_map([batch_id], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(groups)
    }

    /// Whether `group`'s episodes are all finished and it has no trainer shard whose job starts
    /// with `job` yet: the moment to queue one.
    fn group_ready(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        job: &str,
    ) -> Result<bool, CoordError> {
        let (started, open): (i64, i64) = conn.query_row(
            "SELECT
               (SELECT COUNT(*) FROM shards WHERE batch_id = ?1 AND role = 'trainer' AND grp = ?2
                  AND job LIKE ?3 || '%'),
               (SELECT COUNT(*) FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.role NOT IN ('judge', 'trainer')
                  AND s.state IN ('queued', 'leased'))",
            params![batch_id, group, job],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        Ok(started == 0 && open == 0)
    }

    /// Records a trainer shard of `group` that cannot run, with the reason.
    fn insert_failed_trainer_shard(
        conn: &Connection,
        batch_id: &str,
        job: &str,
        group: &str,
        error: &str,
    ) -> Result<(), CoordError> {
        conn.execute(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp, error)
             VALUES (?1, '', 0, '', 'trainer', 'failed', ?2, ?3, ?4)",
            params![batch_id, job, group, error],
        )?;
        Ok(())
    }

    /// Queues a trainer shard of `group` running `job`.
    fn insert_trainer_shard(
        conn: &Connection,
        batch_id: &str,
        name: &str,
        group: &str,
        job: &TrainerJob,
    ) -> Result<(), CoordError> {
        conn.execute(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp, input_json)
             VALUES (?1, '', 0, '', 'trainer', 'queued', ?2, ?3, ?4)",
            params![batch_id, name, group, serde_json::to_string(job)?],
        )?;
        Ok(())
    }

    /// Queues the world models of every group of a running batch whose episodes are all finished
    /// (none queued or leased) and that has none yet: one trainer shard per budget, on the
    /// group's first `max(budgets)` clips in planning order (seed-major, so the first budget
    /// holds one episode per task before any task's second). A group with fewer than 2 clips gets
    /// one failed shard saying so.
    fn queue_dynamics(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<DynamicsPlan>(conn, batch_id, "dynamics_json")?
        else {
            return Ok(());
        };
        let groups = Self::groups(conn, batch_id)?;
        let eval = plan.budgets.iter().copied().max().unwrap_or(0) as usize;
        for group in groups {
            if !Self::group_ready(conn, batch_id, &group, "dynamics")? {
                continue;
            }
            let clips: Vec<String> = {
                let mut stmt = conn.prepare(
                    "SELECT json_extract(s.outcome_json, '$.imagery.clip') AS clip
                     FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                     WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.role NOT IN ('judge', 'trainer')
                       AND s.job IS NULL AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
                )?;
                stmt.query_map(params![batch_id, group], |r| r.get(0))?
                    .take(eval)
                    .collect::<Result<_, _>>()?
            };
            if clips.len() < 2 {
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    &format!("dynamics {group}"),
                    &group,
                    &format!(
                        "group {group:?} has {} episode(s) with a dynamics clip; a world model needs at least 2 \
                             (clips are rendered by workers with the render role)",
                        clips.len()
                    ),
                )?;
                continue;
            }
            // A group with fewer clips than a budget trains that budget on all of them; larger
            // budgets would repeat the same fit, so they are left out (the report shows the
            // number trained). Budgets are sorted and distinct since submission.
            let mut budgets = plan.budgets.clone();
            if let Some(covering) = budgets.iter().position(|b| *b as usize >= clips.len()) {
                budgets.truncate(covering + 1);
            }
            for budget in &budgets {
                let job = TrainerJob::Dynamics {
                    group: group.clone(),
                    budget: *budget,
                    clips: clips.clone(),
                    config: plan.config.clone(),
                };
                Self::insert_trainer_shard(
                    conn,
                    batch_id,
                    &format!("dynamics {group} @ {budget}"),
                    &group,
                    &job,
                )?;
            }
        }
        Ok(())
    }

    /// Queues the world-model proxy of every group of a running ranking batch whose episodes are
    /// all finished and that has none yet: one trainer shard per group, trained on the clips of
    /// the training policies' episodes (with their outcomes) and imagining those of the ranked
    /// policies (without). A group with fewer than 2 training clips or no ranked clip gets one
    /// failed shard saying so.
    fn queue_proxy(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<RankingPlan>(conn, batch_id, "ranking_json")? else {
            return Ok(());
        };
        let groups = Self::groups(conn, batch_id)?;
        for group in groups {
            if !Self::group_ready(conn, batch_id, &group, "proxy")? {
                continue;
            }
            let (mut train, mut eval) = (Vec::new(), Vec::new());
            {
                let mut stmt = conn.prepare(
                    "SELECT s.task_id, s.policy, s.seed,
                            json_extract(s.outcome_json, '$.imagery.clip') AS clip,
                            json_extract(s.outcome_json, '$.success'),
                            COALESCE(json_extract(t.spec_json, '$.description'), '')
                     FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                     WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.role NOT IN ('judge', 'trainer')
                       AND s.job IS NULL AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
                )?;
                let mut rows = stmt.query(params![batch_id, group])?;
                while let Some(r) = rows.next()? {
                    let policy: String = r.get(1)?;
                    let training = plan.train_policies.contains(&policy);
                    let ep = ProxyEpisode {
                        task_id: r.get(0)?,
                        policy,
                        seed: r.get::<_, i64>(2)? as u64,
                        clip: r.get(3)?,
                        instruction: r.get(5)?,
                        success: training.then(|| r.get::<_, i64>(4).unwrap_or(0) != 0),
                    };
                    if training {
                        train.push(ep);
                    } else {
                        eval.push(ep);
                    }
                }
            }
            let job_name = format!("proxy {group}");
            if train.len() < 2 || eval.is_empty() {
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    &job_name,
                    &group,
                    &format!(
                        "group {group:?} has {} training episode(s) and {} ranked episode(s) with a clip; \
                             the proxy needs at least 2 and 1 (clips are rendered by workers with the render role)",
                        train.len(),
                        eval.len()
                    ),
                )?;
                continue;
            }
            let job = TrainerJob::Proxy {
                group: group.clone(),
                train,
                eval,
                config: plan.config.clone(),
            };
            Self::insert_trainer_shard(conn, batch_id, &job_name, &group, &job)?;
        }
        Ok(())
    }

    /// Queues the diffusion policy of every group of a running generalization batch whose
    /// episodes are all finished and that has none yet: one trainer shard per group on the
    /// group's first `episodes` clips of the training policy (planning order). A group with fewer
    /// than 2 such clips gets one failed shard saying so.
    fn queue_diffusion(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) =
            Self::running_plan::<GeneralizationPlan>(conn, batch_id, "generalization_json")?
        else {
            return Ok(());
        };
        let groups = Self::groups(conn, batch_id)?;
        for group in groups {
            if !Self::group_ready(conn, batch_id, &group, "diffusion")? {
                continue;
            }
            let clips: Vec<String> = {
                let mut stmt = conn.prepare(
                    "SELECT json_extract(s.outcome_json, '$.imagery.clip') AS clip
                     FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                     WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.role NOT IN ('judge', 'trainer')
                       AND s.policy = ?3 AND s.job IS NULL
                       AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
                )?;
                stmt.query_map(params![batch_id, group, plan.train_policy], |r| r.get(0))?
                    .take(plan.episodes as usize)
                    .collect::<Result<_, _>>()?
            };
            let job_name = format!("diffusion {group}");
            if clips.len() < 2 {
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    &job_name,
                    &group,
                    &format!(
                        "group {group:?} has {} episode(s) of {} with a clip; a diffusion policy needs at least 2 \
                             (clips are rendered by workers with the render role)",
                        clips.len(),
                        plan.train_policy
                    ),
                )?;
                continue;
            }
            let job = TrainerJob::Diffusion {
                group: group.clone(),
                clips,
                config: plan.config.clone(),
            };
            Self::insert_trainer_shard(conn, batch_id, &job_name, &group, &job)?;
        }
        Ok(())
    }

    /// Queues, for every judge of the batch that looks at images (every one but the built-in
    /// `offline`, whose completion is the simulator's), one judge shard per imagined rollout of
    /// a finished proxy: the ranked episode's outcome with the imagined keyframes as its imagery
    /// and no scene views, so the judge is asked about completion only. Returns how many.
    fn queue_imagined_judging(
        conn: &Connection,
        batch_id: &str,
        result: &ProxyResult,
    ) -> Result<u32, CoordError> {
        let judges: String = conn.query_row(
            "SELECT judges_json FROM batches WHERE id = ?1",
            [batch_id],
            |r| r.get(0),
        )?;
        let judges: Vec<String> = serde_json::from_str(&judges)?;
        let judges: Vec<&String> = judges.iter().filter(|j| *j != "offline").collect();
        if judges.is_empty() {
            return Ok(0);
        }
        let mut real = conn.prepare(
            "SELECT outcome_json FROM shards WHERE batch_id = ?1 AND task_id = ?2 AND seed = ?3
               AND policy = ?4 AND role NOT IN ('judge', 'trainer') AND job IS NULL AND state = 'done'",
        )?;
        let mut ins = conn.prepare(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, judge, input_json, job, grp)
             VALUES (?1, ?2, ?3, ?4, ?5, 'queued', ?6, ?7, ?8, ?9)",
        )?;
        let mut n = 0;
        for p in result
            .predictions
            .iter()
            .filter(|p| !p.imagined_keyframes.is_empty())
        {
            let Some(json) = real
                .query_row(params![batch_id, p.task_id, p.seed as i64, p.policy], |r| {
                    r.get::<_, String>(0)
                })
                .optional()?
            else {
                continue;
            };
            let mut episode: EpisodeOutcome = serde_json::from_str(&json)?;
            episode.imagery = Some(EpisodeImagery {
                adapter: "world model (imagined)".into(),
                views: Vec::new(),
                keyframes: p.imagined_keyframes.clone(),
                contact_sheet: String::new(),
                video: None,
                caption: None,
                clip: None,
            });
            let input = serde_json::to_string(&episode)?;
            for judge in &judges {
                ins.execute(params![
                    batch_id,
                    p.task_id,
                    p.seed as i64,
                    p.policy,
                    role::JUDGE,
                    judge,
                    input,
                    IMAGINED_JUDGING,
                    result.group,
                ])?;
                n += 1;
            }
        }
        Ok(n)
    }

    /// Queues the evaluation episodes of `group`'s trained diffusion policy `model`: every
    /// (task, seed) it was trained on, and every task of the group under the plan's held-out
    /// seeds. Returns how many.
    fn queue_generalization_episodes(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        model: &str,
    ) -> Result<u32, CoordError> {
        let plan: Option<String> = conn.query_row(
            "SELECT generalization_json FROM batches WHERE id = ?1",
            [batch_id],
            |r| r.get(0),
        )?;
        let Some(plan) = plan else {
            return Ok(0);
        };
        let plan: GeneralizationPlan = serde_json::from_str(&plan)?;
        let policy = plan.policy_name(model);
        let trained: Vec<(String, i64)> = {
            let mut stmt = conn.prepare(
                "SELECT s.task_id, s.seed, json_extract(s.outcome_json, '$.imagery.clip') AS clip
                 FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                 WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.role NOT IN ('judge', 'trainer')
                   AND s.policy = ?3 AND s.job IS NULL
                   AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
            )?;
            stmt.query_map(params![batch_id, group, plan.train_policy], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })?
            .take(plan.episodes as usize)
            .collect::<Result<_, _>>()?
        };
        let tasks: Vec<String> = {
            let mut stmt = conn.prepare(
                "SELECT task_id FROM tasks WHERE batch_id = ?1 AND grp = ?2 ORDER BY rowid",
            )?;
            stmt.query_map(params![batch_id, group], |r| r.get(0))?
                .collect::<Result<_, _>>()?
        };
        let role: String = conn.query_row(
            "SELECT role FROM shards WHERE batch_id = ?1 AND job IS NULL AND role NOT IN ('judge', 'trainer') LIMIT 1",
            [batch_id],
            |r| r.get(0),
        )?;
        let mut ins = conn.prepare(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp)
             VALUES (?1, ?2, ?3, ?4, ?5, 'queued', ?6, ?7)",
        )?;
        let mut n = 0;
        for (task, seed) in &trained {
            ins.execute(params![
                batch_id,
                task,
                seed,
                policy,
                role,
                TRAIN_VARIATIONS,
                group
            ])?;
            n += 1;
        }
        for k in 0..u64::from(plan.held_out_seeds) {
            for task in &tasks {
                let seed = (plan.held_out_seed_base + k) as i64;
                ins.execute(params![
                    batch_id,
                    task,
                    seed,
                    policy,
                    role,
                    HELD_OUT_VARIATIONS,
                    group
                ])?;
                n += 1;
            }
        }
        Ok(n)
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
        Ok(assay_core::hash::sha256_hex(
            settings.to_string().as_bytes(),
        ))
    }

    /// The figures `/metrics` shows, read in one pass.
    pub fn metrics(&self) -> Result<crate::metrics::Snapshot, CoordError> {
        crate::metrics::Snapshot::read(&self.conn)
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

    /// Builds the batch's report from the store (partial while the batch runs).
    pub fn report(&self, batch_id: &str) -> Result<Report, CoordError> {
        #[allow(clippy::type_complexity)]
        let (name, state, policies, seeds, invalid, submitted, finished, ranking_plan): (String, String, String, String, String, i64, Option<i64>, Option<String>) =
            self.conn
                .query_row(
                    "SELECT name, state, policies_json, seeds_json, invalid_json, submitted_ms, finished_ms, ranking_json FROM batches WHERE id = ?1",
                    [batch_id],
                    |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?, r.get(7)?)),
                )
                .optional()?
                .ok_or_else(|| CoordError::NotFound(format!("batch '{batch_id}'")))?;
        let policies: Vec<String> = serde_json::from_str(&policies)?;
        let seeds: Vec<u64> = serde_json::from_str(&seeds)?;
        let invalid: Vec<SpecError> = serde_json::from_str(&invalid)?;
        let tasks: Vec<TaskInfo> = {
            let mut stmt = self
                .conn
                .prepare("SELECT task_id, name, grp, pipeline, origin, spec_hash FROM tasks WHERE batch_id = ?1")?;
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
            it.collect::<Result<_, _>>()?
        };
        let mut workers = std::collections::BTreeSet::new();
        let mut extra_attempts = 0u64;
        let mut shards = Vec::new();
        let mut judged = Vec::new();
        let mut diversity: Option<DiversityResults> = None;
        let mut error_groups: Vec<Option<String>> = Vec::new();
        let mut proxies = Vec::new();
        let mut proxy_errors = Vec::new();
        let mut imagined = Vec::new();
        let mut trained = Vec::new();
        let mut general_errors = Vec::new();
        let mut evaluated = Vec::new();
        {
            let mut stmt = self.conn.prepare(
                "SELECT task_id, seed, policy, attempts, state, outcome_json, error, worker, role, judge, job, grp
                 FROM shards WHERE batch_id = ?1 ORDER BY id",
            )?;
            let mut rows = stmt.query([batch_id])?;
            while let Some(r) = rows.next()? {
                let attempts: u32 = r.get(3)?;
                let state: String = r.get(4)?;
                let outcome: Option<String> = r.get(5)?;
                if let Some(w) = r.get::<_, Option<String>>(7)? {
                    workers.insert(w);
                }
                extra_attempts += u64::from(attempts.saturating_sub(1));
                if r.get::<_, String>(8)? == role::TRAINER {
                    let job: String = r.get::<_, Option<String>>(10)?.unwrap_or_default();
                    if job.starts_with("diffusion") {
                        let group = r.get::<_, Option<String>>(11)?.unwrap_or_default();
                        match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                if let TrainerOutcome::Diffusion { group, model, fit } =
                                    serde_json::from_str::<TrainerOutcome>(&json)?
                                {
                                    trained.push((group, model, *fit));
                                }
                            }
                            (FAILED, _) => general_errors
                                .push((group, r.get::<_, Option<String>>(6)?.unwrap_or_default())),
                            _ => {}
                        }
                        continue;
                    }
                    if job.starts_with("proxy") {
                        match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                if let TrainerOutcome::Proxy { result } =
                                    serde_json::from_str::<TrainerOutcome>(&json)?
                                {
                                    proxies.push(*result);
                                }
                            }
                            (FAILED, _) => proxy_errors.push((
                                r.get::<_, Option<String>>(11)?.unwrap_or_default(),
                                r.get::<_, Option<String>>(6)?.unwrap_or_default(),
                            )),
                            _ => {}
                        }
                        continue;
                    }
                    let div = diversity.get_or_insert_with(DiversityResults::default);
                    match (state.as_str(), outcome) {
                        (DONE, Some(json)) => {
                            match serde_json::from_str::<TrainerOutcome>(&json)? {
                                TrainerOutcome::Text { table } => div.text = Some(table),
                                TrainerOutcome::Dynamics { fit } => div.dynamics.push(*fit),
                                TrainerOutcome::Proxy { .. } | TrainerOutcome::Diffusion { .. } => {
                                }
                            }
                        }
                        (FAILED, _) => {
                            div.errors
                                .push((job, r.get::<_, Option<String>>(6)?.unwrap_or_default()));
                            error_groups.push(r.get::<_, Option<String>>(11)?);
                        }
                        _ => {}
                    }
                    continue;
                }
                if r.get::<_, String>(8)? == role::JUDGE
                    && r.get::<_, Option<String>>(10)?.as_deref() == Some(IMAGINED_JUDGING)
                {
                    // A judge's verdict on an imagined rollout: a proxy's, not quality.
                    let completion = match (state.as_str(), outcome) {
                        (DONE, Some(json)) => {
                            let o = serde_json::from_str::<JudgeOutcome>(&json)?;
                            let item = o.item(Item::Completion);
                            let scores = item.map(|i| i.scores.as_slice()).unwrap_or_default();
                            if scores.is_empty() {
                                Err(item
                                    .and_then(|i| i.errors.first())
                                    .map_or("no completion score".into(), |e| e.error.clone()))
                            } else {
                                Ok(scores.iter().sum::<f64>() / scores.len() as f64)
                            }
                        }
                        (FAILED, _) => Err(r.get::<_, Option<String>>(6)?.unwrap_or_default()),
                        (CANCELLED, _) => Err("cancelled".into()),
                        _ => continue,
                    };
                    imagined.push(ImaginedJudgement {
                        task_id: r.get(0)?,
                        seed: r.get::<_, i64>(1)? as u64,
                        policy: r.get(2)?,
                        judge: r.get::<_, Option<String>>(9)?.unwrap_or_default(),
                        completion,
                    });
                    continue;
                }
                if r.get::<_, String>(8)? == role::JUDGE {
                    judged.push(JudgeRecord {
                        task_id: r.get(0)?,
                        seed: r.get::<_, i64>(1)? as u64,
                        policy: r.get(2)?,
                        judge: r.get::<_, Option<String>>(9)?.unwrap_or_default(),
                        attempts,
                        outcome: match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                Some(serde_json::from_str::<JudgeOutcome>(&json)?)
                            }
                            _ => None,
                        },
                        error: if state == FAILED { r.get(6)? } else { None },
                        cancelled: state == CANCELLED,
                    });
                    continue;
                }
                let outcome = match (state.as_str(), outcome) {
                    (DONE, Some(json)) => Some(serde_json::from_str::<EpisodeOutcome>(&json)?),
                    _ => None,
                };
                let job: Option<String> = r.get(10)?;
                if let Some(job) = job.filter(|j| j.starts_with("generalization")) {
                    // A trained policy's evaluation episode: its own section, not the batch's
                    // success tables.
                    evaluated.push(EvalEpisode {
                        group: r.get::<_, Option<String>>(11)?.unwrap_or_default(),
                        task_id: r.get(0)?,
                        held_out: job == HELD_OUT_VARIATIONS,
                        success: match (state.as_str(), &outcome) {
                            (DONE, Some(o)) => Some(Ok(o.success)),
                            (FAILED, _) => {
                                Some(Err(r.get::<_, Option<String>>(6)?.unwrap_or_default()))
                            }
                            (CANCELLED, _) => Some(Err("cancelled".into())),
                            _ => None,
                        },
                    });
                    continue;
                }
                let open = state == QUEUED || state == LEASED;
                shards.push(ShardRecord {
                    task_id: r.get(0)?,
                    seed: r.get::<_, i64>(1)? as u64,
                    policy: r.get(2)?,
                    attempts,
                    outcome,
                    error: if open {
                        Some(format!("still {state}"))
                    } else {
                        r.get(6)?
                    },
                    cancelled: state == CANCELLED,
                });
            }
        }
        if let Some(div) = diversity.as_mut() {
            // Groups finish (and queue their fits) in whatever order their episodes do, and fits
            // finish in any order: the report lists them by group (task order) and budget.
            let rank = |g: Option<&str>| g.map(|g| tasks.iter().position(|t| t.group == g));
            div.dynamics
                .sort_by_key(|f| (rank(Some(&f.group)), f.budget));
            let mut errors: Vec<_> = error_groups
                .iter()
                .map(|g| rank(g.as_deref()))
                .zip(std::mem::take(&mut div.errors))
                .collect();
            errors.sort_by_key(|(r, _)| *r);
            div.errors = errors.into_iter().map(|(_, e)| e).collect();
        }
        let mut results =
            report::build_results(&name, &policies, &seeds, &tasks, &shards, &invalid);
        let episodes: Vec<EpisodeOutcome> =
            shards.iter().filter_map(|s| s.outcome.clone()).collect();
        // A trained policy's evaluation episodes (generalization) are judged too when the batch
        // has judges, but quality is about the batch's own policies' episodes.
        judged.retain(|j| policies.contains(&j.policy));
        results.quality = assay_core::quality_report::build_quality(&tasks, &episodes, &judged);
        results.diversity = diversity;
        if !trained.is_empty() || !general_errors.is_empty() {
            let rank = |g: &str| tasks.iter().position(|t| t.group == g);
            trained.sort_by_key(|(g, _, _)| rank(g));
            general_errors.sort_by_key(|(g, _)| rank(g));
            results.generalization = Some(GeneralizationResults {
                groups: trained
                    .into_iter()
                    .map(|(g, model, fit)| GroupGeneralization::build(&g, &model, fit, &evaluated))
                    .collect(),
                errors: general_errors,
            });
        }
        if let Some(plan) = ranking_plan {
            let plan: RankingPlan = serde_json::from_str(&plan)?;
            let ranked: Vec<String> = policies
                .iter()
                .filter(|p| !plan.train_policies.contains(p))
                .cloned()
                .collect();
            let real: Vec<RealEpisode> = episodes
                .iter()
                .filter(|e| ranked.contains(&e.policy))
                .map(|e| {
                    let scores: Vec<f64> = judged
                        .iter()
                        .filter(|j| {
                            j.task_id == e.task_id && j.seed == e.seed && j.policy == e.policy
                        })
                        .filter_map(|j| j.outcome.as_ref())
                        .filter_map(|o| o.item(Item::Completion))
                        .flat_map(|i| i.scores.iter().copied())
                        .collect();
                    RealEpisode {
                        task_id: e.task_id.clone(),
                        policy: e.policy.clone(),
                        seed: e.seed,
                        success: e.success,
                        judged_completion: (!scores.is_empty())
                            .then(|| scores.iter().sum::<f64>() / scores.len() as f64),
                    }
                })
                .collect();
            let task_groups: Vec<(String, String)> = tasks
                .iter()
                .map(|t| (t.id.clone(), t.group.clone()))
                .collect();
            results.ranking = Some(ranking_results(
                &plan,
                &ranked,
                &task_groups,
                &real,
                proxies,
                &imagined,
                proxy_errors,
            ));
        }
        let wall = finished.map(|f| (f - submitted) as f64 / 1000.0);
        let rate = |x: f64| wall.filter(|w| *w > 0.0).map(|w| x / w);
        let run = RunInfo {
            batch_id: batch_id.to_owned(),
            state,
            submitted_at_unix_ms: submitted,
            finished_at_unix_ms: finished,
            wall_time_s: wall,
            episodes_per_s: rate(results.totals.episodes_completed as f64),
            sim_steps_per_s: rate(results.totals.sim_steps as f64),
            extra_attempts,
            workers: workers.into_iter().collect(),
        };
        let provenance = report::Provenance::of(
            &results,
            &episodes,
            concat!("assay-coordinator ", env!("CARGO_PKG_VERSION")),
            &self.config_hash(batch_id)?,
        );
        Ok(Report {
            report_version: report::REPORT_VERSION,
            results,
            run,
            provenance,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use assay_core::report::LabelSource;

    use super::*;

    const TTL: i64 = 1_000;

    fn batch(tasks: &[&str], seeds: &[u64], max_attempts: u32) -> NewBatch {
        NewBatch {
            name: "t".into(),
            tasks: tasks
                .iter()
                .map(|id| PlannedTask {
                    info: TaskInfo {
                        id: (*id).into(),
                        name: (*id).into(),
                        group: "g".into(),
                        pipeline: "assay".into(),
                        origin: format!("{id}.yaml"),
                        spec_hash: "h".into(),
                    },
                    spec_json: "{}".into(),
                })
                .collect(),
            policies: vec!["oracle".into()],
            seeds: seeds.to_vec(),
            max_attempts,
            invalid: vec![],
            role: "sim".into(),
            judges: vec![],
            judge_repeats: 0,
            judge_budget_usd: None,
            content_hash: tasks.join(","),
            text_models: Vec::new(),
            text_groups: Vec::new(),
            dynamics: None,
            ranking: None,
            generalization: None,
        }
    }

    fn outcome(l: &Lease) -> String {
        serde_json::to_string(&episode(l)).unwrap()
    }

    fn episode(l: &Lease) -> EpisodeOutcome {
        EpisodeOutcome {
            task_id: "x".into(),
            seed: l.seed,
            policy: l.policy.clone(),
            success: true,
            label_source: LabelSource::Sim,
            predicates: vec![],
            steps: 1,
            sim_time_s: 0.0,
            artifact: String::new(),
            spec_hash: String::new(),
            versions: BTreeMap::new(),
            imagery: None,
        }
    }

    fn sim() -> Vec<String> {
        vec!["sim".into()]
    }

    #[test]
    fn plans_seed_major_and_completes_once() {
        let mut s = Store::open_in_memory().unwrap();
        let (id, n) = s.submit(&batch(&["a", "b"], &[0, 1], 3), 0).unwrap();
        assert_eq!(n, 4);
        let leases = s.lease("w1", &sim(), 10, 0, TTL).unwrap();
        assert_eq!(leases.len(), 4);
        assert_eq!((leases[0].seed, leases[1].seed, leases[2].seed), (0, 0, 1));
        for l in &leases {
            let (ok, _) = s
                .complete("w1", l.lease_id, l.shard_id, &outcome(l), 0.1, 5)
                .unwrap();
            assert!(ok);
            // A duplicate of the same result is not counted again.
            let (again, _) = s
                .complete("w1", l.lease_id, l.shard_id, &outcome(l), 0.1, 5)
                .unwrap();
            assert!(!again);
        }
        let c = s.counts(&id).unwrap();
        assert_eq!((c.done, c.successes, c.state.as_str()), (4, 4, "completed"));
        assert_eq!(c.finished_ms, Some(5));
    }

    #[test]
    fn expired_lease_requeues_and_late_result_is_rejected() {
        let mut s = Store::open_in_memory().unwrap();
        let (id, _) = s.submit(&batch(&["a"], &[0], 3), 0).unwrap();
        let first = s.lease("w1", &sim(), 1, 0, TTL).unwrap().remove(0);
        // Heartbeats keep it alive past the original deadline.
        assert_eq!(
            s.heartbeat("w1", &[first.lease_id], 900, TTL).unwrap(),
            vec![first.lease_id]
        );
        assert_eq!(s.expire(1_500, None).unwrap().requeued, 0);
        // Silence: it expires and goes back to the queue.
        assert_eq!(s.expire(2_000, None).unwrap().requeued, 1);
        let second = s.lease("w2", &sim(), 1, 2_000, TTL).unwrap().remove(0);
        assert_eq!(second.shard_id, first.shard_id);
        assert_eq!(second.attempt, 2);
        // The first worker's late result does not count; the second's does.
        assert!(
            !s.complete(
                "w1",
                first.lease_id,
                first.shard_id,
                &outcome(&first),
                0.1,
                2_100
            )
            .unwrap()
            .0
        );
        assert!(
            s.complete(
                "w2",
                second.lease_id,
                second.shard_id,
                &outcome(&second),
                0.1,
                2_200
            )
            .unwrap()
            .0
        );
        let c = s.counts(&id).unwrap();
        assert_eq!((c.done, c.total), (1, 1));
        // A heartbeat for a lease the worker no longer holds is refused.
        assert!(
            s.heartbeat("w1", &[first.lease_id], 2_300, TTL)
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn failures_retry_a_bounded_number_of_times_then_record_the_error() {
        let mut s = Store::open_in_memory().unwrap();
        let (id, _) = s.submit(&batch(&["a"], &[0], 2), 0).unwrap();
        let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
        assert_eq!(
            s.fail(l.lease_id, l.shard_id, "boom", true, 1)
                .unwrap()
                .requeued,
            1
        );
        let l = s.lease("w", &sim(), 1, 2, TTL).unwrap().remove(0);
        assert_eq!(l.attempt, 2);
        assert_eq!(
            s.fail(l.lease_id, l.shard_id, "boom", true, 3)
                .unwrap()
                .requeued,
            0
        );
        let c = s.counts(&id).unwrap();
        assert_eq!((c.failed, c.state.as_str()), (1, "completed"));
        let r = s.report(&id).unwrap();
        assert_eq!(
            r.results.tasks[0].failures[0].error,
            "boom (after 2 attempts)"
        );
        // Non-retryable errors fail at once.
        let (id2, _) = s.submit(&batch(&["b"], &[0], 5), 0).unwrap();
        let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
        s.fail(l.lease_id, l.shard_id, "bad spec", false, 1)
            .unwrap();
        assert_eq!(s.counts(&id2).unwrap().failed, 1);
    }

    #[test]
    fn returned_leases_do_not_count_as_attempts_and_disconnects_do() {
        let mut s = Store::open_in_memory().unwrap();
        let (_, _) = s.submit(&batch(&["a", "b"], &[0], 1), 0).unwrap();
        let ls = s.lease("w", &sim(), 2, 0, TTL).unwrap();
        s.return_leases("w", &[ls[0].lease_id]).unwrap();
        let again = s.lease("w2", &sim(), 1, 0, TTL).unwrap().remove(0);
        assert_eq!(again.attempt, 1);
        // w disconnects holding ls[1]: with max_attempts 1 the shard fails with the reason.
        let ch = s.expire(10, Some(("w", &[ls[1].lease_id]))).unwrap();
        assert_eq!(ch.requeued, 0);
        let r = s.report(&ls[1].batch_id).unwrap();
        let failure = &r
            .results
            .tasks
            .iter()
            .find(|t| t.id == "b")
            .unwrap()
            .failures[0];
        assert_eq!(failure.attempts, 1);
        assert!(
            failure.error.contains("worker w disconnected"),
            "{}",
            failure.error
        );
    }

    #[test]
    fn survives_reopen_with_leases_intact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.db");
        let (id, lease) = {
            let mut s = Store::open(&path).unwrap();
            let (id, _) = s.submit(&batch(&["a", "b"], &[0], 3), 0).unwrap();
            (id, s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0))
        };
        let mut s = Store::open(&path).unwrap();
        assert_eq!(s.running_batches().unwrap(), vec![id.clone()]);
        assert_eq!(s.refresh_leases(50_000, TTL).unwrap(), 1);
        // The worker reconnects running `lease` and knowing nothing of a second lease that was
        // assigned just before the crash: that one goes back without costing an attempt.
        let lost = s.lease("w", &sim(), 1, 50_000, TTL).unwrap().remove(0);
        let (kept, returned) = s.reconcile("w", &[lease.lease_id, 999]).unwrap();
        assert_eq!(kept, vec![lease.lease_id]);
        assert_eq!(returned.requeued, 1);
        let again = s.lease("w2", &sim(), 1, 50_000, TTL).unwrap().remove(0);
        assert_eq!((again.shard_id, again.attempt), (lost.shard_id, 1));
        assert!(
            s.complete(
                "w",
                lease.lease_id,
                lease.shard_id,
                &outcome(&lease),
                0.1,
                50_001
            )
            .unwrap()
            .0
        );
        // Lease ids keep increasing across reopen.
        assert!(lost.lease_id > lease.lease_id && again.lease_id > lost.lease_id);
    }

    #[test]
    fn cancel_stops_queued_and_leased_shards() {
        let mut s = Store::open_in_memory().unwrap();
        let (id, _) = s.submit(&batch(&["a", "b", "c"], &[0], 3), 0).unwrap();
        let l = s.lease("w", &sim(), 1, 0, TTL).unwrap().remove(0);
        s.cancel(&id, 1).unwrap();
        let c = s.counts(&id).unwrap();
        assert_eq!((c.cancelled, c.state.as_str()), (3, "cancelled"));
        assert!(
            !s.complete("w", l.lease_id, l.shard_id, &outcome(&l), 0.1, 2)
                .unwrap()
                .0
        );
        assert!(s.lease("w", &sim(), 5, 3, TTL).unwrap().is_empty());
    }

    fn rendered(l: &Lease) -> String {
        rendered_with_clip(l, None)
    }

    /// A rendered episode's outcome, with a dynamics clip when `clip` is given.
    fn rendered_with_clip(l: &Lease, clip: Option<String>) -> String {
        let mut e = episode(l);
        e.imagery = Some(assay_core::report::EpisodeImagery {
            adapter: "test".into(),
            views: vec![],
            keyframes: vec![],
            contact_sheet: String::new(),
            video: None,
            caption: None,
            clip,
        });
        serde_json::to_string(&e).unwrap()
    }

    fn judged(l: &Lease, cost: f64) -> String {
        let j = l.judge.as_ref().unwrap();
        serde_json::to_string(&JudgeOutcome {
            judge: j.judge.clone(),
            backend: "openai".into(),
            model: "m".into(),
            task_id: "a".into(),
            seed: l.seed,
            policy: l.policy.clone(),
            repeats: j.repeats,
            items: vec![],
            usage: assay_core::quality::Usage {
                cost_usd: cost,
                ..Default::default()
            },
            transcript: None,
        })
        .unwrap()
    }

    #[test]
    fn rendered_episodes_of_judged_batches_queue_one_judge_shard_per_judge() {
        let mut s = Store::open_in_memory().unwrap();
        let mut b = batch(&["a", "b"], &[0], 3);
        b.judges = vec!["offline".into(), "vlm".into()];
        b.judge_repeats = 3;
        b.judge_budget_usd = Some(1.0);
        let (id, _) = s.submit(&b, 0).unwrap();
        let judge = vec!["judge".to_owned()];
        let leases = s.lease("w", &sim(), 2, 1, TTL).unwrap();
        // An episode without imagery cannot be judged: nothing is queued for it.
        assert!(
            s.complete(
                "w",
                leases[0].lease_id,
                leases[0].shard_id,
                &outcome(&leases[0]),
                0.1,
                2
            )
            .unwrap()
            .0
        );
        assert!(s.lease("w", &judge, 5, 3, TTL).unwrap().is_empty());
        let c = s.counts(&id).unwrap();
        assert_eq!((c.judge_total, c.state.as_str()), (0, "running"));
        // A rendered one gets a shard per judge, carrying the episode, in the same transaction:
        // the batch is not finished while they wait.
        let (ok, changed) = s
            .complete(
                "w",
                leases[1].lease_id,
                leases[1].shard_id,
                &rendered(&leases[1]),
                0.1,
                4,
            )
            .unwrap();
        assert!(ok);
        assert_eq!(changed.requeued, 2, "judge workers are woken");
        let c = s.counts(&id).unwrap();
        assert_eq!((c.total, c.done, c.judge_total, c.judge_done), (2, 2, 2, 0));
        assert_eq!(c.state, "running");
        let js = s.lease("j", &judge, 5, 5, TTL).unwrap();
        assert_eq!(js.len(), 2);
        let names: Vec<&str> = js
            .iter()
            .map(|l| l.judge.as_ref().unwrap().judge.as_str())
            .collect();
        assert_eq!(names, ["offline", "vlm"]);
        for l in &js {
            let j = l.judge.as_ref().unwrap();
            assert_eq!((j.repeats, j.budget_left_usd), (3, Some(1.0)));
            assert_eq!(j.episode_json, rendered(&leases[1]));
            assert_eq!(l.role, "judge");
        }
        // A judge outcome that does not parse is a failed attempt, not a result.
        let (ok, _) = s
            .complete("j", js[0].lease_id, js[0].shard_id, "{\"nope\": 1}", 0.1, 6)
            .unwrap();
        assert!(!ok);
        let again = s.lease("j", &judge, 5, 7, TTL).unwrap();
        assert_eq!(again.len(), 1);
        // What is spent counts against the budget of shards leased later.
        assert!(
            s.complete(
                "j",
                js[1].lease_id,
                js[1].shard_id,
                &judged(&js[1], 0.25),
                0.1,
                8
            )
            .unwrap()
            .0
        );
        assert_eq!(s.counts(&id).unwrap().judge_cost_usd, 0.25);
        s.fail(again[0].lease_id, again[0].shard_id, "flaky", true, 9)
            .unwrap();
        let last = s.lease("j", &judge, 5, 10, TTL).unwrap();
        assert_eq!(last[0].judge.as_ref().unwrap().budget_left_usd, Some(0.75));
        assert!(
            s.complete(
                "j",
                last[0].lease_id,
                last[0].shard_id,
                &judged(&last[0], 0.0),
                0.1,
                11
            )
            .unwrap()
            .0
        );
        let c = s.counts(&id).unwrap();
        assert_eq!((c.judge_done, c.state.as_str()), (2, "completed"));
        // The report has the judges' quality beside the episodes.
        let r = s.report(&id).unwrap();
        assert_eq!(r.results.totals.episodes_completed, 2);
        let q = r.results.quality.unwrap();
        assert_eq!(q.judges.len(), 2);
        assert_eq!(q.judges.iter().map(|j| j.episodes_judged).sum::<u64>(), 2);
    }

    /// Once a group's episodes are done, one fit per budget on its clips in planning order; a
    /// budget at or above the number of clips covers them all, and larger ones are not queued.
    #[test]
    fn a_finished_group_queues_one_fit_per_budget_its_clips_can_tell_apart() {
        let mut s = Store::open_in_memory().unwrap();
        let mut b = batch(&["a", "b", "c", "d", "e"], &[0], 3);
        b.dynamics = Some(DynamicsPlan {
            budgets: vec![2, 5, 8, 40],
            config: DynamicsConfig::default(),
        });
        let (id, _) = s.submit(&b, 0).unwrap();
        let trainer = vec!["trainer".to_owned()];
        let leases = s.lease("w", &sim(), 5, 1, TTL).unwrap();
        for (i, l) in leases.iter().enumerate() {
            let json = rendered_with_clip(l, Some(format!("clips/{i}.clip")));
            assert!(
                s.complete("w", l.lease_id, l.shard_id, &json, 0.1, 2)
                    .unwrap()
                    .0
            );
            // Nothing is trained while the group still has episodes to run.
            let queued = s.lease("t", &trainer, 10, 2, TTL).unwrap();
            assert_eq!(queued.is_empty(), i + 1 < leases.len(), "after episode {i}");
            if !queued.is_empty() {
                let jobs: Vec<TrainerJob> = queued
                    .iter()
                    .map(|l| serde_json::from_str(l.trainer_job.as_deref().unwrap()).unwrap())
                    .collect();
                let clips: Vec<String> = (0..5).map(|i| format!("clips/{i}.clip")).collect();
                let budgets: Vec<u32> = jobs
                    .iter()
                    .map(|j| match j {
                        TrainerJob::Dynamics {
                            group,
                            budget,
                            clips: c,
                            ..
                        } => {
                            assert_eq!((group.as_str(), c), ("g", &clips));
                            *budget
                        }
                        other => panic!("{other:?}"),
                    })
                    .collect();
                assert_eq!(budgets, [2, 5]);
            }
        }
        let c = s.counts(&id).unwrap();
        assert_eq!((c.trainer_total, c.state.as_str()), (2, "running"));
    }

    #[test]
    fn a_ranking_batch_queues_one_proxy_per_group_that_never_sees_the_ranked_outcomes() {
        use assay_core::proxy::{ProxyConfig, ProxyPrediction};
        use assay_core::quality::ItemOutcome;
        use assay_core::report::Keyframe;
        let mut s = Store::open_in_memory().unwrap();
        let tasks = ["a", "b"];
        let mut b = batch(&tasks, &[0, 1], 3);
        let policies = ["oracle", "oracle:noise=0.03", "oracle:noise=0.01"];
        b.policies = policies.iter().map(|p| p.to_string()).collect();
        // The offline judge judges the real episodes only; a VLM judges the imagined ones too.
        b.judges = vec!["offline".into(), "vlm".into()];
        b.ranking = Some(RankingPlan {
            train_policies: vec!["oracle:noise=0.01".into()],
            config: ProxyConfig::default(),
        });
        let (id, n) = s.submit(&b, 0).unwrap();
        assert_eq!(n, 12);
        let trainer = vec!["trainer".to_owned()];
        let leases = s.lease("w", &sim(), 12, 1, TTL).unwrap();
        // Every episode of a ranking batch renders a clip of the proxy's frame size.
        assert!(leases.iter().all(|l| l.clip_size == 64));
        let mut truth = std::collections::HashMap::new();
        for (i, l) in leases.iter().enumerate() {
            // Seed-major, then policy, then task.
            assert_eq!(l.policy, policies[(i / 2) % 3]);
            let mut e = episode(l);
            e.task_id = tasks[i % 2].into();
            e.success = i % 3 != 0;
            e.imagery = Some(assay_core::report::EpisodeImagery {
                adapter: "test".into(),
                views: vec![],
                keyframes: vec![],
                contact_sheet: String::new(),
                video: None,
                caption: None,
                clip: Some(format!("clips/{i}.clip")),
            });
            truth.insert((e.task_id.clone(), e.policy.clone(), e.seed), e.success);
            let json = serde_json::to_string(&e).unwrap();
            assert!(
                s.complete("w", l.lease_id, l.shard_id, &json, 0.1, 2)
                    .unwrap()
                    .0
            );
        }
        let judge = vec!["judge".to_owned()];
        let real_judging = s.lease("j", &judge, 100, 2, TTL).unwrap();
        assert_eq!(real_judging.len(), 24);
        for l in &real_judging {
            assert!(
                s.complete("j", l.lease_id, l.shard_id, &judged(l, 0.0), 0.1, 2)
                    .unwrap()
                    .0
            );
        }
        let queued = s.lease("t", &trainer, 10, 3, TTL).unwrap();
        assert_eq!(queued.len(), 1);
        let input = queued[0].trainer_job.clone().unwrap();
        let TrainerJob::Proxy {
            group, train, eval, ..
        } = serde_json::from_str(&input).unwrap()
        else {
            panic!("{input}")
        };
        assert_eq!(group, "g");
        assert_eq!(train.len(), 4);
        assert!(
            train
                .iter()
                .all(|e| e.policy == "oracle:noise=0.01" && e.success.is_some())
        );
        assert_eq!(eval.len(), 8);
        // The ranked episodes' outcomes never reach the trainer.
        assert!(
            eval.iter()
                .all(|e| e.success.is_none() && e.policy != "oracle:noise=0.01")
        );
        assert_eq!(input.matches("\"success\"").count(), 4);
        // The proxy predicts the opposite of the truth for one ranked episode.
        let predictions = eval
            .iter()
            .map(|e| {
                let real = truth[&(e.task_id.clone(), e.policy.clone(), e.seed)];
                let wrong = e.task_id == "a" && e.seed == 0 && e.policy == "oracle";
                let success = real != wrong;
                ProxyPrediction {
                    task_id: e.task_id.clone(),
                    policy: e.policy.clone(),
                    seed: e.seed,
                    p_success: if success { 0.9 } else { 0.1 },
                    success,
                    p_success_real_frame: if real { 0.8 } else { 0.2 },
                    last_frame_mse: 0.001,
                    imagined_keyframes: (0..8)
                        .map(|k| Keyframe {
                            step: k,
                            camera: "imagined".into(),
                            artifact: format!("imagery/{}-{}-{k}.png", e.task_id, e.seed),
                            goals_met: 0,
                        })
                        .collect(),
                }
            })
            .collect();
        let fit: assay_core::dynamics::DynamicsFit = serde_json::from_value(serde_json::json!({
            "group": "g", "budget": 4, "train_episodes": 4, "eval_episodes": 8, "eval_image_mse": 0.001,
            "eval_proprio_mse": 0.0, "per_episode": [], "episodes": [], "final_train_loss": 1.0,
            "steps": 10, "epochs": 1.0, "device": "cpu", "config": {}
        }))
        .unwrap();
        let outcome = TrainerOutcome::Proxy {
            result: Box::new(ProxyResult {
                group: "g".into(),
                world_model: fit,
                judge_examples: 8,
                judge_positives: 5,
                judge_train_accuracy: 1.0,
                predictions,
                seconds: 1.0,
                imagined_frames: Vec::new(),
            }),
        };
        let json = serde_json::to_string(&outcome).unwrap();
        let l = &queued[0];
        assert!(
            s.complete("t", l.lease_id, l.shard_id, &json, 1.0, 4)
                .unwrap()
                .0
        );
        // The VLM is asked about every imagined rollout: the real episode with the imagined
        // keyframes for imagery and no scene views. The batch waits for it.
        assert_eq!(s.counts(&id).unwrap().state, "running");
        let imagined = s.lease("j", &judge, 100, 5, TTL).unwrap();
        assert_eq!(imagined.len(), 8);
        for (k, l) in imagined.iter().enumerate() {
            let j = l.judge.as_ref().unwrap();
            assert_eq!(j.judge, "vlm");
            let e: EpisodeOutcome = serde_json::from_str(&j.episode_json).unwrap();
            let img = e.imagery.unwrap();
            assert!(img.views.is_empty());
            assert_eq!(img.keyframes.len(), 8);
            assert!(
                img.keyframes[7]
                    .artifact
                    .ends_with(&format!("{}-{}-7.png", e.task_id, e.seed))
            );
            if k == 0 {
                s.fail(l.lease_id, l.shard_id, "HTTP 400", false, 6)
                    .unwrap();
                continue;
            }
            // The VLM says what really happened.
            let real = truth[&(e.task_id.clone(), e.policy.clone(), e.seed)];
            let mut o: JudgeOutcome = serde_json::from_str(&judged(l, 0.0)).unwrap();
            o.task_id = e.task_id.clone();
            o.items = vec![ItemOutcome {
                item: Item::Completion,
                prompt: "completion/v1".into(),
                scores: vec![if real { 9.0 } else { 1.0 }],
                errors: vec![],
                unjudged: 0,
            }];
            let o = serde_json::to_string(&o).unwrap();
            assert!(
                s.complete("j", l.lease_id, l.shard_id, &o, 0.1, 6)
                    .unwrap()
                    .0
            );
        }
        assert_eq!(s.counts(&id).unwrap().state, "completed");
        let k = s.report(&id).unwrap().results.ranking.unwrap();
        assert_eq!(k.ranked_policies, ["oracle", "oracle:noise=0.03"]);
        assert_eq!(k.rows.len(), 4);
        assert!(
            k.rows
                .iter()
                .all(|r| r.real.trials == 2 && r.proxy.as_ref().unwrap().trials == 2)
        );
        let agree = k.proxy_agreement.unwrap();
        assert_eq!((agree.successes, agree.trials), (7, 8));
        let judge = k.judge_agreement_real_frames.unwrap();
        assert_eq!((judge.successes, judge.trials), (8, 8));
        // Verdicts on imagined rollouts are a proxy of their own, not quality.
        assert_eq!(k.judging_errors.len(), 1);
        assert!(k.judging_errors[0].4.contains("HTTP 400"));
        let judged: u64 = k
            .rows
            .iter()
            .flat_map(|r| &r.judged_proxy)
            .map(|j| j.success.trials)
            .sum();
        assert_eq!(judged, 7);
        let ranking = k.ranking.expect("two policies ranked");
        let proxies: Vec<&str> = ranking
            .comparisons
            .iter()
            .map(|c| c.proxy.as_str())
            .collect();
        assert_eq!(proxies, ["world-model", "world-model+vlm"]);
        assert_eq!(ranking.comparisons[0].policies.len(), 2);
        assert_eq!(ranking.comparisons[1].mmrv.value, Some(0.0));
        // The VLM's quality covers the batch's 12 real episodes, not its imagined rollouts.
        let q = s.report(&id).unwrap().results.quality.unwrap();
        let vlm = q.judges.iter().find(|j| j.judge == "vlm").unwrap();
        assert_eq!((vlm.episodes_judged, vlm.episodes_failed), (12, 0));
    }

    #[test]
    fn a_store_from_before_judges_gains_their_columns() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.db");
        {
            let conn = Connection::open(&path).unwrap();
            conn.execute_batch(SCHEMA).unwrap();
            conn.execute_batch(
                "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms)
                 VALUES ('b1', 1, 'old', 'completed', '[\"oracle\"]', '[0]', 3, '[]', 0)",
            )
            .unwrap();
        }
        let s = Store::open(&path).unwrap();
        let r = s.report("b1").unwrap();
        assert!(r.results.quality.is_none());
        let mut s = s;
        let (id, _) = s.submit(&batch(&["a"], &[0], 3), 1).unwrap();
        assert_eq!(s.counts(&id).unwrap().total, 1);
    }
}
