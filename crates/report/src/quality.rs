//! Quality in reports: what the judges said about each task (scene alignment 1–5 from the 4 views
//! of the initial scene, task completion 0–10 from the 8 keyframes), aggregated per task, per
//! group and per judge, and set against the simulator's ground truth; the "## Quality" section of
//! report.md and the points of the paper's figure 4 (scene alignment against task completion,
//! marker size = variance), drawn by `crate::figures`.
//!
//! Owns: the aggregation and its presentation. Never does IO and never calls a judge: it reads
//! the judge shards as the job store has them and returns data and text. Deterministic: the same
//! shards in any order give the same results, Markdown and SVG, byte for byte.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use assay_model::episode::{EpisodeOutcome, JudgeRecord, TaskInfo};
use assay_model::quality::{Item, ItemOutcome, ScoreStats, Usage};
use assay_stats::agreement::{Agreement, BOOTSTRAP_RESAMPLES, agreement};

/// Seed of the bootstrap behind the judge-vs-simulator intervals (fixed, so reports repeat).
pub const VS_SIM_SEED: u64 = 0;

/// Item errors and shard failures listed in report.md; the rest are counted (all are in the JSON).
pub const ERRORS_SHOWN: usize = 50;

/// What the offline judge is, said after its name wherever its scores are shown.
pub const OFFLINE_JUDGE_NOTE: &str = "is Assay's built-in offline judge, not a vision-language \
model: it scores scene alignment by comparing a structured caption of the render (segmentation, \
measured colours, sizes, positions, relations) with the task description, and completion from \
the simulator's goal predicates at the 8 keyframes, so its completion agreement with the \
simulator is high by construction.";

/// Characters of a judge's raw answer kept in an error line.
const RAW_SHOWN: usize = 200;

/// The group of a judged task that the batch's task list does not know.
pub const NO_GROUP: &str = "(no group)";

/// Quality of every judged task, per judge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct QualityResults {
    /// Sorted by name.
    pub judges: Vec<JudgeSummary>,
    /// Sorted by (group, task id, judge).
    pub tasks: Vec<TaskQuality>,
}

/// One judge over the whole batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct JudgeSummary {
    pub judge: String,
    /// `offline`, `openai`, `caption+llm`; several joined by ", " if the shards disagree; empty
    /// when no shard of this judge finished.
    pub backend: String,
    pub model: String,
    /// Distinct prompt versions seen (`completion/v1`, ...), sorted.
    pub prompts: Vec<String>,
    /// `backend == "offline"`: the built-in judge, not a vision-language model.
    pub offline: bool,
    /// Repeats per item (the largest any shard reports).
    pub repeats: u32,
    /// Episodes this judge reported on.
    pub episodes_judged: u64,
    /// Shards that failed (not cancelled).
    pub episodes_failed: u64,
    /// Shards with no outcome, no error and not cancelled.
    pub episodes_pending: u64,
    /// Shards cancelled before an outcome.
    pub episodes_cancelled: u64,
    /// Item outcomes with repeats left unasked because the judge budget was spent.
    pub items_unjudged: u64,
    /// Repeats that gave no valid score.
    pub item_errors: u64,
    pub usage: Usage,
    /// Over the judge's task means: the mean of the task means and their sample variance.
    pub scene_alignment: ScoreStats,
    pub completion: ScoreStats,
    /// Sorted by name.
    pub groups: Vec<GroupQuality>,
    /// Completion (episode mean over repeats, 0–10) against simulator success × 10, over the
    /// judged episodes with a completion score and a simulator outcome; `None` when there are none.
    pub vs_sim: Option<Agreement>,
}

/// One judge over one group: statistics of the group's task means.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GroupQuality {
    pub group: String,
    /// Tasks of the group this judge has shards for.
    pub tasks: u64,
    pub scene_alignment: ScoreStats,
    pub completion: ScoreStats,
}

