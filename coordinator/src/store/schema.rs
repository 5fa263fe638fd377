//! The job store's schema: tables and indexes, and the columns added since the first release.
//!
//! Owns: every `CREATE` statement (tables, indexes, the triggers that keep each batch's load)
//! and the migration of an older store file when it is opened, with the backfill of the one
//! added column older rows cannot do without (a shard's kind, from its job name) and the
//! recount of the loads. Never reads rows, nor changes them otherwise.

use assay_model::generalization::HELD_OUT_VARIATIONS;
use assay_model::job::JobKind;
use assay_model::proxy::IMAGINED_JUDGING;
use rusqlite::Connection;

use crate::error::CoordError;

/// A new store's pages are 2 KiB (SQLite's default is 4 KiB; a store made before keeps its own):
/// a lease or a completion changes one row and a few index entries, and writes each page it
/// changes to the log whole, so smaller pages write fewer bytes — but a read of many rows (a
/// batch's counts, a report) visits more pages. `assay bench coordinator --workers 1000
/// --shards 100000`, release, the store alone (one transaction per call): 22,000
/// lease+complete/s at 2 KiB, 18,000 at 4 KiB, about 20,000 at 1 KiB; `assay bench churn` (status
/// read ten times a second): 7,600 shards/s at 2 KiB, 8,900 at 4 KiB, 5,800 at 1 KiB.
pub(super) const SCHEMA: &str = r#"
PRAGMA page_size = 2048;
PRAGMA journal_mode = WAL;
PRAGMA synchronous = NORMAL;
PRAGMA temp_store = MEMORY;
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
    // Policy ranking (JSON `assay_model::proxy::RankingPlan`; NULL: none).
    ("batches", "ranking_json", "TEXT"),
    // Generalization (JSON `assay_model::generalization::GeneralizationPlan`; NULL: none).
    ("batches", "generalization_json", "TEXT"),
    // Continuous evaluation: the batch's content hash, and for a skipped batch the batch it
    // repeats.
    ("batches", "content_hash", "TEXT NOT NULL DEFAULT ''"),
    ("batches", "duplicate_of", "TEXT"),
    // Capabilities (issue 28): whether the batch renders its episodes; what a shard needs of its
    // worker (JSON array; NULL: its role), and an episode's stage ('render' while it waits for
    // its pictures; NULL: simulating or done).
    ("batches", "render", "INTEGER NOT NULL DEFAULT 0"),
    ("shards", "needs", "TEXT"),
    ("shards", "stage", "TEXT"),
    // What a shard does (`assay_model::job::JobKind`): what the store selects shards by. A row
    // written before it gets its kind from its role and job name (`backfill_kinds`).
    ("shards", "kind", "TEXT"),
    // Sharing the cluster (issue 42): the batch's priority class, who submitted it (one
    // submitter's batches of a class share that class's weight) and the most workers it may
    // hold at once (0: no cap).
    ("batches", "priority", "TEXT NOT NULL DEFAULT 'normal'"),
    ("batches", "submitter", "TEXT NOT NULL DEFAULT ''"),
    ("batches", "max_workers", "INTEGER NOT NULL DEFAULT 0"),
];

