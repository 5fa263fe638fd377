//! Episode outcomes and batch reports.
//!
//! A report has two parts: `results`, which depends only on the batch, its seeds and the versions
//! of the code (the determinism contract: the same batch gives byte-identical `results`), and `run`,
//! which holds what depends on the machine and the moment (ids, timings, throughput, workers).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use assay_model::episode::{
    EpisodeImagery, EpisodeOutcome, LabelSource, PredicateValue, ShardRecord, TaskInfo,
};
use assay_spec::error::SpecError;
use assay_stats::stats::Proportion;

use crate::quality::QualityResults;

/// The report's schema version. 2 added `provenance`; a version-1 report reads as one with
/// empty provenance. Field names are stable within a version: a rename or removal bumps it.
pub const REPORT_VERSION: u32 = 2;

/// Where report.md expects the artifact store, relative to itself (`assay eval` puts it there).
pub const ARTIFACTS_LINK: &str = "artifacts";

/// The quality figure (scene alignment against completion), written next to report.md.
pub const QUALITY_FIGURE: &str = "quality.svg";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Report {
    pub report_version: u32,
    pub results: Results,
    pub run: RunInfo,
    /// What produced the figures: code and model versions, settings, inputs, devices.
    #[serde(default)]
    pub provenance: Provenance,
    /// What `assay eval --import` read: each generator tree and what became of its tasks.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub imports: Vec<ImportSummary>,
}

/// A generator's tree as `assay eval --import` read it (`import-report.json`, beside the report,
/// has every mapping line).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ImportSummary {
    /// `gensim`, `robogen` or `bbsea`.
    pub pipeline: String,
    /// The tree that was read.
    pub root: String,
    /// Its mapping file, relative to the report.
    pub mapping_file: String,
    pub tasks: Vec<ImportedTaskSummary>,
}

/// One task of an imported tree.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ImportedTaskSummary {
    pub id: String,
    pub name: String,
    /// The file it was read from.
    pub source: String,
    pub imported: bool,
    /// Why it was not imported: `field: reason` per error.
    pub errors: Vec<String>,
    /// What was inferred (a guess), `field: note` per line.
    pub inferred: Vec<String>,
    /// What was left out, with the reason, `field: note` per line.
    pub not_mapped: Vec<String>,
}

/// What produced a report's figures, so two reports can be told apart or trusted to compare.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Provenance {
    /// The coordinator that built the report (`assay-coordinator 0.1.0`).
    pub assay_version: String,
    /// SHA-256 of the batch's settings (policies, seeds, attempts, judges and their repeats and
    /// budget, embedding models, dynamics budgets and world-model settings, ranking and
    /// generalization plans) as canonical JSON: equal hashes, equal settings.
    pub config_hash: String,
    /// SHA-256 of the batch's tasks: their spec hashes, sorted, one per line. A batch with the
    /// same tasks has the same hash wherever its files came from (`assay watch` skips it).
    pub batch_hash: String,
    pub seeds: Vec<u64>,
    /// Task id → SHA-256 of its canonical spec.
    pub spec_hashes: BTreeMap<String, String>,
    /// Versions of the code that ran the episodes (`assay-sim`, `rapier3d`, ...), over all.
    pub code_versions: BTreeMap<String, String>,
    /// Judges: backend, model and prompt versions.
    pub judges: Vec<JudgeProvenance>,
    /// Sentence-embedding models of text diversity (name, model, dimensions).
    pub embedding_models: Vec<assay_stats::diversity::EmbeddingModel>,
    /// Graphics adapters that rendered the episodes.
    pub render_adapters: Vec<String>,
    /// Devices and libtorch versions of the trainer's fits (`cpu · libtorch 2.13.0`).
    pub trainer_devices: Vec<String>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct JudgeProvenance {
    pub judge: String,
    pub backend: String,
    pub model: String,
    pub prompts: Vec<String>,
}

/// Where the committed JSON Schema of report.json lives, relative to the repository.
pub const SCHEMA_FILE: &str = "schema/report-v2.schema.json";