/// One judge over one task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TaskQuality {
    pub task_id: String,
    pub group: String,
    pub judge: String,
    /// Over all valid scores of all the task's episodes (every repeat).
    pub scene_alignment: ScoreStats,
    pub completion: ScoreStats,
    /// One line per item error (`seed 3 · oracle · completion · repeat 2: <error> — answer:
    /// <raw>`) and per failed shard, in (policy, seed) order.
    pub errors: Vec<String>,
    /// Item outcomes with repeats left unasked because the judge budget was spent.
    pub unjudged: u64,
    /// The pooled variance above split as the first paper reports it: over the k repeats of
    /// the same input (judge consistency, its Tables 4–5) and over the task's episodes.
    #[serde(default)]
    pub scene_alignment_split: VarianceSplit,
    #[serde(default)]
    pub completion_split: VarianceSplit,
    /// Each judged episode's scores: the mean over its repeats.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub episodes: Vec<EpisodeScores>,
}

/// Where a task's score variance comes from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VarianceSplit {
    /// The mean over the task's episodes of the variance of one episode's k repeats (the same
    /// pictures asked again): the judge's own inconsistency. None with fewer than 2 repeats.
    pub over_repeats: Option<f64>,
    /// The variance over the task's episodes of each episode's mean score: how much the
    /// episodes (seeds, policies) differ. None with fewer than 2 judged episodes.
    pub over_episodes: Option<f64>,
}

impl VarianceSplit {
    /// From each episode's valid repeat scores.
    fn of<'a>(per_episode: impl Iterator<Item = &'a [f64]>) -> Self {
        let (mut within, mut means) = (Vec::new(), Vec::new());
        for scores in per_episode {
            let s = ScoreStats::of(scores);
            within.extend(s.variance);
            means.extend(s.mean);
        }
        Self {
            over_repeats: ScoreStats::of(&within).mean,
            over_episodes: ScoreStats::of(&means).variance,
        }
    }
}

/// One judged episode's mean scores over its repeats (None: no valid score).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct EpisodeScores {
    pub seed: u64,
    pub policy: String,
    pub scene_alignment: Option<f64>,
    pub completion: Option<f64>,
}

#[derive(Default)]
struct TaskAcc {
    scene_alignment: Vec<f64>,
    completion: Vec<f64>,
    /// Per judged episode: (seed, policy, scene alignment repeats, completion repeats).
    episodes: Vec<(u64, String, Vec<f64>, Vec<f64>)>,
    errors: Vec<String>,
    unjudged: u64,
}

#[derive(Default)]
struct JudgeAcc<'a> {
    backends: BTreeSet<&'a str>,
    models: BTreeSet<&'a str>,
    prompts: BTreeSet<&'a str>,
    repeats: u32,
    judged: u64,
    failed: u64,
    pending: u64,
    cancelled: u64,
    items_unjudged: u64,
    item_errors: u64,
    usage: Usage,
    /// (simulator success × 10, completion episode mean).
    pairs: Vec<(f64, f64)>,
    tasks: BTreeMap<&'a str, TaskAcc>,
}

/// The valid scores of one item outcome (inside the item's range).
fn valid_scores(item: &ItemOutcome) -> impl Iterator<Item = f64> + '_ {
    let (lo, hi) = item.item.range();
    item.scores
        .iter()
        .copied()
        .filter(move |s| s.is_finite() && (lo..=hi).contains(s))
}

/// Collapses whitespace and keeps the first `RAW_SHOWN` characters.
fn short(raw: &str) -> String {
    let flat = raw.split_whitespace().collect::<Vec<_>>().join(" ");
    match flat.char_indices().nth(RAW_SHOWN) {
        Some((at, _)) => format!("{}…", &flat[..at]),
        None => flat,
    }
}