/// What leasing reads, made after the added columns exist (an older store gains them first);
/// the triggers are made afresh on every open, so a store keeps this version's.
///
/// The shards' indexes are chosen by what a lease and a completion write: SQLite writes every
/// page a transaction changes to the log whole, and an index entry that moves (its state is
/// part of its key) changes two leaves. An index with no column a change of state touches costs
/// nothing then; a partial index of the shards in one state changes one leaf as a shard enters
/// it and one as it leaves. Earlier versions had three indexes of every shard keyed by state
/// (`shards_by_state (state, role, id)`, `shards_by_batch (batch_id, state)`, `shards_by_needs
/// (state, batch_id, needs, id)`) and `shards_by_lease (lease_id)`: about ten leaves a shard,
/// where these write three.
///
/// - `shards_in_batch`: a batch's shards, in id order (counts, reports, the planner's reads).
///   No change of state touches it.
/// - `shards_waiting`: the queued shards, by batch and what they need of a worker, in id order —
///   a lease reads the few queued shards it takes from it, however long the queue (the earlier
///   lease query ordered every queued shard by id, a cost in the queue's length). `needs` is
///   always set (a shard that needs only its role gets `json_array(role)`: backfilled here, and
///   by the `shards_needs` trigger for every new row), so the index is on plain columns.
/// - `shards_leased`: the shards leased now, by worker and lease (a heartbeat, a hand-back, the
///   lease sweep, a worker's leases when it comes back; a batch's workers read all of it, a
///   few thousand entries at most).
/// - `batch_load`: per batch with open shards, how many are queued and how many leased, kept by
///   triggers on every change of a shard's state (whichever statement makes it), so the fair
///   share reads the running batches' loads without counting shards. A batch leaves it when
///   nothing of it is open. Rebuilt from the shards on every open ([`rebuild_load`]).
const LEASING: &str = r#"
DROP INDEX IF EXISTS shards_queue;
DROP INDEX IF EXISTS shards_queued;
DROP INDEX IF EXISTS batch_load_queued;
DROP INDEX IF EXISTS shards_by_needs;
DROP INDEX IF EXISTS shards_by_batch;
DROP INDEX IF EXISTS shards_by_lease;
DROP INDEX IF EXISTS shards_by_state;
UPDATE shards SET needs = json_array(role) WHERE needs IS NULL;
DROP TRIGGER IF EXISTS shards_needs;
CREATE TRIGGER shards_needs AFTER INSERT ON shards WHEN new.needs IS NULL BEGIN
    UPDATE shards SET needs = json_array(new.role) WHERE id = new.id;
END;
CREATE INDEX IF NOT EXISTS shards_in_batch ON shards (batch_id);
CREATE INDEX IF NOT EXISTS shards_waiting ON shards (batch_id, needs, id) WHERE state = 'queued';
CREATE INDEX IF NOT EXISTS shards_leased ON shards (lease_worker, lease_id) WHERE state = 'leased';
CREATE TABLE IF NOT EXISTS batch_load (
    batch_id TEXT PRIMARY KEY,
    queued INTEGER NOT NULL,
    leased INTEGER NOT NULL
);
DROP TRIGGER IF EXISTS batch_load_insert;
DROP TRIGGER IF EXISTS batch_load_update;
DROP TRIGGER IF EXISTS batch_load_move;
DROP TRIGGER IF EXISTS batch_load_close;
DROP TRIGGER IF EXISTS batch_load_reopen;
DROP TRIGGER IF EXISTS batch_load_delete;
CREATE TRIGGER batch_load_insert AFTER INSERT ON shards
WHEN new.state IN ('queued', 'leased') BEGIN
    INSERT OR IGNORE INTO batch_load (batch_id, queued, leased) VALUES (new.batch_id, 0, 0);
    UPDATE batch_load SET queued = queued + (new.state = 'queued'),
                          leased = leased + (new.state = 'leased')
     WHERE batch_id = new.batch_id;
END;
CREATE TRIGGER batch_load_move AFTER UPDATE OF state ON shards
WHEN old.state IS NOT new.state AND old.state IN ('queued', 'leased')
 AND new.state IN ('queued', 'leased') BEGIN
    UPDATE batch_load SET queued = queued + (new.state = 'queued') - (old.state = 'queued'),
                          leased = leased + (new.state = 'leased') - (old.state = 'leased')
     WHERE batch_id = new.batch_id;
END;
CREATE TRIGGER batch_load_close AFTER UPDATE OF state ON shards
WHEN old.state IN ('queued', 'leased') AND new.state NOT IN ('queued', 'leased') BEGIN
    UPDATE batch_load SET queued = queued - (old.state = 'queued'),
                          leased = leased - (old.state = 'leased')
     WHERE batch_id = new.batch_id;
    DELETE FROM batch_load WHERE batch_id = new.batch_id AND queued = 0 AND leased = 0;
