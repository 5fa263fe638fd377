//! The job store: batches, tasks and shards in one SQLite file.
//!
//! Every state change of a shard is one SQL statement guarded by its current state and lease id,
//! so a late or duplicate message can never count a shard twice. Time is passed in (`now_ms`), so
//! lease logic is tested without sleeping.
//!
//! Owns: the [`Store`] and its one connection, the types its callers exchange with it, opening,
//! group commit, and the helpers several concerns share. The rest is split by concern, each file
//! adding its own `impl Store` block: `schema` (tables and migrations), `planner` (which shards a
//! batch has, at submission and as its groups finish), `leases` (the shard state machine),
//! `read_model` (counts, batch lists, the rows a report is assembled from) and `metrics` (the
//! figures `/metrics` shows).
//! Never: gRPC, scheduling or threads (the service and the store actor), nor formatting text.

use std::path::Path;

use assay_model::generalization::GeneralizationPlan;
pub use assay_model::job::Priority;
use assay_model::proxy::RankingPlan;
use assay_spec::SpecError;
use rusqlite::{Connection, OptionalExtension, params};

use crate::error::CoordError;

mod cache;
mod checkpoint;
mod fair;
pub use fair::BatchShare;
mod leases;
mod metrics;
pub use metrics::{SHARD_SECONDS_BUCKETS, Snapshot};
mod planner;
mod read_model;
pub use read_model::REPORT_GENERATOR;
mod schema;
#[cfg(test)]
mod tests;

/// States a shard moves through, as stored (`assay_model::job::ShardState`): queued → leased →
/// done | failed | cancelled; an expired or returned lease goes back to queued.
pub mod shard_state {
    use assay_model::job::ShardState;

    pub const QUEUED: &str = ShardState::Queued.as_str();
    pub const LEASED: &str = ShardState::Leased.as_str();
    pub const DONE: &str = ShardState::Done.as_str();
    pub const FAILED: &str = ShardState::Failed.as_str();
    pub const CANCELLED: &str = ShardState::Cancelled.as_str();
}

pub mod batch_state {
    pub const RUNNING: &str = "running";
    pub const COMPLETED: &str = "completed";
    pub const CANCELLED: &str = "cancelled";
    /// Not run: the same tasks were evaluated before (`duplicate_of`).
    pub const SKIPPED: &str = "skipped";
}

/// Shard roles.
pub mod role {
    pub const SIM: &str = "sim";
    pub const RENDER: &str = "render";
    pub const JUDGE: &str = "judge";
    pub const TRAINER: &str = "trainer";
}

pub use assay_plan::{DynamicsPlan, PlannedTask};

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
    /// Every episode is rendered (views, keyframes, contact sheet).
    pub render: bool,
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
    /// Its share of the cluster beside other running batches, who submitted it (one submitter's
    /// batches of a class share the class's weight) and the most workers it may hold at once
    /// (0: no cap). See `fair`.
    pub share: Share,
}

/// How a batch shares the cluster with the other running batches.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Share {
    pub priority: Priority,
    pub submitter: String,
    pub max_workers: u32,
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
    /// For a trainer shard: its job (JSON `assay_model::trainer::TrainerJob`).
    pub trainer_job: Option<String>,
    /// For an episode of a batch that measures dynamics diversity: the clip's frame size.
    pub clip_size: u32,
    /// With `clip_size`: the policy interface the clip is recorded at (empty: the original).
    pub clip_interface: String,
    /// For an episode of a batch that renders: its pictures are wanted.
    pub render: bool,
    /// For an episode waiting for its pictures (role `render`): its outcome with its scenes.
    pub render_input: Option<String>,
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
    /// Its share of the cluster: as submitted, and what it holds now.
    pub share: BatchShare,
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
    /// Copies the write-ahead log into the file beside the store's thread (a store in a file;
    /// first, so that it stops before the connection closes).
    checkpointer: Option<checkpoint::Checkpointer>,
    conn: Connection,
    /// What leasing and completion read of a batch that never changes once submitted.
    cache: cache::Cache,
    /// Lease ids taken from the file's counter and not yet handed out: `next..end`.
    lease_ids: Option<std::ops::Range<u64>>,
}

/// Lease ids the store takes from its counter at once: a lease writes the counter's page once
/// per this many leases instead of every time. Ids left when the store closes are never used.
const LEASE_ID_BLOCK: u64 = 1024;

impl Store {
    pub fn open(path: &Path) -> Result<Self, CoordError> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        let mut store = Self::init(conn)?;
        store
            .conn
            .pragma_update(None, "wal_autocheckpoint", checkpoint::WAL_AUTOCHECKPOINT)?;
        store.checkpointer = Some(checkpoint::Checkpointer::start(path)?);
        Ok(store)
    }

    pub fn open_in_memory() -> Result<Self, CoordError> {
        Self::init(Connection::open_in_memory()?)
    }

    fn init(conn: Connection) -> Result<Self, CoordError> {
        // Every statement a lease, a completion and the planner prepare stays prepared: with
        // rusqlite's default of 16, a lease and its completion evicted each other's statements
        // and parsed them again on every call.
        conn.set_prepared_statement_cache_capacity(256);
        schema::migrate(&conn)?;
        Ok(Self {
            checkpointer: None,
            conn,
            cache: Default::default(),
            lease_ids: None,
        })
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
            // What the group's calls read of batches it submitted is gone with them, and so
            // are the lease ids they took from the counter.
            self.cache.clear();
            self.lease_ids = None;
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

    /// `n` consecutive lease ids; returns the first. Taken from the block the store holds, or a
    /// new block from the counter (in `tx`: a caller whose transaction does not commit must drop
    /// the block, see [`Store::lease`]).
    fn next_lease_ids(
        tx: &Connection,
        block: &mut Option<std::ops::Range<u64>>,
        n: u64,
    ) -> Result<u64, CoordError> {
        match block {
            Some(ids) if ids.end - ids.start >= n => {
                let first = ids.start;
                ids.start += n;
                Ok(first)
            }
            _ => {
                let take = n.max(LEASE_ID_BLOCK);
                let first = Self::next_counter(tx, "lease_seq", take)?;
                *block = Some(first + n..first + take);
                Ok(first)
            }
        }
    }

    /// Takes the next `n` values of the counter `key` (batch numbers, lease ids); returns the
    /// first.
    fn next_counter(tx: &Connection, key: &str, n: u64) -> Result<u64, CoordError> {
        // One statement where the counter exists (every lease but the store's first).
        let taken: Option<i64> = tx
            .prepare_cached(
                "UPDATE meta SET value = value + ?2 WHERE key = ?1 RETURNING value - ?2",
            )?
            .query_row(params![key, n as i64], |r| r.get(0))
            .optional()?;
        if let Some(first) = taken {
            return Ok(first as u64);
        }
        tx.prepare_cached("INSERT INTO meta (key, value) VALUES (?1, ?2)")?
            .execute(params![key, (1 + n) as i64])?;
        Ok(1)
    }
}