/// Quality of every judged task. `None` when there are no judge records. Tasks, episodes and
/// records may come in any order.
pub fn build_quality(
    tasks: &[TaskInfo],
    episodes: &[EpisodeOutcome],
    judged: &[JudgeRecord],
) -> Option<QualityResults> {
    if judged.is_empty() {
        return None;
    }
    // Duplicates resolved independently of order: the smallest group, success only if every
    // copy succeeded.
    let mut group_of: BTreeMap<&str, &str> = BTreeMap::new();
    for t in tasks {
        let g = group_of.entry(t.id.as_str()).or_insert(t.group.as_str());
        *g = (*g).min(t.group.as_str());
    }
    let mut truth: BTreeMap<(&str, &str, u64), bool> = BTreeMap::new();
    for e in episodes {
        let s = truth
            .entry((e.task_id.as_str(), e.policy.as_str(), e.seed))
            .or_insert(e.success);
        *s &= e.success;
    }
    let mut records: Vec<&JudgeRecord> = judged.iter().collect();
    records.sort_by_key(|r| {
        (
            r.judge.as_str(),
            r.task_id.as_str(),
            r.policy.as_str(),
            r.seed,
            r.outcome.is_some(),
            r.cancelled,
            r.attempts,
            r.error.as_deref(),
        )
    });

    let mut judges: BTreeMap<&str, JudgeAcc<'_>> = BTreeMap::new();
    for r in records {
        let j = judges.entry(r.judge.as_str()).or_default();
        let task = j.tasks.entry(r.task_id.as_str()).or_default();
        let Some(o) = &r.outcome else {
            match (&r.error, r.cancelled) {
                (_, true) => j.cancelled += 1,
                (Some(e), false) => {
                    j.failed += 1;
                    task.errors.push(format!(
                        "seed {} · {} · judge shard failed after {} attempt{}: {}",
                        r.seed,
                        r.policy,
                        r.attempts,
                        if r.attempts == 1 { "" } else { "s" },
                        short(e)
                    ));
                }
                (None, false) => j.pending += 1,
            }
            continue;
        };
        j.judged += 1;
        j.backends.insert(o.backend.as_str());
        j.models.insert(o.model.as_str());
        j.repeats = j.repeats.max(o.repeats);
        j.usage.add(&o.usage);
        let repeats = |which: Item| -> Vec<f64> {
            o.item(which)
                .map(|i| valid_scores(i).collect())
                .unwrap_or_default()
        };
        task.episodes.push((
            r.seed,
            r.policy.clone(),
            repeats(Item::SceneAlignment),
            repeats(Item::Completion),
        ));
        for item in &o.items {
            j.prompts.insert(item.prompt.as_str());
            match item.item {
                Item::SceneAlignment => task.scene_alignment.extend(valid_scores(item)),
                Item::Completion => task.completion.extend(valid_scores(item)),
            }
            if item.unjudged > 0 {
                j.items_unjudged += 1;
                task.unjudged += 1;
            }
            j.item_errors += item.errors.len() as u64;
            for e in &item.errors {
                let answer = e
                    .raw
                    .as_deref()
                    .map(|raw| format!(" — answer: {}", short(raw)))
                    .unwrap_or_default();
                task.errors.push(format!(
                    "seed {} · {} · {} · repeat {}: {}{answer}",
                    r.seed,
                    r.policy,
                    item.item.name(),
                    e.repeat,
                    short(&e.error)
                ));
            }
        }
        let completion = repeats(Item::Completion);
        let sim = truth.get(&(r.task_id.as_str(), r.policy.as_str(), r.seed));
        if let (Some(mean), Some(ok)) = (ScoreStats::of(&completion).mean, sim) {
            j.pairs.push((if *ok { 10.0 } else { 0.0 }, mean));
        }
    }

    let mut summaries = Vec::new();
    let mut task_rows = Vec::new();
    for (name, j) in judges {
        let mut by_group: BTreeMap<&str, (u64, Vec<f64>, Vec<f64>)> = BTreeMap::new();
        let (mut sa_means, mut c_means) = (Vec::new(), Vec::new());
        for (task_id, t) in j.tasks {
            let group = group_of.get(task_id).copied().unwrap_or(NO_GROUP);
            let row = TaskQuality {
                task_id: task_id.to_owned(),
                group: group.to_owned(),
                judge: name.to_owned(),
                scene_alignment: ScoreStats::of(&t.scene_alignment),
                completion: ScoreStats::of(&t.completion),
                errors: t.errors,
                unjudged: t.unjudged,
                scene_alignment_split: VarianceSplit::of(
                    t.episodes.iter().map(|(_, _, sa, _)| sa.as_slice()),
                ),
                completion_split: VarianceSplit::of(
                    t.episodes.iter().map(|(_, _, _, c)| c.as_slice()),
                ),
                episodes: t
                    .episodes
                    .into_iter()
                    .map(|(seed, policy, sa, c)| EpisodeScores {
                        seed,
                        policy,
                        scene_alignment: ScoreStats::of(&sa).mean,
                        completion: ScoreStats::of(&c).mean,
                    })
                    .collect(),
            };
            let g = by_group.entry(group).or_default();
            g.0 += 1;
            if let Some(m) = row.scene_alignment.mean {
                g.1.push(m);
                sa_means.push(m);
            }
            if let Some(m) = row.completion.mean {
                g.2.push(m);
                c_means.push(m);
            }
            task_rows.push(row);
        }
        let (reference, scores): (Vec<f64>, Vec<f64>) = j.pairs.into_iter().unzip();
        let join = |s: &BTreeSet<&str>| s.iter().copied().collect::<Vec<_>>().join(", ");
        let backend = join(&j.backends);
        summaries.push(JudgeSummary {
            judge: name.to_owned(),
            offline: backend == "offline",
            backend,
            model: join(&j.models),
            prompts: j.prompts.iter().map(|p| (*p).to_owned()).collect(),
            repeats: j.repeats,
            episodes_judged: j.judged,
            episodes_failed: j.failed,
            episodes_pending: j.pending,
            episodes_cancelled: j.cancelled,
            items_unjudged: j.items_unjudged,
            item_errors: j.item_errors,
            usage: j.usage,
            scene_alignment: ScoreStats::of(&sa_means),
            completion: ScoreStats::of(&c_means),
            groups: by_group
                .into_iter()
                .map(|(group, (tasks, sa, c))| GroupQuality {
                    group: group.to_owned(),
                    tasks,
                    scene_alignment: ScoreStats::of(&sa),
                    completion: ScoreStats::of(&c),
                })
                .collect(),
            vs_sim: (!reference.is_empty())
                .then(|| agreement(&reference, &scores, BOOTSTRAP_RESAMPLES, VS_SIM_SEED)),
        });
    }
    task_rows
        .sort_by(|a, b| (&a.group, &a.task_id, &a.judge).cmp(&(&b.group, &b.task_id, &b.judge)));
    Some(QualityResults {
        judges: summaries,
        tasks: task_rows,
    })
}

