//! A batch's report assembled from the rows its job store holds (partial while the batch runs).
//!
//! Owns: which shard feeds which section, told by its [`JobKind`], and in which order each
//! section lists what it gathers: the success tables and quality (the batch's episodes and their
//! judging), diversity, generalization, ranking with its ladder labels, run info and provenance.
//! Never reads a store (the coordinator selects [`BatchRows`]), never encodes or formats the
//! report (`markdown`, `html`), never aggregates within a section (each section's module does).

use std::collections::BTreeSet;

use assay_model::diffusion::Backbone;
use assay_model::episode::{EpisodeOutcome, JudgeRecord, ShardRecord, TaskInfo};
use assay_model::job::{JobKind, ShardState};
use assay_model::proxy::{ImaginedJudgement, LadderPlan, ProxyResult, RankingPlan};
use assay_model::quality::Item;
use assay_model::trainer::{KeptPolicy, TrainerOutcome};

use crate::diversity::DiversityResults;
use crate::generalization::{EvalEpisode, GeneralizationResults, GroupGeneralization};
use crate::quality::build_quality;
use crate::ranking::{RankingResults, RealEpisode, ladder_label, ranking_results};
use crate::report::{self, Provenance, Report, Results, RunInfo};
use crate::rows::{BatchRows, ShardRow};

/// The batch's report. `generator` names what assembled it (provenance's `assay_version`:
/// `assay-coordinator 0.1.0`).
pub fn report(rows: &BatchRows, generator: &str) -> Report {
    let batch = &rows.batch;
    let shards = episode_records(rows);
    // A ranking ladder's learned policies are the batch's too: planned as its groups finish.
    let mut policies = batch.policies.clone();
    for s in &shards {
        if !policies.contains(&s.policy) {
            policies.push(s.policy.clone());
        }
    }
    let mut results = report::build_results(
        &batch.name,
        &policies,
        &batch.seeds,
        &rows.tasks,
        &shards,
        &batch.invalid,
    );
    let episodes: Vec<EpisodeOutcome> = shards.iter().filter_map(|s| s.outcome.clone()).collect();
    // A trained policy's evaluation episodes (generalization) are judged too when the batch
    // has judges, but quality is about the batch's own policies' episodes.
    let mut judged = judge_records(rows);
    judged.retain(|j| policies.contains(&j.policy));
    results.quality = build_quality(&rows.tasks, &episodes, &judged);
    results.diversity = diversity(rows);
    results.generalization = generalization(rows);
    results.ranking = batch
        .ranking
        .as_ref()
        .map(|plan| ranking(rows, plan, &policies, &episodes, &judged));
    let run = run_info(rows, &results);
    let provenance = Provenance::of(&results, &episodes, generator, &rows.config_hash);
    Report {
        report_version: report::REPORT_VERSION,
        results,
        run,
        provenance,
        imports: Vec::new(),
    }
}

/// The shards of `kind`, in queue order.
fn of_kind(rows: &BatchRows, kind: JobKind) -> impl Iterator<Item = &ShardRow> {
    rows.shards.iter().filter(move |s| s.kind == kind)
}

/// Where `group` first appears in the batch's tasks (the order sections list groups in).
fn group_rank(tasks: &[TaskInfo], group: &str) -> Option<usize> {
    tasks.iter().position(|t| t.group == group)
}

/// The batch's episodes (its own policies' and a ladder's) as the success tables read them: an
/// open one says so as its error.
fn episode_records(rows: &BatchRows) -> Vec<ShardRecord> {
    of_kind(rows, JobKind::Episode)
        .map(|s| ShardRecord {
            task_id: s.task_id.clone(),
            seed: s.seed,
            policy: s.policy.clone(),
            judge: String::new(),
            attempts: s.attempts,
            outcome: s.episode().cloned(),
            error: if s.state.is_open() {
                Some(format!("still {}", s.state))
            } else {
                s.error.clone()
            },
            cancelled: s.state == ShardState::Cancelled,
        })
        .collect()
}

