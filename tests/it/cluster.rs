//! Real processes on loopback: a coordinator and sim workers, killed and restarted mid-batch.

use std::time::Duration;

use assay_proto::v1 as pb;

use crate::common::*;

const STACKING: &str = "examples/tasks/stacking";

#[test]
fn a_worker_killed_mid_batch_loses_nothing_and_counts_nothing_twice() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(
        dir.path(),
        "127.0.0.1:0",
        &["--heartbeat-ms", "300", "--lease-ttl-ms", "3000"],
    );
    let mut victim = worker(dir.path(), &addr, 0, 1);
    let _survivor = worker(dir.path(), &addr, 1, 1);
    runtime().block_on(async {
        let sub = submit(&addr, &[STACKING], 4).await;
        assert!(sub.rejected.is_empty(), "{:?}", sub.rejected);
        let tasks = sub.accepted_tasks as usize;
        // Kill while the victim holds a lease, with work still queued.
        wait_for(&addr, &sub.batch_id, Duration::from_secs(120), |s| {
            s.shards_done >= 6 && s.shards_running >= 2
        })
        .await;
        victim.kill9();
        let s = wait_for(&addr, &sub.batch_id, Duration::from_secs(300), finished).await;
        assert_eq!(s.shards_done, s.shards_total);
        let r = report(&addr, &sub.batch_id).await;
        assert_each_episode_once(&r, tasks, 4);
        // The shard the victim held was run again by the survivor.
        assert!(
            r.run.extra_attempts >= 1,
            "no shard was re-run: {:?}",
            r.run
        );
    });
}

#[test]
fn a_coordinator_killed_mid_batch_resumes_from_its_store() {
    let dir = tempfile::tempdir().unwrap();
    let (mut coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &["--heartbeat-ms", "300"]);
    let listen = addr.trim_start_matches("http://").to_owned();
    let _w0 = worker(dir.path(), &addr, 0, 1);
    let _w1 = worker(dir.path(), &addr, 1, 1);
    runtime().block_on(async {
        let sub = submit(&addr, &[STACKING], 4).await;
        let tasks = sub.accepted_tasks as usize;
        wait_for(&addr, &sub.batch_id, Duration::from_secs(120), |s| {
            s.shards_done >= 6
        })
        .await;
        coord.kill9();
        // Same store, same address: the workers reconnect by themselves.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let (_coord2, addr2) = coordinator(dir.path(), &listen, &["--heartbeat-ms", "300"]);
        assert_eq!(addr2, addr);
        let s = wait_for(&addr, &sub.batch_id, Duration::from_secs(300), finished).await;
        assert_eq!(s.shards_done, s.shards_total);
        let r = report(&addr, &sub.batch_id).await;
        assert_each_episode_once(&r, tasks, 4);
        assert_eq!(r.run.batch_id, sub.batch_id);
    });
}

#[test]
fn a_worker_stopped_with_sigterm_hands_its_leases_back() {
    let dir = tempfile::tempdir().unwrap();
    let (coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &["--heartbeat-ms", "300"]);
    let mut leaving = worker(dir.path(), &addr, 0, 2);
    runtime().block_on(async {
        let sub = submit(&addr, &[STACKING], 2).await;
        wait_for(&addr, &sub.batch_id, Duration::from_secs(120), |s| {
            s.shards_running == 2
        })
        .await;
        assert!(
            leaving.term(Duration::from_secs(10)),
            "the worker did not exit cleanly on SIGTERM:\n{}\ncoordinator:\n{}",
            leaving.log_text(),
            coord.log_text()
        );
        // The coordinator re-queued what it held without counting an attempt.
        let s = wait_for(&addr, &sub.batch_id, Duration::from_secs(30), |s| {
            s.shards_running == 0
        })
        .await;
        assert!(s.shards_queued > 0);
        let returned: u64 = coord
            .log_text()
            .lines()
            .filter(|l| l.contains("leases handed back"))
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter_map(|v| v["fields"]["leases"].as_u64())
            .sum();
        assert!(
            returned >= 1,
            "no leases handed back:\n{}",
            coord.log_text()
        );
        let _finisher = worker(dir.path(), &addr, 1, 2);
        wait_for(&addr, &sub.batch_id, Duration::from_secs(300), finished).await;
        let r = report(&addr, &sub.batch_id).await;
        assert_each_episode_once(&r, sub.accepted_tasks as usize, 2);
        assert_eq!(
            r.run.extra_attempts, 0,
            "handed-back leases must not count as attempts"
        );
    });
}