impl QualityResults {
    /// One marker per (task, judge) with both means: the points of the paper's figure 4,
    /// coloured by group, sized by the scores' spread ([`crate::figures::SPREAD_RULE`]).
    pub fn scene_points(&self) -> Vec<crate::figures::ScenePoint> {
        let judge_index = |j: &str| {
            self.judges
                .iter()
                .position(|s| s.judge == j)
                .unwrap_or(self.judges.len())
        };
        self.tasks
            .iter()
            .filter_map(|t| {
                Some(crate::figures::ScenePoint {
                    group: t.group.clone(),
                    judge: judge_index(&t.judge),
                    scene_alignment: t.scene_alignment.mean?,
                    completion: t.completion.mean?,
                    spread: crate::figures::spread(
                        t.scene_alignment.variance,
                        t.completion.variance,
                    ),
                })
            })
            .collect()
    }

    /// The paper's figure 4 as a standalone SVG drawn by plotters: scene alignment (1–5) against
    /// completion (0–10), one marker per (task, judge) (see [`Self::scene_points`]).
    pub fn figure_svg(&self) -> String {
        crate::figures::scene_vs_completion(&self.scene_points())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_model::episode::LabelSource;
    use assay_model::quality::ItemError;

    use crate::testing::{self, info};

    /// [`testing::judged`], by an `openai` backend unless the judge is `offline`, and having
    /// spent a little.
    fn judged(judge: &str, task: &str, seed: u64, sa: &[f64], c: &[f64]) -> JudgeRecord {
        let mut r = testing::judged(judge, task, seed, sa, c);
        let o = r.outcome.as_mut().expect("judged");
        if judge != "offline" {
            o.backend = "openai".into();
            o.model = judge.into();
        }
        o.usage = Usage {
            calls: 4,
            cached: 1,
            tokens_in: 100,
            tokens_out: 10,
            cost_usd: 0.25,
        };
        r
    }

    fn episode(task: &str, seed: u64, success: bool) -> EpisodeOutcome {
        EpisodeOutcome {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            success,
            label_source: LabelSource::Sim,
            predicates: Vec::new(),
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

    fn unfinished(task: &str, seed: u64, error: Option<&str>, cancelled: bool) -> JudgeRecord {
        JudgeRecord {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            judge: "offline".into(),
            attempts: 3,
            outcome: None,
            error: error.map(Into::into),
            cancelled,
        }
    }

    fn close(a: Option<f64>, b: f64) {
        let a = a.expect("a value");
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }

    /// Tasks a, b in g1 and c in g2, judged by `offline` and `gpt-4o` (the latter scoring
    /// higher completion in g2 than in g1).
    fn fixture() -> (Vec<TaskInfo>, Vec<EpisodeOutcome>, Vec<JudgeRecord>) {
        let tasks = vec![info("a", "g1"), info("b", "g1"), info("c", "g2")];
        let episodes = vec![
            episode("a", 0, true),
            episode("a", 1, false),
            episode("b", 0, true),
            episode("c", 0, false),
        ];
        let records = vec![
            judged("offline", "a", 0, &[4.0, 4.0], &[10.0, 10.0]),
            judged("offline", "a", 1, &[2.0, 2.0], &[0.0, 0.0]),
            judged("offline", "b", 0, &[5.0, 3.0], &[8.0, 6.0]),
            judged("offline", "c", 0, &[1.0, 1.0], &[2.0, 2.0]),
            judged("gpt-4o", "a", 0, &[3.0, 3.0], &[2.0, 3.0]),
            judged("gpt-4o", "c", 0, &[4.0, 5.0], &[9.0, 7.0]),
        ];
        (tasks, episodes, records)
    }

    #[test]
    fn no_records_no_quality() {
        assert_eq!(build_quality(&[info("a", "g")], &[], &[]), None);
    }

    #[test]
    fn aggregates_tasks_groups_and_judges() {
        let (tasks, episodes, records) = fixture();
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        let names: Vec<&str> = q.judges.iter().map(|j| j.judge.as_str()).collect();
        assert_eq!(names, ["gpt-4o", "offline"]);
        let order: Vec<(&str, &str)> = q
            .tasks
            .iter()
            .map(|t| (t.task_id.as_str(), t.judge.as_str()))
            .collect();
        assert_eq!(
            order,
            [
                ("a", "gpt-4o"),
                ("a", "offline"),
                ("b", "offline"),
                ("c", "gpt-4o"),
                ("c", "offline")
            ]
        );

        // Task a for offline pools every repeat of both episodes.
        let a = &q.tasks[1];
        assert_eq!(a.scene_alignment, ScoreStats::of(&[4.0, 4.0, 2.0, 2.0]));
        assert_eq!(a.scene_alignment.n, 4);
        close(a.scene_alignment.mean, 3.0);
        close(a.scene_alignment.variance, 4.0 / 3.0);
        close(a.completion.mean, 5.0);
        close(a.completion.variance, 100.0 / 3.0);

        let off = &q.judges[1];
        assert!(off.offline && !q.judges[0].offline);
        assert_eq!(off.backend, "offline");
        assert_eq!(off.model, "caption");
        assert_eq!(off.prompts, ["completion/v1", "scene_alignment/v1"]);
        assert_eq!(off.repeats, 2);
        assert_eq!(off.episodes_judged, 4);
        assert_eq!(
            off.usage,
            Usage {
                calls: 16,
                cached: 4,
                tokens_in: 400,
                tokens_out: 40,
                cost_usd: 1.0
            }
        );
        // Judge level: over the task means 3, 4, 1 and 5, 7, 2.
        assert_eq!(off.scene_alignment, ScoreStats::of(&[3.0, 4.0, 1.0]));
        assert_eq!(off.completion, ScoreStats::of(&[5.0, 7.0, 2.0]));
        // Group level: g1 over tasks a and b; g2 has one task and so no variance.
        let g1 = &off.groups[0];
        assert_eq!((g1.group.as_str(), g1.tasks), ("g1", 2));
        close(g1.scene_alignment.mean, 3.5);
        close(g1.scene_alignment.variance, 0.5);
        close(g1.completion.mean, 6.0);
        close(g1.completion.variance, 2.0);
        let g2 = &off.groups[1];
        assert_eq!((g2.group.as_str(), g2.tasks), ("g2", 1));
        close(g2.scene_alignment.mean, 1.0);
        assert_eq!(g2.scene_alignment.variance, None);

        let gpt = &q.judges[0];
        assert_eq!(gpt.groups.len(), 2);
        assert_eq!(gpt.groups[0].tasks, 1);
        close(gpt.groups[1].completion.mean, 8.0);
    }

    /// The paper's split: the variance over one episode's repeats (judge consistency) apart from
    /// the variance over episodes of their means; each episode's means kept for the table.
    #[test]
    fn variance_splits_into_repeats_and_episodes() {
        let tasks = vec![info("a", "g")];
        let records = vec![
            judged("offline", "a", 0, &[4.0, 4.0, 4.0], &[2.0, 4.0, 6.0]),
            judged("offline", "a", 1, &[2.0, 2.0, 2.0], &[8.0, 8.0, 8.0]),
            judged("offline", "a", 2, &[3.0], &[5.0]),
        ];
        let q = build_quality(&tasks, &[], &records).unwrap();
        let t = &q.tasks[0];
        // Completion: repeats' variances 4 and 0 (one repeat has none) -> 2; means 4, 8, 5 ->
        // variance 13/3. Scene alignment: no spread over repeats; means 4, 2, 3 -> 1.
        assert_eq!(t.completion_split.over_repeats, Some(2.0));
        assert!((t.completion_split.over_episodes.unwrap() - 13.0 / 3.0).abs() < 1e-12);
        assert_eq!(t.scene_alignment_split.over_repeats, Some(0.0));
        assert_eq!(t.scene_alignment_split.over_episodes, Some(1.0));
        let means: Vec<_> = t.episodes.iter().map(|e| (e.seed, e.completion)).collect();
        assert_eq!(means, [(0, Some(4.0)), (1, Some(8.0)), (2, Some(5.0))]);
        // One judged episode: no spread over episodes to speak of.
        let q = build_quality(&tasks, &[], &records[..1]).unwrap();
        assert_eq!(q.tasks[0].completion_split.over_episodes, None);
    }

    #[test]
    fn judge_against_simulator() {
        let tasks = vec![info("t", "g")];
        let mut episodes = Vec::new();
        let mut records = Vec::new();
        for seed in 0..20u64 {
            let ok = seed % 3 != 0;
            episodes.push(episode("t", seed, ok));
            let wobble = (seed % 4) as f64 * 0.5;
            let c = if ok {
                [10.0 - wobble, 9.0]
            } else {
                [wobble, 1.0]
            };
            records.push(judged("vlm", "t", seed, &[3.0, 3.0], &c));
        }
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        let a = q.judges[0].vs_sim.as_ref().unwrap();
        assert_eq!(a.n, 20);
        assert!(a.pearson.value.unwrap() > 0.9, "{a:?}");
        assert!(a.kendall.value.unwrap() > 0.5, "{a:?}");
        let [lo, hi] = a.pearson.ci95.unwrap();
        assert!(lo <= hi);

        // Every episode succeeded: the simulator side is constant, correlations are undefined.
        for e in &mut episodes {
            e.success = true;
        }
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        let a = q.judges[0].vs_sim.as_ref().unwrap();
        assert_eq!(a.pearson.value, None);
        let why = a.pearson.undefined.as_deref().unwrap();
        assert!(why.contains("constant"), "{why}");
        assert!(a.mae.value.is_some());
        let md = q.markdown(None);
        assert!(
            md.contains("undefined: the reference scores are constant"),
            "{md}"
        );

        // No completion scores at all: no agreement.
        for r in &mut records {
            let o = r.outcome.as_mut().unwrap();
            o.items.retain(|i| i.item == Item::SceneAlignment);
        }
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        assert_eq!(q.judges[0].vs_sim, None);
        assert!(
            q.markdown(None)
                .contains("no judged episode has a completion score")
        );
    }

    #[test]
    fn input_order_does_not_matter() {
        let (mut tasks, mut episodes, mut records) = fixture();
        records.push(unfinished("b", 7, Some("timeout"), false));
        let q1 = build_quality(&tasks, &episodes, &records).unwrap();
        tasks.reverse();
        episodes.reverse();
        records.reverse();
        records.rotate_left(3);
        let q2 = build_quality(&tasks, &episodes, &records).unwrap();
        assert_eq!(q1, q2);
        assert_eq!(
            q1.markdown(Some("quality.svg")),
            q2.markdown(Some("quality.svg"))
        );
        assert_eq!(q1.figure_svg(), q2.figure_svg());
        assert_eq!(
            serde_json::to_string(&q1).unwrap(),
            serde_json::to_string(&q2).unwrap()
        );
        // The JSON reads back (serde_json without `float_roundtrip` may move a float by an ulp, so
        // the floats are not compared here).
        let back: QualityResults =
            serde_json::from_str(&serde_json::to_string(&q1).unwrap()).unwrap();
        assert_eq!(back.tasks.len(), q1.tasks.len());
        assert_eq!(back.judges[1].groups, q1.judges[1].groups);
    }

    #[test]
    fn counts_pending_failed_cancelled_errors_and_unjudged() {
        let tasks = vec![info("a", "g")];
        let mut one = judged("offline", "a", 0, &[4.0], &[10.0]);
        {
            let o = one.outcome.as_mut().unwrap();
            o.items[0].errors.push(ItemError {
                repeat: 2,
                error: "no line of the form 'Score: X'".into(),
                raw: Some(format!("I think\n{}", "x".repeat(500))),
            });
            o.items[1].errors.push(ItemError {
                repeat: 1,
                error: "timeout".into(),
                raw: None,
            });
            o.items[1].unjudged = 1;
        }
        let records = vec![
            one,
            unfinished("a", 1, Some("model | unreachable"), false),
            unfinished("a", 2, None, false),
            unfinished("a", 3, None, true),
            unfinished("a", 4, Some("cancelled by user"), true),
            unfinished("x", 0, None, false),
        ];
        let q = build_quality(&tasks, &[episode("a", 0, true)], &records).unwrap();
        let j = &q.judges[0];
        assert_eq!(j.episodes_judged, 1);
        assert_eq!(j.episodes_failed, 1);
        assert_eq!(j.episodes_pending, 2);
        assert_eq!(j.episodes_cancelled, 2);
        assert_eq!(j.item_errors, 2);
        assert_eq!(j.items_unjudged, 1);
        // The unknown task is kept, under no group.
        assert_eq!(q.tasks.len(), 2);
        assert_eq!(
            (q.tasks[0].task_id.as_str(), q.tasks[0].group.as_str()),
            ("x", NO_GROUP)
        );

        let a = &q.tasks[1];
        assert_eq!(a.unjudged, 1);
        assert_eq!(a.errors.len(), 3, "{:?}", a.errors);
        let sa = &a.errors[0];
        assert!(
            sa.starts_with(
                "seed 0 · oracle · scene_alignment · repeat 2: no line of the form 'Score: X' — answer: I think xxx"
            ),
            "{sa}"
        );
        assert!(sa.ends_with('…') && sa.chars().count() < 300, "{sa}");
        assert_eq!(
            a.errors[1],
            "seed 0 · oracle · completion · repeat 1: timeout"
        );
        assert_eq!(
            a.errors[2],
            "seed 1 · oracle · judge shard failed after 3 attempts: model | unreachable"
        );

        let md = q.markdown(None);
        assert!(md.contains("### Item errors"), "{md}");
        assert!(md.contains("model \\| unreachable"), "{md}");
        assert!(md.contains("### Unjudged items"), "{md}");
        assert!(md.contains("- `a` · `offline`: 1 item\n"), "{md}");
        assert!(
            md.contains("| `offline` | offline | caption | completion/v1, scene_alignment/v1 | 2 | 1 | 1 | 2 | 2 | 2 | 1 | 4 | 1 | 100 | 10 | 0.25 |"),
            "{md}"
        );
    }

    #[test]
    fn item_errors_are_capped_in_markdown() {
        let mut r = judged("offline", "a", 0, &[4.0], &[10.0]);
        r.outcome.as_mut().unwrap().items[1].errors = (0..60)
            .map(|k| ItemError {
                repeat: k,
                error: "bad".into(),
                raw: None,
            })
            .collect();
        let q = build_quality(&[info("a", "g")], &[], &[r]).unwrap();
        let md = q.markdown(None);
        assert!(md.contains("(60 in all)"), "{md}");
        assert!(md.contains("- … and 10 more (all in report.json)"), "{md}");
        assert_eq!(md.matches("· bad").count(), 0);
        assert_eq!(md.matches(": bad").count(), ERRORS_SHOWN);
    }

    #[test]
    fn markdown_has_the_key_lines() {
        let (tasks, episodes, records) = fixture();
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        let md = q.markdown(Some("quality.svg"));
        for line in [
            "## Quality\n",
            "### Judges\n",
            "| judge | backend | model | prompt versions | repeats | episodes judged |",
            "`offline` is Assay's built-in offline judge, not a vision-language model",
            "high by construction",
            "#### `offline`\n",
            "| g1 | 2 | 3.50 (var 0.50, n 2) | 6.00 (var 2.00, n 2) |",
            "| g2 | 1 | 1.00 (var –, n 1) | 2.00 (var –, n 1) |",
            "| **all** | **3** | **2.67 (var 2.33, n 3)** | **4.67 (var 6.33, n 3)** |",
            "### Judge against simulator\n",
            "| judge | against | group | n | Pearson r | MAE | Spearman ρ | Kendall τ |",
            "![Scene alignment against task completion per group](quality.svg)",
            "### Quality per task\n",
            // The pooled completion variance 33.33 splits into 0 over repeats (the offline judge
            // repeats itself) and 50 over the two episodes' means (10 and 0).
            "| `a` | g1 | `offline` | 3.00 (var 1.33, n 4) | 5.00 (var 33.33, n 4) | 0.000 | 50.000 | 0 |",
            "| `a` | g1 | `gpt-4o` | 3.00 (var 0.00, n 2) | 2.50 (var 0.50, n 2) | 0.500 | – | 0 |",
        ] {
            assert!(md.contains(line), "missing {line:?} in\n{md}");
        }
        // Offline judge: 4 episodes, completion 10, 0, 7, 2 against 10, 0, 10, 0.
        let off = q.judges[1].vs_sim.as_ref().unwrap();
        assert_eq!(off.n, 4);
        assert!(md.contains(&format!(
            "| `offline` | simulator | all | 4 | {:.3}",
            off.pearson.value.unwrap()
        )));
        assert!(!md.contains("-0.00"));
        assert!(!q.markdown(None).contains("quality.svg"));
        // Only the offline judge gets the offline sentence.
        assert!(!md.contains("`gpt-4o` is Assay's"));
    }

    #[test]
    fn figure_has_a_marker_per_task_and_judge_at_its_means() {
        let (tasks, episodes, records) = fixture();
        let q = build_quality(&tasks, &episodes, &records).unwrap();
        let points = q.scene_points();
        // Every (task, judge) with both scores, judges numbered in name order.
        assert_eq!(points.len(), q.tasks.len());
        for (p, t) in points.iter().zip(&q.tasks) {
            assert_eq!(p.scene_alignment, t.scene_alignment.mean.unwrap());
            assert_eq!(p.completion, t.completion.mean.unwrap());
            assert_eq!(
                p.judge,
                q.judges.iter().position(|j| j.judge == t.judge).unwrap()
            );
            assert!((0.0..=1.0).contains(&p.spread));
        }
        let svg = q.figure_svg();
        assert!(
            svg.contains("<svg") && svg.trim_end().ends_with("</svg>"),
            "{svg}"
        );
        assert!(svg.matches("<circle").count() >= points.len());
        assert_eq!(svg, q.figure_svg(), "deterministic");
    }
}
