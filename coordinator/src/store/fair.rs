//! Sharing the cluster between running batches: which queued shards a worker's lease takes.
//!
//! Each running batch with queued work has a weight: its priority class's
//! ([`Priority::weight`]), divided between the running batches one submitter has in that class
//! (a researcher with five batches does not get five shares). A lease goes, shard by shard, to
//! the batch that would be least over its weight with one more (`(leased + 1) / weight`, the
//! older batch on a tie), among those with a shard this worker can do and below their cap on
//! workers. So a short batch submitted behind a long one gets its first shard at the next lease,
//! and its share from then on; a low-priority batch keeps moving beside a normal one (1 in 5
//! shards), never starved.
//!
//! Every read here costs the same whatever the queue's length: the running batches' loads come
//! from `batch_load` (kept by triggers), a batch's kinds of queued work from a skip-scan of the
//! `shards_waiting` index (one seek per kind: sim, render, a judge, trainer), and its next shards
//! from the same index in id order.
//!
//! Owns: the fair share and the choice of the shards a lease takes, and each batch's share as
//! `status` shows it. Never changes a row (`leases` does, with the ids chosen here).

use std::collections::BTreeMap;

use assay_model::job::{JobKind, Priority};
use rusqlite::{Connection, OptionalExtension, params};

use super::cache::Cache;
use super::{Share, role};
use crate::error::CoordError;

/// A batch's share of the cluster: as submitted, and what it holds now.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BatchShare {
    pub share: Share,
    /// Workers holding its shards now, and its shards they hold.
    pub workers: u32,
    pub leased: u32,
    /// Its weight over the weights of every batch with open work (0 when it has none).
    pub fair_share: f64,
    /// Its leases over every lease held now (0 when none is held).
    pub holds: f64,
}

/// A running batch with queued work, as the fair share sees it.
struct Candidate {
    id: String,
    leased: f64,
    weight: f64,
    /// The shards this worker can do, next first (filled on first use); `None`: not read yet.
    next: Option<std::collections::VecDeque<QueuedShard>>,
}

/// What a key of `shards_waiting` (a shard's `needs`, a JSON array; a bare role in a store
/// written before `needs` was always set) asks of a worker.
fn needs_of(key: &str) -> Vec<String> {
    if key.starts_with('[') {
        serde_json::from_str(key).unwrap_or_else(|_| vec![key.to_owned()])
    } else {
        vec![key.to_owned()]
    }
}

/// Each open batch's weight: its class's, shared between the open batches of its submitter
/// in that class. `rows`: (batch, priority, submitter).
fn weights(rows: &[(String, Priority, String)]) -> BTreeMap<String, f64> {
    let mut same: BTreeMap<(Priority, &str), u32> = BTreeMap::new();
    for (_, p, who) in rows {
        *same.entry((*p, who.as_str())).or_default() += 1;
    }
    rows.iter()
        .map(|(id, p, who)| {
            (
                id.clone(),
                p.weight() / f64::from(same[&(*p, who.as_str())]),
            )
        })
        .collect()
}

/// Up to `n` queued shards for a worker offering `capabilities`, in the order they are to be
/// leased: shared between the running batches by weight.
pub(super) fn pick(
    conn: &Connection,
    cache: &mut Cache,
    worker: &str,
    capabilities: &[String],
    n: u32,
) -> Result<Vec<QueuedShard>, CoordError> {
    // The running batches with queued work and what they hold now; their share settings from
    // the cache (they follow the seeds in the batch's row: a walk of its overflow pages).
    let rows: Vec<(String, i64)> = {
        let mut stmt = conn.prepare_cached(
            "SELECT l.batch_id, l.leased
             FROM batch_load l CROSS JOIN batches b ON b.id = l.batch_id
             WHERE l.queued > 0 AND b.state = 'running' ORDER BY b.seq",
        )?;
        let it = stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?;
        it.collect::<Result<_, _>>()?
    };
    let mut keyed: Vec<(String, Priority, String)> = Vec::with_capacity(rows.len());
    let mut caps = Vec::with_capacity(rows.len());
    for (id, _) in &rows {
        let info = cache.batch(conn, id)?;
        keyed.push((
            id.clone(),
            info.share.priority,
            info.share.submitter.clone(),
        ));
        caps.push(info.share.max_workers);
    }
    let weight = weights(&keyed);
    let mut candidates = Vec::with_capacity(rows.len());
    for ((id, leased), cap) in rows.into_iter().zip(caps) {
        if cap > 0 && !below_cap(conn, &id, worker, cap)? {
            continue;
        }
        candidates.push(Candidate {
            weight: weight[&id],
            id,
            leased: leased as f64,
            next: None,
        });
    }
    let mut out = Vec::with_capacity(n as usize);
    while out.len() < n as usize && !candidates.is_empty() {
        // The batch least over its weight with one more shard; the older one on a tie (the
        // candidates are in submission order and `min_by` keeps the first of equals).
        let (k, _) = candidates
            .iter()
            .enumerate()
            .map(|(k, c)| (k, (c.leased + 1.0) / c.weight))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("candidates is not empty");
        let c = &mut candidates[k];
        if c.next.is_none() {
            c.next = Some(next_shards(conn, &c.id, capabilities, n)?.into());
        }
        match c.next.as_mut().and_then(|q| q.pop_front()) {
            Some(shard) => {
                out.push(shard);
                c.leased += 1.0;
            }
            None => {
                candidates.remove(k);
            }
        }
    }
    Ok(out)
}

