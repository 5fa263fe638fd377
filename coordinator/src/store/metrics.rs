//! The figures `/metrics` shows, read from the job store in one pass.
//!
//! Owns: [`Snapshot`], its histogram buckets, and the SQL behind it: shards by role and state with their attempts beyond the
//! first, finished shards' wall times, judge usage per judge, batches by state. Never formats
//! text (that is `crate::metrics`) and never writes.

use std::collections::BTreeMap;

use super::{Store, shard_state};
use crate::error::CoordError;

/// Upper bounds (seconds) of the shard wall-time histogram: an episode takes 0.1–10 s, a judge
/// call group about a second, a world-model fit minutes.
pub const SHARD_SECONDS_BUCKETS: &[f64] = &[0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0];

/// What `/metrics` shows, read from the store in one pass.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Snapshot {
    /// (role, state) → shards.
    pub shards: BTreeMap<(String, String), u64>,
    /// role → attempts beyond the first, over all shards (lease expiries, retries, hand-backs).
    pub retries: BTreeMap<String, u64>,
    /// role → (bucket counts, cumulative, one per [`SHARD_SECONDS_BUCKETS`] bound; count; sum).
    pub shard_seconds: BTreeMap<String, (Vec<u64>, u64, f64)>,
    /// judge → (calls, cached, tokens in, tokens out, cost in USD), over finished judge shards.
    pub judges: BTreeMap<String, (u64, u64, u64, u64, f64)>,
    /// batch state → batches.
    pub batches: BTreeMap<String, u64>,
}

impl Snapshot {
    /// Counts one finished shard's wall time into its role's histogram.
    pub(crate) fn observe_shard_seconds(&mut self, role: String, secs: f64) {
        let h = self
            .shard_seconds
            .entry(role)
            .or_insert_with(|| (vec![0; SHARD_SECONDS_BUCKETS.len()], 0, 0.0));
        for (bucket, bound) in h.0.iter_mut().zip(SHARD_SECONDS_BUCKETS) {
            *bucket += u64::from(secs <= *bound);
        }
        h.1 += 1;
        h.2 += secs;
    }
}

impl Store {
    /// The figures `/metrics` shows, read in one pass.
    pub fn metrics(&self) -> Result<Snapshot, CoordError> {
        let conn = &self.conn;
        let mut s = Snapshot::default();
        let mut stmt = conn.prepare(
            // An episode waiting for its pictures is render work (what a render pool scales on).
            "SELECT CASE WHEN stage = 'render' AND state IN ('queued', 'leased') THEN 'render' ELSE role END AS r,
                    state, COUNT(*), COALESCE(SUM(MAX(attempts - 1, 0)), 0) FROM shards GROUP BY r, state",
        )?;
        let rows = stmt.query_map([], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, i64>(2)?,
                r.get::<_, i64>(3)?,
            ))
        })?;
        for row in rows {
            let (role, state, n, retries) = row?;
            s.shards.insert((role.clone(), state), n as u64);
            *s.retries.entry(role).or_default() += retries as u64;
        }
        let mut stmt =
            conn.prepare("SELECT role, wall_time_s FROM shards WHERE wall_time_s IS NOT NULL")?;
        let rows = stmt.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, f64>(1)?)))?;
        for row in rows {
            let (role, secs) = row?;
            s.observe_shard_seconds(role, secs);
        }
        let mut stmt = conn.prepare(
            "SELECT COALESCE(judge, ''),
                    COALESCE(SUM(json_extract(outcome_json, '$.usage.calls')), 0),
                    COALESCE(SUM(json_extract(outcome_json, '$.usage.cached')), 0),
                    COALESCE(SUM(json_extract(outcome_json, '$.usage.tokens_in')), 0),
                    COALESCE(SUM(json_extract(outcome_json, '$.usage.tokens_out')), 0),
                    COALESCE(SUM(json_extract(outcome_json, '$.usage.cost_usd')), 0.0)
             FROM shards WHERE role = 'judge' AND state = ?1 GROUP BY judge",
        )?;
        let rows = stmt.query_map([shard_state::DONE], |r| {
            Ok((
                r.get::<_, String>(0)?,
                (
                    r.get::<_, i64>(1)? as u64,
                    r.get::<_, i64>(2)? as u64,
                    r.get::<_, i64>(3)? as u64,
                    r.get::<_, i64>(4)? as u64,
                    r.get::<_, f64>(5)?,
                ),
            ))
        })?;
        for row in rows {
            let (judge, usage) = row?;
            s.judges.insert(judge, usage);
        }
        let mut stmt = conn.prepare("SELECT state, COUNT(*) FROM batches GROUP BY state")?;
        let rows = stmt.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)?)))?;
        for row in rows {
            let (state, n) = row?;
            s.batches.insert(state, n as u64);
        }
        Ok(s)
    }
}
