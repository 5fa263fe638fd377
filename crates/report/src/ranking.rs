//! The policy-ranking section of a report (the video-world-model paper, §III): per (task,
//! ranked policy) the real success from the simulator, the world-model proxy's and the judges'
//! verdicts on imagined rollouts, and the ranking statistics of the proxies against the real rates
//! ([`assay_stats::ranking`]); per policy the same pooled over tasks; the leak ablation as a
//! comparison of its own; and how consistently each judge scored an imagined rollout over its
//! repeats. The proxy's plans and the trainer's results are [`assay_model::proxy`]'s.
//!
//! Owns: the aggregation. Never trains, imagines or judges anything.

use serde::{Deserialize, Serialize};

use assay_model::diffusion::Backbone;
use assay_model::proxy::{
    CALIBRATED_SOURCE, CROSS_FAMILY_SOURCE, CROSS_FIT_SOURCE, ImaginedJudgement, JudgedProxy,
    LEAK_SOURCE, OBJECTS_SOURCE, PROXY_SOURCE, ProxyConfig, ProxyPrediction, ProxyResult,
    REAL_SOURCE, RELIABILITY_BINS, RankingPlan, judged_source,
};
use assay_model::quality::ScoreStats;
use assay_stats::calibration::{Reliability, reliability};
use assay_stats::ranking::{Cell, Ranking, RankingConfig, rank};
use assay_stats::stats::Proportion;

/// One ranked episode as the report builder reads it from the store.
#[derive(Debug, Clone, PartialEq)]
pub struct RealEpisode {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    pub success: bool,
    /// Mean completion score (0–10) of the batch's judges on this episode, when judged.
    pub judged_completion: Option<f64>,
    /// Per judge that looks at images (not the built-in `offline`, whose completion is the
    /// simulator's), its mean completion score on this episode.
    pub completion_by_judge: Vec<(String, f64)>,
}

/// How often one judge's verdicts agree with the simulator and with the frame judge (issue 45;
/// the paper's VLM annotation accuracy, 65–80 %). A verdict is a success when the mean
/// completion is at least `completion_threshold` (the frame judge: a probability at least
/// `threshold`). Over the ranked policies' episodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct JudgeAgreement {
    /// The judge's name, or [`FRAME_JUDGE`].
    pub judge: String,
    /// On the real rollouts: its verdict against the simulator's outcome.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub real_vs_sim: Option<Proportion>,
    /// On the imagined rollouts: its verdict against the simulator's outcome of the real episode.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imagined_vs_sim: Option<Proportion>,
    /// On the imagined rollouts: its verdict against the frame judge's on the same rollout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imagined_vs_frame_judge: Option<Proportion>,
}

/// [`JudgeAgreement::judge`] of the proxy's frame judge.
pub const FRAME_JUDGE: &str = "frame judge";

/// Real, proxy and judged success of one (task, ranked policy).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingRow {
    pub task_id: String,
    pub group: String,
    pub policy: String,
    /// Ground truth: the simulator's predicates.
    pub real: Proportion,
    /// The world-model proxy's verdicts (absent until the group's proxy job is done).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy: Option<Proportion>,
    /// Mean of the frame judge's probabilities on the imagined last frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy_mean_p: Option<f64>,
    /// Mean completion (0–10) the batch's judges gave the real rollouts, when they were judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judged_completion: Option<f64>,
    /// The judge role's verdicts on the imagined rollouts, one per judge (VLM judges only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub judged_proxy: Vec<JudgedProxy>,
    /// The leak ablation's verdicts (imagined for the real episode's length), when asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub leak: Option<Proportion>,
}

/// One ranked policy's success, episodes pooled over the tasks of the ranking.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankedPolicy {
    pub policy: String,
    /// Tasks with real episodes of the policy.
    pub tasks: u64,
    /// Real success (the simulator's predicates).
    pub real: Proportion,
    /// Each proxy's predicted success (and the leak ablation's), in the order of the ranking's
    /// comparisons, over the episodes it gave a verdict on.
    pub predicted: Vec<SourceSuccess>,
}

/// A success source's pooled verdicts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SourceSuccess {
    pub source: String,
    pub success: Proportion,
}

/// How consistently one judge scored the imagined rollouts of one ranked policy (of every one
/// when `policy` is absent) over its k repeats: the first paper's repeat consistency.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RepeatConsistency {
    pub judge: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub policy: Option<String>,
    /// Repeats asked per rollout (k).
    pub repeats: u32,
    /// Imagined rollouts with a verdict.
    pub rollouts: u64,
    /// Mean over those rollouts (the ones with at least two scores) of the sample variance
    /// (n − 1) of their completion scores; 0 when the judge always answers the same.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_variance: Option<f64>,
    /// Rollouts whose repeats fall on both sides of `completion_threshold`: the verdict (the
    /// mean's) hides a disagreement of the judge with itself.
    pub split: u64,
}

/// One task group's ranking: every proxy against the real success over its tasks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GroupRanking {
    pub group: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking: Option<Ranking>,
    /// Why the group has no ranking.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub missing: Option<String>,
}

/// The reliability diagram of one proxy's probabilities on the ranked episodes, against the
/// simulator's outcomes of the same episodes (issue 45: calibrated, not only ordered).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ReliabilityCurve {
    /// Whose probabilities: [`PROXY_SOURCE`] (the frame judge's on the last imagined frame) or
    /// [`CALIBRATED_SOURCE`] (the same through the group's calibration).
    pub source: String,
    /// The group whose ranked episodes; absent: every ranked episode.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    pub reliability: Reliability,
}

/// The reliability figure of report.md (beside report.json and report.html).
pub const RELIABILITY_FIGURE: &str = "ranking-reliability.svg";

/// What the reliability diagrams are (report.md and report.html).
pub const RELIABILITY_NOTE: &str = "Per ranked episode, the proxy's probability of success \
    (the frame judge's on the last imagined frame, and the same through the calibration fitted \
    on the training policies) against the simulator's outcome of that episode, in 5 equal-width \
    bins: each bin's mean predicted probability beside the share of its episodes that succeeded \
    (95 % Wilson interval). A calibrated proxy's points lie on the diagonal; ECE is the mean \
    over episodes of their bin's |mean predicted − observed|. The ranked policies' outcomes are \
    read here only, never by the fit. The table also gives each group's diagrams on the training \
    episodes the calibration was fitted on (their out-of-fold probabilities; in sample).";

/// The policy-ranking section of a report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingResults {
    pub train_policies: Vec<String>,
    pub ranked_policies: Vec<String>,
    /// The proxy's settings: the frame judge's threshold and `done_frames`, the judge role's
    /// `completion_threshold`, whether the leak ablation ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<ProxyConfig>,
    pub rows: Vec<RankingRow>,
    /// Per ranked policy, best real success first: real and predicted success pooled over tasks.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub policies: Vec<RankedPolicy>,
    /// Per judge of imagined rollouts: its repeat consistency per policy, then over all.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub repeat_consistency: Vec<RepeatConsistency>,
    /// Per group: the world model, the frame judge and every prediction.
    pub groups: Vec<ProxyResult>,
    /// Pearson, MMRV, Spearman and Kendall of each proxy against the real success rates, over the
    /// tasks whose proxy is done: the frame judge's, each judge's, then the leak ablation's
    /// ([`LEAK_SOURCE`], never a proxy: the real episode's length given to the proxy).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking: Option<Ranking>,
    /// Why there is no ranking yet (or at all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking_missing: Option<String>,
    /// With tasks of several groups: the same statistics per group, over that group's tasks only
    /// (the paper's Table I ranks per task), in report order; `ranking` is the pooled one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_group: Vec<GroupRanking>,
    /// Of the ranked episodes the proxy judged: how often its verdict matches the real outcome,
    /// and how often the frame judge is right on the *real* last frames (its own error, without
    /// the world model's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy_agreement: Option<Proportion>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_agreement_real_frames: Option<Proportion>,
    /// The frame judge's and each judge's agreement with the simulator and with each other, on
    /// real and imagined rollouts (the frame judge first, then the judges by name).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub judge_agreements: Vec<JudgeAgreement>,
    /// Reliability diagrams of the frame judge's probabilities on the ranked episodes, raw and
    /// calibrated: over every ranked episode, then per group when the ranked tasks span several.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reliability: Vec<ReliabilityCurve>,
    /// Proxy jobs that failed: (group, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<(String, String)>,
    /// Imagined rollouts the judge role could not judge: (judge, task, policy, seed, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub judging_errors: Vec<(String, String, String, u64, String)>,
    /// Readable names of the ladder's learned policies: (policy name, label), the label saying
    /// what each was trained on and for how long ([`ladder_label`]: `diffusion 10 ep @ 300`),
    /// in ladder order (group, episodes, step). The tables and plots show a policy by its label
    /// (the full name as the page's title, and listed under report.md's tables) and the
    /// per-policy tables list the labelled policies in this order, after the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub labels: Vec<(String, String)>,
    /// With a ladder: where its policies ran (held-out seeds, or the batch's, whose first ones
    /// are their demonstrations' layouts).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ladder_seeds: Option<crate::ladder_seeds::LadderSeeds>,
}