/// Whether `worker` may take a shard of a batch capped at `cap` workers: it holds one of its
/// shards already, or fewer than `cap` workers do. Reads the leased shards only (`INDEXED BY`:
/// SQLite would rather seek the batch's shards by `shards_in_batch`, all of them).
fn below_cap(conn: &Connection, batch: &str, worker: &str, cap: u32) -> Result<bool, CoordError> {
    let (workers, mine): (u32, bool) = conn
        .prepare_cached(
            "SELECT COUNT(DISTINCT lease_worker), COALESCE(MAX(lease_worker = ?2), 0) FROM shards INDEXED BY shards_leased
             WHERE batch_id = ?1 AND state = 'leased'",
        )?
        .query_row(params![batch, worker], |r| Ok((r.get(0)?, r.get(1)?)))?;
    Ok(mine || workers < cap)
}

/// A queued shard as a lease reads it; the rest of what the lease hands out is the batch's and
/// its task's ([`Cache`]).
#[derive(Debug, Clone)]
pub(super) struct QueuedShard {
    pub id: i64,
    pub batch_id: String,
    pub task_id: String,
    pub seed: i64,
    pub policy: String,
    pub role: String,
    pub attempts: u32,
    pub judge: Option<String>,
    pub input_json: Option<String>,
    pub stage: Option<String>,
}

/// A batch's next queued shards of one kind of work (`?1` batch, `?2` its `shards_waiting` key,
/// `?3` the dynamics-fit kind, `?4` how many): `(is a fit, QueuedShard)`, read from the index
/// and the shards' rows alone.
///
/// Every parameter of a statement here is `CAST` to its type: this SQLite (libsqlite3-sys's
/// bundle, built with STAT4) otherwise marks a statement that compares a parameter with an
/// indexed column under an `ORDER BY` to be prepared again on its next run after the parameter
/// is bound, and rusqlite clears the bindings of every cached statement — so each lease parsed
/// and planned these statements again (`SQLITE_STMTSTATUS_REPREPARE`: one per run; with the
/// casts, none).
macro_rules! queued_shards {
    ($order:literal) => {
        concat!(
            "SELECT s.kind = CAST(?3 AS TEXT), s.id, s.batch_id, s.task_id, s.seed, s.policy,
                    s.role, s.attempts, s.judge, s.input_json, s.stage
             FROM shards s
             WHERE s.state = 'queued' AND s.batch_id = CAST(?1 AS TEXT)
               AND s.needs = CAST(?2 AS TEXT)
             ORDER BY ",
            $order,
            " LIMIT CAST(?4 AS INTEGER)"
        )
    };
}

fn read_queued(r: &rusqlite::Row<'_>) -> rusqlite::Result<(bool, QueuedShard)> {
    Ok((
        r.get(0)?,
        QueuedShard {
            id: r.get(1)?,
            batch_id: r.get(2)?,
            task_id: r.get(3)?,
            seed: r.get(4)?,
            policy: r.get(5)?,
            role: r.get(6)?,
            attempts: r.get(7)?,
            judge: r.get(8)?,
            input_json: r.get(9)?,
            stage: r.get(10)?,
        },
    ))
}

