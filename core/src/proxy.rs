//! The world-model proxy of policy ranking (the video-world-model paper, §III): per task group,
//! a world model is trained on the episodes of *training* policies (never the ranked ones, as
//! the paper's footnote asks), each ranked episode is imagined from its first real frame, and a
//! frame judge decides from the last imagined frame whether the task was done. The predicted
//! success rates R_S are then ranked against the real ones R from the simulator
//! ([`crate::ranking`]). Plain data: the models live in `assay-trainer`.

use serde::{Deserialize, Serialize};

use crate::dynamics::{DynamicsConfig, DynamicsFit};
use crate::ranking::{Cell, Ranking, RankingConfig, rank};
use crate::stats::Proportion;

/// Settings of the proxy: the world model and the frame judge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProxyConfig {
    /// The world model (the dynamics-diversity model and its settings).
    pub world_model: DynamicsConfig,
    /// Training steps of the frame judge (a small CNN on last frames, batch 16).
    pub judge_steps: u32,
    /// Adam learning rate of the frame judge.
    pub judge_lr: f64,
    /// An imagined episode succeeds when the judge's probability is at least this.
    pub threshold: f64,
}

impl Default for ProxyConfig {
    fn default() -> Self {
        Self {
            world_model: DynamicsConfig::default(),
            judge_steps: 600,
            judge_lr: 1e-3,
            threshold: 0.5,
        }
    }
}

impl ProxyConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.judge_steps == 0 {
            return Err("judge_steps: must be at least 1".into());
        }
        if !(self.judge_lr.is_finite() && self.judge_lr > 0.0) {
            return Err(format!(
                "judge_lr: {} is not a positive number",
                self.judge_lr
            ));
        }
        if !(0.0..=1.0).contains(&self.threshold) {
            return Err(format!("threshold: {} is outside [0, 1]", self.threshold));
        }
        Ok(())
    }
}

/// The ranking part of a batch: which of its policies only provide the world model's training
/// episodes (every other policy of the batch is ranked), and the proxy's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RankingPlan {
    pub train_policies: Vec<String>,
    #[serde(default)]
    pub config: ProxyConfig,
}

/// One episode the proxy uses: its dynamics clip in the artifact store and, for a training
/// episode only, its real outcome (the ranked episodes' outcomes never reach the trainer).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProxyEpisode {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    pub clip: String,
    /// The task's instruction (what a policy object is told when it acts in the world model).
    #[serde(default)]
    pub instruction: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub success: Option<bool>,
}

/// The proxy's verdict on one ranked episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProxyPrediction {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    /// The frame judge's probability of success on the last imagined frame.
    pub p_success: f64,
    /// `p_success ≥ threshold`.
    pub success: bool,
    /// The frame judge's probability on the episode's real last frame: compared with the real
    /// outcome, it separates the judge's errors from the world model's.
    pub p_success_real_frame: f64,
    /// Mean squared error per pixel-channel of the last imagined frame against the real one.
    pub last_frame_mse: f64,
}

/// What the proxy job of one group reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProxyResult {
    pub group: String,
    /// The world model's fit (its one-step error measured on the ranked episodes).
    pub world_model: DynamicsFit,
    /// Frame-judge training examples (real and imagined last frames of the training episodes)
    /// and how many of them were successes.
    pub judge_examples: u32,
    pub judge_positives: u32,
    /// The judge's accuracy on its own training examples.
    pub judge_train_accuracy: f64,
    pub predictions: Vec<ProxyPrediction>,
    /// Seconds the whole job took (world model, judge, imagination). Measured, so not
    /// serialised: a report's results are the same for the same batch (the trainer logs it).
    #[serde(skip)]
    pub seconds: f64,
}

/// One ranked episode as the report builder reads it from the store.
#[derive(Debug, Clone, PartialEq)]
pub struct RealEpisode {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    pub success: bool,
    /// Mean completion score (0–10) of the batch's judges on this episode, when judged.
    pub judged_completion: Option<f64>,
}

/// Real, proxy and judged success of one (task, ranked policy).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
}

/// The policy-ranking section of a report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RankingResults {
    pub train_policies: Vec<String>,
    pub ranked_policies: Vec<String>,
    pub rows: Vec<RankingRow>,
    /// Per group: the world model, the frame judge and every prediction.
    pub groups: Vec<ProxyResult>,
    /// Pearson, MMRV, Spearman and Kendall of the proxy against the real success rates, over the
    /// tasks whose proxy is done.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking: Option<Ranking>,
    /// Why there is no ranking yet (or at all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranking_missing: Option<String>,
    /// Of the ranked episodes the proxy judged: how often its verdict matches the real outcome,
    /// and how often the frame judge is right on the *real* last frames (its own error, without
    /// the world model's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proxy_agreement: Option<Proportion>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_agreement_real_frames: Option<Proportion>,
    /// Proxy jobs that failed: (group, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<(String, String)>,
}

/// Source names of the ranking's success cells.
pub const REAL_SOURCE: &str = "sim";
pub const PROXY_SOURCE: &str = "world-model";

/// The correlation plot written beside `report.md` (predicted against real success).
pub const RANKING_FIGURE: &str = "ranking.svg";

/// Bootstrap resamples of the report's ranking statistics.
pub const RANKING_RESAMPLES: usize = 2000;

