//! The planner: which shards a batch has.
//!
//! Owns: storing a submitted batch and its episodes (seed-major), the repeat of an evaluated
//! batch, and the shards queued as a batch's work finishes: judge shards for a rendered episode,
//! per group the world models (dynamics), the ladder of learned policies to rank and their
//! episodes, the proxy's world model (fitted while the ladder trains), the proxy (those two and
//! the proxy's episodes in `ranking`) and its imagined-rollout judging, the diffusion policy
//! and its evaluation episodes. Each runs on the caller's transaction or savepoint, so a batch
//! never looks finished between one shard and those it queues.
//! Never changes a shard's state once queued (that is `leases`).

use assay_model::diffusion::Backbone;
use assay_model::episode::{EpisodeImagery, EpisodeOutcome};
use assay_model::generalization::{GeneralizationPlan, HELD_OUT_VARIATIONS, TRAIN_VARIATIONS};
use assay_model::job::JobKind;
use assay_model::proxy::{IMAGINED_JUDGING, ProxyResult, RankingPlan};
use assay_model::quality::DEFAULT_REPEATS;
use assay_model::trainer::TrainerJob;
use rusqlite::{Connection, OptionalExtension, params};

use super::shard_state::QUEUED;
use super::{DynamicsPlan, NewBatch, PlannedTask, Store, batch_state, role};
use crate::error::CoordError;

mod ranking;

impl Store {
    fn insert_tasks(
        tx: &Connection,
        batch_id: &str,
        tasks: &[PlannedTask],
    ) -> Result<(), CoordError> {
        for t in tasks {
            tx.execute(
                "INSERT INTO tasks (batch_id, task_id, name, grp, pipeline, origin, spec_hash, spec_json)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![batch_id, t.info.id, t.info.name, t.info.group, t.info.pipeline, t.info.origin, t.info.spec_hash, t.spec_json],
            )?;
        }
        Ok(())
    }

    /// The first batch evaluated (running or completed, not itself skipped) with this content
    /// hash, if any.
    pub fn evaluated_with(&self, content_hash: &str) -> Result<Option<String>, CoordError> {
        Ok(self
            .conn
            .query_row(
                "SELECT id FROM batches WHERE content_hash = ?1 AND state IN ('running', 'completed')
                 ORDER BY seq LIMIT 1",
                [content_hash],
                |r| r.get(0),
            )
            .optional()?)
    }