/// The JSON Schema of report.json at [`REPORT_VERSION`] (committed as [`SCHEMA_FILE`]).
pub fn json_schema() -> serde_json::Value {
    let mut schema =
        serde_json::to_value(schemars::schema_for!(Report)).expect("schema serialises");
    schema["$id"] = format!("https://assay.dev/{SCHEMA_FILE}").into();
    schema["description"] = format!(
        "Assay report.json, report_version {REPORT_VERSION}. `results` depends only on the batch, \
         its seeds and the code's versions; `run` on the machine and the moment; `provenance` \
         says what produced the figures."
    )
    .into();
    schema
}

/// [`Provenance::batch_hash`] of tasks with these spec hashes.
pub use assay_spec::hash::batch_hash;

impl Provenance {
    /// (what, values) in the order people read them: report.md and report.html show these.
    pub fn rows(&self) -> Vec<(&'static str, Vec<String>)> {
        let one = |s: &str| match s {
            "" => Vec::new(),
            s => vec![s.to_owned()],
        };
        vec![
            ("built by", one(&self.assay_version)),
            ("settings (SHA-256)", one(&self.config_hash)),
            ("tasks (SHA-256 of spec hashes)", one(&self.batch_hash)),
            (
                "code",
                self.code_versions
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect(),
            ),
            (
                "judges",
                self.judges
                    .iter()
                    .map(|j| {
                        format!(
                            "{}: {} {} ({})",
                            j.judge,
                            j.backend,
                            j.model,
                            j.prompts.join(", ")
                        )
                    })
                    .collect(),
            ),
            (
                "embedding models",
                self.embedding_models
                    .iter()
                    .map(|m| format!("{}: {} ({} dimensions)", m.name, m.model, m.dimensions))
                    .collect(),
            ),
            ("rendered on", self.render_adapters.clone()),
            ("trained on", self.trainer_devices.clone()),
        ]
    }