/// Up to `n` queued shards of `batch` a worker offering `capabilities` can do, in lease order:
/// by id, except that a trainer takes the dynamics-diversity fits last (nothing waits for them,
/// while a proxy, a ladder or a generalization policy has episodes or a proxy after it).
fn next_shards(
    conn: &Connection,
    batch: &str,
    capabilities: &[String],
    n: u32,
) -> Result<Vec<QueuedShard>, CoordError> {
    // The batch's kinds of queued work: one index seek each, past the previous kind (the first
    // has no kind to start past).
    let mut keys: Vec<String> = Vec::new();
    let mut first = conn.prepare_cached(
        "SELECT needs FROM shards WHERE state = 'queued' AND batch_id = CAST(?1 AS TEXT)
         ORDER BY needs LIMIT 1",
    )?;
    let mut next = conn.prepare_cached(
        "SELECT needs FROM shards
         WHERE state = 'queued' AND batch_id = CAST(?1 AS TEXT) AND needs > CAST(?2 AS TEXT)
         ORDER BY needs LIMIT 1",
    )?;
    let mut key = first
        .query_row([batch], |r| r.get::<_, String>(0))
        .optional()?;
    while let Some(k) = key {
        key = next
            .query_row(params![batch, k], |r| r.get::<_, String>(0))
            .optional()?;
        keys.push(k);
    }
    let trainer = capabilities.iter().any(|c| c == role::TRAINER);
    let mut found: Vec<(bool, QueuedShard)> = Vec::new();
    let mut by_id = conn.prepare_cached(queued_shards!("s.id"))?;
    let mut fits_last = conn.prepare_cached(queued_shards!("s.kind = CAST(?3 AS TEXT), s.id"))?;
    for key in keys {
        let needs = needs_of(&key);
        if !needs.iter().all(|need| capabilities.contains(need)) {
            continue;
        }
        // Only a trainer's queue holds fits; it is a batch's few trainer shards, sorted here.
        let stmt = if trainer && needs.iter().any(|x| x == role::TRAINER) {
            &mut fits_last
        } else {
            &mut by_id
        };
        let rows = stmt.query_map(
            params![batch, key, JobKind::DynamicsFit.as_str(), n],
            read_queued,
        )?;
        for row in rows {
            found.push(row?);
        }
    }
    if trainer {
        found.sort_unstable_by_key(|(fit, q)| (*fit, q.id));
    } else {
        found.sort_unstable_by_key(|(_, q)| q.id);
    }
    Ok(found.into_iter().take(n as usize).map(|(_, q)| q).collect())
}

/// A batch's share of the cluster now: its priority, submitter and cap, the workers and leases
/// it holds, its fair share and what it holds of every lease.
pub(super) fn share(conn: &Connection, batch: &str) -> Result<BatchShare, CoordError> {
    let (priority, submitter, max_workers): (String, String, u32) = conn
        .prepare_cached("SELECT priority, submitter, max_workers FROM batches WHERE id = ?1")?
        .query_row([batch], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?;
    let (workers, leased): (u32, u32) = conn
        .prepare_cached(
            "SELECT COUNT(DISTINCT lease_worker), COUNT(*) FROM shards INDEXED BY shards_leased
             WHERE batch_id = ?1 AND state = 'leased'",
        )?
        .query_row([batch], |r| Ok((r.get(0)?, r.get(1)?)))?;
    // Every batch with open work: its weight and leases (`batch_load` holds only those).
    #[allow(clippy::type_complexity)]
    let open: Vec<(String, String, String, i64)> = {
        let mut stmt = conn.prepare_cached(
            "SELECT l.batch_id, b.priority, b.submitter, l.leased
             FROM batch_load l CROSS JOIN batches b ON b.id = l.batch_id
             WHERE b.state = 'running'",
        )?;
        let it = stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))?;
        it.collect::<Result<_, _>>()?
    };
    let keyed: Vec<(String, Priority, String)> = open
        .iter()
        .map(|(id, p, who, _)| (id.clone(), p.parse().unwrap_or_default(), who.clone()))
        .collect();
    let weight = weights(&keyed);
    let total_weight: f64 = weight.values().sum();
    let total_leased: i64 = open.iter().map(|o| o.3).sum();
    Ok(BatchShare {
        share: Share {
            priority: priority.parse().unwrap_or_default(),
            submitter,
            max_workers,
        },
        workers,
        leased,
        fair_share: weight.get(batch).map_or(0.0, |w| w / total_weight),
        holds: if total_leased > 0 {
            f64::from(leased) / total_leased as f64
        } else {
            0.0
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_submitter_s_batches_of_a_class_share_its_weight() {
        let rows = vec![
            ("a".to_owned(), Priority::Normal, "ann".to_owned()),
            ("b".to_owned(), Priority::Normal, "ann".to_owned()),
            ("c".to_owned(), Priority::Normal, "bob".to_owned()),
            ("d".to_owned(), Priority::Low, "ann".to_owned()),
            ("e".to_owned(), Priority::High, "cy".to_owned()),
        ];
        let w = weights(&rows);
        assert_eq!(w["a"], 2.0);
        assert_eq!(w["b"], 2.0);
        assert_eq!(w["c"], 4.0);
        assert_eq!(w["d"], 1.0);
        assert_eq!(w["e"], 16.0);
    }

    #[test]
    fn a_queue_key_is_a_needs_array_or_a_role() {
        assert_eq!(needs_of(r#"["sim","render"]"#), vec!["sim", "render"]);
        assert_eq!(needs_of("judge"), vec!["judge"]);
    }
}