    /// Records `batch` as skipped, a repeat of `duplicate_of`: in the history, with no shards.
    pub fn record_skipped(
        &mut self,
        batch: &NewBatch,
        duplicate_of: &str,
        now_ms: i64,
    ) -> Result<String, CoordError> {
        let tx = self.conn.savepoint()?;
        let seq = Self::next_counter(&tx, "batch_seq", 1)?;
        let id = format!("b{seq:05}-{:x}", now_ms & 0xff_ffff);
        tx.execute(
            "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms,
             finished_ms, content_hash, duplicate_of)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?9, ?10, ?11)",
            params![
                id,
                seq as i64,
                batch.name,
                batch_state::SKIPPED,
                serde_json::to_string(&batch.policies)?,
                serde_json::to_string(&batch.seeds)?,
                batch.max_attempts,
                serde_json::to_string(&batch.invalid)?,
                now_ms,
                batch.content_hash,
                duplicate_of,
            ],
        )?;
        Self::insert_tasks(&tx, &id, &batch.tasks)?;
        tx.commit()?;
        Ok(id)
    }

    /// Stores a batch and plans its shards: seed-major (every task's first seed runs before any
    /// task's second), then policy, then task in submission order.
    pub fn submit(&mut self, batch: &NewBatch, now_ms: i64) -> Result<(String, u32), CoordError> {
        let tx = self.conn.savepoint()?;
        let seq = Self::next_counter(&tx, "batch_seq", 1)?;
        let id = format!("b{seq:05}-{:x}", now_ms & 0xff_ffff);
        tx.execute(
            "INSERT INTO batches (id, seq, name, state, policies_json, seeds_json, max_attempts, invalid_json, submitted_ms,
             judges_json, judge_repeats, judge_budget_usd, text_models_json, dynamics_json)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
            params![
                id,
                seq as i64,
                batch.name,
                batch_state::RUNNING,
                serde_json::to_string(&batch.policies)?,
                serde_json::to_string(&batch.seeds)?,
                batch.max_attempts,
                serde_json::to_string(&batch.invalid)?,
                now_ms,
                serde_json::to_string(&batch.judges)?,
                if batch.judge_repeats == 0 { DEFAULT_REPEATS } else { batch.judge_repeats },
                batch.judge_budget_usd,
                serde_json::to_string(&batch.text_models)?,
                batch.dynamics.as_ref().map(serde_json::to_string).transpose()?,
            ],
        )?;
        Self::insert_tasks(&tx, &id, &batch.tasks)?;
        let mut n = 0u32;
        {
            let mut ins = tx.prepare(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, kind)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
            )?;
            for seed in &batch.seeds {
                for policy in &batch.policies {
                    for t in &batch.tasks {
                        ins.execute(params![
                            id,
                            t.info.id,
                            *seed as i64,
                            policy,
                            batch.role,
                            QUEUED,
                            JobKind::Episode.as_str(),
                        ])?;
                        n += 1;
                    }
                }
            }
        }
        tx.execute(
            "UPDATE batches SET content_hash = ?1, render = ?2, priority = ?3, submitter = ?4,
             max_workers = ?5 WHERE id = ?6",
            params![
                batch.content_hash,
                batch.render,
                batch.share.priority.as_str(),
                batch.share.submitter,
                batch.share.max_workers,
                id
            ],
        )?;
        Self::mark_rendering_in_loop(&tx, &id)?;
        if let Some(plan) = &batch.ranking {
            tx.execute(
                "UPDATE batches SET ranking_json = ?1 WHERE id = ?2",
                params![serde_json::to_string(plan)?, id],
            )?;
        }
        if let Some(plan) = &batch.generalization {
            tx.execute(
                "UPDATE batches SET generalization_json = ?1 WHERE id = ?2",
                params![serde_json::to_string(plan)?, id],
            )?;
        }
        if !batch.text_models.is_empty() && !batch.tasks.is_empty() {
            let job = TrainerJob::Text {
                models: batch.text_models.clone(),
                groups: batch.text_groups.clone(),
            };
            tx.execute(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, input_json, kind)
                 VALUES (?1, '', 0, '', ?2, ?3, 'text', ?4, ?5)",
                params![
                    id,
                    role::TRAINER,
                    QUEUED,
                    serde_json::to_string(&job)?,
                    JobKind::TextDiversity.as_str()
                ],
            )?;
        }
        tx.commit()?;
        Ok((id, n))
    }

    /// Queues one judge shard per judge for a rendered episode, carrying its outcome. Returns
    /// how many.
    pub(super) fn queue_episode_judging(
        conn: &Connection,
        batch_id: &str,
        task_id: &str,
        seed: i64,
        policy: &str,
        judges: &[String],
        outcome_json: &str,
    ) -> Result<u32, CoordError> {
        for judge in judges {
            conn.execute(
                "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, judge, input_json, needs, kind)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![
                    batch_id,
                    task_id,
                    seed,
                    policy,
                    role::JUDGE,
                    QUEUED,
                    judge,
                    outcome_json,
                    judge_needs(judge)?,
                    JobKind::EpisodeJudging.as_str(),
                ],
            )?;
        }
        Ok(judges.len() as u32)
    }

    /// The plan in `column` of a running batch (None: the batch is not running or has none).
    fn running_plan<T: serde::de::DeserializeOwned>(
        conn: &Connection,
        batch_id: &str,
        column: &str,
    ) -> Result<Option<T>, CoordError> {
        let row: Option<(String, Option<String>)> = conn
            .prepare_cached(&format!(
                "SELECT state, {column} FROM batches WHERE id = ?1"
            ))?
            .query_row([batch_id], |r| Ok((r.get(0)?, r.get(1)?)))
            .optional()?;
        match row {
            Some((state, Some(plan))) if state == batch_state::RUNNING => {
                Ok(Some(serde_json::from_str(&plan)?))
            }
            _ => Ok(None),
        }
    }

    /// The batch's task groups in task order.
    fn groups(conn: &Connection, batch_id: &str) -> Result<Vec<String>, CoordError> {
        let mut stmt = conn.prepare(
            "SELECT grp FROM tasks WHERE batch_id = ?1 GROUP BY grp ORDER BY MIN(rowid)",
        )?;
        let groups = stmt
            .query_map([batch_id], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(groups)
    }

    /// Whether `group`'s episodes are all finished and it has no trainer shard of `kind` yet: the
    /// moment to queue one.
    fn group_ready(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        kind: JobKind,
    ) -> Result<bool, CoordError> {
        // The open shards from the partial indexes of the queued and the leased shards (SQLite
        // would rather seek the batch's leased ones by `shards_in_batch`, all of its shards).
        let (started, open): (i64, i64) = conn.query_row(
            "SELECT
               (SELECT COUNT(*) FROM shards WHERE batch_id = ?1 AND kind = ?3 AND grp = ?2),
               EXISTS (SELECT 1 FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                WHERE s.state = 'queued' AND s.batch_id = ?1 AND t.grp = ?2
                  AND s.role NOT IN ('judge', 'trainer'))
               OR EXISTS (SELECT 1 FROM shards s INDEXED BY shards_leased
                JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                WHERE s.state = 'leased' AND s.batch_id = ?1 AND t.grp = ?2
                  AND s.role NOT IN ('judge', 'trainer'))",
            params![batch_id, group, kind.as_str()],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        Ok(started == 0 && open == 0)
    }

    /// Whether `group`'s ladder trainings (a ranking batch's learned policies) are all queued and
    /// finished, done or failed: until then the proxy waits, since their episodes are ranked.
    fn ladder_settled(conn: &Connection, batch_id: &str, group: &str) -> Result<bool, CoordError> {
        let (shards, open): (i64, i64) = conn.query_row(
            "SELECT COUNT(*), COUNT(CASE WHEN state IN ('queued', 'leased') THEN 1 END) FROM shards
             WHERE batch_id = ?1 AND kind = ?3 AND grp = ?2",
            params![batch_id, group, JobKind::LadderTraining.as_str()],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        Ok(shards > 0 && open == 0)
    }

    /// The dynamics clips of `group`'s finished episodes of `policy` (the batch's own, not a
    /// trained policy's evaluation episodes), in planning order.
    fn policy_clips(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        policy: &str,
    ) -> Result<Vec<String>, CoordError> {
        let mut stmt = conn.prepare_cached(
            "SELECT json_extract(s.outcome_json, '$.imagery.clip') AS clip
             FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
             WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.kind = ?4 AND s.policy = ?3
               AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
        )?;
        let clips = stmt
            .query_map(
                params![batch_id, group, policy, JobKind::Episode.as_str()],
                |r| r.get(0),
            )?
            .collect::<Result<_, _>>()?;
        Ok(clips)
    }

    /// The role of the batch's own episodes (what its policies' shards run on).
    fn episode_role(conn: &Connection, batch_id: &str) -> Result<String, CoordError> {
        Ok(conn.query_row(
            "SELECT role FROM shards WHERE batch_id = ?1 AND kind = ?2 LIMIT 1",
            [batch_id, JobKind::Episode.as_str()],
            |r| r.get(0),
        )?)
    }

    /// Why a policy trained on `group`'s episodes of `policy` cannot be: fewer than 2 with a clip.
    fn too_few_clips(group: &str, have: usize, policy: &str, what: &str) -> String {
        format!(
            "group {group:?} has {have} episode(s) of {policy} with a clip; {what} needs at least 2 \
             (clips are rendered by workers with the render role)"
        )
    }

    /// Records a trainer shard of `kind` of `group`, named `job`, that cannot run, with the
    /// reason.
    fn insert_failed_trainer_shard(
        conn: &Connection,
        batch_id: &str,
        kind: JobKind,
        job: &str,
        group: &str,
        error: &str,
    ) -> Result<(), CoordError> {
        conn.execute(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp, error, kind)
             VALUES (?1, '', 0, '', 'trainer', 'failed', ?2, ?3, ?4, ?5)",
            params![batch_id, job, group, error, kind.as_str()],
        )?;
        Ok(())
    }

    /// Queues a trainer shard of `kind` of `group`, named `name`, running `job`.
    fn insert_trainer_shard(
        conn: &Connection,
        batch_id: &str,
        kind: JobKind,
        name: &str,
        group: &str,
        job: &TrainerJob,
    ) -> Result<(), CoordError> {
        conn.execute(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp, input_json, kind)
             VALUES (?1, '', 0, '', 'trainer', 'queued', ?2, ?3, ?4, ?5)",
            params![batch_id, name, group, serde_json::to_string(job)?, kind.as_str()],
        )?;
        Ok(())
    }

    /// Queues the world models of every group of a running batch whose episodes are all finished
    /// (none queued or leased) and that has none yet: one trainer shard per budget, on the
    /// group's first `max(budgets)` clips in planning order (seed-major, so the first budget
    /// holds one episode per task before any task's second). A group with fewer than 2 clips gets
    /// one failed shard saying so.
    pub(super) fn queue_dynamics(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<DynamicsPlan>(conn, batch_id, "dynamics_json")?
        else {
            return Ok(());
        };
        let groups = Self::groups(conn, batch_id)?;
        let eval = plan.budgets.iter().copied().max().unwrap_or(0) as usize;
        for group in groups {
            if !Self::group_ready(conn, batch_id, &group, JobKind::DynamicsFit)? {
                continue;
            }
            let clips: Vec<String> = {
                let mut stmt = conn.prepare(
                    "SELECT json_extract(s.outcome_json, '$.imagery.clip') AS clip
                     FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                     WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.kind = ?3
                       AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
                )?;
                stmt.query_map(params![batch_id, group, JobKind::Episode.as_str()], |r| {
                    r.get(0)
                })?
                .take(eval)
                .collect::<Result<_, _>>()?
            };
            if clips.len() < 2 {
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    JobKind::DynamicsFit,
                    &format!("dynamics {group}"),
                    &group,
                    &format!(
                        "group {group:?} has {} episode(s) with a dynamics clip; a world model needs at least 2 \
                             (clips are rendered by workers with the render role)",
                        clips.len()
                    ),
                )?;
                continue;
            }
            // A group with fewer clips than a budget trains that budget on all of them; larger
            // budgets would repeat the same fit, so they are left out (the report shows the
            // number trained). Budgets are sorted and distinct since submission.
            let mut budgets = plan.budgets.clone();
            if let Some(covering) = budgets.iter().position(|b| *b as usize >= clips.len()) {
                budgets.truncate(covering + 1);
            }
            for budget in &budgets {
                let job = TrainerJob::Dynamics {
                    group: group.clone(),
                    budget: *budget,
                    clips: clips.clone(),
                    config: plan.config.clone(),
                };
                Self::insert_trainer_shard(
                    conn,
                    batch_id,
                    JobKind::DynamicsFit,
                    &format!("dynamics {group} @ {budget}"),
                    &group,
                    &job,
                )?;
            }
        }
        Ok(())
    }

    /// Queues the diffusion policy of every group of a running generalization batch whose
    /// episodes are all finished and that has none yet: one trainer shard per group on the
    /// group's first `episodes` clips of the training policy (planning order). A group with fewer
    /// than 2 such clips gets one failed shard saying so.
    pub(super) fn queue_diffusion(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) =
            Self::running_plan::<GeneralizationPlan>(conn, batch_id, "generalization_json")?
        else {
            return Ok(());
        };
        let groups = Self::groups(conn, batch_id)?;
        for group in groups {
            if !plan.covers(&group)
                || !Self::group_ready(conn, batch_id, &group, JobKind::GeneralizationTraining)?
            {
                continue;
            }
            let mut clips = Self::policy_clips(conn, batch_id, &group, &plan.train_policy)?;
            clips.truncate(plan.episodes as usize);
            let (kind, job_name) = (
                JobKind::GeneralizationTraining,
                format!("diffusion {group}"),
            );
            if clips.len() < 2 {
                let why = Self::too_few_clips(
                    &group,
                    clips.len(),
                    &plan.train_policy,
                    "a diffusion policy",
                );
                Self::insert_failed_trainer_shard(conn, batch_id, kind, &job_name, &group, &why)?;
                continue;
            }
            let job = TrainerJob::Diffusion {
                group: group.clone(),
                clips,
                config: plan.config.clone(),
                checkpoints: Vec::new(),
            };
            Self::insert_trainer_shard(conn, batch_id, kind, &job_name, &group, &job)?;
        }
        Ok(())
    }

    /// Queues the ladder of learned policies of every group of a running ranking batch with a
    /// ladder whose episodes are all finished and that has none yet: one diffusion training per
    /// run (`ladder.episodes` and `train_episodes`) on the group's first `n` clips of the
    /// ladder's training policy in planning order, for as many steps as its last checkpoint
    /// (ranked or training-only) and kept at every one. A group with fewer clips than a run trains it on all of them, and
    /// larger runs, which would repeat that training, are left out. A group with fewer than 2
    /// such clips gets one failed shard saying so (and its proxy ranks what it has).
    pub(super) fn queue_ladder(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let Some(plan) = Self::running_plan::<RankingPlan>(conn, batch_id, "ranking_json")? else {
            return Ok(());
        };
        let Some(ladder) = &plan.ladder else {
            return Ok(());
        };
        let runs = ladder.runs();
        let checkpoints = ladder.kept_steps();
        let steps = checkpoints.last().copied().unwrap_or(ladder.config.steps);
        for group in Self::groups(conn, batch_id)? {
            if !plan.covers(&group)
                || !Self::group_ready(conn, batch_id, &group, JobKind::LadderTraining)?
            {
                continue;
            }
            let clips = Self::policy_clips(conn, batch_id, &group, &ladder.train_policy)?;
            if clips.len() < 2 {
                let why = Self::too_few_clips(
                    &group,
                    clips.len(),
                    &ladder.train_policy,
                    "a ladder policy",
                );
                Self::insert_failed_trainer_shard(
                    conn,
                    batch_id,
                    JobKind::LadderTraining,
                    &format!("ladder {group}"),
                    &group,
                    &why,
                )?;
                continue;
            }
            let mut runs = runs.clone();
            if let Some(covering) = runs.iter().position(|n| *n as usize >= clips.len()) {
                runs.truncate(covering + 1);
            }
            for backbone in ladder.families() {
                for &n in &runs {
                    let job = TrainerJob::Diffusion {
                        group: group.clone(),
                        clips: clips.iter().take(n as usize).cloned().collect(),
                        config: assay_model::diffusion::DiffusionConfig {
                            steps,
                            backbone,
                            ..ladder.config.clone()
                        },
                        checkpoints: checkpoints.clone(),
                    };
                    // The U-Net's runs keep the names they had before there were families.
                    let name = match backbone {
                        Backbone::Unet => format!("ladder {group} @ {n}"),
                        other => format!("ladder {group} @ {n} {}", other.as_str()),
                    };
                    let kind = JobKind::LadderTraining;
                    Self::insert_trainer_shard(conn, batch_id, kind, &name, &group, &job)?;
                }
            }
        }
        Ok(())
    }

    /// Queues the episodes of the policies one ladder training of `group` kept (each checkpoint
    /// and the final model, each key once): every (task, seed) of the group the batch planned
    /// for its own policies — or, with the ladder's `held_out_seeds`, every task of the group
    /// under those seeds instead — as ordinary episodes of the batch (kind `Episode`, no job
    /// name: they count in its success tables and are ranked by the proxy, or train it when kept
    /// at a `train_checkpoints` step or by a `train_episodes` run). Returns how many.
    pub(super) fn queue_ladder_episodes(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        model: &str,
        checkpoints: &[(u64, String)],
    ) -> Result<u32, CoordError> {
        let (plan, seeds): (Option<String>, String) = conn.query_row(
            "SELECT ranking_json, seeds_json FROM batches WHERE id = ?1",
            [batch_id],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        let Some(RankingPlan {
            ladder: Some(ladder),
            ..
        }) = plan.map(|p| serde_json::from_str(&p)).transpose()?
        else {
            return Ok(0);
        };
        let seeds = ladder.episode_seeds(&serde_json::from_str::<Vec<u64>>(&seeds)?);
        let mut kept: Vec<(u64, &str)> =
            checkpoints.iter().map(|(s, k)| (*s, k.as_str())).collect();
        kept.sort_unstable();
        kept.push((u64::MAX, model));
        let mut policies: Vec<String> = Vec::new();
        for (_, key) in kept {
            let name = ladder.policy_name(key);
            let exists: bool = conn
                .prepare_cached(
                    "SELECT EXISTS (SELECT 1 FROM shards WHERE batch_id = ?1 AND policy = ?2 AND kind = ?3)",
                )?
                .query_row(
                    params![batch_id, name, JobKind::Episode.as_str()],
                    |r| r.get(0),
                )?;
            if !exists && !policies.contains(&name) {
                policies.push(name);
            }
        }
        let tasks: Vec<String> = {
            let mut stmt = conn.prepare(
                "SELECT task_id FROM tasks WHERE batch_id = ?1 AND grp = ?2 ORDER BY rowid",
            )?;
            stmt.query_map(params![batch_id, group], |r| r.get(0))?
                .collect::<Result<_, _>>()?
        };
        let role = Self::episode_role(conn, batch_id)?;
        let mut ins = conn.prepare(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, kind)
             VALUES (?1, ?2, ?3, ?4, ?5, 'queued', ?6)",
        )?;
        let mut n = 0;
        for seed in &seeds {
            for policy in &policies {
                for task in &tasks {
                    let kind = JobKind::Episode.as_str();
                    ins.execute(params![batch_id, task, *seed as i64, policy, role, kind])?;
                    n += 1;
                }
            }
        }
        Self::mark_rendering_in_loop(conn, batch_id)?;
        Ok(n)
    }

    /// Queues, for every judge of the batch that looks at images (every one but the built-in
    /// `offline`, whose completion is the simulator's), one judge shard per imagined rollout of
    /// a finished proxy: the ranked episode's outcome with the imagined keyframes as its imagery
    /// and no scene views, so the judge is asked about completion only. Returns how many.
    pub(super) fn queue_imagined_judging(
        conn: &Connection,
        batch_id: &str,
        result: &ProxyResult,
    ) -> Result<u32, CoordError> {
        let judges: String = conn.query_row(
            "SELECT judges_json FROM batches WHERE id = ?1",
            [batch_id],
            |r| r.get(0),
        )?;
        let judges: Vec<String> = serde_json::from_str(&judges)?;
        let judges: Vec<&String> = judges.iter().filter(|j| *j != "offline").collect();
        if judges.is_empty() {
            return Ok(0);
        }
        let mut real = conn.prepare(
            "SELECT outcome_json FROM shards WHERE batch_id = ?1 AND task_id = ?2 AND seed = ?3
               AND policy = ?4 AND kind = ?5 AND state = 'done'",
        )?;
        let mut ins = conn.prepare(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, judge, input_json, job, grp, needs, kind)
             VALUES (?1, ?2, ?3, ?4, ?5, 'queued', ?6, ?7, ?8, ?9, ?10, ?11)",
        )?;
        let mut n = 0;
        for p in result
            .predictions
            .iter()
            .filter(|p| !p.imagined_keyframes.is_empty())
        {
            let episode_kind = JobKind::Episode.as_str();
            let Some(json) = real
                .query_row(
                    params![batch_id, p.task_id, p.seed as i64, p.policy, episode_kind],
                    |r| r.get::<_, String>(0),
                )
                .optional()?
            else {
                continue;
            };
            let mut episode: EpisodeOutcome = serde_json::from_str(&json)?;
            episode.imagery = Some(EpisodeImagery {
                adapter: "world model (imagined)".into(),
                views: Vec::new(),
                keyframes: p.imagined_keyframes.clone(),
                contact_sheet: String::new(),
                video: None,
                caption: None,
                clip: None,
            });
            let input = serde_json::to_string(&episode)?;
            for judge in &judges {
                ins.execute(params![
                    batch_id,
                    p.task_id,
                    p.seed as i64,
                    p.policy,
                    role::JUDGE,
                    judge,
                    input,
                    IMAGINED_JUDGING,
                    result.group,
                    judge_needs(judge)?,
                    JobKind::ImaginedJudging.as_str(),
                ])?;
                n += 1;
            }
        }
        Ok(n)
    }

    /// Queues the evaluation episodes of `group`'s trained diffusion policy `model`: every
    /// (task, seed) it was trained on, and every task of the group under the plan's held-out
    /// seeds. Returns how many.
    pub(super) fn queue_generalization_episodes(
        conn: &Connection,
        batch_id: &str,
        group: &str,
        model: &str,
    ) -> Result<u32, CoordError> {
        let plan: Option<String> = conn.query_row(
            "SELECT generalization_json FROM batches WHERE id = ?1",
            [batch_id],
            |r| r.get(0),
        )?;
        let Some(plan) = plan else {
            return Ok(0);
        };
        let plan: GeneralizationPlan = serde_json::from_str(&plan)?;
        let policy = plan.policy_name(model);
        let trained: Vec<(String, i64)> = {
            let mut stmt = conn.prepare(
                "SELECT s.task_id, s.seed, json_extract(s.outcome_json, '$.imagery.clip') AS clip
                 FROM shards s JOIN tasks t ON t.batch_id = s.batch_id AND t.task_id = s.task_id
                 WHERE s.batch_id = ?1 AND t.grp = ?2 AND s.kind = ?4 AND s.policy = ?3
                   AND s.state = 'done' AND clip IS NOT NULL ORDER BY s.id",
            )?;
            let episode = JobKind::Episode.as_str();
            stmt.query_map(params![batch_id, group, plan.train_policy, episode], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })?
            .take(plan.episodes as usize)
            .collect::<Result<_, _>>()?
        };
        let tasks: Vec<String> = {
            let mut stmt = conn.prepare(
                "SELECT task_id FROM tasks WHERE batch_id = ?1 AND grp = ?2 ORDER BY rowid",
            )?;
            stmt.query_map(params![batch_id, group], |r| r.get(0))?
                .collect::<Result<_, _>>()?
        };
        let role = Self::episode_role(conn, batch_id)?;
        let mut ins = conn.prepare(
            "INSERT INTO shards (batch_id, task_id, seed, policy, role, state, job, grp, kind)
             VALUES (?1, ?2, ?3, ?4, ?5, 'queued', ?6, ?7, ?8)",
        )?;
        let mut n = 0;
        for (task, seed) in &trained {
            ins.execute(params![
                batch_id,
                task,
                seed,
                policy,
                role,
                TRAIN_VARIATIONS,
                group,
                JobKind::GeneralizationTrainEpisode.as_str(),
            ])?;
            n += 1;
        }
        for k in 0..u64::from(plan.held_out_seeds) {
            for task in &tasks {
                let seed = (plan.held_out_seed_base + k) as i64;
                ins.execute(params![
                    batch_id,
                    task,
                    seed,
                    policy,
                    role,
                    HELD_OUT_VARIATIONS,
                    group,
                    JobKind::GeneralizationHeldOutEpisode.as_str(),
                ])?;
                n += 1;
            }
        }
        Self::mark_rendering_in_loop(conn, batch_id)?;
        Ok(n)
    }

    /// Queued episodes of a policy that may see while it runs need a worker that renders beside
    /// its simulator (`PolicySpec::renders_in_loop`): frames in the loop cannot wait for a
    /// render shard. (An episode that needs only its role has `needs` = `[role]`, or NULL in a
    /// store not yet opened by this version.)
    fn mark_rendering_in_loop(conn: &Connection, batch_id: &str) -> Result<(), CoordError> {
        let policies: Vec<(String, String)> = {
            let mut stmt = conn.prepare(
                "SELECT DISTINCT policy, role FROM shards WHERE batch_id = ?1 AND state = 'queued'
                 AND (needs IS NULL OR needs = json_array(role)) AND stage IS NULL
                 AND role NOT IN ('judge', 'trainer')",
            )?;
            stmt.query_map([batch_id], |r| Ok((r.get(0)?, r.get(1)?)))?
                .collect::<Result<_, _>>()?
        };
        for (policy, role) in policies {
            let sees =
                assay_model::policy::PolicySpec::parse(&policy).is_ok_and(|p| p.renders_in_loop());
            if sees {
                conn.execute(
                    "UPDATE shards SET needs = ?1 WHERE batch_id = ?2 AND policy = ?3 AND state = 'queued'
                     AND (needs IS NULL OR needs = json_array(role)) AND stage IS NULL AND role = ?4",
                    params![
                        serde_json::to_string(&[role.as_str(), super::role::RENDER])?,
                        batch_id,
                        policy,
                        role
                    ],
                )?;
            }
        }
        Ok(())
    }
}

/// What a judge shard needs of its worker: the judge role and that judge configured.
fn judge_needs(judge: &str) -> Result<String, CoordError> {
    Ok(serde_json::to_string(&[
        role::JUDGE.to_owned(),
        format!("judge:{judge}"),
    ])?)
}