/// A ladder policy's label: its family, the episodes it was trained on and the training step it
/// was kept at, `diffusion 10 ep @ 300` (the U-Net) or `transformer diffusion 10 ep @ 300`; with
/// its group when a batch has ladders in several groups (`diffusion 10 ep @ 300, g1`), so that no
/// two policies read the same.
pub fn ladder_label(backbone: Backbone, episodes: u32, step: u64, group: Option<&str>) -> String {
    let family = match backbone {
        Backbone::Unet => "diffusion",
        Backbone::Transformer => "transformer diffusion",
    };
    match group {
        Some(g) => format!("{family} {episodes} ep @ {step}, {g}"),
        None => format!("{family} {episodes} ep @ {step}"),
    }
}

/// The correlation plot written beside `report.md` (predicted against real success).
pub const RANKING_FIGURE: &str = "ranking.svg";

/// The file of the correlation plot of `proxy`: [`RANKING_FIGURE`] for the frame judge's, one
/// per judge for the judge role's verdicts on imagined rollouts, and `ranking-calibrated.svg`,
/// `ranking-cross-fit.svg`, `ranking-leak.svg`, `ranking-cross-family.svg` for the calibrated
/// proxy, cross-fitting and the two ablations.
pub fn ranking_figure(proxy: &str) -> String {
    if proxy == LEAK_SOURCE {
        return "ranking-leak.svg".to_owned();
    }
    if proxy == CALIBRATED_SOURCE {
        return "ranking-calibrated.svg".to_owned();
    }
    if proxy == CROSS_FAMILY_SOURCE {
        return "ranking-cross-family.svg".to_owned();
    }
    if proxy == CROSS_FIT_SOURCE {
        return "ranking-cross-fit.svg".to_owned();
    }
    if proxy == OBJECTS_SOURCE {
        return "ranking-objects.svg".to_owned();
    }
    match proxy.strip_prefix(&format!("{PROXY_SOURCE}+")) {
        Some(judge) => {
            let safe: String = judge
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            format!("ranking-{safe}.svg")
        }
        None => RANKING_FIGURE.to_owned(),
    }
}

/// Whether a comparison's source is an ablation — the leak's or the cross-family one's (shown
/// as such, never as the proxy).
pub fn is_ablation(source: &str) -> bool {
    source == LEAK_SOURCE || source == CROSS_FAMILY_SOURCE
}

/// A success source as a column, heading or plot title reads: an ablation says it is one.
pub fn source_title(source: &str) -> String {
    if is_ablation(source) {
        format!("{source} (ablation)")
    } else {
        source.to_owned()
    }
}

/// A caution per group whose frame judge learned "not done" from no frame in the later half of
/// the ranked rollouts' step budget: it judges those late imagined frames by what it learned of the
/// training episodes' endings, and may call them done (the demo's did, near frame 30, while its
/// training episodes all ended by frame 43 and its rollouts could run to 250).
pub fn late_frame_cautions(r: &RankingResults) -> Vec<String> {
    r.groups
        .iter()
        .filter_map(|g| {
            let last = g.ranked_last_frame?;
            let seen = g.judge_latest_not_done;
            if last == 0 || seen.is_some_and(|s| 2 * s >= last) {
                return None;
            }
            let from = seen.map_or_else(
                || "no frame at all".to_owned(),
                |s| format!("no frame later than {s}"),
            );
            Some(format!(
                "{}: the frame judge learned \"not done\" from {from}, while a ranked rollout may \
                 run to frame {last}. It judges later imagined frames by what it learned of the \
                 training episodes' endings, and may call them done: give the group a training \
                 policy that fails at full length (such as random exploration with max_steps at \
                 the ranked policies' step budget).",
                g.group
            ))
        })
        .collect()
}

/// The caption of the per-policy table (report.md and report.html).
pub const PER_POLICY_NOTE: &str = "Episodes pooled over each policy's tasks: rate (successes/\
    trials) [95 % Wilson interval]. The ranking statistics below compare R and R_S as each \
    policy's mean over tasks of its per-task rate instead, which differs from the pooled rate \
    when its tasks have different numbers of episodes.";

/// What the per-group table says.
pub const PER_GROUP_NOTE: &str = "Each task group ranked on its own tasks (the paper ranks per \
    task), then pooled over every group. Calibration is the mean over policies of |R_S − R|: how \
    far the predicted success rates are from the real ones as rates, which an order can get right \
    while every rate is off. The simulator rerun is the Pearson r the real evaluation itself would \
    reach in the proxy's place (its trials, new seeds): the bar the trials' noise sets. Intervals: \
    95 % bootstrap, as below.";

/// What the simulator rerun figures mean.
pub const RETEST_NOTE: &str = "The simulator rerun: each cell's true rate drawn from its Jeffreys \
    posterior, measured twice (with the real side's trials and with the proxy's), and the two \
    compared over the policies — what the real evaluation itself would reach in the proxy's place \
    on new seeds. A proxy near it ranks as well as a rerun would; with few trials per policy no \
    proxy is expected far above it. The estimate is within about ±0.1 of the realised figure at \
    10 trials (measured on synthetic ladders of 8 policies): read the interval.";

/// What the action test measures.
pub const ACTION_TEST_NOTE: &str = "The world model's open-loop image error on the ranked \
    episodes' real clips, cut into windows of the given frames, each imagined from its real first \
    frame and state with its true actions, with the next episode's actions for the same window, \
    and with zero actions. A world model that uses its actions errs more with the wrong ones: a \
    ratio near 1 means the actions barely matter to it. PSNR and SSIM are those of the \
    true-action predictions (the video-world-model paper's Table II).";

/// What the judge repeat consistency table shows.
pub const REPEAT_NOTE: &str = "Each imagined rollout is judged k times; its verdict is the \
    mean completion's (a success when the mean is at least the threshold). Variance: the sample \
    variance (n − 1) of a rollout's k completion scores, averaged over the policy's rollouts (0: \
    the judge always answers the same). Split: rollouts whose repeats fall on both sides of the \
    threshold.";

/// What the leak ablation's comparison is.
pub const LEAK_NOTE: &str = "An ablation, not the proxy: every ranked episode imagined for \
    exactly as many frames as its real episode had and judged on that last frame — the real \
    episode's length given to the proxy. It measures what that leak is worth.";

/// What the cross-family ablation's section says.
pub const CROSS_FAMILY_NOTE: &str = "An ablation, not the proxy: each family of ranked ladder \
    policies imagined by a world model of the same settings trained on the training policies' \
    episodes and the other families' ranked episodes (their clips, never their outcomes), judged \
    by a frame judge trained as the proxy's on that model's replays of the training episodes — a \
    world model that has seen rollouts of policies it does not rank.";

/// What cross-fitting's section says.
pub const CROSS_FIT_NOTE: &str = "A proxy beside the frame judge's: the ranked policies dealt \
    into folds (each family's in turn), and each fold's episodes imagined by a world model of the \
    same settings trained on the training policies' episodes and the other folds' ranked episodes \
    (their clips, never their outcomes), judged by a frame judge trained as the proxy's on that \
    model's replays of the training episodes — no policy imagined by a model that saw its \
    episodes, every model having seen rollouts of learned policies.";

/// What the object judge's section says.
pub const OBJECTS_NOTE: &str = "A proxy beside the frame judge's: each ranked episode imagined \
    again by the same world model, which also predicts where each scene object is, and stopped \
    and judged by the object judge — a logistic regression on the predicted state and the \
    objects' heights and pairwise distances, fitted on the training policies' episodes only \
    (their last frames with their outcome, earlier frames not done, real and replayed) — \
    rather than by the frame judge on the imagined frames.";

