//! The planner's part of policy ranking: the episodes a group's proxy learns from and ranks
//! (with each ranked ladder policy's family), the proxy's world model fitted ahead of it, and
//! the proxy itself.

use std::collections::HashMap;

use assay_model::job::JobKind;
use assay_model::policy::PolicySpec;
use assay_model::proxy::{ProxyEpisode, RankingPlan};
use assay_model::trainer::{KeptPolicy, TrainerJob, TrainerOutcome};
use assay_spec::spec::PhysicsSettings;
use rusqlite::{Connection, OptionalExtension, params};

use super::super::Store;
use super::super::shard_state::{LEASED, QUEUED};
use crate::error::CoordError;

impl Store {
    /// The episodes of `group` with a clip, split into the training policies' (with their
    /// outcomes; the ladder's training-only policies among them) and the ranked policies'
    /// (without), in planning order: the batch's own first, then each ladder training's (queued
    /// when it finished) in the order the trainings were planned, so that which training
    /// finished first changes neither list (the world model's windows and the action test's
    /// pairing of episodes follow it).
    fn proxy_episodes(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        plan: &RankingPlan,
    ) -> Result<(Vec<ProxyEpisode>, Vec<ProxyEpisode>), CoordError> {
        let default_budget = PhysicsSettings::default().max_steps;
        let trainings = Self::ladder_trainings(conn, batch_id, group, plan)?;
        // Each ladder policy with the planned place of the training that kept it (the first,
        // when two kept the same model).
        let mut ladder: HashMap<&str, (usize, &KeptPolicy)> = HashMap::new();
        for (place, kept) in trainings.iter().enumerate() {
            for p in kept {
                ladder.entry(p.name.as_str()).or_insert((place, p));
            }
        }
        let (mut train, mut eval) = (Vec::new(), Vec::new());
        let mut stmt = conn.prepare(
            "SELECT s.task_id, s.policy, s.seed,
                    json_extract(s.outcome_json, '$.imagery.clip') AS clip,
                    json_extract(s.outcome_json, '$.success'),
                    COALESCE(json_extract(t.spec_json, '$.description'), ''),
                    COALESCE(json_extract(t.spec_json, '$.physics.max_steps'), ?3)
             FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
             WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.kind = ?4
               AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
        )?;
        let mut rows = stmt.query(params![
            batch_id,
            group,
            default_budget,
            JobKind::Episode.as_str()
        ])?;
        while let Some(r) = rows.next()? {
            let policy: String = r.get(1)?;
            let (place, of_ladder) = match ladder.get(policy.as_str()) {
                Some(&(place, p)) => (Some(place), Some(p)),
                None => (None, None),
            };
            let training =
                plan.train_policies.contains(&policy) || of_ladder.is_some_and(|p| p.trains_only);
            // The simulator's horizon: the task's budget, or the policy's when smaller.
            let task_budget: u32 = r.get(6)?;
            let budget_steps = match PolicySpec::parse_with_horizon(&policy) {
                Ok((_, Some(h))) => h.min(task_budget),
                _ => task_budget,
            };
            let family = match of_ladder {
                Some(p) if !training => p.family.as_str().to_owned(),
                _ => String::new(),
            };
            let ep = ProxyEpisode {
                task_id: r.get(0)?,
                family,
                policy,
                seed: r.get::<_, i64>(2)? as u64,
                clip: r.get(3)?,
                instruction: r.get(5)?,
                success: training.then(|| r.get::<_, i64>(4).unwrap_or(0) != 0),
                budget_steps,
            };
            if training {
                train.push((place, ep));
            } else {
                eval.push((place, ep));
            }
        }
        // Stable: within a place, planning order (`s.id`) as read.
        let in_order = |mut v: Vec<(Option<usize>, ProxyEpisode)>| {
            v.sort_by_key(|(place, _)| *place);
            v.into_iter().map(|(_, e)| e).collect()
        };
        Ok((in_order(train), in_order(eval)))
    }

    /// The policies each finished ladder training of `group` kept, one list per training, the
    /// trainings in the order they were planned.
    fn ladder_trainings(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        plan: &RankingPlan,
    ) -> Result<Vec<Vec<KeptPolicy>>, CoordError> {
        let Some(ladder) = &plan.ladder else {
            return Ok(Vec::new());
        };
        let mut out = Vec::new();
        let mut stmt = conn.prepare(
            "SELECT outcome_json FROM shards WHERE batch_id = ?1 AND grp = ?2 AND kind = ?3
               AND state = 'done' AND outcome_json IS NOT NULL ORDER BY id",
        )?;
        let mut rows = stmt.query(params![batch_id, group, JobKind::LadderTraining.as_str()])?;
        while let Some(r) = rows.next()? {
            let json: String = r.get(0)?;
            if let Ok(outcome) = serde_json::from_str::<TrainerOutcome>(&json) {
                out.push(outcome.ladder_policies(ladder));
            }
        }
        Ok(out)
    }

