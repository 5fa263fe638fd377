//! The shard state machine: queued → leased → done | failed | cancelled, and back to queued.
//!
//! Owns: leasing, heartbeats, completion, failure and retries, handed-back and expired leases,
//! reconciliation after a restart, cancellation, and finishing a batch once nothing is open.
//! Every change is one statement guarded by the shard's state and lease id. Never decides which
//! shards a batch has: completion and finishing call the planner inside the same savepoint.

use assay_model::episode::EpisodeOutcome;
use assay_model::job::JobKind;
use assay_model::quality::JudgeOutcome;
use assay_model::trainer::TrainerOutcome;
use rusqlite::{Connection, OptionalExtension, params};

use super::cache::Cache;
use super::{Changed, JudgeLease, Lease, Store, batch_state, role};
use crate::error::CoordError;

impl Store {
    /// Leases up to `n` queued shards of running batches to a worker offering `capabilities`
    /// (its roles and what else it can do): only shards that need nothing else, shared between
    /// the running batches by weight (`fair::pick` chooses them).
    pub fn lease(
        &mut self,
        worker: &str,
        capabilities: &[String],
        n: u32,
        now_ms: i64,
        ttl_ms: i64,
    ) -> Result<Vec<Lease>, CoordError> {
        if n == 0 || capabilities.is_empty() {
            return Ok(Vec::new());
        }
        let leased = self.lease_in(worker, capabilities, n, now_ms, ttl_ms);
        if leased.is_err() {
            // Its savepoint rolled back, with any lease ids it took from the counter.
            self.lease_ids = None;
        }
        leased
    }

    fn lease_in(
        &mut self,
        worker: &str,
        capabilities: &[String],
        n: u32,
        now_ms: i64,
        ttl_ms: i64,
    ) -> Result<Vec<Lease>, CoordError> {
        let Store {
            conn,
            cache,
            lease_ids,
            ..
        } = self;
        let tx = conn.savepoint()?;
        let rows = super::fair::pick(&tx, cache, worker, capabilities, n)?;
        if rows.is_empty() {
            return Ok(Vec::new());
        }
        let first = Self::next_lease_ids(&tx, lease_ids, rows.len() as u64)?;
        let mut out = Vec::with_capacity(rows.len());
        for (k, q) in rows.into_iter().enumerate() {
            let batch = cache.batch(&tx, &q.batch_id)?;
            let spec = cache.spec(&tx, &q.batch_id, &q.task_id)?;
            // An episode waiting for its pictures goes to a render worker with its scenes.
            let (shard_role, render_input, input) = if q.stage.as_deref() == Some(role::RENDER) {
                (role::RENDER.to_owned(), q.input_json, None)
            } else {
                (q.role, None, q.input_json)
            };
            let trainer_job = if shard_role == role::TRAINER {
                input.clone()
            } else {
                None
            };
            let clip_size = match (batch.clip_size, shard_role.as_str()) {
                (Some(size), r) if r != role::JUDGE && r != role::TRAINER => size as u32,
                _ => 0,
            };
            let clip_interface = if clip_size > 0 {
                batch.clip_interface.clone()
            } else {
                String::new()
            };
            let judge = match (q.judge, input) {
                (Some(judge), Some(episode_json)) => Some(JudgeLease {
                    judge,
                    budget_left_usd: match batch.judge_budget_usd {
                        Some(b) => Some(b - Self::judge_spent(&tx, &q.batch_id)?),
                        None => None,
                    },
                    episode_json,
                    repeats: batch.judge_repeats,
                }),
                _ => None,
            };
            let lease_id = first + k as u64;
            tx.prepare_cached(
                "UPDATE shards SET state = 'leased', attempts = attempts + 1, lease_id = ?1, lease_worker = ?2,
                 lease_expires_ms = ?3 WHERE id = ?4 AND state = 'queued'",
            )?
            .execute(params![lease_id as i64, worker, now_ms + ttl_ms, q.id])?;
            out.push(Lease {
                lease_id,
                shard_id: q.id as u64,
                batch_id: q.batch_id,
                task_spec_json: spec.to_string(),
                seed: q.seed as u64,
                policy: q.policy,
                role: shard_role,
                attempt: q.attempts + 1,
                judge,
                trainer_job,
                clip_size,
                clip_interface,
                render: batch.render || clip_size > 0,
                render_input,
            });
        }
        tx.commit()?;
        Ok(out)
    }