    /// Provenance of `results`, built by `assay_version` with settings hashed to `config_hash`.
    /// `episodes` are the batch's episode outcomes (their code versions are kept).
    pub fn of(
        results: &Results,
        episodes: &[EpisodeOutcome],
        assay_version: &str,
        config_hash: &str,
    ) -> Self {
        let mut code_versions = BTreeMap::new();
        let mut adapters = std::collections::BTreeSet::new();
        for e in results.tasks.iter().flat_map(|t| &t.episodes) {
            if let Some(i) = &e.imagery {
                adapters.insert(i.adapter.clone());
            }
        }
        for (k, v) in episodes.iter().flat_map(|e| &e.versions) {
            code_versions.insert(k.clone(), v.clone());
        }
        let judges = results
            .quality
            .iter()
            .flat_map(|q| &q.judges)
            .map(|j| JudgeProvenance {
                judge: j.judge.clone(),
                backend: j.backend.clone(),
                model: j.model.clone(),
                prompts: j.prompts.clone(),
            })
            .collect();
        let div = results.diversity.as_ref();
        let mut devices = std::collections::BTreeSet::new();
        let device = |d: &str, lib: &str| match lib {
            "" => d.to_owned(),
            lib => format!("{d} · libtorch {lib}"),
        };
        for f in div.iter().flat_map(|d| &d.dynamics) {
            devices.insert(device(&f.device, &f.libtorch));
        }
        for g in results.generalization.iter().flat_map(|g| &g.groups) {
            devices.insert(device(&g.fit.device, &g.fit.libtorch));
        }
        Provenance {
            assay_version: assay_version.to_owned(),
            config_hash: config_hash.to_owned(),
            batch_hash: batch_hash(results.tasks.iter().map(|t| t.spec_hash.as_str())),
            seeds: results.seeds.clone(),
            spec_hashes: results
                .tasks
                .iter()
                .map(|t| (t.id.clone(), t.spec_hash.clone()))
                .collect(),
            code_versions,
            judges,
            embedding_models: div
                .and_then(|d| d.text.as_ref())
                .map(|t| t.models.clone())
                .unwrap_or_default(),
            render_adapters: adapters.into_iter().collect(),
            trainer_devices: devices.into_iter().collect(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Results {
    pub batch_name: String,
    pub policies: Vec<String>,
    pub seeds: Vec<u64>,
    pub totals: Totals,
    /// Ground-truth success of each policy over every task.
    pub by_policy: Vec<PolicySuccess>,
    pub groups: Vec<GroupResult>,
    pub tasks: Vec<TaskResult>,
    /// Tasks that never ran because their spec is invalid, with every problem found.
    pub invalid_tasks: Vec<SpecError>,
    /// What the batch's judges said of its tasks (absent when no judge ran).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<QualityResults>,
    /// Text and dynamics diversity (absent when the batch asked for neither).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diversity: Option<crate::diversity::DiversityResults>,
    /// Policy ranking by the world-model proxy (absent when the batch did not ask for it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking: Option<crate::ranking::RankingResults>,
    /// Diffusion policies trained per group and their success on training and held-out
    /// variations (absent when the batch did not ask for it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generalization: Option<crate::generalization::GeneralizationResults>,
}

impl Results {
    /// Readable names of the ranking ladder's policies (policy name, label): how every table
    /// and plot shows them (`diffusion 10 ep @ 300`), the full name as its title.
    pub fn policy_labels(&self) -> &[(String, String)] {
        self.ranking.as_ref().map_or(&[], |k| k.labels.as_slice())
    }

    /// The policies in the order the report shows them: by name, except that the ladder's
    /// policies (those with a label) take their places in the order of their labels — by group,
    /// episodes and training step, not by the hash in their names. `policies` stays in name order
    /// (report.json's order).
    pub fn policies_shown(&self) -> Vec<&String> {
        in_shown_order(
            self.policies.iter().collect(),
            |p| p.as_str(),
            self.policy_labels(),
        )
    }

    /// `items` (one per policy, in name order, as `by_policy` lists them) in the order of
    /// [`Results::policies_shown`].
    pub fn shown<'a, T>(&self, items: &'a [T], policy: impl Fn(&T) -> &str) -> Vec<&'a T> {
        in_shown_order(items.iter().collect(), policy, self.policy_labels())
    }
}

/// `items` with those whose policy has a label moved, among their own places, into the order of
/// `labels`.
fn in_shown_order<'a, T: ?Sized>(
    mut items: Vec<&'a T>,
    policy: impl Fn(&T) -> &str,
    labels: &[(String, String)],
) -> Vec<&'a T> {
    let rank = |item: &T| labels.iter().position(|(p, _)| p == policy(item));
    let places: Vec<usize> = (0..items.len())
        .filter(|&i| rank(items[i]).is_some())
        .collect();
    let mut labelled: Vec<&'a T> = places.iter().map(|&i| items[i]).collect();
    labelled.sort_by_key(|item| rank(item));
    for (place, item) in places.into_iter().zip(labelled) {
        items[place] = item;
    }
    items
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Totals {
    pub tasks: u64,
    pub invalid_tasks: u64,
    pub episodes_planned: u64,
    pub episodes_completed: u64,
    pub episodes_failed: u64,
    pub episodes_cancelled: u64,
    pub success: Proportion,
    pub sim_steps: u64,
    pub sim_time_s: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GroupResult {
    pub group: String,
    pub tasks: u64,
    /// All policies together.
    pub success: Proportion,
    pub by_policy: Vec<PolicySuccess>,
}

/// One policy's ground-truth success.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PolicySuccess {
    pub policy: String,
    pub success: Proportion,
}

/// Success of each of `policies` over `(policy, success)` rows (policies without rows get none).
fn per_policy<'a>(
    policies: &[String],
    rows: impl Iterator<Item = (&'a str, bool)>,
) -> Vec<PolicySuccess> {
    let mut counts: BTreeMap<&str, (u64, u64)> =
        policies.iter().map(|p| (p.as_str(), (0, 0))).collect();
    for (p, ok) in rows {
        let c = counts.entry(p).or_default();
        c.0 += u64::from(ok);
        c.1 += 1;
    }
    counts
        .into_iter()
        .map(|(p, (k, n))| PolicySuccess {
            policy: p.to_owned(),
            success: Proportion::new(k, n),
        })
        .collect()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TaskResult {
    pub id: String,
    pub name: String,
    pub group: String,
    pub pipeline: String,
    pub origin: String,
    pub spec_hash: String,
    /// Ground-truth success (goal predicates in the simulator) over completed episodes, all
    /// policies together; `by_policy` splits it.
    pub success: Proportion,
    pub by_policy: Vec<PolicySuccess>,
    /// Per predicate: how often it held.
    pub predicates: Vec<PredicateRate>,
    pub episodes: Vec<EpisodeRow>,
    pub failures: Vec<FailureRow>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PredicateRate {
    pub label: String,
    pub holds: u64,
    pub of: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct EpisodeRow {
    pub seed: u64,
    pub policy: String,
    pub success: bool,
    pub label_source: LabelSource,
    pub steps: u64,
    pub artifact: String,
    /// Predicates that did not hold, with what was measured.
    pub unmet: Vec<PredicateValue>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imagery: Option<EpisodeImagery>,
    /// Why it stopped early (the step limit), when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutoff: Option<String>,
    /// The generator's own staged reward (GenSim's), beside success, where the task has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator_reward: Option<assay_model::episode::GeneratorReward>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FailureRow {
    pub seed: u64,
    pub policy: String,
    pub attempts: u32,
    pub error: String,
    pub cancelled: bool,
}

/// What depends on the run, not on the batch.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RunInfo {
    pub batch_id: String,
    pub state: String,
    pub submitted_at_unix_ms: i64,
    pub finished_at_unix_ms: Option<i64>,
    pub wall_time_s: Option<f64>,
    pub episodes_per_s: Option<f64>,
    pub sim_steps_per_s: Option<f64>,
    /// Attempts beyond the first, summed over shards (lease expiries, retries, hand-backs).
    pub extra_attempts: u64,
    pub workers: Vec<String>,
    /// What happened to the run beyond its shards, in order: local processes that exited and
    /// were started again, a run that went on from its job store.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<String>,
}

/// `(policy, success)` of every completed episode, of one group or of all.
fn episode_rows<'a>(
    tasks: &'a [TaskResult],
    group: Option<&'a str>,
) -> impl Iterator<Item = (&'a str, bool)> + 'a {
    tasks
        .iter()
        .filter(move |t| group.is_none_or(|g| t.group == g))
        .flat_map(|t| t.episodes.iter().map(|e| (e.policy.as_str(), e.success)))
}

/// Builds the deterministic part of a report. Tasks, shards and errors may come in any order.
pub fn build_results(
    batch_name: &str,
    policies: &[String],
    seeds: &[u64],
    tasks: &[TaskInfo],
    shards: &[ShardRecord],
    invalid: &[SpecError],
) -> Results {
    let mut policies = policies.to_vec();
    policies.sort();
    let mut by_task: BTreeMap<&str, Vec<&ShardRecord>> = BTreeMap::new();
    for s in shards {
        by_task.entry(s.task_id.as_str()).or_default().push(s);
    }
    let mut task_results = Vec::new();
    let (mut completed, mut failed, mut cancelled, mut ok, mut steps, mut sim_time) =
        (0, 0, 0, 0, 0, 0.0);
    let mut sorted_tasks: Vec<&TaskInfo> = tasks.iter().collect();
    sorted_tasks.sort_by(|a, b| (&a.group, &a.id).cmp(&(&b.group, &b.id)));
    for t in sorted_tasks {
        let mut rows = by_task.remove(t.id.as_str()).unwrap_or_default();
        rows.sort_by(|a, b| (&a.policy, a.seed).cmp(&(&b.policy, b.seed)));
        let mut episodes = Vec::new();
        let mut failures = Vec::new();
        let mut preds: Vec<PredicateRate> = Vec::new();
        for r in rows {
            match &r.outcome {
                Some(o) => {
                    for p in &o.predicates {
                        match preds.iter_mut().find(|q| q.label == p.label) {
                            Some(q) => {
                                q.of += 1;
                                q.holds += u64::from(p.holds);
                            }
                            None => preds.push(PredicateRate {
                                label: p.label.clone(),
                                holds: u64::from(p.holds),
                                of: 1,
                            }),
                        }
                    }
                    steps += o.steps;
                    sim_time += o.sim_time_s;
                    episodes.push(EpisodeRow {
                        seed: o.seed,
                        policy: o.policy.clone(),
                        success: o.success,
                        label_source: o.label_source,
                        steps: o.steps,
                        artifact: o.artifact.clone(),
                        unmet: o.predicates.iter().filter(|p| !p.holds).cloned().collect(),
                        imagery: o.imagery.clone(),
                        cutoff: o.cutoff.clone(),
                        generator_reward: o.generator_reward.clone(),
                    });
                }
                None => failures.push(FailureRow {
                    seed: r.seed,
                    policy: r.policy.clone(),
                    attempts: r.attempts,
                    error: r.error.clone().unwrap_or_else(|| "not finished".into()),
                    cancelled: r.cancelled,
                }),
            }
        }
        let k = episodes.iter().filter(|e| e.success).count() as u64;
        completed += episodes.len() as u64;
        ok += k;
        failed += failures.iter().filter(|f| !f.cancelled).count() as u64;
        cancelled += failures.iter().filter(|f| f.cancelled).count() as u64;
        let by_policy = per_policy(
            &policies,
            episodes.iter().map(|e| (e.policy.as_str(), e.success)),
        );
        task_results.push(TaskResult {
            id: t.id.clone(),
            name: t.name.clone(),
            group: t.group.clone(),
            pipeline: t.pipeline.clone(),
            origin: t.origin.clone(),
            spec_hash: t.spec_hash.clone(),
            success: Proportion::new(k, episodes.len() as u64),
            by_policy,
            predicates: preds,
            episodes,
            failures,
        });
    }
    let mut groups: BTreeMap<&str, (u64, u64, u64)> = BTreeMap::new();
    for t in &task_results {
        let g = groups.entry(t.group.as_str()).or_default();
        g.0 += 1;
        g.1 += t.success.successes;
        g.2 += t.success.trials;
    }
    let overall_by_policy = per_policy(&policies, episode_rows(&task_results, None));
    let groups: Vec<GroupResult> = groups
        .into_iter()
        .map(|(g, (n, k, t))| GroupResult {
            group: g.to_owned(),
            tasks: n,
            success: Proportion::new(k, t),
            by_policy: per_policy(&policies, episode_rows(&task_results, Some(g))),
        })
        .collect();
    let mut invalid_tasks = invalid.to_vec();
    invalid_tasks.sort_by(|a, b| (&a.origin, &a.task, &a.path).cmp(&(&b.origin, &b.task, &b.path)));
    let invalid_count = invalid_tasks
        .iter()
        .map(|e| (e.origin.as_str(), e.task.as_deref()))
        .collect::<std::collections::BTreeSet<_>>()
        .len() as u64;
    Results {
        batch_name: batch_name.to_owned(),
        policies,
        seeds: seeds.to_vec(),
        totals: Totals {
            tasks: task_results.len() as u64,
            invalid_tasks: invalid_count,
            episodes_planned: shards.len() as u64,
            episodes_completed: completed,
            episodes_failed: failed,
            episodes_cancelled: cancelled,
            success: Proportion::new(ok, completed),
            sim_steps: steps,
            sim_time_s: sim_time,
        },
        by_policy: overall_by_policy,
        groups,
        tasks: task_results,
        invalid_tasks,
        quality: None,
        diversity: None,
        ranking: None,
        generalization: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::info;

    #[test]
    fn the_committed_report_schema_is_current() {
        let committed = include_str!("../../../schema/report-v2.schema.json");
        let committed: serde_json::Value = serde_json::from_str(committed).unwrap();
        assert_eq!(
            committed,
            json_schema(),
            "the report's fields changed: if a field was renamed or removed, bump REPORT_VERSION; \
             then regenerate with: assay schema report > {SCHEMA_FILE}"
        );
    }

    fn outcome(task: &str, seed: u64, success: bool) -> EpisodeOutcome {
        EpisodeOutcome {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            success,
            label_source: LabelSource::Sim,
            predicates: vec![PredicateValue {
                label: "p".into(),
                holds: success,
                detail: String::new(),
            }],
            steps: 10,
            sim_time_s: 0.1,
            artifact: format!("a{seed}"),
            spec_hash: "h".into(),
            versions: BTreeMap::new(),
            imagery: None,
            cutoff: None,
            generator_reward: None,
            scenes: None,
        }
    }

    #[test]
    fn results_aggregate_per_task_and_group_independent_of_order() {
        let tasks = vec![info("b", "g1"), info("a", "g1"), info("c", "g2")];
        let mut shards = vec![
            ShardRecord {
                task_id: "a".into(),
                seed: 1,
                policy: "oracle".into(),
                judge: String::new(),
                attempts: 1,
                outcome: Some(outcome("a", 1, true)),
                error: None,
                cancelled: false,
            },
            ShardRecord {
                task_id: "a".into(),
                seed: 0,
                policy: "oracle".into(),
                judge: String::new(),
                attempts: 1,
                outcome: Some(outcome("a", 0, false)),
                error: None,
                cancelled: false,
            },
            ShardRecord {
                task_id: "b".into(),
                seed: 0,
                policy: "oracle".into(),
                judge: String::new(),
                attempts: 3,
                outcome: None,
                error: Some("boom".into()),
                cancelled: false,
            },
            ShardRecord {
                task_id: "c".into(),
                seed: 0,
                policy: "oracle".into(),
                judge: String::new(),
                attempts: 1,
                outcome: Some(outcome("c", 0, true)),
                error: None,
                cancelled: false,
            },
        ];
        let r1 = build_results("x", &["oracle".into()], &[0, 1], &tasks, &shards, &[]);
        shards.reverse();
        let r2 = build_results("x", &["oracle".into()], &[0, 1], &tasks, &shards, &[]);
        assert_eq!(r1, r2);
        assert_eq!(r1.totals.episodes_planned, 4);
        assert_eq!(r1.totals.episodes_completed, 3);
        assert_eq!(r1.totals.episodes_failed, 1);
        assert_eq!(r1.totals.success.successes, 2);
        assert_eq!(r1.groups[0].group, "g1");
        assert_eq!(r1.groups[0].success.trials, 2);
        assert_eq!(r1.groups[0].success.successes, 1);
        let a = &r1.tasks[0];
        assert_eq!(a.id, "a");
        assert_eq!(a.episodes[0].seed, 0);
        assert_eq!(a.predicates[0].holds, 1);
        assert_eq!(r1.tasks[1].failures[0].error, "boom");
    }

    #[test]
    fn several_policies_are_reported_apart() {
        let tasks = vec![info("a", "g")];
        let shard = |seed: u64, policy: &str, success: bool| {
            let mut o = outcome("a", seed, success);
            o.policy = policy.into();
            ShardRecord {
                task_id: "a".into(),
                seed,
                policy: policy.into(),
                judge: String::new(),
                attempts: 1,
                outcome: Some(o),
                error: None,
                cancelled: false,
            }
        };
        let shards = vec![
            shard(0, "good", true),
            shard(1, "good", true),
            shard(0, "bad", false),
            shard(1, "bad", true),
        ];
        let policies = ["good".to_owned(), "bad".to_owned()];
        let r = build_results("x", &policies, &[0, 1], &tasks, &shards, &[]);
        let rate =
            |by: &[PolicySuccess], p: &str| by.iter().find(|x| x.policy == p).unwrap().success.rate;
        assert_eq!(rate(&r.by_policy, "good"), Some(1.0));
        assert_eq!(rate(&r.by_policy, "bad"), Some(0.5));
        assert_eq!(rate(&r.groups[0].by_policy, "bad"), Some(0.5));
        assert_eq!(rate(&r.tasks[0].by_policy, "good"), Some(1.0));
        let report = Report {
            report_version: REPORT_VERSION,
            results: r,
            run: RunInfo::default(),
            provenance: Provenance::default(),
            imports: Vec::new(),
        };
        let md = report.to_markdown();
        assert!(md.contains("## Success per policy"), "{md}");
        assert!(
            md.contains("| episodes | bad | good | most often unmet |"),
            "{md}"
        );
        assert!(
            md.contains("| g | 1 | 4 | 50 % (1/2) [9, 91] | 100 % (2/2) [34, 100] |"),
            "{md}"
        );
    }
}