/// What the section of a comparison says about its source, when it needs saying: the
/// ablations, the calibration, cross-fitting, the object judge.
pub fn source_note(source: &str) -> Option<&'static str> {
    match source {
        LEAK_SOURCE => Some(LEAK_NOTE),
        CROSS_FAMILY_SOURCE => Some(CROSS_FAMILY_NOTE),
        CALIBRATED_SOURCE => Some(CALIBRATION_NOTE),
        CROSS_FIT_SOURCE => Some(CROSS_FIT_NOTE),
        OBJECTS_SOURCE => Some(OBJECTS_NOTE),
        _ => None,
    }
}

/// What the judges' agreement table says.
pub const JUDGE_AGREEMENT_NOTE: &str = "Over the ranked policies' episodes: how often each \
    judge's verdict (a mean completion at or above the completion threshold; the frame judge: a \
    probability at or above its threshold, on the real last frame or as the proxy's verdict on \
    the imagined rollout) matches the simulator's outcome, and on imagined rollouts how often a \
    judge and the frame judge agree. The paper's VLM annotation accuracy on real rollouts is \
    65–80 %.";

/// What the calibrated proxy is (report.md and report.html, under its comparison).
pub const CALIBRATION_NOTE: &str = "The frame judge's verdicts made rates: each ranked \
    episode's judge probability on its last imagined frame mapped to a probability of real \
    success by Platt scaling fitted per group on the training policies' episodes only (their \
    out-of-fold judge probabilities on replays in the world model, against their real outcomes); \
    a cell's R_S is its episodes' mean calibrated probability (counted as the rounded expected \
    successes). The ranked policies' outcomes never reach the fit.";

/// Bootstrap resamples of the report's ranking statistics.
pub const RANKING_RESAMPLES: usize = 2000;

/// The share of successes among the verdicts given (`None` ones are not counted); `None` when
/// none was given.
fn successes(verdicts: impl Iterator<Item = Option<bool>>) -> Option<Proportion> {
    let given: Vec<bool> = verdicts.flatten().collect();
    (!given.is_empty()).then(|| {
        Proportion::new(
            given.iter().filter(|ok| **ok).count() as u64,
            given.len() as u64,
        )
    })
}

/// Builds the ranking section: `episodes` are the finished episodes of the ranked policies,
/// `groups` the finished proxy jobs, `imagined` the judge role's verdicts on their imagined
/// rollouts, `task_groups` (task id, group) in report order. Its `labels` are left empty:
/// assembly, which knows the ladder's trainings, fills them (`assemble`).
pub fn ranking_results(
    plan: &RankingPlan,
    ranked_policies: &[String],
    task_groups: &[(String, String)],
    episodes: &[RealEpisode],
    mut groups: Vec<ProxyResult>,
    imagined: &[ImaginedJudgement],
    errors: Vec<(String, String)>,
) -> RankingResults {
    let mut judges: Vec<&str> = imagined.iter().map(|j| j.judge.as_str()).collect();
    judges.sort_unstable();
    judges.dedup();
    let group_order = |g: &str| task_groups.iter().position(|(_, x)| x == g);
    groups.sort_by_key(|r| group_order(&r.group));
    let predictions: Vec<&ProxyPrediction> =
        groups.iter().flat_map(|g| g.predictions.iter()).collect();
    let mut rows = Vec::new();
    let mut cells = Vec::new();
    let mut agree = (0u64, 0u64);
    let mut judge_real = (0u64, 0u64);
    // (group, source, probability, real outcome) of every ranked episode the proxy judged.
    let mut probabilities: Vec<(&str, &str, f64, bool)> = Vec::new();
    for (task, group) in task_groups {
        for policy in ranked_policies {
            let eps: Vec<&RealEpisode> = episodes
                .iter()
                .filter(|e| &e.task_id == task && &e.policy == policy)
                .collect();
            if eps.is_empty() {
                continue;
            }
            let real_ok = eps.iter().filter(|e| e.success).count() as u64;
            let real = Proportion::new(real_ok, eps.len() as u64);
            let preds: Vec<&ProxyPrediction> = predictions
                .iter()
                .copied()
                .filter(|p| &p.task_id == task && &p.policy == policy)
                .collect();
            for p in &preds {
                if let Some(e) = eps.iter().find(|e| e.seed == p.seed) {
                    agree.1 += 1;
                    agree.0 += u64::from(p.success == e.success);
                    judge_real.1 += 1;
                    judge_real.0 +=
                        u64::from((p.p_success_real_frame >= plan.config.threshold) == e.success);
                    probabilities.push((group, PROXY_SOURCE, p.p_success, e.success));
                    if let Some(c) = p.p_calibrated {
                        probabilities.push((group, CALIBRATED_SOURCE, c, e.success));
                    }
                }
            }
            let proxy = successes(preds.iter().map(|p| Some(p.success)));
            let leak = successes(preds.iter().map(|p| p.leak.as_ref().map(|l| l.success)));
            // The cross-family ablation: the episodes imagined by the world model trained with
            // the other families' episodes.
            let cross = successes(
                preds
                    .iter()
                    .map(|p| p.cross_family.as_ref().map(|v| v.success)),
            );
            // Cross-fitting: each episode imagined by the model of its policy's fold.
            let cross_fit = successes(
                preds
                    .iter()
                    .map(|p| p.cross_fit.as_ref().map(|v| v.success)),
            );
            // The object judge: the episodes judged by the predicted state and objects.
            let objects = successes(
                preds
                    .iter()
                    .map(|p| p.object_judge.as_ref().map(|v| v.success)),
            );
            let judged: Vec<f64> = eps.iter().filter_map(|e| e.judged_completion).collect();
            let mut judged_proxy = Vec::new();
            for judge in &judges {
                let scores: Vec<f64> = imagined
                    .iter()
                    .filter(|j| j.judge == *judge && &j.task_id == task && &j.policy == policy)
                    .filter_map(|j| j.completion.as_ref().ok().copied())
                    .collect();
                if scores.is_empty() {
                    continue;
                }
                let ok = scores
                    .iter()
                    .filter(|c| **c >= plan.config.completion_threshold)
                    .count() as u64;
                let success = Proportion::new(ok, scores.len() as u64);
                cells.push(Cell {
                    task: task.clone(),
                    policy: policy.clone(),
                    source: judged_source(judge),
                    trials: Some(success.trials),
                    successes: Some(success.successes),
                    rate: success.rate.unwrap_or(0.0),
                });
                judged_proxy.push(JudgedProxy {
                    judge: (*judge).to_owned(),
                    success,
                    mean_completion: Some(scores.iter().sum::<f64>() / scores.len() as f64),
                });
            }
            cells.push(Cell {
                task: task.clone(),
                policy: policy.clone(),
                source: REAL_SOURCE.into(),
                trials: Some(real.trials),
                successes: Some(real.successes),
                rate: real.rate.unwrap_or(0.0),
            });
            // The calibrated verdicts: the expected successes, rounded, so that the bootstrap
            // draws them as the others (from their posterior, with as many trials).
            let calibrated: Vec<f64> = preds.iter().filter_map(|p| p.p_calibrated).collect();
            let calibrated = (!calibrated.is_empty()).then(|| {
                let expected = calibrated.iter().sum::<f64>().round() as u64;
                Proportion::new(expected, calibrated.len() as u64)
            });
            for (source, p) in [
                (PROXY_SOURCE, &proxy),
                (CALIBRATED_SOURCE, &calibrated),
                (CROSS_FIT_SOURCE, &cross_fit),
                (OBJECTS_SOURCE, &objects),
                (LEAK_SOURCE, &leak),
                (CROSS_FAMILY_SOURCE, &cross),
            ] {
                if let Some(p) = p {
                    cells.push(Cell {
                        task: task.clone(),
                        policy: policy.clone(),
                        source: source.into(),
                        trials: Some(p.trials),
                        successes: Some(p.successes),
                        rate: p.rate.unwrap_or(0.0),
                    });
                }
            }
            rows.push(RankingRow {
                task_id: task.clone(),
                group: group.clone(),
                policy: policy.clone(),
                real,
                proxy,
                proxy_mean_p: (!preds.is_empty())
                    .then(|| preds.iter().map(|p| p.p_success).sum::<f64>() / preds.len() as f64),
                judged_completion: (!judged.is_empty())
                    .then(|| judged.iter().sum::<f64>() / judged.len() as f64),
                judged_proxy,
                leak,
            });
        }
    }
    // The frame judge's proxy first, then each judge's, then the calibrated frame judge's,
    // cross-fitting's and the object judge's, then the leak and cross-family ablations, as far
    // as they have verdicts.
    let proxies: Vec<String> = std::iter::once(PROXY_SOURCE.to_owned())
        .chain(judges.iter().map(|j| judged_source(j)))
        .chain([
            CALIBRATED_SOURCE.to_owned(),
            CROSS_FIT_SOURCE.to_owned(),
            OBJECTS_SOURCE.to_owned(),
            LEAK_SOURCE.to_owned(),
            CROSS_FAMILY_SOURCE.to_owned(),
        ])
        .filter(|p| cells.iter().any(|c| &c.source == p))
        .collect();
    let policies = pooled(ranked_policies, &proxies, &cells);
    let repeat_consistency = repeat_consistency(
        &judges,
        ranked_policies,
        imagined,
        plan.config.completion_threshold,
    );
    let rank_cells = |cells: &[Cell]| -> (Option<Ranking>, Option<String>) {
        let proxies: Vec<String> = proxies
            .iter()
            .filter(|p| cells.iter().any(|c| &c.source == *p))
            .cloned()
            .collect();
        if proxies.is_empty() {
            return (None, Some("no proxy job has finished".to_owned()));
        }
        let cfg = RankingConfig {
            real: REAL_SOURCE.into(),
            proxies,
            resamples: RANKING_RESAMPLES,
            seed: 0,
        };
        match rank(cells, &cfg) {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(e)),
        }
    };
    let (ranking, ranking_missing) = rank_cells(&cells);
    // Per group, when the ranked tasks span several.
    let mut ranked_groups: Vec<&str> = Vec::new();
    for (task, group) in task_groups {
        if cells.iter().any(|c| &c.task == task) && !ranked_groups.contains(&group.as_str()) {
            ranked_groups.push(group);
        }
    }
    let per_group = if ranked_groups.len() < 2 {
        Vec::new()
    } else {
        ranked_groups
            .iter()
            .map(|&group| {
                let of_group: Vec<Cell> = cells
                    .iter()
                    .filter(|c| task_groups.iter().any(|(t, g)| t == &c.task && g == group))
                    .cloned()
                    .collect();
                let (ranking, missing) = rank_cells(&of_group);
                GroupRanking {
                    group: group.to_owned(),
                    ranking,
                    missing,
                }
            })
            .collect()
    };
    // Over the ranked tasks' episodes only (a ranked policy may run tasks of other groups).
    let ranked_episodes: Vec<RealEpisode> = episodes
        .iter()
        .filter(|e| task_groups.iter().any(|(t, _)| *t == e.task_id))
        .cloned()
        .collect();
    let reliability = reliability_curves(&probabilities, &ranked_groups);
    let proxy_agreement = (agree.1 > 0).then(|| Proportion::new(agree.0, agree.1));
    let judge_agreement_real_frames =
        (judge_real.1 > 0).then(|| Proportion::new(judge_real.0, judge_real.1));
    // The frame judge's row is the two counts above; then each judge's.
    let judge_agreements: Vec<JudgeAgreement> = (!predictions.is_empty())
        .then(|| JudgeAgreement {
            judge: FRAME_JUDGE.to_owned(),
            real_vs_sim: judge_agreement_real_frames,
            imagined_vs_sim: proxy_agreement,
            imagined_vs_frame_judge: None,
        })
        .into_iter()
        .chain(judge_agreements(
            plan,
            &judges,
            &ranked_episodes,
            &predictions,
            imagined,
        ))
        .collect();
    RankingResults {
        train_policies: plan.train_policies.clone(),
        ranked_policies: ranked_policies.to_vec(),
        config: Some(plan.config.clone()),
        rows,
        policies,
        repeat_consistency,
        groups,
        ranking,
        ranking_missing,
        per_group,
        proxy_agreement,
        judge_agreement_real_frames,
        judge_agreements,
        reliability,
        errors,
        judging_errors: imagined
            .iter()
            .filter_map(|j| {
                j.completion.as_ref().err().map(|e| {
                    (
                        j.judge.clone(),
                        j.task_id.clone(),
                        j.policy.clone(),
                        j.seed,
                        e.clone(),
                    )
                })
            })
            .collect(),
        labels: Vec::new(),
        ladder_seeds: None,
    }
}

