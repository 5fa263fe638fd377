//! Shards' kinds: a store from before them gets them from its job names, and the planner writes
//! the kinds that backfill would give. Also the report the tests ask a store for, selected then
//! assembled as `GetReport` does.

use assay_model::job::JobKind;
use assay_report::report::Report;

use super::*;

impl Store {
    /// The batch's report as `GetReport` builds it: the rows, then their assembly. Every report a
    /// test asks for also checks that the shards' kinds are those the backfill would give them.
    pub(crate) fn report(&self, batch_id: &str) -> Result<Report, CoordError> {
        self.assert_kinds_backfill_alike();
        let rows = self.batch_rows(batch_id)?;
        Ok(assay_report::assemble::report(&rows, REPORT_GENERATOR))
    }

    /// The kinds the planner wrote equal those `backfill_kinds` gives the same rows without one.
    fn assert_kinds_backfill_alike(&self) {
        let kinds = || -> Vec<(i64, Option<String>)> {
            let mut stmt = self
                .conn
                .prepare("SELECT id, kind FROM shards ORDER BY id")
                .unwrap();
            stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
                .unwrap()
                .collect::<Result<_, _>>()
                .unwrap()
        };
        let written = kinds();
        self.conn
            .execute_batch("SAVEPOINT kinds; UPDATE shards SET kind = NULL;")
            .unwrap();
        super::super::schema::backfill_kinds(&self.conn).unwrap();
        let backfilled = kinds();
        self.conn
            .execute_batch("ROLLBACK TO kinds; RELEASE kinds;")
            .unwrap();
        assert_eq!(written, backfilled, "(shard id, kind): written, backfilled");
    }
}

/// Every job name an earlier version wrote, by role, with the kind it meant.
const LEGACY: &[(&str, Option<&str>, JobKind)] = &[
    ("sim", None, JobKind::Episode),
    (
        "sim",
        Some("generalization train"),
        JobKind::GeneralizationTrainEpisode,
    ),
    (
        "sim",
        Some("generalization held-out"),
        JobKind::GeneralizationHeldOutEpisode,
    ),
    ("judge", None, JobKind::EpisodeJudging),
    ("judge", Some("proxy imagined"), JobKind::ImaginedJudging),
    ("trainer", Some("text"), JobKind::TextDiversity),
    ("trainer", Some("dynamics g @ 4"), JobKind::DynamicsFit),
    ("trainer", Some("dynamics g"), JobKind::DynamicsFit),
    ("trainer", Some("world model g"), JobKind::ProxyWorldModel),
    ("trainer", Some("proxy g"), JobKind::Proxy),
    ("trainer", Some("proxy proxy"), JobKind::Proxy),
    ("trainer", Some("ladder g @ 10"), JobKind::LadderTraining),
    ("trainer", Some("ladder proxy"), JobKind::LadderTraining),
    (
        "trainer",
        Some("diffusion g"),
        JobKind::GeneralizationTraining,
    ),
];

fn insert_legacy(conn: &Connection) {
    for (role, job, _) in LEGACY {
        conn.execute(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job)
             VALUES ('b1', 'a', 0, 'oracle', ?1, 'done', ?2)",
            params![role, job],
        )
        .unwrap();
    }
}

fn kinds(conn: &Connection) -> Vec<String> {
    let mut stmt = conn.prepare("SELECT kind FROM shards ORDER BY id").unwrap();
    stmt.query_map([], |r| r.get(0))
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap()
}

/// A store from before kinds (no `kind` column) gets each shard's kind from its role and job
/// name when it is opened; rows an older version adds to it later get theirs on the next open.
#[test]
fn a_store_from_before_kinds_gets_them_from_its_job_names() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("old.db");
    drop(Store::open(&path).unwrap());
    {
        let conn = Connection::open(&path).unwrap();
        conn.execute_batch("ALTER TABLE shards DROP COLUMN kind")
            .unwrap();
        insert_legacy(&conn);
    }
    let want: Vec<String> = LEGACY.iter().map(|(.., k)| k.to_string()).collect();
    drop(Store::open(&path).unwrap());
    let conn = Connection::open(&path).unwrap();
    assert_eq!(kinds(&conn), want);
    // An older coordinator writes into the migrated store: its rows have no kind.
    insert_legacy(&conn);
    drop(conn);
    let mut s = Store::open(&path).unwrap();
    let both: Vec<String> = want.iter().chain(&want).cloned().collect();
    assert_eq!(kinds(s.conn()), both);
}