/// The judges' verdicts on the batch's episodes, whatever their state.
fn judge_records(rows: &BatchRows) -> Vec<JudgeRecord> {
    of_kind(rows, JobKind::EpisodeJudging)
        .map(|s| JudgeRecord {
            task_id: s.task_id.clone(),
            seed: s.seed,
            policy: s.policy.clone(),
            judge: s.judge.clone().unwrap_or_default(),
            attempts: s.attempts,
            outcome: s.judgement().cloned(),
            error: if s.state == ShardState::Failed {
                s.error.clone()
            } else {
                None
            },
            cancelled: s.state == ShardState::Cancelled,
        })
        .collect()
}

/// The diversity section: the text table and the dynamics fits, and the fits that failed, each
/// list by group (task order) — groups finish, and their fits, in whatever order their episodes
/// do — and the fits by budget within a group. `None` when the batch measures no diversity.
fn diversity(rows: &BatchRows) -> Option<DiversityResults> {
    let mut div: Option<DiversityResults> = None;
    let mut error_groups: Vec<Option<&str>> = Vec::new();
    for s in rows
        .shards
        .iter()
        .filter(|s| matches!(s.kind, JobKind::TextDiversity | JobKind::DynamicsFit))
    {
        let div = div.get_or_insert_with(DiversityResults::default);
        match (s.state, s.trained()) {
            (ShardState::Done, Some(TrainerOutcome::Text { table })) => {
                div.text = Some(table.clone());
            }
            (ShardState::Done, Some(TrainerOutcome::Dynamics { fit })) => {
                div.dynamics.push((**fit).clone());
            }
            (ShardState::Failed, _) => {
                div.errors
                    .push((s.job.clone().unwrap_or_default(), s.error_text()));
                error_groups.push(s.group.as_deref());
            }
            _ => {}
        }
    }
    let mut div = div?;
    let rank = |g: Option<&str>| g.map(|g| group_rank(&rows.tasks, g));
    div.dynamics
        .sort_by_key(|f| (rank(Some(&f.group)), f.budget));
    let mut errors: Vec<_> = error_groups
        .iter()
        .map(|g| rank(*g))
        .zip(std::mem::take(&mut div.errors))
        .collect();
    errors.sort_by_key(|(r, _)| *r);
    div.errors = errors.into_iter().map(|(_, e)| e).collect();
    Some(div)
}

/// The generalization section: each group's trained policy with its evaluation episodes, and the
/// trainings that failed, by group (task order). `None` when no training finished or failed.
fn generalization(rows: &BatchRows) -> Option<GeneralizationResults> {
    let mut trained = Vec::new();
    let mut errors = Vec::new();
    for s in of_kind(rows, JobKind::GeneralizationTraining) {
        match (s.state, s.trained()) {
            (
                ShardState::Done,
                Some(TrainerOutcome::Diffusion {
                    group, model, fit, ..
                }),
            ) => trained.push((group.clone(), model.clone(), (**fit).clone())),
            (ShardState::Failed, _) => {
                errors.push((s.group.clone().unwrap_or_default(), s.error_text()));
            }
            _ => {}
        }
    }
    if trained.is_empty() && errors.is_empty() {
        return None;
    }
    let evaluated = evaluation_episodes(rows);
    trained.sort_by_key(|(g, _, _)| group_rank(&rows.tasks, g));
    errors.sort_by_key(|(g, _)| group_rank(&rows.tasks, g));
    Some(GeneralizationResults {
        groups: trained
            .into_iter()
            .map(|(g, model, fit)| GroupGeneralization::build(&g, &model, fit, &evaluated))
            .collect(),
        errors,
    })
}

/// A trained policy's evaluation episodes: their own section, not the batch's success tables.
fn evaluation_episodes(rows: &BatchRows) -> Vec<EvalEpisode> {
    rows.shards
        .iter()
        .filter(|s| {
            matches!(
                s.kind,
                JobKind::GeneralizationTrainEpisode | JobKind::GeneralizationHeldOutEpisode
            )
        })
        .map(|s| EvalEpisode {
            group: s.group.clone().unwrap_or_default(),
            task_id: s.task_id.clone(),
            held_out: s.kind == JobKind::GeneralizationHeldOutEpisode,
            success: match (s.state, s.episode()) {
                (ShardState::Done, Some(o)) => Some(Ok(o.success)),
                (ShardState::Failed, _) => Some(Err(s.error_text())),
                (ShardState::Cancelled, _) => Some(Err("cancelled".into())),
                _ => None,
            },
        })
        .collect()
}

