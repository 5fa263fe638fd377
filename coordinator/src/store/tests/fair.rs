//! The store's tests of sharing workers between running batches: a short batch behind a long
//! one, priority classes, one submitter's batches, a cap on workers, and the shares `status`
//! shows.

use super::*;

fn shared(tasks: &[&str], seeds: u64, priority: Priority, submitter: &str) -> NewBatch {
    let mut b = batch(tasks, &(0..seeds).collect::<Vec<_>>(), 3);
    b.share = Share {
        priority,
        submitter: submitter.into(),
        max_workers: 0,
    };
    b
}

/// `workers` workers, each holding one lease: every worker completes what it holds and takes
/// one more shard; returns the batch of each new lease, by worker.
fn round(s: &mut Store, held: &mut [Option<Lease>], now: &mut i64) -> Vec<Option<String>> {
    let mut got = Vec::new();
    for (k, slot) in held.iter_mut().enumerate() {
        let w = format!("w{k}");
        *now += 1;
        if let Some(l) = slot.take() {
            let (ok, _) = s
                .complete(&w, l.lease_id, l.shard_id, &outcome(&l), 0.0, *now)
                .unwrap();
            assert!(ok);
        }
        *slot = s.lease(&w, &sim(), 1, *now, TTL).unwrap().pop();
        got.push(slot.as_ref().map(|l| l.batch_id.clone()));
    }
    got
}

#[test]
fn a_short_batch_behind_a_long_one_gets_its_share_at_the_next_lease_and_ends_first() {
    let mut s = Store::open_in_memory().unwrap();
    let (long, _) = s
        .submit(&shared(&["long"], 400, Priority::Normal, "ann"), 0)
        .unwrap();
    let mut held: Vec<Option<Lease>> = vec![None; 4];
    let mut now = 0;
    for _ in 0..3 {
        assert!(
            round(&mut s, &mut held, &mut now)
                .iter()
                .all(|b| b.as_deref() == Some(long.as_str()))
        );
    }
    let (short, _) = s
        .submit(&shared(&["short"], 10, Priority::Normal, "bob"), now)
        .unwrap();
    // The first round after it was submitted already gives it half the workers.
    let first = round(&mut s, &mut held, &mut now);
    let took = first
        .iter()
        .filter(|b| b.as_deref() == Some(short.as_str()))
        .count();
    assert_eq!(
        took, 2,
        "half the workers go to the short batch at once: {first:?}"
    );
    let status = s.counts(&short).unwrap();
    assert_eq!(status.share.workers, 2);
    assert!((status.share.fair_share - 0.5).abs() < 1e-9);
    assert!((status.share.holds - 0.5).abs() < 1e-9);
    let mut rounds = 1;
    while s.counts(&short).unwrap().state == "running" {
        round(&mut s, &mut held, &mut now);
        rounds += 1;
        assert!(rounds < 20, "the short batch did not finish");
    }
    assert_eq!(
        s.counts(&long).unwrap().state,
        "running",
        "the short batch ends first"
    );
    assert!(
        rounds <= 6,
        "10 shards on half of 4 workers take 5 rounds and a last completion, not {rounds}"
    );
    // With the short batch done, the long one has every worker again.
    let after = round(&mut s, &mut held, &mut now);
    assert!(
        after.iter().all(|b| b.as_deref() == Some(long.as_str())),
        "{after:?}"
    );
}

/// Leases with `workers` workers until each holds one shard; the count each batch got.
fn spread(s: &mut Store, workers: usize) -> BTreeMap<String, usize> {
    let mut got = BTreeMap::new();
    for k in 0..workers {
        for l in s.lease(&format!("w{k}"), &sim(), 1, 1, TTL).unwrap() {
            *got.entry(l.batch_id).or_insert(0) += 1;
        }
    }
    got
}

