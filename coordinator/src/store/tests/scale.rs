//! The store's guard against leasing that grows with the queue: the cost of a lease and its
//! completion, per shard, at a long queue against a short one, measured in one run (a ratio of
//! two timings, never a wall-clock bound). A store whose lease query visits every queued shard
//! costs ten times more per shard at ten times the queue; one that serves the lease from an
//! index costs about the same.

use std::time::Instant;

use super::*;

/// Leases and completes `n` shards one at a time, as `workers` workers taking turns; returns
/// the seconds it took.
fn drain(s: &mut Store, n: usize, workers: usize, now: &mut i64) -> f64 {
    let t = Instant::now();
    for k in 0..n {
        let w = format!("w{}", k % workers);
        *now += 1;
        let l = s.lease(&w, &sim(), 1, *now, TTL).unwrap().remove(0);
        let (ok, _) = s
            .complete(&w, l.lease_id, l.shard_id, &outcome(&l), 0.0, *now)
            .unwrap();
        assert!(ok);
    }
    t.elapsed().as_secs_f64()
}

/// Seconds per shard to lease and complete 500 shards with at least `queue` shards queued,
/// spread over `batches` running batches (the fair share visits each), the best of three rounds.
fn per_shard(queue: u64, batches: u64) -> f64 {
    let mut s = Store::open_in_memory().unwrap();
    // What the rounds drain is added, so the queue never falls below `queue`.
    let planned = queue + 100 + 3 * 500;
    for b in 0..batches {
        let seeds: Vec<u64> = (0..planned / batches).collect();
        s.submit(&batch(&[&format!("t{b}")], &seeds, 3), 0).unwrap();
    }
    let mut now = 0;
    drain(&mut s, 100, 50, &mut now);
    (0..3)
        .map(|_| drain(&mut s, 500, 50, &mut now) / 500.0)
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn a_lease_costs_the_same_at_a_ten_times_longer_queue() {
    for batches in [1, 4] {
        // Interleaved, twice each, so a busy moment of the machine does not land on one side.
        let short = per_shard(2_000, batches).min(per_shard(2_000, batches));
        let long = per_shard(20_000, batches).min(per_shard(20_000, batches));
        let ratio = long / short;
        println!(
            "{batches} batch(es): {:.1} µs per shard at 2,000 queued, {:.1} µs at 20,000: ratio {ratio:.2}",
            short * 1e6,
            long * 1e6
        );
        assert!(
            ratio < 3.0,
            "with {batches} batch(es), a lease and completion cost {ratio:.1}× as much at 20,000 \
             queued shards as at 2,000: leasing grows with the queue"
        );
    }
}