/// The reliability diagrams of `probabilities` ((group, source, probability, outcome)): per
/// source (the raw proxy first), over every group, then per group when there are several.
fn reliability_curves(
    probabilities: &[(&str, &str, f64, bool)],
    groups: &[&str],
) -> Vec<ReliabilityCurve> {
    let mut scopes = vec![None];
    if groups.len() > 1 {
        scopes.extend(groups.iter().map(|g| Some(*g)));
    }
    let mut out = Vec::new();
    for group in scopes {
        for source in [PROXY_SOURCE, CALIBRATED_SOURCE] {
            let pairs: Vec<(f64, bool)> = probabilities
                .iter()
                .filter(|(g, s, _, _)| *s == source && group.is_none_or(|x| x == *g))
                .map(|&(_, _, p, ok)| (p, ok))
                .collect();
            if pairs.is_empty() {
                continue;
            }
            out.push(ReliabilityCurve {
                source: source.to_owned(),
                group: group.map(str::to_owned),
                reliability: reliability(&pairs, RELIABILITY_BINS),
            });
        }
    }
    out
}

/// Per ranked policy, best real success first: its cells' trials and successes summed over
/// tasks, for the real source and each of `sources`.
fn pooled(ranked: &[String], sources: &[String], cells: &[Cell]) -> Vec<RankedPolicy> {
    let sum = |policy: &str, source: &str| {
        let of: Vec<&Cell> = cells
            .iter()
            .filter(|c| c.policy == policy && c.source == source)
            .collect();
        let count = |f: fn(&Cell) -> Option<u64>| of.iter().filter_map(|c| f(c)).sum::<u64>();
        (!of.is_empty()).then(|| {
            (
                of.len() as u64,
                Proportion::new(count(|c| c.successes), count(|c| c.trials)),
            )
        })
    };
    let mut out: Vec<RankedPolicy> = ranked
        .iter()
        .filter_map(|policy| {
            let (tasks, real) = sum(policy, REAL_SOURCE)?;
            Some(RankedPolicy {
                policy: policy.clone(),
                tasks,
                real,
                predicted: sources
                    .iter()
                    .filter_map(|s| {
                        sum(policy, s).map(|(_, success)| SourceSuccess {
                            source: s.clone(),
                            success,
                        })
                    })
                    .collect(),
            })
        })
        .collect();
    out.sort_by(|a, b| {
        let rate = |p: &RankedPolicy| p.real.rate.unwrap_or(0.0);
        rate(b).total_cmp(&rate(a)).then(a.policy.cmp(&b.policy))
    });
    out
}

/// Per judge: the spread of its completion scores over the repeats of each imagined rollout it
/// gave a verdict on, per ranked policy and then over all of them.
fn repeat_consistency(
    judges: &[&str],
    ranked: &[String],
    imagined: &[ImaginedJudgement],
    threshold: f64,
) -> Vec<RepeatConsistency> {
    let mut out = Vec::new();
    for judge in judges {
        let verdicts: Vec<&ImaginedJudgement> = imagined
            .iter()
            .filter(|j| j.judge == *judge && j.completion.is_ok())
            .collect();
        let k = verdicts.iter().map(|j| j.repeats).max().unwrap_or(0);
        for policy in ranked.iter().map(Some).chain([None]) {
            let of: Vec<&ImaginedJudgement> = verdicts
                .iter()
                .copied()
                .filter(|j| policy.is_none_or(|p| &j.policy == p))
                .collect();
            if of.is_empty() {
                continue;
            }
            let variances: Vec<f64> = of
                .iter()
                .filter_map(|j| ScoreStats::of(&j.scores).variance)
                .collect();
            out.push(RepeatConsistency {
                judge: (*judge).to_owned(),
                policy: policy.cloned(),
                repeats: k,
                rollouts: of.len() as u64,
                mean_variance: (!variances.is_empty())
                    .then(|| variances.iter().sum::<f64>() / variances.len() as f64),
                split: of
                    .iter()
                    .filter(|j| {
                        j.scores.iter().any(|s| *s >= threshold)
                            && j.scores.iter().any(|s| *s < threshold)
                    })
                    .count() as u64,
            });
        }
    }
    out
}

