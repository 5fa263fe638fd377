//! What leasing writes and keeps beside the file: the indexes an older store is given, lease ids
//! taken in blocks, the cache of what never changes, and checkpoints off the store's thread.

use super::*;

/// The names of the shards' indexes, sorted.
fn shard_indexes(conn: &Connection) -> Vec<String> {
    let mut stmt = conn
        .prepare(
            "SELECT name FROM sqlite_master WHERE type = 'index' AND tbl_name = 'shards'
               AND name NOT LIKE 'sqlite_%' ORDER BY name",
        )
        .unwrap();
    stmt.query_map([], |r| r.get(0))
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap()
}

#[test]
fn a_store_with_the_earlier_indexes_gets_this_version_s_and_keeps_its_leases() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("jobs.db");
    let (queued, leased) = {
        let mut s = Store::open(&path).unwrap();
        s.submit(&batch(&["a", "b", "c"], &[0, 1], 3), 0).unwrap();
        let leased = s.lease("w", &sim(), 2, 0, TTL).unwrap();
        // The indexes of the version before this one, as it left them.
        s.conn()
            .execute_batch(
                "DROP INDEX shards_in_batch; DROP INDEX shards_waiting; DROP INDEX shards_leased;
                 CREATE INDEX shards_by_state ON shards (state, role, id);
                 CREATE INDEX shards_by_batch ON shards (batch_id, state);
                 CREATE UNIQUE INDEX shards_by_lease ON shards (lease_id);
                 CREATE INDEX shards_by_needs ON shards (state, batch_id, needs, id);",
            )
            .unwrap();
        (4, leased)
    };
    let mut s = Store::open(&path).unwrap();
    assert_eq!(
        shard_indexes(s.conn()),
        vec!["shards_in_batch", "shards_leased", "shards_waiting"]
    );
    // The leased shards are found by their leases, the queued ones leased in order.
    assert_eq!(
        s.heartbeat("w", &[leased[0].lease_id, leased[1].lease_id], 10, TTL)
            .unwrap(),
        vec![leased[0].lease_id, leased[1].lease_id]
    );
    let rest = s.lease("w2", &sim(), 10, 10, TTL).unwrap();
    assert_eq!(rest.len(), queued);
    assert!(rest.windows(2).all(|w| w[0].shard_id < w[1].shard_id));
    assert!(rest[0].lease_id > leased[1].lease_id);
}

/// A table whose rows make the open transaction fail at COMMIT: a deferred foreign key to a row
/// that does not exist.
fn make_commit_fail(s: &mut Store) {
    s.conn()
        .execute_batch(
            "PRAGMA foreign_keys = ON;
             CREATE TABLE IF NOT EXISTS parent (id INTEGER PRIMARY KEY);
             CREATE TABLE IF NOT EXISTS child (
               p INTEGER REFERENCES parent (id) DEFERRABLE INITIALLY DEFERRED);",
        )
        .unwrap();
}

#[test]
fn a_group_that_does_not_commit_takes_back_its_lease_ids_and_what_was_cached() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("jobs.db");
    let mut spec_first = batch(&["a"], &[0], 3);
    spec_first.tasks[0].spec_json = r#"{"first":true}"#.into();
    let mut spec_second = batch(&["a"], &[0], 3);
    spec_second.tasks[0].spec_json = r#"{"second":true}"#.into();
    let after_rollback = {
        let mut s = Store::open(&path).unwrap();
        make_commit_fail(&mut s);
        // One group: a batch submitted and leased (its spec read into the cache, a block of
        // lease ids taken from the counter), then a row the commit refuses.
        s.begin_group().unwrap();
        let (lost_id, _) = s.submit(&spec_first, 7).unwrap();
        let lost = s.lease("w", &sim(), 1, 7, TTL).unwrap().remove(0);
        assert_eq!(lost.task_spec_json, r#"{"first":true}"#);
        s.conn()
            .execute("INSERT INTO child (p) VALUES (42)", [])
            .unwrap();
        assert!(s.commit_group().is_err(), "the commit was to fail");
        assert!(s.running_batches().unwrap().is_empty());
        // The next submission, at the same millisecond, takes the same batch id: its lease
        // hands out its own spec, not the rolled-back batch's.
        let (id, _) = s.submit(&spec_second, 7).unwrap();
        assert_eq!(id, lost_id);
        let l = s.lease("w", &sim(), 1, 8, TTL).unwrap().remove(0);
        assert_eq!(l.task_spec_json, r#"{"second":true}"#);
        l.lease_id
    };
    // Reopened: the counter was never told of ids the rolled-back group took, so had the store
    // gone on handing them out, a lease after reopening would take one again.
    let mut s = Store::open(&path).unwrap();
    s.submit(&batch(&["b"], &[0], 3), 9).unwrap();
    let next = s.lease("w", &sim(), 1, 9, TTL).unwrap().remove(0);
    assert!(
        next.lease_id > after_rollback,
        "lease id {} handed out again after reopening (the last before was {after_rollback})",
        next.lease_id
    );
    let ids: Vec<i64> = {
        let mut stmt = s
            .conn()
            .prepare("SELECT lease_id FROM shards WHERE lease_id IS NOT NULL")
            .unwrap();
        stmt.query_map([], |r| r.get(0))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap()
    };
    let distinct: std::collections::BTreeSet<_> = ids.iter().collect();
    assert_eq!(distinct.len(), ids.len(), "{ids:?}");
}

#[test]
fn a_thread_checkpoints_and_the_log_starts_again_while_leases_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("jobs.db");
    let mut s = Store::open(&path).unwrap();
    let seeds: Vec<u64> = (0..4_000).collect();
    let before = std::fs::metadata(&path).unwrap().len();
    s.submit(&batch(&["a"], &seeds, 3), 0).unwrap();
    // The submission is a few hundred pages of log, far from the store's own checkpoint: the
    // checkpoint thread copies them into the file.
    let copied = std::time::Instant::now();
    while std::fs::metadata(&path).unwrap().len() < before + 200_000 {
        assert!(
            copied.elapsed() < std::time::Duration::from_secs(10),
            "nothing was checkpointed in 10 s (the file has {} bytes)",
            std::fs::metadata(&path).unwrap().len()
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let wal = path.with_extension("db-wal");
    let page = s
        .conn()
        .query_row("PRAGMA page_size", [], |r| r.get::<_, i64>(0))
        .unwrap() as u64;
    let mut most = 0;
    for k in 0..seeds.len() as i64 {
        let l = s.lease("w", &sim(), 1, k, TTL).unwrap().remove(0);
        let (ok, _) = s
            .complete("w", l.lease_id, l.shard_id, &outcome(&l), 0.0, k)
            .unwrap();
        assert!(ok);
        most = most.max(std::fs::metadata(&wal).map_or(0, |m| m.len()));
    }
    // 8,000 transactions of a few pages each: the log holds far more than one checkpoint's
    // worth of pages in all, and starts again from its beginning after each checkpoint.
    let frames = most / (page + 24);
    assert!(
        frames < 2 * u64::from(super::super::checkpoint::WAL_AUTOCHECKPOINT),
        "the log grew to {frames} pages: it never started again"
    );
    // What was checkpointed is in the database file itself.
    let file = std::fs::metadata(&path).unwrap().len();
    assert!(file > 1_000_000, "the database file holds {file} bytes");
}