#[test]
fn workers_are_shared_by_priority_and_a_submitter_s_batches_share_one_weight() {
    let mut s = Store::open_in_memory().unwrap();
    let (low, _) = s
        .submit(&shared(&["a"], 100, Priority::Low, "ci"), 0)
        .unwrap();
    let (normal, _) = s
        .submit(&shared(&["b"], 100, Priority::Normal, "ann"), 0)
        .unwrap();
    let got = spread(&mut s, 10);
    assert_eq!(
        (got[&low], got[&normal]),
        (2, 8),
        "weights 1 and 4: {got:?}"
    );

    let mut s = Store::open_in_memory().unwrap();
    let (a1, _) = s
        .submit(&shared(&["a"], 100, Priority::Normal, "ann"), 0)
        .unwrap();
    let (a2, _) = s
        .submit(&shared(&["b"], 100, Priority::Normal, "ann"), 0)
        .unwrap();
    let (b1, _) = s
        .submit(&shared(&["c"], 100, Priority::Normal, "bob"), 0)
        .unwrap();
    let got = spread(&mut s, 8);
    assert_eq!(
        (got[&a1], got[&a2], got[&b1]),
        (2, 2, 4),
        "ann's two batches share one weight: {got:?}"
    );
    assert!((s.counts(&b1).unwrap().share.fair_share - 0.5).abs() < 1e-9);

    let mut s = Store::open_in_memory().unwrap();
    let (normal, _) = s
        .submit(&shared(&["a"], 100, Priority::Normal, "ann"), 0)
        .unwrap();
    let (high, _) = s
        .submit(&shared(&["b"], 100, Priority::High, "bob"), 0)
        .unwrap();
    let got = spread(&mut s, 10);
    assert_eq!(
        (got[&normal], got[&high]),
        (2, 8),
        "weights 4 and 16: {got:?}"
    );
}

#[test]
fn a_capped_batch_never_holds_more_workers_than_its_cap() {
    let mut s = Store::open_in_memory().unwrap();
    let mut capped = shared(&["a"], 100, Priority::High, "ann");
    capped.share.max_workers = 2;
    let (capped, _) = s.submit(&capped, 0).unwrap();
    // A worker holding one of its shards may take more; a third worker may not.
    assert_eq!(s.lease("w0", &sim(), 3, 1, TTL).unwrap().len(), 3);
    assert_eq!(s.lease("w1", &sim(), 1, 1, TTL).unwrap().len(), 1);
    assert!(
        s.lease("w2", &sim(), 1, 1, TTL).unwrap().is_empty(),
        "the cap leaves w2 idle"
    );
    assert_eq!(s.lease("w1", &sim(), 1, 1, TTL).unwrap().len(), 1);
    let c = s.counts(&capped).unwrap();
    assert_eq!(
        (c.share.workers, c.share.leased, c.share.share.max_workers),
        (2, 5, 2)
    );
    // Another batch takes the workers the cap leaves.
    let (other, _) = s
        .submit(&shared(&["b"], 10, Priority::Low, "bob"), 1)
        .unwrap();
    let l = s.lease("w2", &sim(), 1, 2, TTL).unwrap();
    assert_eq!(l[0].batch_id, other);
}

#[test]
fn the_load_the_triggers_keep_equals_a_recount_after_every_kind_of_change() {
    let mut s = Store::open_in_memory().unwrap();
    let (a, _) = s.submit(&batch(&["a", "b"], &[1, 2, 3], 2), 0).unwrap();
    let (b, _) = s.submit(&batch(&["c"], &[1, 2], 2), 0).unwrap();
    let load = |s: &mut Store| -> Vec<(String, i64, i64)> {
        let conn = s.conn();
        let mut stmt = conn
            .prepare(
                "SELECT batch_id, queued, leased FROM batch_load
                 WHERE queued > 0 OR leased > 0 ORDER BY batch_id",
            )
            .unwrap();
        stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap()
    };
    let check = |s: &mut Store| {
        let kept = load(s);
        super::schema::rebuild_load(s.conn()).unwrap();
        assert_eq!(kept, load(s));
        kept
    };
    assert_eq!(check(&mut s), vec![(a.clone(), 6, 0), (b.clone(), 2, 0)]);
    let ls = s.lease("w", &sim(), 4, 1, TTL).unwrap();
    check(&mut s);
    s.complete(
        "w",
        ls[0].lease_id,
        ls[0].shard_id,
        &outcome(&ls[0]),
        0.0,
        2,
    )
    .unwrap();
    s.fail(ls[1].lease_id, ls[1].shard_id, "boom", true, 2)
        .unwrap();
    s.return_leases("w", &[ls[2].lease_id]).unwrap();
    s.expire(i64::MAX, None).unwrap();
    check(&mut s);
    s.cancel(&b, 3).unwrap();
    assert!(
        check(&mut s).iter().all(|(id, _, _)| *id != b),
        "a cancelled batch has no load"
    );
}