END;
CREATE TRIGGER batch_load_reopen AFTER UPDATE OF state ON shards
WHEN old.state NOT IN ('queued', 'leased') AND new.state IN ('queued', 'leased') BEGIN
    INSERT OR IGNORE INTO batch_load (batch_id, queued, leased) VALUES (new.batch_id, 0, 0);
    UPDATE batch_load SET queued = queued + (new.state = 'queued'),
                          leased = leased + (new.state = 'leased')
     WHERE batch_id = new.batch_id;
END;
CREATE TRIGGER batch_load_delete AFTER DELETE ON shards
WHEN old.state IN ('queued', 'leased') BEGIN
    UPDATE batch_load SET queued = queued - (old.state = 'queued'),
                          leased = leased - (old.state = 'leased')
     WHERE batch_id = old.batch_id;
    DELETE FROM batch_load WHERE batch_id = old.batch_id AND queued = 0 AND leased = 0;
END;
"#;

/// Creates what is missing: the tables and indexes of a new store, the columns an older one lacks.
pub(super) fn migrate(conn: &Connection) -> Result<(), CoordError> {
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
    backfill_kinds(conn)?;
    conn.execute_batch(LEASING)?;
    rebuild_load(conn)?;
    Ok(())
}

/// Counts `batch_load` afresh from the shards: a store written by a version without the
/// triggers, or a file changed by hand, is right again once opened.
pub(super) fn rebuild_load(conn: &Connection) -> Result<(), CoordError> {
    conn.execute_batch(
        "DELETE FROM batch_load;
         INSERT INTO batch_load (batch_id, queued, leased)
         SELECT batch_id, SUM(queued), SUM(leased) FROM (
           SELECT batch_id, COUNT(*) AS queued, 0 AS leased FROM shards
            WHERE state = 'queued' GROUP BY batch_id
           UNION ALL
           SELECT batch_id, 0, COUNT(*) FROM shards INDEXED BY shards_leased
            WHERE state = 'leased' GROUP BY batch_id)
          GROUP BY batch_id;",
    )?;
    Ok(())
}

/// Gives every shard without a kind (written by a version before kinds, even after this one
/// migrated the file) the kind its role and job name meant to that version, as its read model and
/// planner told them apart. Job names start with their kind's word: "ladder G @ N", "ladder G"
/// (failed), "world model G", "proxy G", "diffusion G", "dynamics G @ B", "dynamics G" (failed),
/// "text"; an episode's job is NULL or a generalization's variations ("generalization train",
/// [`HELD_OUT_VARIATIONS`]), a judge's NULL or [`IMAGINED_JUDGING`]. GLOB, unlike LIKE, minds
/// case, as the `starts_with` of that version's read model did.
pub(super) fn backfill_kinds(conn: &Connection) -> Result<(), CoordError> {
    use JobKind as K;
    let sql = format!(
        "UPDATE shards SET kind = CASE
           WHEN role = 'trainer' THEN CASE
             WHEN job GLOB 'diffusion*' THEN '{generalization}'
             WHEN job GLOB 'ladder*' THEN '{ladder}'
             WHEN job GLOB 'world model*' THEN '{world}'
             WHEN job GLOB 'proxy*' THEN '{proxy}'
             WHEN job GLOB 'dynamics*' THEN '{dynamics}'
             ELSE '{text}' END
           WHEN role = 'judge' THEN CASE
             WHEN job IS '{imagined_job}' THEN '{imagined}'
             ELSE '{judging}' END
           WHEN job IS '{held_out_job}' THEN '{held_out}'
           WHEN job GLOB 'generalization*' THEN '{train}'
           ELSE '{episode}' END
         WHERE kind IS NULL",
        generalization = K::GeneralizationTraining,
        ladder = K::LadderTraining,
        world = K::ProxyWorldModel,
        proxy = K::Proxy,
        dynamics = K::DynamicsFit,
        text = K::TextDiversity,
        imagined_job = IMAGINED_JUDGING,
        imagined = K::ImaginedJudging,
        judging = K::EpisodeJudging,
        held_out_job = HELD_OUT_VARIATIONS,
        held_out = K::GeneralizationHeldOutEpisode,
        train = K::GeneralizationTrainEpisode,
        episode = K::Episode,
    );
    conn.execute_batch(&sql)?;
    Ok(())
}