/// Builds the ranking section: `episodes` are the finished episodes of the ranked policies,
/// `groups` the finished proxy jobs, `task_groups` (task id, group) in report order.
pub fn ranking_results(
    plan: &RankingPlan,
    ranked_policies: &[String],
    task_groups: &[(String, String)],
    episodes: &[RealEpisode],
    mut groups: Vec<ProxyResult>,
    errors: Vec<(String, String)>,
) -> RankingResults {
    let group_order = |g: &str| task_groups.iter().position(|(_, x)| x == g);
    groups.sort_by_key(|r| group_order(&r.group));
    let predictions: Vec<&ProxyPrediction> =
        groups.iter().flat_map(|g| g.predictions.iter()).collect();
    let mut rows = Vec::new();
    let mut cells = Vec::new();
    let mut agree = (0u64, 0u64);
    let mut judge_real = (0u64, 0u64);
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
                }
            }
            let proxy = (!preds.is_empty()).then(|| {
                Proportion::new(
                    preds.iter().filter(|p| p.success).count() as u64,
                    preds.len() as u64,
                )
            });
            let judged: Vec<f64> = eps.iter().filter_map(|e| e.judged_completion).collect();
            cells.push(Cell {
                task: task.clone(),
                policy: policy.clone(),
                source: REAL_SOURCE.into(),
                trials: Some(real.trials),
                successes: Some(real.successes),
                rate: real.rate.unwrap_or(0.0),
            });
            if let Some(p) = &proxy {
                cells.push(Cell {
                    task: task.clone(),
                    policy: policy.clone(),
                    source: PROXY_SOURCE.into(),
                    trials: Some(p.trials),
                    successes: Some(p.successes),
                    rate: p.rate.unwrap_or(0.0),
                });
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
            });
        }
    }
    let (ranking, ranking_missing) = if !cells.iter().any(|c| c.source == PROXY_SOURCE) {
        (None, Some("no proxy job has finished".to_owned()))
    } else {
        let cfg = RankingConfig {
            real: REAL_SOURCE.into(),
            proxies: vec![PROXY_SOURCE.into()],
            resamples: RANKING_RESAMPLES,
            seed: 0,
        };
        match rank(&cells, &cfg) {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(e)),
        }
    };
    RankingResults {
        train_policies: plan.train_policies.clone(),
        ranked_policies: ranked_policies.to_vec(),
        rows,
        groups,
        ranking,
        ranking_missing,
        proxy_agreement: (agree.1 > 0).then(|| Proportion::new(agree.0, agree.1)),
        judge_agreement_real_frames: (judge_real.1 > 0)
            .then(|| Proportion::new(judge_real.0, judge_real.1)),
        errors,
    }
}

impl RankingResults {
    /// The section of `report.md`.
    pub fn markdown(&self) -> String {
        let pct = |p: &Proportion| match p.rate {
            Some(r) => format!("{:.0} % ({}/{})", r * 100.0, p.successes, p.trials),
            None => "–".into(),
        };
        let mut out = format!(
            "Ranked: {}. World model and frame judge trained on the episodes of: {}.\n\n",
            self.ranked_policies.join(", "),
            self.train_policies.join(", ")
        );
        out.push_str("| task | policy | real (sim) | world-model proxy | proxy mean p | judged completion |\n|---|---|---:|---:|---:|---:|\n");
        for r in &self.rows {
            out.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} |\n",
                r.task_id,
                r.policy,
                pct(&r.real),
                r.proxy.as_ref().map_or("–".into(), pct),
                r.proxy_mean_p.map_or("–".into(), |p| format!("{p:.2}")),
                r.judged_completion
                    .map_or("–".into(), |c| format!("{c:.1}")),
            ));
        }
        out.push('\n');
        if let Some(a) = &self.proxy_agreement {
            out.push_str(&format!(
                "Proxy verdicts matching the real outcome: {}.",
                pct(a)
            ));
        }
        if let Some(a) = &self.judge_agreement_real_frames {
            out.push_str(&format!(
                " The frame judge on the real last frames: {} (its own error, without the world model's).",
                pct(a)
            ));
        }
        out.push_str("\n\n| group | world-model steps | one-step image MSE ×10³ | judge examples (successes) | judge train accuracy | mean last-frame MSE ×10³ |\n|---|---:|---:|---:|---:|---:|\n");
        for g in &self.groups {
            let mse = g.predictions.iter().map(|p| p.last_frame_mse).sum::<f64>()
                / g.predictions.len().max(1) as f64;
            out.push_str(&format!(
                "| {} | {} | {:.3} | {} ({}) | {:.2} | {:.3} |\n",
                g.group,
                g.world_model.steps,
                g.world_model.eval_image_mse * 1e3,
                g.judge_examples,
                g.judge_positives,
                g.judge_train_accuracy,
                mse * 1e3,
            ));
        }
        out.push('\n');
        match (&self.ranking, &self.ranking_missing) {
            (Some(r), _) => {
                out.push_str(&r.markdown());
                if !r.comparisons.is_empty() {
                    out.push_str(&format!(
                        "\n![predicted against real success, one point per policy]({RANKING_FIGURE})\n"
                    ));
                }
            }
            (None, Some(why)) => out.push_str(&format!("No ranking: {why}.\n")),
            (None, None) => {}
        }
        for (group, e) in &self.errors {
            out.push_str(&format!("\nProxy of group {group} failed: {e}\n"));
        }
        out
    }
}