/// The ranking section: the ranked policies (every policy of the batch but the training ones
/// and the ladder's training-only ones) of the ranked groups, their real and judged success
/// against the proxies' predictions, and the ladder's labels.
fn ranking(
    rows: &BatchRows,
    plan: &RankingPlan,
    policies: &[String],
    episodes: &[EpisodeOutcome],
    judged: &[JudgeRecord],
) -> RankingResults {
    let ladder_training = plan
        .ladder
        .as_ref()
        .map(|l| ladder_training_policies(rows, l))
        .unwrap_or_default();
    let ranked: Vec<String> = policies
        .iter()
        .filter(|p| !plan.train_policies.contains(p) && !ladder_training.contains(p))
        .cloned()
        .collect();
    let real = real_episodes(&ranked, episodes, judged);
    // Only the ranked groups: a served policy's episodes elsewhere have no proxy.
    let task_groups: Vec<(String, String)> = rows
        .tasks
        .iter()
        .filter(|t| plan.covers(&t.group))
        .map(|t| (t.id.clone(), t.group.clone()))
        .collect();
    let (proxies, errors) = proxy_jobs(rows);
    let imagined = imagined_judgements(rows);
    let mut ranking = ranking_results(
        plan,
        &ranked,
        &task_groups,
        &real,
        proxies,
        &imagined,
        errors,
    );
    if let Some(ladder) = &plan.ladder {
        ladder_labels(rows, ladder, &mut ranking.labels);
        ranking.ladder_seeds = Some(crate::ladder_seeds::LadderSeeds::of(ladder));
    }
    for p in ladder_training {
        if !ranking.train_policies.contains(&p) {
            ranking.train_policies.push(p);
        }
    }
    ranking
}

/// The ladder's policies kept at a `train_checkpoints` step or by a `train_episodes` run (they
/// train the proxy and are never ranked), in their trainings' queue order.
fn ladder_training_policies(rows: &BatchRows, plan: &LadderPlan) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for p in ladder_kept(rows, plan) {
        if p.trains_only && !out.contains(&p.name) {
            out.push(p.name);
        }
    }
    out
}

/// Every policy the batch's finished ladder trainings kept, in their trainings' queue order.
fn ladder_kept(rows: &BatchRows, plan: &LadderPlan) -> Vec<KeptPolicy> {
    of_kind(rows, JobKind::LadderTraining)
        .filter_map(|s| s.trained())
        .flat_map(|outcome| outcome.ladder_policies(plan))
        .collect()
}

/// The ranked policies' finished episodes, each with its judges' mean completion score.
fn real_episodes(
    ranked: &[String],
    episodes: &[EpisodeOutcome],
    judged: &[JudgeRecord],
) -> Vec<RealEpisode> {
    episodes
        .iter()
        .filter(|e| ranked.contains(&e.policy))
        .map(|e| {
            // Every judge's completion scores (the mean over them all), and per judge that looks
            // at images its own.
            let mut scores: Vec<f64> = Vec::new();
            let mut by_judge: Vec<(String, Vec<f64>)> = Vec::new();
            for o in judged
                .iter()
                .filter(|j| j.task_id == e.task_id && j.seed == e.seed && j.policy == e.policy)
                .filter_map(|j| j.outcome.as_ref())
            {
                let Some(item) = o.item(Item::Completion) else {
                    continue;
                };
                scores.extend(&item.scores);
                if o.backend == "offline" {
                    continue;
                }
                match by_judge.iter_mut().find(|(j, _)| *j == o.judge) {
                    Some((_, s)) => s.extend(&item.scores),
                    None => by_judge.push((o.judge.clone(), item.scores.clone())),
                }
            }
            RealEpisode {
                task_id: e.task_id.clone(),
                policy: e.policy.clone(),
                seed: e.seed,
                success: e.success,
                judged_completion: (!scores.is_empty())
                    .then(|| scores.iter().sum::<f64>() / scores.len() as f64),
                completion_by_judge: by_judge
                    .into_iter()
                    .filter(|(_, s)| !s.is_empty())
                    .map(|(j, s)| (j, s.iter().sum::<f64>() / s.len() as f64))
                    .collect(),
            }
        })
        .collect()
}