    /// The job name of `group`'s world model fitted ahead of its proxy.
    fn proxy_world_job(group: &str) -> String {
        format!("world model {group}")
    }

    /// Queues, for every ranked group of a running ranking batch with a ladder whose episodes
    /// are all finished, the proxy's world model ahead of the proxy: it trains on the training
    /// policies' episodes while the ladder's policies train and run, instead of after them.
    /// With training-only ladder policies (`train_checkpoints`, `train_episodes`) their
    /// episodes are training episodes too, so the fit waits for the ladder's trainings and
    /// episodes to finish. A served world model is not fitted; a group with fewer than 2
    /// training clips gets none (its proxy says why).
    pub(in crate::store) fn queue_proxy_world(
        conn: &Connection,
        batch_id: &str,
    ) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<RankingPlan>(conn, batch_id, "ranking_json")? else {
            return Ok(());
        };
        let Some(ladder) = &plan.ladder else {
            return Ok(());
        };
        if plan.config.external.is_some() {
            return Ok(());
        }
        let trains_on_ladder = ladder.has_training_only();
        for group in Self::groups(conn, batch_id)? {
            if !plan.covers(&group)
                || !Self::group_ready(conn, batch_id, &group, JobKind::ProxyWorldModel)?
                || (trains_on_ladder && !Self::ladder_settled(conn, batch_id, &group)?)
            {
                continue;
            }
            let (train, _) = Self::proxy_episodes(conn, batch_id, &group, &plan)?;
            // Exactly the clips the proxy's own fit takes (`world_model_policies`).
            let train: Vec<ProxyEpisode> = train
                .into_iter()
                .filter(|e| plan.config.trains_world_model(&e.policy))
                .collect();
            if train.len() < 2 {
                continue;
            }
            let job = TrainerJob::ProxyWorld {
                group: group.clone(),
                train,
                config: plan.config.clone(),
            };
            let name = Self::proxy_world_job(&group);
            let kind = JobKind::ProxyWorldModel;
            Self::insert_trainer_shard(conn, batch_id, kind, &name, &group, &job)?;
        }
        Ok(())
    }

    /// `group`'s world model fitted ahead of its proxy: `Err(())` while it is still queued or
    /// running (the proxy waits), its checkpoint's key once done, `None` when there is none or
    /// it failed (the proxy fits its own).
    fn proxy_world(
        conn: &Connection,
        batch_id: &str,
        group: &str,
    ) -> Result<Result<Option<String>, ()>, CoordError> {
        let row: Option<(String, Option<String>)> = conn
            .query_row(
                "SELECT state, outcome_json FROM shards WHERE batch_id = ?1 AND kind = ?3 AND grp = ?2",
                params![batch_id, group, JobKind::ProxyWorldModel.as_str()],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()?;
        Ok(match row {
            Some((state, _)) if state == QUEUED || state == LEASED => Err(()),
            Some((_, Some(json))) => match serde_json::from_str(&json) {
                Ok(TrainerOutcome::ProxyWorld { checkpoint, .. }) => Ok(Some(checkpoint)),
                _ => Ok(None),
            },
            _ => Ok(None),
        })
    }

    /// Queues the world-model proxy of every group of a running ranking batch whose episodes are
    /// all finished and that has none yet: one trainer shard per group, trained on the clips of
    /// the training policies' episodes (with their outcomes) and imagining those of the ranked
    /// policies (without), from the world model fitted ahead of it when there is one. A group
    /// with fewer than 2 training clips or no ranked clip gets one failed shard saying so.
    pub(in crate::store) fn queue_proxy(
        conn: &Connection,
        batch_id: &str,
    ) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<RankingPlan>(conn, batch_id, "ranking_json")? else {
            return Ok(());
        };
        for group in Self::groups(conn, batch_id)? {
            if !plan.covers(&group)
                || !Self::group_ready(conn, batch_id, &group, JobKind::Proxy)?
                || (plan.ladder.is_some() && !Self::ladder_settled(conn, batch_id, &group)?)
            {
                continue;
            }
            let Ok(world_model) = Self::proxy_world(conn, batch_id, &group)? else {
                continue;
            };
            let (train, eval) = Self::proxy_episodes(conn, batch_id, &group, &plan)?;
            let job_name = format!("proxy {group}");
            if train.len() < 2 || eval.is_empty() {
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    JobKind::Proxy,
                    &job_name,
                    &group,
                    &format!(
                        "group {group:?} has {} training episode(s) and {} ranked episode(s) with a clip; \
                             the proxy needs at least 2 and 1 (clips are rendered by workers with the render role)",
                        train.len(),
                        eval.len()
                    ),
                )?;
                continue;
            }
            let job = TrainerJob::Proxy {
                group: group.clone(),
                train,
                eval,
                config: plan.config.clone(),
                world_model,
            };
            let kind = JobKind::Proxy;
            Self::insert_trainer_shard(conn, batch_id, kind, &job_name, &group, &job)?;
        }
        Ok(())
    }
}