/// Each judge's agreement: with the simulator on real and imagined rollouts, and with the frame
/// judge on imagined ones. `judges`: those of imagined rollouts; a judge that only judged real
/// rollouts is listed too.
fn judge_agreements(
    plan: &RankingPlan,
    judges: &[&str],
    episodes: &[RealEpisode],
    predictions: &[&ProxyPrediction],
    imagined: &[ImaginedJudgement],
) -> Vec<JudgeAgreement> {
    let proportion = |pairs: &mut dyn Iterator<Item = (bool, bool)>| {
        let (mut agree, mut n) = (0u64, 0u64);
        for (a, b) in pairs {
            n += 1;
            agree += u64::from(a == b);
        }
        (n > 0).then(|| Proportion::new(agree, n))
    };
    let real_of = |task: &str, policy: &str, seed: u64| {
        episodes
            .iter()
            .find(|e| e.task_id == task && e.policy == policy && e.seed == seed)
    };
    let frame_of = |task: &str, policy: &str, seed: u64| {
        predictions
            .iter()
            .find(|p| p.task_id == task && p.policy == policy && p.seed == seed)
    };
    let done = |completion: f64| completion >= plan.config.completion_threshold;
    let mut out = Vec::new();
    let mut names: Vec<&str> = judges.to_vec();
    for e in episodes {
        for (j, _) in &e.completion_by_judge {
            if !names.contains(&j.as_str()) {
                names.push(j);
            }
        }
    }
    names.sort_unstable();
    for judge in names {
        let verdicts = || {
            imagined
                .iter()
                .filter(move |j| j.judge == judge)
                .filter_map(|j| j.completion.as_ref().ok().map(|c| (j, done(*c))))
        };
        out.push(JudgeAgreement {
            judge: judge.to_owned(),
            real_vs_sim: proportion(&mut episodes.iter().filter_map(|e| {
                e.completion_by_judge
                    .iter()
                    .find(|(j, _)| j == judge)
                    .map(|(_, c)| (done(*c), e.success))
            })),
            imagined_vs_sim: proportion(&mut verdicts().filter_map(|(j, ok)| {
                real_of(&j.task_id, &j.policy, j.seed).map(|e| (ok, e.success))
            })),
            imagined_vs_frame_judge: proportion(&mut verdicts().filter_map(|(j, ok)| {
                frame_of(&j.task_id, &j.policy, j.seed).map(|p| (ok, p.success))
            })),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_model::proxy::ProxyConfig;

    fn real(task: &str, policy: &str, seed: u64, success: bool) -> RealEpisode {
        RealEpisode {
            task_id: task.into(),
            policy: policy.into(),
            seed,
            success,
            judged_completion: None,
            completion_by_judge: Vec::new(),
        }
    }

    fn verdict(
        judge: &str,
        task: &str,
        policy: &str,
        seed: u64,
        completion: Result<f64, &str>,
    ) -> ImaginedJudgement {
        ImaginedJudgement {
            task_id: task.into(),
            policy: policy.into(),
            seed,
            judge: judge.into(),
            scores: completion.iter().copied().collect(),
            repeats: 1,
            completion: completion.map_err(str::to_owned),
        }
    }

    /// A plan with one training policy and three ranked ones: good, fair and poor.
    fn good_fair_poor() -> (RankingPlan, Vec<String>) {
        let plan = RankingPlan {
            train_policies: vec!["teacher".into()],
            config: ProxyConfig::default(),
            ladder: None,
            groups: Vec::new(),
        };
        (plan, ["good", "fair", "poor"].map(String::from).to_vec())
    }

    #[test]
    fn each_judge_of_imagined_rollouts_is_a_proxy_of_its_own() {
        let (plan, ranked) = good_fair_poor();
        let task_groups = vec![("t1".into(), "g".into()), ("t2".into(), "g".into())];
        let mut episodes = Vec::new();
        let mut imagined = Vec::new();
        // Real success: good 4/4, fair 2/4, poor 0/4. The VLM's completions on the imagined
        // rollouts follow it (threshold 5: 4/4, 2/4, 0/3 and one error); "coarse" judges only
        // two policies and gets them the wrong way round.
        let vlm = [
            ("good", [9.0, 8.0, 7.0, 6.0]),
            ("fair", [6.0, 2.0, 5.0, 1.0]),
            ("poor", [1.0, 0.0, 4.9, f64::NAN]),
        ];
        for (policy, scores) in vlm {
            for (k, score) in scores.into_iter().enumerate() {
                let (task, seed) = (if k < 2 { "t1" } else { "t2" }, k as u64 % 2);
                let ok = match policy {
                    "good" => true,
                    "fair" => seed == 0,
                    _ => false,
                };
                episodes.push(real(task, policy, seed, ok));
                imagined.push(verdict(
                    "vlm",
                    task,
                    policy,
                    seed,
                    if score.is_nan() {
                        Err("HTTP 500")
                    } else {
                        Ok(score)
                    },
                ));
            }
        }
        imagined.push(verdict("coarse", "t1", "good", 0, Ok(2.0)));
        imagined.push(verdict("coarse", "t1", "poor", 0, Ok(8.0)));
        let r = ranking_results(
            &plan,
            &ranked,
            &task_groups,
            &episodes,
            Vec::new(),
            &imagined,
            Vec::new(),
        );

        let ranking = r.ranking.as_ref().unwrap_or_else(|| panic!("{r:?}"));
        let proxies: Vec<&str> = ranking
            .comparisons
            .iter()
            .map(|c| c.proxy.as_str())
            .collect();
        // No frame-judge proxy has finished; each judge is a proxy, in name order.
        assert_eq!(proxies, ["world-model+coarse", "world-model+vlm"]);
        let v = &ranking.comparisons[1];
        let points: Vec<(&str, f64, f64)> = v
            .policies
            .iter()
            .map(|p| (p.policy.as_str(), p.real, p.proxy))
            .collect();
        assert_eq!(
            points,
            [("good", 1.0, 1.0), ("fair", 0.5, 0.5), ("poor", 0.0, 0.0)]
        );
        assert_eq!(v.mmrv.value, Some(0.0));
        assert!((v.pearson.value.unwrap() - 1.0).abs() < 1e-12);
        let c = &ranking.comparisons[0];
        assert_eq!(c.policies.len(), 2);
        // Ranked the wrong way round: every policy's worst swap is the full real gap.
        assert_eq!(c.mmrv.value, Some(1.0));

        let row = |task: &str, policy: &str| {
            r.rows
                .iter()
                .find(|x| x.task_id == task && x.policy == policy)
                .unwrap()
        };
        let fair = &row("t1", "fair").judged_proxy;
        assert_eq!(fair.len(), 1);
        assert_eq!(
            (fair[0].judge.as_str(), &fair[0].success),
            ("vlm", &Proportion::new(1, 2))
        );
        assert_eq!(fair[0].mean_completion, Some(4.0));
        // 4.9 is below the threshold; the failed shard is not a verdict but an error.
        assert_eq!(
            row("t2", "poor").judged_proxy[0].success,
            Proportion::new(0, 1)
        );
        assert_eq!(
            r.judging_errors,
            [(
                "vlm".into(),
                "t2".into(),
                "poor".into(),
                1,
                "HTTP 500".into()
            )]
        );
        let md = r.markdown();
        assert!(md.contains("vlm: 50 % (1/2) (4.0)"), "{md}");
        assert!(md.contains("(ranking-vlm.svg)"), "{md}");
        assert!(
            md.contains("1 imagined rollouts could not be judged"),
            "{md}"
        );
    }

    #[test]
    fn tasks_of_several_groups_are_ranked_per_group_and_pooled_with_their_calibration() {
        let (plan, ranked) = good_fair_poor();
        let task_groups = vec![
            ("a1".into(), "placement".into()),
            ("b1".into(), "stacking".into()),
        ];
        // Real success on 4 seeds of each task: good 4, fair 2, poor 0. The judge of imagined
        // rollouts gets placement's order right but every rate too high (half the spread),
        // and stacking's the wrong way round.
        let mut episodes = Vec::new();
        let mut imagined = Vec::new();
        for (policy, real_ok, placement, stacking) in
            [("good", 4, 4, 0), ("fair", 2, 3, 2), ("poor", 0, 2, 4)]
        {
            for (task, predicted) in [("a1", placement), ("b1", stacking)] {
                for seed in 0..4u64 {
                    episodes.push(real(task, policy, seed, seed < real_ok));
                    let score = if seed < predicted { 9.0 } else { 1.0 };
                    imagined.push(verdict("vlm", task, policy, seed, Ok(score)));
                }
            }
        }
        let r = ranking_results(
            &plan,
            &ranked,
            &task_groups,
            &episodes,
            Vec::new(),
            &imagined,
            Vec::new(),
        );
        let groups: Vec<&str> = r.per_group.iter().map(|g| g.group.as_str()).collect();
        assert_eq!(groups, ["placement", "stacking"]);
        let stat = |g: usize| {
            let c = &r.per_group[g].ranking.as_ref().unwrap().comparisons[0];
            assert_eq!((c.policies.len(), c.tasks.len()), (3, 1));
            (
                c.pearson.value.unwrap(),
                c.mmrv.value.unwrap(),
                c.calibration_mae.as_ref().unwrap().value.unwrap(),
            )
        };
        // Placement: (1, 0.75, 0.5) against (1, 0.5, 0): ordered, a quarter off on average.
        let (pearson, mmrv, calibration) = stat(0);
        assert!(
            (pearson - 1.0).abs() < 1e-9 && mmrv == 0.0,
            "{pearson} {mmrv}"
        );
        assert!((calibration - 0.25).abs() < 1e-12, "{calibration}");
        // Stacking: (0, 0.5, 1) against (1, 0.5, 0): reversed, 2/3 off on average.
        let (pearson, mmrv, calibration) = stat(1);
        // MMRV: each policy's largest violated real gap, (1 + 0.5 + 1) / 3.
        assert!((pearson + 1.0).abs() < 1e-9 && (mmrv - 2.5 / 3.0).abs() < 1e-12);
        assert!((calibration - 2.0 / 3.0).abs() < 1e-12, "{calibration}");
        // Pooled over both groups the judge's rates are flat (0.5, 0.625, 0.75): the wrong order,
        // neither group's picture.
        let pooled = &r.ranking.as_ref().unwrap().comparisons[0];
        assert_eq!(pooled.tasks.len(), 2);
        let md = r.markdown();
        assert!(md.contains("### Per task group"), "{md}");
        for g in ["placement", "stacking", "(pooled)"] {
            assert!(md.contains(&format!("| {g} |")), "{g}: {md}");
        }
        // The page shows the table and one scatter per group.
        let report = crate::testing::report_with_ranking(r.clone());
        let html = crate::html::report_html(&crate::html::HtmlInputs {
            report: &report,
            artifact: &|_| None,
            human: None,
        });
        assert!(html.contains("Per task group"));
        assert!(html.contains("group placement:") && html.contains("group stacking:"));
        // One group: no per-group table (the pooled ranking is the group's).
        let one = ranking_results(
            &plan,
            &ranked,
            &task_groups[..1],
            &episodes,
            Vec::new(),
            &imagined,
            Vec::new(),
        );
        assert!(one.per_group.is_empty());
        assert!(!one.markdown().contains("Per task group"));
    }

    /// A group's proxy result with `predictions` (task, policy, seed, judge probability) and the
    /// calibration `calibration`, whose calibrated probabilities it carries as the trainer
    /// computes them.
    fn calibrated_group(
        predictions: &[(&str, &str, u64, f64)],
        calibration: &assay_model::proxy::Calibration,
    ) -> ProxyResult {
        let predictions: Vec<serde_json::Value> = predictions
            .iter()
            .map(|(task, policy, seed, p)| {
                serde_json::json!({
                    "task_id": task, "policy": policy, "seed": seed, "p_success": p,
                    "success": *p >= 0.5, "p_success_real_frame": 0.5, "last_frame_mse": 0.001,
                    "p_calibrated": calibration.apply(*p),
                })
            })
            .collect();
        serde_json::from_value(serde_json::json!({
            "group": "g",
            "world_model": {
                "group": "g", "budget": 4, "train_episodes": 4, "eval_episodes": 0,
                "eval_image_mse": 0.0, "eval_proprio_mse": 0.0, "per_episode": [],
                "episodes": [], "final_train_loss": 0.0, "steps": 1, "epochs": 0.0,
                "device": "cpu", "config": {}
            },
            "judge_examples": 16, "judge_positives": 6, "judge_train_accuracy": 0.9,
            "calibration": calibration,
            "predictions": predictions,
        }))
        .unwrap()
    }

    #[test]
    fn the_calibrated_proxy_reads_the_training_fit_and_never_the_ranked_outcomes() {
        let (plan, ranked) = good_fair_poor();
        let task_groups = vec![("t1".into(), "g".into())];
        // The frame judge calls every imagined rollout done (p 0.9, 0.7, 0.55 by policy); the
        // calibration fitted on the training episodes maps those to 0.72, 0.47, 0.35.
        let calibration = assay_model::proxy::Calibration {
            a: -0.8,
            b: 0.8,
            episodes: 16,
            positives: 6,
            folds: 2,
            train_error: 0.3,
            train_error_uncalibrated: 0.4,
            // The fit's own diagrams, in sample: shown beside the ranked episodes', read from
            // the trainer's result as they are.
            train_reliability: Some(assay_model::proxy::TrainReliability {
                raw: reliability(
                    &[(0.95, true), (0.9, false), (0.1, false)],
                    RELIABILITY_BINS,
                ),
                calibrated: reliability(
                    &[(0.7, true), (0.65, false), (0.2, false)],
                    RELIABILITY_BINS,
                ),
            }),
        };
        let p_of = |policy: &str| match policy {
            "good" => 0.9,
            "fair" => 0.7,
            _ => 0.55,
        };
        let predictions: Vec<(&str, &str, u64, f64)> = ranked
            .iter()
            .flat_map(|policy| {
                (0..4u64).map(move |seed| ("t1", policy.as_str(), seed, p_of(policy)))
            })
            .collect();
        let expected: Vec<f64> = ranked
            .iter()
            .map(|policy| (4.0 * calibration.apply(p_of(policy))).round() / 4.0)
            .collect();
        assert_eq!(
            expected,
            [0.75, 0.5, 0.25],
            "the fixture's calibrated rates"
        );
        let with_real = |real_ok: [u64; 3]| {
            let episodes: Vec<RealEpisode> = ranked
                .iter()
                .zip(real_ok)
                .flat_map(|(policy, ok)| {
                    (0..4u64).map(move |seed| real("t1", policy, seed, seed < ok))
                })
                .collect();
            ranking_results(
                &plan,
                &ranked,
                &task_groups,
                &episodes,
                vec![calibrated_group(&predictions, &calibration)],
                &[],
                Vec::new(),
            )
        };
        let points = |r: &RankingResults, source: &str| -> Vec<(f64, f64)> {
            let c = r
                .ranking
                .as_ref()
                .unwrap()
                .comparisons
                .iter()
                .find(|c| c.proxy == source)
                .unwrap_or_else(|| panic!("no {source} comparison"));
            c.policies.iter().map(|p| (p.real, p.proxy)).collect()
        };
        let r = with_real([4, 2, 0]);
        let proxies: Vec<&str> = r
            .ranking
            .as_ref()
            .unwrap()
            .comparisons
            .iter()
            .map(|c| c.proxy.as_str())
            .collect();
        assert_eq!(proxies, [PROXY_SOURCE, CALIBRATED_SOURCE]);
        // Uncalibrated: every policy 100 %; calibrated: readable rates in the right order.
        assert!(points(&r, PROXY_SOURCE).iter().all(|(_, p)| *p == 1.0));
        let calibrated = points(&r, CALIBRATED_SOURCE);
        assert_eq!(calibrated, [(1.0, 0.75), (0.5, 0.5), (0.0, 0.25)]);
        // Other real outcomes of the ranked policies: R moves, the calibrated R_S does not.
        let other = points(&with_real([1, 3, 4]), CALIBRATED_SOURCE);
        assert_eq!(other, [(0.25, 0.75), (0.75, 0.5), (1.0, 0.25)]);
        // The reliability diagrams read the ranked episodes' outcomes (an evaluation, after the
        // fit): raw, 0.9 / 0.7 / 0.55 in bins 4, 3 and 2 with 4/4, 2/4 and 0/4 successes.
        let curve = |r: &RankingResults, source: &str| -> Reliability {
            let c = r.reliability.iter().find(|c| c.source == source).unwrap();
            assert_eq!(c.group, None, "one group: the pooled curves only");
            c.reliability.clone()
        };
        let raw = curve(&r, PROXY_SOURCE);
        let bins: Vec<(f64, f64, u64, u64)> = raw
            .bins
            .iter()
            .map(|b| {
                (
                    b.lower,
                    b.mean_predicted,
                    b.observed.successes,
                    b.observed.trials,
                )
            })
            .collect();
        assert_eq!(
            bins,
            [(0.4, 0.55, 0, 4), (0.6, 0.7, 2, 4), (0.8, 0.9, 4, 4)]
        );
        let ece = (4.0 * 0.55 + 4.0 * 0.2 + 4.0 * 0.1) / 12.0;
        assert!((raw.ece.unwrap() - ece).abs() < 1e-9, "{:?}", raw.ece);
        let cal = curve(&r, CALIBRATED_SOURCE);
        let ece: f64 = [(0.9, 1.0), (0.7, 0.5), (0.55, 0.0)]
            .iter()
            .map(|(p, observed)| (calibration.apply(*p) - observed).abs())
            .sum::<f64>()
            / 3.0;
        assert!((cal.ece.unwrap() - ece).abs() < 1e-9, "{:?} {ece}", cal.ece);
        // Other outcomes, another diagram: it measures the calibration, it does not make it.
        assert_ne!(curve(&with_real([1, 3, 4]), PROXY_SOURCE), raw);
        let md = r.markdown();
        assert!(
            md.contains("### Reliability of the predicted probabilities"),
            "{md}"
        );
        assert!(md.contains("(ranking-reliability.svg)"), "{md}");
        assert!(md.contains("| [0.8, 1.0] | 4 | 0.90 | 100 % (4/4)"), "{md}");
        // The fit's diagrams beside them: raw ECE (0.1 + 2 · 0.425) / 3, calibrated
        // (0.2 + 2 · 0.175) / 3.
        let fit = "training policies (the fit's, in sample) | g";
        let raw_row =
            format!("| `world-model` | {fit} | 0.317 | [0.0, 0.2) | 1 | 0.10 | 0 % (0/1)");
        assert!(md.contains(&raw_row), "{md}");
        assert!(
            md.contains(&format!("| `world-model-calibrated` | {fit} | 0.183 |")),
            "{md}"
        );
        assert!(
            crate::figures::ranking_reliability(&r)
                .unwrap()
                .contains("ECE 0.283, 12 episodes")
        );
        assert!(md.contains("Platt scaling fitted per group"), "{md}");
        assert!(md.contains("(ranking-calibrated.svg)"), "{md}");
        assert!(
            md.contains(
                "σ(-0.80 + 0.80·logit p), fitted on 16 training episodes (6 successes, 2 folds)"
            ),
            "{md}"
        );
    }

    #[test]
    fn each_judge_s_agreement_with_the_simulator_and_the_frame_judge_is_counted() {
        let (plan, ranked) = good_fair_poor();
        let task_groups = vec![("t1".into(), "g".into())];
        let identity = assay_model::proxy::Calibration {
            a: 0.0,
            b: 1.0,
            episodes: 8,
            positives: 4,
            folds: 2,
            train_error: 0.0,
            train_error_uncalibrated: 0.0,
            train_reliability: None,
        };
        // Real: good 4/4, fair 2/4 (seeds 0, 1), poor 0/4. The frame judge calls good's and
        // fair's imagined rollouts done and poor's not, and every real last frame done (0.5).
        // The VLM: on real rollouts 8 for a success and 2 for a failure, but 7 for poor's seed 0;
        // on imagined ones 9 for good and 1 for the others.
        let mut episodes = Vec::new();
        let mut predictions = Vec::new();
        let mut imagined = Vec::new();
        for policy in &ranked {
            for seed in 0..4u64 {
                let ok = policy == "good" || (policy == "fair" && seed < 2);
                let mut e = real("t1", policy, seed, ok);
                let real_score = if policy == "poor" && seed == 0 {
                    7.0
                } else if ok {
                    8.0
                } else {
                    2.0
                };
                e.completion_by_judge = vec![("vlm".into(), real_score)];
                episodes.push(e);
                predictions.push((
                    "t1",
                    policy.as_str(),
                    seed,
                    if policy == "poor" { 0.2 } else { 0.9 },
                ));
                let score = if policy == "good" { 9.0 } else { 1.0 };
                imagined.push(verdict("vlm", "t1", policy, seed, Ok(score)));
            }
        }
        let r = ranking_results(
            &plan,
            &ranked,
            &task_groups,
            &episodes,
            vec![calibrated_group(&predictions, &identity)],
            &imagined,
            Vec::new(),
        );
        let p = |a: u64, n: u64| Some(Proportion::new(a, n));
        assert_eq!(
            r.judge_agreements,
            [
                JudgeAgreement {
                    judge: FRAME_JUDGE.into(),
                    real_vs_sim: p(6, 12),
                    imagined_vs_sim: p(10, 12),
                    imagined_vs_frame_judge: None,
                },
                JudgeAgreement {
                    judge: "vlm".into(),
                    real_vs_sim: p(11, 12),
                    imagined_vs_sim: p(10, 12),
                    imagined_vs_frame_judge: p(8, 12),
                },
            ]
        );
        let md = r.markdown();
        assert!(md.contains("### Judges' agreement"), "{md}");
        assert!(
            md.contains(
                "| `vlm` | 92 % (11/12) [65, 99] | 83 % (10/12) [55, 95] | 67 % (8/12) [39, 86] |"
            ),
            "{md}"
        );
    }

    #[test]
    fn the_section_shows_what_was_compared_per_policy_success_the_ablation_and_repeats() {
        use crate::testing::{LADDER_BEST, LADDER_WORST, ranking_fixture, report_with_ranking};
        let r = ranking_fixture();
        // Aggregation: pooled per policy, best real success first.
        let best = &r.policies[0];
        assert_eq!(best.policy, LADDER_BEST);
        assert_eq!((best.tasks, &best.real), (3, &Proportion::new(6, 6)));
        let sources: Vec<(&str, &Proportion)> = best
            .predicted
            .iter()
            .map(|s| (s.source.as_str(), &s.success))
            .collect();
        assert_eq!(
            sources,
            [
                (PROXY_SOURCE, &Proportion::new(5, 6)),
                ("world-model+vlm", &Proportion::new(2, 2)),
                (LEAK_SOURCE, &Proportion::new(6, 6)),
            ]
        );
        assert_eq!(r.policies[2].policy, LADDER_WORST);
        let ranking = r.ranking.as_ref().unwrap();
        let proxies: Vec<&str> = ranking
            .comparisons
            .iter()
            .map(|c| c.proxy.as_str())
            .collect();
        assert_eq!(proxies, [PROXY_SOURCE, "world-model+vlm", LEAK_SOURCE]);
        // The leak gives the real outcome back: a perfect ranking, as an ablation.
        let leak = &ranking.comparisons[2];
        assert!((leak.pearson.value.unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(leak.mmrv.value, Some(0.0));
        assert_eq!(ranking_figure(LEAK_SOURCE), "ranking-leak.svg");
        // Repeats: per-rollout sample variances 1, 0 | 4, 3 | 0, 4.5.
        let consistency: Vec<(Option<&str>, u32, u64, f64, u64)> = r
            .repeat_consistency
            .iter()
            .map(|c| {
                (
                    c.policy.as_deref(),
                    c.repeats,
                    c.rollouts,
                    c.mean_variance.unwrap(),
                    c.split,
                )
            })
            .collect();
        assert_eq!(
            consistency,
            [
                (Some(LADDER_BEST), 3, 2, 0.5, 0),
                (Some("scripted"), 3, 2, 3.5, 2),
                (Some(LADDER_WORST), 3, 2, 2.25, 0),
                (None, 3, 6, 12.5 / 6.0, 2),
            ]
        );
        // report.json keeps it (a float read back may be an ulp off, so parts are compared).
        let back: RankingResults =
            serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.config, r.config);
        assert_eq!(back.policies.len(), 3);
        assert_eq!(back.policies[2].predicted.len(), 3);
        assert_eq!(back.repeat_consistency.len(), 4);
        assert!(back.rows.iter().all(|x| x.leak.is_some()));

        let report = report_with_ranking(r);
        let md = report.to_markdown();
        let html = crate::html::report_html(&crate::html::HtmlInputs {
            report: &report,
            artifact: &|_| None,
            human: None,
        });
        let both = |md_text: &str, html_text: &str| {
            assert!(md.contains(md_text), "{md_text} not in:\n{md}");
            assert!(html.contains(html_text), "{html_text} not in the page");
        };
        // Per policy, with Wilson intervals: 6/6 [61, 100], 5/6 [44, 97], 2/2 [34, 100].
        both(
            "| R_S world-model | R_S world-model+vlm | R_S world-model-leak (ablation) |",
            "<th>R_S world-model-leak (ablation)</th>",
        );
        both(
            "| diffusion 3fa9c2d1 | 3 | 100 % (6/6) [61, 100] | 83 % (5/6) [44, 97] | \
             100 % (2/2) [34, 100] | 100 % (6/6) [61, 100] |",
            "<td class=\"n\">83 % (5/6) [44, 97]</td>",
        );
        both(
            "| scripted | 3 | 50 % (3/6) [19, 81] | 33 % (2/6) [10, 70] | 50 % (1/2) [9, 91] | \
             50 % (3/6) [19, 81] |",
            "<td class=\"n\">33 % (2/6) [10, 70]</td>",
        );
        both(
            "| diffusion 77be01aa | 3 | 17 % (1/6) [3, 56] | 0 % (0/6) [0, 39] | \
             0 % (0/2) [0, 66] | 17 % (1/6) [3, 56] |",
            "<td class=\"n\">0 % (0/2) [0, 66]</td>",
        );
        both(PER_POLICY_NOTE, PER_POLICY_NOTE);
        // Ladder policies shown short, their full names kept.
        both(
            &format!("- diffusion 3fa9c2d1: `{LADDER_BEST}`"),
            &format!("<span title=\"{LADDER_BEST}\">diffusion 3fa9c2d1</span>"),
        );
        // What was compared.
        for text in [
            "an imagined rollout stops as a success once the frame judge calls 2 frames in a row \
             done; otherwise it runs the task's whole step budget",
            "vlm: k = 3 repeats",
            "a rollout succeeds when its mean completion over k repeats is ≥ 5.00 (0–10)",
            "assay RSSM (groups g1)",
            "cosmos (http://wm:50051) (groups g2)",
            "the real episode's length given to the proxy",
        ] {
            both(text, text);
        }
        both(
            "| training policies (their episodes train the world model and the frame judge) | \
             oracle |",
            "<td>oracle</td>",
        );
        both(
            "| ranked policies (never trained on) | diffusion 3fa9c2d1, scripted, \
             diffusion 77be01aa |",
            "diffusion 3fa9c2d1</span>, scripted, <span",
        );
        both(
            "| g1 | assay RSSM | 500 | 1.200 | 40 (12) | 0.95 | 6/12 | 30.0 | 4.000 |",
            "<td class=\"n\">6/12</td>",
        );
        // The action test: 16-frame windows, 2.000 against 5.000 and 8.000: 2.50 and 4.00 times
        // the error; PSNR and SSIM beside.
        both(
            "| g1 | assay RSSM | 4 | 16 | 2.000 | 5.000 | 8.000 | 2.50 | 4.00 | 27.00 | 0.900 |",
            "<td class=\"n\">4.00</td>",
        );
        // Repeat consistency: scripted's rollouts vary by 4 and 3, both split; 12.5/6 overall.
        both(
            "| `vlm` | scripted | 3 | 2 | 3.500 | 2 |",
            "<td class=\"n\">3.500</td>",
        );
        both(
            "| `vlm` | **all** | **3** | **6** | **2.083** | **2** |",
            "<th class=\"n\">2.083</th>",
        );
        // The ablation's comparison, labelled as one.
        both(
            "## Policy ranking: world-model-leak (ablation) against sim\n\nAn ablation, not the proxy",
            "<h3>world-model-leak (ablation) against sim</h3><p class=\"caption\">An ablation",
        );
        both(
            "(ranking-leak.svg)",
            "world-model-leak (ablation) against sim: r = 1.000",
        );
    }

    #[test]
    fn ladder_policies_read_by_their_episodes_and_step_in_ladder_order() {
        use crate::testing::{LADDER_BEST, LADDER_WORST, ranking_fixture, report_with_ranking};
        assert_eq!(
            ladder_label(Backbone::Unet, 10, 300, None),
            "diffusion 10 ep @ 300"
        );
        assert_eq!(
            ladder_label(Backbone::Unet, 40, 3000, Some("g1")),
            "diffusion 40 ep @ 3000, g1"
        );
        let mut r = ranking_fixture();
        r.labels = vec![
            (
                LADDER_WORST.to_owned(),
                ladder_label(Backbone::Unet, 10, 300, None),
            ),
            (
                LADDER_BEST.to_owned(),
                ladder_label(Backbone::Unet, 40, 3000, None),
            ),
        ];
        let back: RankingResults =
            serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.labels, r.labels);
        let report = report_with_ranking(r);
        let md = report.to_markdown();
        let html = crate::html::report_html(&crate::html::HtmlInputs {
            report: &report,
            artifact: &|_| None,
            human: None,
        });
        let both = |md_text: &str, html_text: &str| {
            assert!(md.contains(md_text), "{md_text} not in:\n{md}");
            assert!(html.contains(html_text), "{html_text} not in the page");
        };
        // Per policy: the others by real success, then the ladder by episodes and step.
        let per_policy = [
            "| scripted | 3 | 50 % (3/6) [19, 81] |",
            "| diffusion 10 ep @ 300 | 3 | 17 % (1/6) [3, 56] |",
            "| diffusion 40 ep @ 3000 | 3 | 100 % (6/6) [61, 100] |",
        ]
        .map(|row| {
            md.find(row)
                .unwrap_or_else(|| panic!("{row} not in:\n{md}"))
        });
        assert!(per_policy.is_sorted(), "{per_policy:?} in:\n{md}");
        // What was compared, the comparisons' tables, the plots: the label, the full name
        // listed (report.md) or as the title (report.html).
        both(
            "| ranked policies (never trained on) | diffusion 40 ep @ 3000, scripted, \
             diffusion 10 ep @ 300 |",
            &format!("<span title=\"{LADDER_BEST}\">diffusion 40 ep @ 3000</span>, scripted, "),
        );
        both(
            "| diffusion 40 ep @ 3000 | 3 | 1.000 (6 trials) |",
            &format!("<span title=\"{LADDER_WORST}\">diffusion 10 ep @ 300</span>"),
        );
        both(
            &format!("- diffusion 40 ep @ 3000: `{LADDER_BEST}`"),
            ">\ndiffusion 40 ep @ 3000\n</text>",
        );
        both(
            &format!("- diffusion 10 ep @ 300: `{LADDER_WORST}`"),
            ">\ndiffusion 10 ep @ 300\n</text>",
        );
        for shortened in ["diffusion 3fa9c2d1", "diffusion 77be01aa"] {
            assert!(
                !md.contains(shortened) && !html.contains(shortened),
                "{shortened}"
            );
        }
    }

    #[test]
    fn figures_are_named_by_proxy() {
        assert_eq!(ranking_figure(PROXY_SOURCE), RANKING_FIGURE);
        assert_eq!(
            ranking_figure(&judged_source("gpt-4o")),
            "ranking-gpt-4o.svg"
        );
        assert_eq!(ranking_figure(&judged_source("a/b c")), "ranking-a_b_c.svg");
    }

    #[test]
    fn a_frame_judge_that_saw_no_late_failure_is_cautioned_with_both_frames() {
        use crate::testing::{ranking_fixture, report_with_ranking};
        let render = |r: RankingResults| {
            let report = report_with_ranking(r);
            let html = crate::html::report_html(&crate::html::HtmlInputs {
                report: &report,
                artifact: &|_| None,
                human: None,
            });
            (report.to_markdown(), html)
        };
        // The fixture's judges saw "not done" at frame 40 of rollouts that may run to 60.
        let r = ranking_fixture();
        assert!(late_frame_cautions(&r).is_empty());
        let (md, html) = render(r.clone());
        assert!(!md.contains("Caution."), "{md}");
        assert!(!html.contains("Caution."));
        assert!(md.contains("| 40 / 60 |"), "{md}");
        // Half the budget seen is enough; less is cautioned, naming the group and both frames.
        let mut half = r.clone();
        half.groups[0].judge_latest_not_done = Some(30);
        half.groups[0].ranked_last_frame = Some(60);
        assert!(late_frame_cautions(&half).is_empty());
        let mut late = r.clone();
        late.groups[1].judge_latest_not_done = Some(30);
        late.groups[1].ranked_last_frame = Some(250);
        let cautions = late_frame_cautions(&late);
        assert_eq!(cautions.len(), 1, "{cautions:?}");
        let group = &late.groups[1].group;
        assert!(
            cautions[0].starts_with(&format!("{group}: "))
                && cautions[0].contains("no frame later than 30")
                && cautions[0].contains("run to frame 250"),
            "{}",
            cautions[0]
        );
        let (md, html) = render(late.clone());
        assert!(md.contains("**Caution.** "), "{md}");
        assert!(md.contains("| 30 / 250 |"), "{md}");
        assert!(html.contains("Caution. "));
        assert!(html.contains("no frame later than 30"));
        // A judge without any "not done" example is cautioned too; a report from before the
        // fields existed is not.
        let mut none = r.clone();
        none.groups[0].judge_latest_not_done = None;
        assert_eq!(late_frame_cautions(&none).len(), 1);
        assert!(late_frame_cautions(&none)[0].contains("from no frame at all"));
        let mut old = r;
        for g in &mut old.groups {
            g.judge_latest_not_done = None;
            g.ranked_last_frame = None;
        }
        assert!(late_frame_cautions(&old).is_empty());
    }
}
