//! The read model: what the store tells about its batches.
//!
//! Owns: a batch's counts, the lists of batches, and the report built from the store (partial
//! while the batch runs), with the hash of the batch's settings. Never writes.

use assay_model::episode::{EpisodeOutcome, JudgeRecord, ShardRecord, TaskInfo};
use assay_model::generalization::HELD_OUT_VARIATIONS;
use assay_model::proxy::{IMAGINED_JUDGING, ImaginedJudgement, RankingPlan};
use assay_model::quality::{Item, JudgeOutcome};
use assay_model::trainer::TrainerOutcome;
use assay_report::diversity::DiversityResults;
use assay_report::generalization::{EvalEpisode, GeneralizationResults, GroupGeneralization};
use assay_report::ranking::{RealEpisode, ladder_label, ranking_results};
use assay_report::report::{self, Report, RunInfo};
use assay_spec::SpecError;
use rusqlite::OptionalExtension;

use super::shard_state::{CANCELLED, DONE, FAILED, LEASED, QUEUED};
use super::{BatchCounts, Store, role};
use crate::error::CoordError;

impl Store {
    /// The queued shards of a batch (every running batch when `None`) by what they need of a
    /// worker, as `(needs, count)`.
    pub fn queued_needs(
        &self,
        batch_id: Option<&str>,
    ) -> Result<Vec<(Vec<String>, u32)>, CoordError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT COALESCE(s.needs, json_array(s.role)) AS nd, COUNT(*) FROM shards s
             JOIN batches b ON b.id = s.batch_id
             WHERE s.state = 'queued' AND b.state = 'running' AND (?1 IS NULL OR s.batch_id = ?1)
             GROUP BY nd ORDER BY nd",
        )?;
        let rows = stmt.query_map([batch_id], |r| {
            Ok((r.get::<_, String>(0)?, r.get::<_, u32>(1)?))
        })?;
        let mut out = Vec::new();
        for row in rows {
            let (needs, n) = row?;
            out.push((serde_json::from_str(&needs)?, n));
        }
        Ok(out)
    }

    pub fn counts(&self, batch_id: &str) -> Result<BatchCounts, CoordError> {
        let mut c: BatchCounts = self
            .conn
            .query_row(
                "SELECT id, name, state, submitted_ms, finished_ms, invalid_json, content_hash, duplicate_of FROM batches WHERE id = ?1",
                [batch_id],
                |r| {
                    let invalid: String = r.get(5)?;
                    let invalid: Vec<SpecError> = serde_json::from_str(&invalid).unwrap_or_default();
                    let distinct: std::collections::BTreeSet<_> =
                        invalid.iter().map(|e| (e.origin.clone(), e.task.clone())).collect();
                    Ok(BatchCounts {
                        id: r.get(0)?,
                        name: r.get(1)?,
                        state: r.get(2)?,
                        submitted_ms: r.get(3)?,
                        finished_ms: r.get(4)?,
                        invalid_tasks: distinct.len() as u32,
                        content_hash: r.get(6)?,
                        duplicate_of: r.get(7)?,
                        ..Default::default()
                    })
                },
            )
            .optional()?
            .ok_or_else(|| CoordError::NotFound(format!("batch '{batch_id}'")))?;
        let mut stmt = self.conn.prepare(
            "SELECT state, role, COUNT(*) FROM shards WHERE batch_id = ?1 GROUP BY state, role",
        )?;
        let rows = stmt.query_map([batch_id], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, u32>(2)?,
            ))
        })?;
        for row in rows {
            let (state, shard_role, n) = row?;
            if shard_role == role::TRAINER {
                c.trainer_total += n;
                match state.as_str() {
                    DONE => c.trainer_done = n,
                    FAILED => c.trainer_failed = n,
                    _ => {}
                }
                continue;
            }
            if shard_role == role::JUDGE {
                c.judge_total += n;
                match state.as_str() {
                    DONE => c.judge_done = n,
                    FAILED => c.judge_failed = n,
                    _ => {}
                }
                continue;
            }
            c.total += n;
            match state.as_str() {
                QUEUED => c.queued = n,
                LEASED => c.leased = n,
                DONE => c.done = n,
                FAILED => c.failed = n,
                CANCELLED => c.cancelled = n,
                _ => {}
            }
        }
        c.successes = self.conn.query_row(
            "SELECT COUNT(*) FROM shards WHERE batch_id = ?1 AND role NOT IN ('judge', 'trainer') AND state = 'done'
             AND json_extract(outcome_json, '$.success') = 1",
            [batch_id],
            |r| r.get(0),
        )?;
        c.judge_cost_usd = Self::judge_spent(&self.conn, batch_id)?;
        Ok(c)
    }

    /// SHA-256 of a batch's settings as canonical JSON (see `Provenance::config_hash`).
    fn config_hash(&self, batch_id: &str) -> Result<String, CoordError> {
        let settings: serde_json::Value = self.conn.query_row(
            "SELECT json_object('policies', json(policies_json), 'seeds', json(seeds_json),
                    'max_attempts', max_attempts, 'judges', json(judges_json),
                    'judge_repeats', judge_repeats, 'judge_budget_usd', judge_budget_usd,
                    'text_models', json(text_models_json), 'dynamics', json(dynamics_json),
                    'ranking', json(ranking_json), 'generalization', json(generalization_json))
             FROM batches WHERE id = ?1",
            [batch_id],
            |r| {
                let text: String = r.get(0)?;
                Ok(serde_json::from_str(&text).unwrap_or(serde_json::Value::Null))
            },
        )?;
        // serde_json's maps are sorted by key: the same settings give the same text.
        Ok(assay_spec::hash::sha256_hex(
            settings.to_string().as_bytes(),
        ))
    }

    /// The task specs of a batch as it stored them (canonical JSON), by task id, in task order.
    pub fn task_specs(&self, batch_id: &str) -> Result<Vec<(String, String)>, CoordError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT task_id, spec_json FROM tasks WHERE batch_id = ?1 ORDER BY rowid",
        )?;
        let rows = stmt.query_map([batch_id], |r| Ok((r.get(0)?, r.get(1)?)))?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    pub fn batch_ids(&self) -> Result<Vec<String>, CoordError> {
        let mut stmt = self.conn.prepare("SELECT id FROM batches ORDER BY seq")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    /// Batches still running (after a restart, these carry on).
    pub fn running_batches(&self) -> Result<Vec<String>, CoordError> {
        let mut stmt = self
            .conn
            .prepare("SELECT id FROM batches WHERE state = 'running' ORDER BY seq")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    /// Builds the batch's report from the store (partial while the batch runs).
    pub fn report(&self, batch_id: &str) -> Result<Report, CoordError> {
        #[allow(clippy::type_complexity)]
        let (name, state, policies, seeds, invalid, submitted, finished, ranking_plan): (String, String, String, String, String, i64, Option<i64>, Option<String>) =
            self.conn
                .query_row(
                    "SELECT name, state, policies_json, seeds_json, invalid_json, submitted_ms, finished_ms, ranking_json FROM batches WHERE id = ?1",
                    [batch_id],
                    |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?, r.get(7)?)),
                )
                .optional()?
                .ok_or_else(|| CoordError::NotFound(format!("batch '{batch_id}'")))?;
        let policies: Vec<String> = serde_json::from_str(&policies)?;
        let seeds: Vec<u64> = serde_json::from_str(&seeds)?;
        let invalid: Vec<SpecError> = serde_json::from_str(&invalid)?;
        let tasks: Vec<TaskInfo> = {
            let mut stmt = self
                .conn
                .prepare("SELECT task_id, name, grp, pipeline, origin, spec_hash FROM tasks WHERE batch_id = ?1")?;
            let it = stmt.query_map([batch_id], |r| {
                Ok(TaskInfo {
                    id: r.get(0)?,
                    name: r.get(1)?,
                    group: r.get(2)?,
                    pipeline: r.get(3)?,
                    origin: r.get(4)?,
                    spec_hash: r.get(5)?,
                })
            })?;
            it.collect::<Result<_, _>>()?
        };
        let mut workers = std::collections::BTreeSet::new();
        let mut extra_attempts = 0u64;
        let mut shards = Vec::new();
        let mut judged = Vec::new();
        let mut diversity: Option<DiversityResults> = None;
        let mut error_groups: Vec<Option<String>> = Vec::new();
        let mut proxies = Vec::new();
        let mut proxy_errors = Vec::new();
        let mut imagined = Vec::new();
        let mut trained = Vec::new();
        // The ladder's kept policies: (group, episodes trained on, step, key).
        let mut ladder: Vec<(String, u32, u64, String)> = Vec::new();
        let mut general_errors = Vec::new();
        let mut evaluated = Vec::new();
        {
            let mut stmt = self.conn.prepare(
                "SELECT task_id, seed, policy, attempts, state, outcome_json, error, worker, role, judge, job, grp
                 FROM shards WHERE batch_id = ?1 ORDER BY id",
            )?;
            let mut rows = stmt.query([batch_id])?;
            while let Some(r) = rows.next()? {
                let attempts: u32 = r.get(3)?;
                let state: String = r.get(4)?;
                let outcome: Option<String> = r.get(5)?;
                if let Some(w) = r.get::<_, Option<String>>(7)? {
                    workers.insert(w);
                }
                extra_attempts += u64::from(attempts.saturating_sub(1));
                if r.get::<_, String>(8)? == role::TRAINER {
                    let job: String = r.get::<_, Option<String>>(10)?.unwrap_or_default();
                    if job.starts_with("diffusion") {
                        let group = r.get::<_, Option<String>>(11)?.unwrap_or_default();
                        match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                if let TrainerOutcome::Diffusion {
                                    group, model, fit, ..
                                } = serde_json::from_str::<TrainerOutcome>(&json)?
                                {
                                    trained.push((group, model, *fit));
                                }
                            }
                            (FAILED, _) => general_errors
                                .push((group, r.get::<_, Option<String>>(6)?.unwrap_or_default())),
                            _ => {}
                        }
                        continue;
                    }
                    // A ladder's policies are ranked by their episodes, and the proxy's world
                    // model fitted ahead of it reports through the proxy: a failure of either is
                    // a failure of the group's ranking (the proxy then ranks what exists, or
                    // fits its own). A finished ladder training says what each kept policy was
                    // trained on and for how long (the report's labels).
                    let ladder_job = job.starts_with("ladder");
                    if ladder_job || job.starts_with("world model") {
                        if ladder_job
                            && let (DONE, Some(json)) = (state.as_str(), &outcome)
                            && let TrainerOutcome::Diffusion {
                                group,
                                model,
                                fit,
                                checkpoints,
                            } = serde_json::from_str::<TrainerOutcome>(json)?
                        {
                            for (step, key) in checkpoints.into_iter().chain([(fit.steps, model)]) {
                                ladder.push((group.clone(), fit.clips, step, key));
                            }
                        }
                        if state == FAILED {
                            let error = r.get::<_, Option<String>>(6)?.unwrap_or_default();
                            proxy_errors.push((
                                r.get::<_, Option<String>>(11)?.unwrap_or_default(),
                                format!("{job}: {error}"),
                            ));
                        }
                        continue;
                    }
                    if job.starts_with("proxy") {
                        match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                if let TrainerOutcome::Proxy { result } =
                                    serde_json::from_str::<TrainerOutcome>(&json)?
                                {
                                    proxies.push(*result);
                                }
                            }
                            (FAILED, _) => proxy_errors.push((
                                r.get::<_, Option<String>>(11)?.unwrap_or_default(),
                                r.get::<_, Option<String>>(6)?.unwrap_or_default(),
                            )),
                            _ => {}
                        }
                        continue;
                    }
                    let div = diversity.get_or_insert_with(DiversityResults::default);
                    match (state.as_str(), outcome) {
                        (DONE, Some(json)) => {
                            match serde_json::from_str::<TrainerOutcome>(&json)? {
                                TrainerOutcome::Text { table } => div.text = Some(table),
                                TrainerOutcome::Dynamics { fit } => div.dynamics.push(*fit),
                                TrainerOutcome::Proxy { .. }
                                | TrainerOutcome::ProxyWorld { .. }
                                | TrainerOutcome::Diffusion { .. } => {}
                            }
                        }
                        (FAILED, _) => {
                            div.errors
                                .push((job, r.get::<_, Option<String>>(6)?.unwrap_or_default()));
                            error_groups.push(r.get::<_, Option<String>>(11)?);
                        }
                        _ => {}
                    }
                    continue;
                }
                if r.get::<_, String>(8)? == role::JUDGE
                    && r.get::<_, Option<String>>(10)?.as_deref() == Some(IMAGINED_JUDGING)
                {
                    // A judge's verdict on an imagined rollout: a proxy's, not quality.
                    // Every repeat's score is kept: their spread is the judge's consistency.
                    let (completion, scores, repeats) = match (state.as_str(), outcome) {
                        (DONE, Some(json)) => {
                            let o = serde_json::from_str::<JudgeOutcome>(&json)?;
                            let item = o.item(Item::Completion);
                            let scores = item.map(|i| i.scores.clone()).unwrap_or_default();
                            let completion = if scores.is_empty() {
                                Err(item
                                    .and_then(|i| i.errors.first())
                                    .map_or("no completion score".into(), |e| e.error.clone()))
                            } else {
                                Ok(scores.iter().sum::<f64>() / scores.len() as f64)
                            };
                            (completion, scores, o.repeats)
                        }
                        (FAILED, _) => (
                            Err(r.get::<_, Option<String>>(6)?.unwrap_or_default()),
                            Vec::new(),
                            0,
                        ),
                        (CANCELLED, _) => (Err("cancelled".into()), Vec::new(), 0),
                        _ => continue,
                    };
                    imagined.push(ImaginedJudgement {
                        task_id: r.get(0)?,
                        seed: r.get::<_, i64>(1)? as u64,
                        policy: r.get(2)?,
                        judge: r.get::<_, Option<String>>(9)?.unwrap_or_default(),
                        completion,
                        scores,
                        repeats,
                    });
                    continue;
                }
                if r.get::<_, String>(8)? == role::JUDGE {
                    judged.push(JudgeRecord {
                        task_id: r.get(0)?,
                        seed: r.get::<_, i64>(1)? as u64,
                        policy: r.get(2)?,
                        judge: r.get::<_, Option<String>>(9)?.unwrap_or_default(),
                        attempts,
                        outcome: match (state.as_str(), outcome) {
                            (DONE, Some(json)) => {
                                Some(serde_json::from_str::<JudgeOutcome>(&json)?)
                            }
                            _ => None,
                        },
                        error: if state == FAILED { r.get(6)? } else { None },
                        cancelled: state == CANCELLED,
                    });
                    continue;
                }
                let outcome = match (state.as_str(), outcome) {
                    (DONE, Some(json)) => Some(serde_json::from_str::<EpisodeOutcome>(&json)?),
                    _ => None,
                };
                let job: Option<String> = r.get(10)?;
                if let Some(job) = job.filter(|j| j.starts_with("generalization")) {
                    // A trained policy's evaluation episode: its own section, not the batch's
                    // success tables.
                    evaluated.push(EvalEpisode {
                        group: r.get::<_, Option<String>>(11)?.unwrap_or_default(),
                        task_id: r.get(0)?,
                        held_out: job == HELD_OUT_VARIATIONS,
                        success: match (state.as_str(), &outcome) {
                            (DONE, Some(o)) => Some(Ok(o.success)),
                            (FAILED, _) => {
                                Some(Err(r.get::<_, Option<String>>(6)?.unwrap_or_default()))
                            }
                            (CANCELLED, _) => Some(Err("cancelled".into())),
                            _ => None,
                        },
                    });
                    continue;
                }
                let open = state == QUEUED || state == LEASED;
                shards.push(ShardRecord {
                    task_id: r.get(0)?,
                    seed: r.get::<_, i64>(1)? as u64,
                    policy: r.get(2)?,
                    judge: String::new(),
                    attempts,
                    outcome,
                    error: if open {
                        Some(format!("still {state}"))
                    } else {
                        r.get(6)?
                    },
                    cancelled: state == CANCELLED,
                });
            }
        }
        if let Some(div) = diversity.as_mut() {
            // Groups finish (and queue their fits) in whatever order their episodes do, and fits
            // finish in any order: the report lists them by group (task order) and budget.
            let rank = |g: Option<&str>| g.map(|g| tasks.iter().position(|t| t.group == g));
            div.dynamics
                .sort_by_key(|f| (rank(Some(&f.group)), f.budget));
            let mut errors: Vec<_> = error_groups
                .iter()
                .map(|g| rank(g.as_deref()))
                .zip(std::mem::take(&mut div.errors))
                .collect();
            errors.sort_by_key(|(r, _)| *r);
            div.errors = errors.into_iter().map(|(_, e)| e).collect();
        }
        // A ranking ladder's learned policies are the batch's too: planned as its groups finish.
        let mut policies = policies;
        for s in &shards {
            if !policies.contains(&s.policy) {
                policies.push(s.policy.clone());
            }
        }
        let mut results =
            report::build_results(&name, &policies, &seeds, &tasks, &shards, &invalid);
        let episodes: Vec<EpisodeOutcome> =
            shards.iter().filter_map(|s| s.outcome.clone()).collect();
        // A trained policy's evaluation episodes (generalization) are judged too when the batch
        // has judges, but quality is about the batch's own policies' episodes.
        judged.retain(|j| policies.contains(&j.policy));
        results.quality = assay_report::quality::build_quality(&tasks, &episodes, &judged);
        results.diversity = diversity;
        if !trained.is_empty() || !general_errors.is_empty() {
            let rank = |g: &str| tasks.iter().position(|t| t.group == g);
            trained.sort_by_key(|(g, _, _)| rank(g));
            general_errors.sort_by_key(|(g, _)| rank(g));
            results.generalization = Some(GeneralizationResults {
                groups: trained
                    .into_iter()
                    .map(|(g, model, fit)| GroupGeneralization::build(&g, &model, fit, &evaluated))
                    .collect(),
                errors: general_errors,
            });
        }
        if let Some(plan) = ranking_plan {
            let plan: RankingPlan = serde_json::from_str(&plan)?;
            let ranked: Vec<String> = policies
                .iter()
                .filter(|p| !plan.train_policies.contains(p))
                .cloned()
                .collect();
            let real: Vec<RealEpisode> = episodes
                .iter()
                .filter(|e| ranked.contains(&e.policy))
                .map(|e| {
                    let scores: Vec<f64> = judged
                        .iter()
                        .filter(|j| {
                            j.task_id == e.task_id && j.seed == e.seed && j.policy == e.policy
                        })
                        .filter_map(|j| j.outcome.as_ref())
                        .filter_map(|o| o.item(Item::Completion))
                        .flat_map(|i| i.scores.iter().copied())
                        .collect();
                    RealEpisode {
                        task_id: e.task_id.clone(),
                        policy: e.policy.clone(),
                        seed: e.seed,
                        success: e.success,
                        judged_completion: (!scores.is_empty())
                            .then(|| scores.iter().sum::<f64>() / scores.len() as f64),
                    }
                })
                .collect();
            // Only the ranked groups: a served policy's episodes elsewhere have no proxy.
            let task_groups: Vec<(String, String)> = tasks
                .iter()
                .filter(|t| plan.covers(&t.group))
                .map(|t| (t.id.clone(), t.group.clone()))
                .collect();
            let mut ranking = ranking_results(
                &plan,
                &ranked,
                &task_groups,
                &real,
                proxies,
                &imagined,
                proxy_errors,
            );
            if let Some(plan) = &plan.ladder {
                // By group (task order), episodes and step; a key kept twice (the final model
                // at the last checkpoint) labelled once. With ladders in several groups, each
                // label names its group.
                let rank = |g: &str| tasks.iter().position(|t| t.group == g);
                ladder.sort_by(|a, b| {
                    (rank(&a.0), a.1, a.2, &a.3).cmp(&(rank(&b.0), b.1, b.2, &b.3))
                });
                let several = ladder.iter().any(|(g, ..)| *g != ladder[0].0);
                for (group, episodes, step, key) in &ladder {
                    let name = plan.policy_name(key);
                    if !ranking.labels.iter().any(|(p, _)| *p == name) {
                        let group = several.then_some(group.as_str());
                        ranking
                            .labels
                            .push((name, ladder_label(*episodes, *step, group)));
                    }
                }
            }
            results.ranking = Some(ranking);
        }
        let wall = finished.map(|f| (f - submitted) as f64 / 1000.0);
        let rate = |x: f64| wall.filter(|w| *w > 0.0).map(|w| x / w);
        let run = RunInfo {
            batch_id: batch_id.to_owned(),
            state,
            submitted_at_unix_ms: submitted,
            finished_at_unix_ms: finished,
            wall_time_s: wall,
            episodes_per_s: rate(results.totals.episodes_completed as f64),
            sim_steps_per_s: rate(results.totals.sim_steps as f64),
            extra_attempts,
            workers: workers.into_iter().collect(),
            events: Vec::new(),
        };
        let provenance = report::Provenance::of(
            &results,
            &episodes,
            concat!("assay-coordinator ", env!("CARGO_PKG_VERSION")),
            &self.config_hash(batch_id)?,
        );
        Ok(Report {
            report_version: report::REPORT_VERSION,
            results,
            run,
            provenance,
            imports: Vec::new(),
        })
    }
}