    /// Extends the leases `worker` still holds; returns the ids that are still valid.
    pub fn heartbeat(
        &mut self,
        worker: &str,
        lease_ids: &[u64],
        now_ms: i64,
        ttl_ms: i64,
    ) -> Result<Vec<u64>, CoordError> {
        let tx = self.conn.savepoint()?;
        let mut kept = Vec::new();
        for id in lease_ids {
            let n = tx.execute(
                "UPDATE shards SET lease_expires_ms = ?1 WHERE lease_id = ?2 AND lease_worker = ?3 AND state = 'leased'",
                params![now_ms + ttl_ms, *id as i64, worker],
            )?;
            if n == 1 {
                kept.push(*id);
            }
        }
        tx.commit()?;
        Ok(kept)
    }

    /// Records a finished shard: `outcome_json` is an `EpisodeOutcome` for a sim shard, a
    /// `JudgeOutcome` for a judge shard. Accepted only if `lease_id` is the shard's current lease:
    /// a result from an expired, returned or completed lease is not counted. An outcome that
    /// does not parse counts as a failed attempt. A rendered episode of a batch with judges
    /// queues one judge shard per judge, and a trained diffusion policy its episodes (a ladder's
    /// or generalization's), in the same transaction, so the batch cannot look finished in
    /// between.
    pub fn complete(
        &mut self,
        worker: &str,
        lease_id: u64,
        shard_id: u64,
        outcome_json: &str,
        wall_time_s: f64,
        now_ms: i64,
    ) -> Result<(bool, Changed), CoordError> {
        let tx = self.conn.savepoint()?;
        #[allow(clippy::type_complexity)]
        let current: Option<(String, String, String, i64, String, String, Option<String>)> = tx
            .prepare_cached(
                "SELECT s.role, s.batch_id, s.task_id, s.seed, s.policy, s.kind, s.stage FROM shards s
                 WHERE s.id = ?1 AND s.lease_id = ?2 AND s.state = 'leased'",
            )?
            .query_row(params![shard_id as i64, lease_id as i64], |r| {
                Ok((
                    r.get(0)?,
                    r.get(1)?,
                    r.get(2)?,
                    r.get(3)?,
                    r.get(4)?,
                    r.get(5)?,
                    r.get(6)?,
                ))
            })
            .optional()?;
        let Some((shard_role, batch, task, seed, policy, kind, stage)) = current else {
            return Ok((false, Changed::default()));
        };
        let kind: JobKind = kind.parse()?;
        // What to queue after it: judge shards for a rendered episode of a judged batch.
        let judges: Vec<String> = match shard_role.as_str() {
            role::JUDGE => match serde_json::from_str::<JudgeOutcome>(outcome_json) {
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable judge outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
            role::TRAINER => match serde_json::from_str::<TrainerOutcome>(outcome_json) {
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable trainer outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
            _ => match serde_json::from_str::<EpisodeOutcome>(outcome_json) {
                // Simulated by a worker without a renderer: the episode waits for a render
                // worker, with its scenes, before it counts as done.
                Ok(o) if o.scenes.is_some() && stage.is_none() => {
                    tx.prepare_cached(
                        "UPDATE shards SET state = 'queued', stage = ?1, needs = ?2, input_json = ?3,
                         attempts = 0, lease_expires_ms = NULL, worker = ?4,
                         wall_time_s = ?5 WHERE id = ?6 AND lease_id = ?7 AND state = 'leased'",
                    )?
                    .execute(params![
                        role::RENDER,
                        serde_json::to_string(&[role::RENDER])?,
                        outcome_json,
                        worker,
                        wall_time_s,
                        shard_id as i64,
                        lease_id as i64
                    ])?;
                    tx.commit()?;
                    return Ok((
                        true,
                        Changed {
                            batches: vec![batch],
                            requeued: 1,
                        },
                    ));
                }
                Ok(o) if o.scenes.is_some() => {
                    drop(tx);
                    let err = "a render worker sent the episode back without its pictures";
                    return Ok((false, self.fail(lease_id, shard_id, err, true, now_ms)?));
                }
                Ok(o) if o.imagery.is_some() => {
                    let judges: String = tx.query_row(
                        "SELECT judges_json FROM batches WHERE id = ?1",
                        [&batch],
                        |r| r.get(0),
                    )?;
                    serde_json::from_str(&judges)?
                }
                Ok(_) => Vec::new(),
                Err(e) => {
                    drop(tx);
                    let err = format!("worker sent an unreadable outcome: {e}");
                    return Ok((false, self.fail(lease_id, shard_id, &err, true, now_ms)?));
                }
            },
        };
        tx.prepare_cached(
            "UPDATE shards SET state = 'done', outcome_json = ?1, wall_time_s = COALESCE(wall_time_s, 0) + ?2,
             worker = CASE WHEN stage IS NULL THEN ?3 ELSE worker END, error = NULL, lease_expires_ms = NULL,
             input_json = CASE WHEN stage IS NULL THEN input_json END
             WHERE id = ?4 AND lease_id = ?5 AND state = 'leased'",
        )?
        .execute(params![outcome_json, wall_time_s, worker, shard_id as i64, lease_id as i64])?;
        let mut queued =
            Self::queue_episode_judging(&tx, &batch, &task, seed, &policy, &judges, outcome_json)?;
        if shard_role == role::TRAINER {
            match serde_json::from_str::<TrainerOutcome>(outcome_json) {
                Ok(TrainerOutcome::Diffusion {
                    group,
                    model,
                    checkpoints,
                    ..
                }) => {
                    // A ladder's policies are ranked; a generalization policy is evaluated.
                    queued += if kind == JobKind::LadderTraining {
                        Self::queue_ladder_episodes(&tx, &batch, &group, &model, &checkpoints)?
                    } else {
                        Self::queue_generalization_episodes(&tx, &batch, &group, &model)?
                    };
                }
                Ok(TrainerOutcome::Proxy { result }) => {
                    queued += Self::queue_imagined_judging(&tx, &batch, &result)?;
                }
                _ => {}
            }
        }
        Self::finish_if_done(&tx, &mut self.cache, &batch, now_ms)?;
        tx.commit()?;
        Ok((
            true,
            Changed {
                batches: vec![batch],
                requeued: queued,
            },
        ))
    }

    /// Records a failed attempt: re-queued while attempts remain and the error is retryable,
    /// failed with its error otherwise.
    pub fn fail(
        &mut self,
        lease_id: u64,
        shard_id: u64,
        error: &str,
        retryable: bool,
        now_ms: i64,
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let row: Option<(String, u32, u32)> = tx
            .query_row(
                "SELECT s.batch_id, s.attempts, b.max_attempts FROM shards s JOIN batches b ON b.id = s.batch_id
                 WHERE s.id = ?1 AND s.lease_id = ?2 AND s.state = 'leased'",
                params![shard_id as i64, lease_id as i64],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()?;
        let mut changed = Changed::default();
        if let Some((batch, attempts, max)) = row {
            if retryable && attempts < max {
                tx.execute(
                    "UPDATE shards SET state = 'queued', error = ?1, lease_worker = NULL, lease_expires_ms = NULL WHERE id = ?2",
                    params![error, shard_id as i64],
                )?;
                changed.requeued = 1;
            } else {
                let msg = if retryable {
                    format!("{error} (after {attempts} attempts)")
                } else {
                    error.to_owned()
                };
                tx.execute(
                    "UPDATE shards SET state = 'failed', error = ?1, lease_expires_ms = NULL WHERE id = ?2",
                    params![msg, shard_id as i64],
                )?;
                Self::finish_if_done(&tx, &mut self.cache, &batch, now_ms)?;
            }
            changed.batches.push(batch);
        }
        tx.commit()?;
        Ok(changed)
    }

    /// A worker hands leases back (graceful shutdown): they are re-queued and the attempt is not
    /// counted against the shard.
    pub fn return_leases(
        &mut self,
        worker: &str,
        lease_ids: &[u64],
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let mut changed = Changed::default();
        for id in lease_ids {
            let batch: Option<String> = tx
                .query_row(
                    "UPDATE shards SET state = 'queued', attempts = attempts - 1, lease_worker = NULL, lease_expires_ms = NULL
                     WHERE lease_id = ?1 AND lease_worker = ?2 AND state = 'leased' RETURNING batch_id",
                    params![*id as i64, worker],
                    |r| r.get(0),
                )
                .optional()?;
            if let Some(b) = batch {
                changed.requeued += 1;
                changed.batches.push(b);
            }
        }
        tx.commit()?;
        Ok(changed)
    }

    /// Ends every lease whose deadline passed (or, with `worker`, the given leases of that worker:
    /// its session broke). Each counts as an attempt; a shard out of attempts fails.
    pub fn expire(
        &mut self,
        now_ms: i64,
        worker: Option<(&str, &[u64])>,
    ) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        let sql_owned;
        let rows: Vec<(i64, String, u32, u32, Option<String>)> = {
            let (sql, args): (&str, Vec<rusqlite::types::Value>) = match worker {
                None => (
                    "SELECT s.id, s.batch_id, s.attempts, b.max_attempts, s.lease_worker FROM shards s JOIN batches b ON b.id = s.batch_id
                     WHERE s.state = 'leased' AND s.lease_expires_ms < ?1",
                    vec![now_ms.into()],
                ),
                Some((w, ids)) => {
                    let list = ids.iter().map(u64::to_string).collect::<Vec<_>>().join(",");
                    sql_owned = format!(
                        "SELECT s.id, s.batch_id, s.attempts, b.max_attempts, s.lease_worker FROM shards s JOIN batches b ON b.id = s.batch_id
                         WHERE s.state = 'leased' AND s.lease_worker = ?1 AND s.lease_id IN ({list})"
                    );
                    (sql_owned.as_str(), vec![w.to_owned().into()])
                }
            };
            let mut stmt = tx.prepare(sql)?;
            let it = stmt.query_map(rusqlite::params_from_iter(args), |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?))
            })?;
            it.collect::<Result<_, _>>()?
        };
        let mut changed = Changed::default();
        for (id, batch, attempts, max, lease_worker) in rows {
            let why = match worker {
                None => format!(
                    "lease expired: worker {} stopped heartbeating",
                    lease_worker.unwrap_or_default()
                ),
                Some((w, _)) => format!("worker {w} disconnected while running the shard"),
            };
            if attempts < max {
                tx.execute(
                    "UPDATE shards SET state = 'queued', error = ?1, lease_worker = NULL, lease_expires_ms = NULL WHERE id = ?2",
                    params![why, id],
                )?;
                changed.requeued += 1;
            } else {
                tx.execute(
                    "UPDATE shards SET state = 'failed', error = ?1, lease_expires_ms = NULL WHERE id = ?2",
                    params![format!("{why} (after {attempts} attempts)"), id],
                )?;
                Self::finish_if_done(&tx, &mut self.cache, &batch, now_ms)?;
            }
            if !changed.batches.contains(&batch) {
                changed.batches.push(batch);
            }
        }
        tx.commit()?;
        Ok(changed)
    }

    /// After a restart: give every surviving lease a fresh deadline, so workers have time to
    /// reconnect and claim them before they expire. Returns how many leases survived.
    pub fn refresh_leases(&mut self, now_ms: i64, ttl_ms: i64) -> Result<usize, CoordError> {
        Ok(self.conn.execute(
            "UPDATE shards SET lease_expires_ms = ?1 WHERE state = 'leased'",
            [now_ms + ttl_ms],
        )?)
    }

    /// A worker (re)registers saying which leases it still runs. Those it still holds are kept;
    /// any other lease recorded for it (assigned while the coordinator went down, never
    /// received) goes back to the queue without counting an attempt.
    pub fn reconcile(
        &mut self,
        worker: &str,
        running: &[u64],
    ) -> Result<(Vec<u64>, Changed), CoordError> {
        let recorded: Vec<u64> = {
            let mut stmt = self.conn.prepare(
                "SELECT lease_id FROM shards WHERE lease_worker = ?1 AND state = 'leased'",
            )?;
            let ids = stmt
                .query_map([worker], |r| r.get::<_, i64>(0))?
                .collect::<Result<Vec<_>, _>>()?;
            ids.into_iter().map(|i| i as u64).collect()
        };
        let (kept, unknown): (Vec<u64>, Vec<u64>) =
            recorded.into_iter().partition(|id| running.contains(id));
        let changed = self.return_leases(worker, &unknown)?;
        Ok((kept, changed))
    }

    pub fn cancel(&mut self, batch_id: &str, now_ms: i64) -> Result<Changed, CoordError> {
        let tx = self.conn.savepoint()?;
        Self::require_batch(&tx, batch_id)?;
        tx.execute(
            "UPDATE shards SET state = 'cancelled', error = 'cancelled', lease_expires_ms = NULL
             WHERE batch_id = ?1 AND state IN ('queued', 'leased')",
            [batch_id],
        )?;
        tx.execute(
            "UPDATE batches SET state = ?1, finished_ms = COALESCE(finished_ms, ?2) WHERE id = ?3 AND state = ?4",
            params![batch_state::CANCELLED, now_ms, batch_id, batch_state::RUNNING],
        )?;
        tx.commit()?;
        self.cache.forget(batch_id);
        Ok(Changed {
            batches: vec![batch_id.to_owned()],
            requeued: 0,
        })
    }

    /// A batch with no shards (every task invalid) is complete as soon as it is stored.
    pub fn finish_if_empty(&mut self, batch_id: &str, now_ms: i64) -> Result<(), CoordError> {
        Self::finish_if_done(&self.conn, &mut self.cache, batch_id, now_ms)
    }

    fn require_batch(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let exists = conn
            .prepare("SELECT 1 FROM batches WHERE id = ?1")?
            .exists([batch_id])?;
        if exists {
            Ok(())
        } else {
            Err(CoordError::NotFound(format!("batch '{batch_id}'")))
        }
    }

    fn finish_if_done(
        conn: &Connection,
        cache: &mut Cache,
        batch_id: &str,
        now_ms: i64,
    ) -> Result<(), CoordError> {
        // Trainer shards lease in the order they are queued (the dynamics fits last): the
        // longest chain first — the proxy's world model, then the ladder whose policies'
        // episodes the proxy also waits for, then the generalization policy.
        // Only a batch with a plan after its episodes has anything to queue.
        let planned = cache.batch(conn, batch_id)?.planned;
        if planned {
            Self::queue_proxy_world(conn, batch_id)?;
            Self::queue_ladder(conn, batch_id)?;
            Self::queue_diffusion(conn, batch_id)?;
            Self::queue_dynamics(conn, batch_id)?;
            Self::queue_proxy(conn, batch_id)?;
        }
        // From `batch_load`, which holds the batches with open shards (kept by triggers): this
        // runs on every completion, and counting the open shards made each one O(open shards) —
        // quadratic over a batch (`assay bench coordinator` found it).
        let open: bool = conn
            .prepare_cached(
                "SELECT EXISTS (SELECT 1 FROM batch_load WHERE batch_id = ?1 AND queued + leased > 0)",
            )?
            .query_row([batch_id], |r| r.get(0))?;
        if !open {
            conn.execute(
                "UPDATE batches SET state = ?1, finished_ms = ?2 WHERE id = ?3 AND state = ?4",
                params![
                    batch_state::COMPLETED,
                    now_ms,
                    batch_id,
                    batch_state::RUNNING
                ],
            )?;
            // Nothing of it is leased again: what the cache holds of it goes.
            cache.forget(batch_id);
        }
        Ok(())
    }
}
