//! The world-model proxy of policy ranking (the video-world-model paper, §III): per task group,
//! a world model is trained on the episodes of *training* policies (never the ranked ones, as
//! the paper's footnote asks), each ranked episode is imagined from its first real frame, and a
//! frame judge decides from the last imagined frame whether the task was done. When the batch
//! has judges (VLMs), each imagined rollout's keyframes are also judged by the judge role, as the
//! paper does: every such judge is a proxy of its own. The predicted success rates R_S are then
//! ranked against the real ones R from the simulator ([`assay_stats::ranking`]). Plain data: the
//! models live in `assay-trainer`.

use serde::{Deserialize, Serialize};

use crate::dynamics::{DynamicsConfig, DynamicsFit};
use crate::episode::Keyframe;
use assay_stats::stats::Proportion;

/// Settings of the proxy: the world model and the frame judge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// An imagined episode judged by the judge role succeeds when its mean completion score
    /// (0–10) is at least this.
    pub completion_threshold: f64,
}

impl Default for ProxyConfig {
    fn default() -> Self {
        Self {
            world_model: DynamicsConfig::default(),
            judge_steps: 600,
            judge_lr: 1e-3,
            threshold: 0.5,
            completion_threshold: 5.0,
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
        if !(0.0..=10.0).contains(&self.completion_threshold) {
            return Err(format!(
                "completion_threshold: {} is outside [0, 10]",
                self.completion_threshold
            ));
        }
        Ok(())
    }
}

/// The ranking part of a batch: which of its policies only provide the world model's training
/// episodes (every other policy of the batch is ranked), and the proxy's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingPlan {
    pub train_policies: Vec<String>,
    #[serde(default)]
    pub config: ProxyConfig,
}

/// One episode the proxy uses: its dynamics clip in the artifact store and, for a training
/// episode only, its real outcome (the ranked episodes' outcomes never reach the trainer).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// The imagined rollout as the judge role sees it: [`IMAGINED_KEYFRAMES`] frames evenly
    /// spaced from the real first frame to the last imagined one, PNGs in the artifact store
    /// (`step` is the frame's index at the clip's rate, `camera` is `imagined`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub imagined_keyframes: Vec<Keyframe>,
}

/// Keyframes of an imagined rollout: as many as the completion prompt shows of a real one.
pub const IMAGINED_KEYFRAMES: usize = 8;

/// The `job` of a judge shard that judges an imagined rollout (not a real episode).
pub const IMAGINED_JUDGING: &str = "proxy imagined";

/// A judge's verdict on one ranked episode's imagined rollout.
#[derive(Debug, Clone, PartialEq)]
pub struct ImaginedJudgement {
    pub task_id: String,
    pub policy: String,
    pub seed: u64,
    pub judge: String,
    /// Mean completion score (0–10); Err when the judge shard failed or gave no score.
    pub completion: Result<f64, String>,
}

/// One judge's verdicts on the imagined rollouts of one (task, policy).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct JudgedProxy {
    pub judge: String,
    /// Rollouts whose mean completion reached `completion_threshold`.
    pub success: Proportion,
    pub mean_completion: Option<f64>,
}

/// The ranking source of a judge's verdicts on imagined rollouts.
pub fn judged_source(judge: &str) -> String {
    format!("{PROXY_SOURCE}+{judge}")
}

/// What the proxy job of one group reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// Per prediction, the imagined keyframes' RGB bytes (`image_size`², frame index first),
    /// before the job runner stores them and names them in `imagined_keyframes`.
    #[serde(skip)]
    pub imagined_frames: Vec<Vec<(u64, Vec<u8>)>>,
}

/// Source names of the ranking's success cells.
pub const REAL_SOURCE: &str = "sim";
pub const PROXY_SOURCE: &str = "world-model";