/// The finished proxies, and the failures of the groups' rankings as (group, error), in queue
/// order. A ladder's policies are ranked by their episodes, and the proxy's world model fitted
/// ahead of it reports through the proxy: a failure of either, named by its job, is a failure of
/// the group's ranking (the proxy then ranks what exists, or fits its own).
fn proxy_jobs(rows: &BatchRows) -> (Vec<ProxyResult>, Vec<(String, String)>) {
    let mut proxies = Vec::new();
    let mut errors = Vec::new();
    for s in &rows.shards {
        let group = || s.group.clone().unwrap_or_default();
        match (s.kind, s.state, s.trained()) {
            (JobKind::Proxy, ShardState::Done, Some(TrainerOutcome::Proxy { result })) => {
                proxies.push((**result).clone());
            }
            (JobKind::Proxy, ShardState::Failed, _) => errors.push((group(), s.error_text())),
            (JobKind::LadderTraining | JobKind::ProxyWorldModel, ShardState::Failed, _) => {
                let job = s.job.as_deref().unwrap_or_default();
                errors.push((group(), format!("{job}: {}", s.error_text())));
            }
            _ => {}
        }
    }
    (proxies, errors)
}

/// The judges' verdicts on imagined rollouts: a proxy's, not quality. Every repeat's score is
/// kept (their spread is the judge's consistency); an open shard is left out.
fn imagined_judgements(rows: &BatchRows) -> Vec<ImaginedJudgement> {
    of_kind(rows, JobKind::ImaginedJudging)
        .filter_map(|s| {
            let (completion, scores, repeats) = match (s.state, s.judgement()) {
                (ShardState::Done, Some(o)) => {
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
                (ShardState::Failed, _) => (Err(s.error_text()), Vec::new(), 0),
                (ShardState::Cancelled, _) => (Err("cancelled".into()), Vec::new(), 0),
                _ => return None,
            };
            Some(ImaginedJudgement {
                task_id: s.task_id.clone(),
                seed: s.seed,
                policy: s.policy.clone(),
                judge: s.judge.clone().unwrap_or_default(),
                completion,
                scores,
                repeats,
            })
        })
        .collect()
}

/// Adds to `labels` what each policy a finished ladder training kept was trained on and for how
/// long, by group (task order), episodes and step; a key kept twice (the final model at the last
/// checkpoint) is labelled once. With ladders in several groups, each label names its group.
fn ladder_labels(rows: &BatchRows, plan: &LadderPlan, labels: &mut Vec<(String, String)>) {
    let mut kept = ladder_kept(rows, plan);
    let rank = |g: &str| group_rank(&rows.tasks, g);
    let order = |b: Backbone| plan.families().iter().position(|f| *f == b);
    kept.sort_by(|a, b| {
        (rank(&a.group), order(a.family), a.clips, a.step, &a.name).cmp(&(
            rank(&b.group),
            order(b.family),
            b.clips,
            b.step,
            &b.name,
        ))
    });
    let several = kept.iter().any(|p| p.group != kept[0].group);
    for p in kept {
        if !labels.iter().any(|(name, _)| *name == p.name) {
            let group = several.then_some(p.group.as_str());
            labels.push((p.name, ladder_label(p.family, p.clips, p.step, group)));
        }
    }
}

/// What depends on the run, not on the batch: timings, throughput, retries and workers (of every
/// shard, whatever it does).
fn run_info(rows: &BatchRows, results: &Results) -> RunInfo {
    let batch = &rows.batch;
    let workers: BTreeSet<&str> = rows
        .shards
        .iter()
        .filter_map(|s| s.worker.as_deref())
        .collect();
    let extra_attempts = rows
        .shards
        .iter()
        .map(|s| u64::from(s.attempts.saturating_sub(1)))
        .sum();
    let wall = batch
        .finished_ms
        .map(|f| (f - batch.submitted_ms) as f64 / 1000.0);
    let rate = |x: f64| wall.filter(|w| *w > 0.0).map(|w| x / w);
    RunInfo {
        batch_id: batch.id.clone(),
        state: batch.state.clone(),
        submitted_at_unix_ms: batch.submitted_ms,
        finished_at_unix_ms: batch.finished_ms,
        wall_time_s: wall,
        episodes_per_s: rate(results.totals.episodes_completed as f64),
        sim_steps_per_s: rate(results.totals.sim_steps as f64),
        extra_attempts,
        workers: workers.into_iter().map(str::to_owned).collect(),
        events: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use assay_model::diffusion::{DiffusionConfig, DiffusionFit};
    use assay_model::proxy::ProxyConfig;

    use super::*;
    use crate::rows::{BatchRow, Outcome};
    use crate::testing::info;

    fn shard(kind: JobKind, state: ShardState, group: &str, job: &str, error: &str) -> ShardRow {
        ShardRow {
            kind,
            state,
            task_id: String::new(),
            seed: 0,
            policy: String::new(),
            attempts: 1,
            outcome: None,
            error: (!error.is_empty()).then(|| error.into()),
            worker: None,
            judge: None,
            job: (!job.is_empty()).then(|| job.into()),
            group: (!group.is_empty()).then(|| group.into()),
        }
    }

    fn ladder_training(
        group: &str,
        clips: u32,
        checkpoints: &[(u64, &str)],
        model: &str,
    ) -> ShardRow {
        let fit = DiffusionFit {
            steps: 1000,
            final_loss: 0.1,
            mean_last_100_loss: 0.1,
            train_seconds: 0.0,
            parameters: 1,
            clips,
            samples: 1,
            device: "cpu".into(),
            libtorch: String::new(),
            config: DiffusionConfig::default(),
        };
        let mut s = shard(
            JobKind::LadderTraining,
            ShardState::Done,
            group,
            "ladder",
            "",
        );
        s.outcome = Some(Outcome::Trainer(Box::new(TrainerOutcome::Diffusion {
            group: group.into(),
            model: model.into(),
            fit: Box::new(fit),
            checkpoints: checkpoints
                .iter()
                .map(|(s, k)| (*s, k.to_string()))
                .collect(),
        })));
        s
    }

    /// Tasks in the store's order: g2's first, so g2 is the first group.
    fn batch_rows(shards: Vec<ShardRow>) -> BatchRows {
        BatchRows {
            batch: BatchRow {
                id: "b1".into(),
                name: "t".into(),
                state: "running".into(),
                policies: vec!["oracle".into()],
                seeds: vec![0],
                invalid: Vec::new(),
                submitted_ms: 1_000,
                finished_ms: None,
                ranking: Some(RankingPlan {
                    train_policies: vec!["oracle".into()],
                    config: ProxyConfig::default(),
                    ladder: Some(LadderPlan::default()),
                    groups: Vec::new(),
                }),
            },
            tasks: vec![info("b", "g2"), info("a", "g1")],
            shards,
            config_hash: "c".into(),
        }
    }

    /// Failures land in their kind's section, by group (task order), then in queue order; a
    /// ladder's and a fitted-ahead world model's are named by their job.
    #[test]
    fn failed_shards_land_in_their_kinds_section_by_group() {
        use assay_model::job::{JobKind as K, ShardState as S};
        let rows = batch_rows(vec![
            shard(K::DynamicsFit, S::Failed, "g1", "dynamics g1", "e1"),
            shard(K::TextDiversity, S::Failed, "", "text", "e0"),
            shard(K::DynamicsFit, S::Failed, "g2", "dynamics g2 @ 4", "e2"),
            shard(K::LadderTraining, S::Failed, "g1", "ladder g1", "too few"),
            shard(K::ProxyWorldModel, S::Failed, "g2", "world model g2", "oom"),
            shard(K::Proxy, S::Failed, "g1", "proxy g1", "no clips"),
            shard(
                K::GeneralizationTraining,
                S::Failed,
                "g1",
                "diffusion g1",
                "x1",
            ),
            shard(
                K::GeneralizationTraining,
                S::Failed,
                "g2",
                "diffusion g2",
                "x2",
            ),
            shard(K::DynamicsFit, S::Queued, "g2", "dynamics g2 @ 8", ""),
        ]);
        let div = diversity(&rows).unwrap();
        let pair = |a: &str, b: &str| (a.to_owned(), b.to_owned());
        assert_eq!(
            div.errors,
            [
                pair("text", "e0"),
                pair("dynamics g2 @ 4", "e2"),
                pair("dynamics g1", "e1")
            ]
        );
        let general = generalization(&rows).unwrap();
        assert_eq!(general.errors, [pair("g2", "x2"), pair("g1", "x1")]);
        let (proxies, errors) = proxy_jobs(&rows);
        assert!(proxies.is_empty());
        assert_eq!(
            errors,
            [
                pair("g1", "ladder g1: too few"),
                pair("g2", "world model g2: oom"),
                pair("g1", "no clips"),
            ]
        );
        // Nothing of diversity or generalization without their shards.
        let none = batch_rows(Vec::new());
        assert_eq!((diversity(&none), generalization(&none)), (None, None));
    }

    /// An open episode says so; its judging, a trained policy's episodes and a trainer's shards
    /// are not episodes of the batch, but every shard's attempts and worker count in the run.
    #[test]
    fn only_the_batchs_episodes_fill_its_tables_and_every_shard_its_run() {
        use assay_model::job::{JobKind as K, ShardState as S};
        let mut episode = shard(K::Episode, S::Leased, "", "", "");
        episode.task_id = "a".into();
        episode.attempts = 3;
        episode.worker = Some("w2".into());
        let mut judging = shard(K::EpisodeJudging, S::Failed, "", "", "timeout");
        judging.worker = Some("w1".into());
        judging.attempts = 2;
        let mut held_out = shard(K::GeneralizationHeldOutEpisode, S::Failed, "g1", "", "fell");
        held_out.worker = Some("w2".into());
        let rows = batch_rows(vec![episode, judging, held_out]);
        let records = episode_records(&rows);
        assert_eq!(records.len(), 1);
        assert_eq!(records[0].error.as_deref(), Some("still leased"));
        let judged = judge_records(&rows);
        assert_eq!(judged[0].error.as_deref(), Some("timeout"));
        let evaluated = evaluation_episodes(&rows);
        assert!(evaluated[0].held_out);
        assert_eq!(evaluated[0].success, Some(Err("fell".to_owned())));
        let report = report(&rows, "assay-test 0");
        assert_eq!(report.run.workers, ["w1", "w2"]);
        assert_eq!(report.run.extra_attempts, 3);
        assert_eq!(report.provenance.assay_version, "assay-test 0");
    }

    /// A ladder's kept policies are labelled by group (task order), episodes and step, each key
    /// once, with their group when ladders ran in several.
    #[test]
    fn ladder_labels_follow_group_episodes_and_step() {
        let rows = batch_rows(vec![
            ladder_training("g1", 10, &[(300, "k1")], "k2"),
            ladder_training("g2", 40, &[(300, "k3"), (1000, "k4")], "k4"),
        ]);
        let plan = LadderPlan::default();
        let mut labels = Vec::new();
        ladder_labels(&rows, &plan, &mut labels);
        let label = |key: &str, l: &str| (plan.policy_name(key), l.to_owned());
        assert_eq!(
            labels,
            [
                label("k3", "diffusion 40 ep @ 300, g2"),
                label("k4", "diffusion 40 ep @ 1000, g2"),
                label("k1", "diffusion 10 ep @ 300, g1"),
                label("k2", "diffusion 10 ep @ 1000, g1"),
            ]
        );
    }

    /// With two families, each policy's label names its family, the families in the plan's
    /// order within a group.
    #[test]
    fn ladder_labels_name_the_family() {
        let mut transformer = ladder_training("g1", 10, &[(300, "t1")], "t2");
        if let Some(Outcome::Trainer(t)) = &mut transformer.outcome
            && let TrainerOutcome::Diffusion { fit, .. } = t.as_mut()
        {
            fit.config.backbone = Backbone::Transformer;
        }
        let rows = batch_rows(vec![transformer, ladder_training("g1", 10, &[], "u1")]);
        let plan = LadderPlan {
            backbones: vec![Backbone::Unet, Backbone::Transformer],
            ..LadderPlan::default()
        };
        let mut labels = Vec::new();
        ladder_labels(&rows, &plan, &mut labels);
        let label = |key: &str, l: &str| (plan.policy_name(key), l.to_owned());
        assert_eq!(
            labels,
            [
                label("u1", "diffusion 10 ep @ 1000"),
                label("t1", "transformer diffusion 10 ep @ 300"),
                label("t2", "transformer diffusion 10 ep @ 1000"),
            ]
        );
    }
}
