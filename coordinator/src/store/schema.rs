//! The job store's schema: tables and indexes, and the columns added since the first release.
//!
//! Owns: every `CREATE` statement and the migration of an older store file when it is opened,
//! with the backfill of the one added column older rows cannot do without (a shard's kind, from
//! its job name). Never reads rows, nor changes them otherwise.

use assay_model::generalization::HELD_OUT_VARIATIONS;
use assay_model::job::JobKind;
use assay_model::proxy::IMAGINED_JUDGING;
use rusqlite::Connection;

use crate::error::CoordError;

pub(super) const SCHEMA: &str = r#"
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
];

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