/// A batch of `seeds` seeds of the stacking tasks from `submitter`.
async fn submit_as(addr: &str, seeds: u64, submitter: &str) -> pb::SubmitBatchResponse {
    client(addr)
        .await
        .submit_batch(pb::SubmitBatchRequest {
            name: submitter.into(),
            tasks: documents(&[STACKING]),
            policies: vec![pb::PolicyRef {
                name: "oracle".into(),
            }],
            seeds: (0..seeds).collect(),
            submitter: submitter.into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner()
}

#[test]
fn a_short_batch_submitted_behind_a_long_one_starts_at_once_and_ends_first() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &["--heartbeat-ms", "300"]);
    let _w0 = worker(dir.path(), &addr, 0, 1);
    let _w1 = worker(dir.path(), &addr, 1, 1);
    runtime().block_on(async {
        let long = submit_as(&addr, 40, "ann").await;
        let long_id = long.batch_id.clone();
        wait_for(&addr, &long_id, Duration::from_secs(120), |s| {
            s.shards_done >= 2 && s.shards_running == 2
        })
        .await;
        let mut c = client(&addr).await;
        // The store, read beside the coordinator (WAL): the last lease before the short batch.
        let store = rusqlite::Connection::open_with_flags(
            dir.path().join("jobs.db"),
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
        )
        .unwrap();
        let last_lease = |store: &rusqlite::Connection| -> i64 {
            store
                .query_row("SELECT COALESCE(MAX(lease_id), 0) FROM shards", [], |r| r.get(0))
                .unwrap()
        };
        let before = last_lease(&store);
        let short = submit_as(&addr, 1, "bob").await;
        let started = wait_for(&addr, &short.batch_id, Duration::from_secs(120), |s| {
            s.shards_running + s.shards_done > 0
        })
        .await;
        // Its first episode starts within two lease rounds: of the leases granted after it was
        // submitted, at most two per worker went to the long batch before its first.
        let first_short: i64 = store
            .query_row(
                "SELECT MIN(lease_id) FROM shards WHERE batch_id = ?1",
                [&short.batch_id],
                |r| r.get(0),
            )
            .unwrap();
        let long_between: i64 = store
            .query_row(
                "SELECT COUNT(*) FROM shards WHERE batch_id = ?1 AND lease_id > ?2 AND lease_id < ?3",
                rusqlite::params![long_id, before, first_short],
                |r| r.get(0),
            )
            .unwrap();
        assert!(
            long_between <= 4,
            "{long_between} leases of the long batch went before the short batch's first"
        );
        assert_eq!(started.priority, "normal");
        assert_eq!(started.submitter, "bob");
        assert!((started.fair_share - 0.5).abs() < 1e-9, "{started:?}");
        // It finishes before the long one.
        let done = wait_for(&addr, &short.batch_id, Duration::from_secs(300), finished).await;
        assert_eq!(done.shards_done, done.shards_total);
        let long_now = c
            .get_batch(pb::GetBatchRequest {
                batch_id: long_id.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(
            long_now.state,
            pb::BatchState::Running as i32,
            "the long batch ended first: {long_now:?}"
        );
        // `assay status` shows each running batch's share.
        let out = ok(&assay(&["status", "--coordinator", &addr]));
        assert!(
            out.contains("share: normal priority") && out.contains("fair share 100%"),
            "{out}"
        );
        c.cancel_batch(pb::GetBatchRequest { batch_id: long_id })
            .await
            .unwrap();
    });
}
