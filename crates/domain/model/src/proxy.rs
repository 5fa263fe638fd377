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
use crate::video::{VideoFit, VideoModelConfig, WorldModelKind};
use assay_stats::stats::Proportion;

/// Settings of the proxy: the world model and the frame judge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ProxyConfig {
    /// Which world model the proxy trains: the action-conditioned video model (`video`, the
    /// default) or the RSSM of dynamics diversity (`rssm`).
    pub model: WorldModelKind,
    /// The video model's settings (`model = "video"`).
    pub video: VideoModelConfig,
    /// The RSSM's settings (`model = "rssm"`; the dynamics-diversity model). Its `seed` also
    /// seeds the frame judge, whichever model imagines.
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
    /// The imagination of a ranked episode stops, as a success, once the frame judge gives this
    /// many consecutive imagined frames a probability of at least `threshold`; otherwise it runs
    /// for the task's whole step budget. Never the real episode's length.
    pub done_frames: u32,
    /// Where the frame judge's "not done" examples lie in each training episode, as fractions
    /// of its length (0.5: its middle frame; 0: its first imagined frame, frame 1), real and
    /// replayed frames alike. Every frame before an episode's last is not done — the simulator
    /// ends an episode at its success — so each fraction in [0, 1) is a true label; the last
    /// frame is labelled with the outcome whatever this says.
    #[serde(skip_serializing_if = "is_default_not_done")]
    pub judge_not_done: Vec<f64>,
    /// Ablation: also imagine every ranked episode for exactly as many frames as its real
    /// episode had and judge that last frame — the leak of the real outcome through the
    /// episode's length, restored on purpose to measure what it is worth. Reported as a proxy
    /// of its own ([`LEAK_SOURCE`]), never as the proxy.
    pub leak_ablation: bool,
    /// Ablation across the ladder's families (the paper's rollouts of policies never ranked):
    /// for each family of ranked ladder policies, a second video model of the same settings is
    /// trained on the world model's training episodes **and the other families' ranked
    /// episodes** (their clips; never their outcomes), imagines that family's episodes, and a
    /// frame judge trained as the proxy's, on this model's replays of the training episodes,
    /// calls them done. Reported as a proxy of its own
    /// ([`CROSS_FAMILY_SOURCE`]), never as the proxy. Costs one more fit per family and group;
    /// needs the video model and ranked policies of two or more families.
    pub cross_family_ablation: bool,
    /// Cross-fitting over the ranked policies (0: off; else at least 2): the ranked policies
    /// are dealt into this many folds (each family's in turn, in order of first appearance, so
    /// every fold holds policies of every family), and each fold's episodes are imagined by a
    /// video model of the proxy's settings trained on the world model's training episodes
    /// **and the other folds' ranked episodes** (their clips; never their outcomes), with a
    /// frame judge of its own trained as the proxy's. No policy is imagined by a model that saw
    /// its episodes; every model has seen rollouts of learned policies — the paper's recipe,
    /// with the ranked policies' siblings as the rollouts. Reported as a proxy of its own
    /// ([`CROSS_FIT_SOURCE`]) beside the proxy. Costs one more fit per fold and group; needs
    /// the video model.
    pub cross_fit_folds: u32,
    /// Also judge every ranked episode by the state and the scene objects' positions the video
    /// model predicts (`video.object_weight` above 0, clips with the objects' section), not by
    /// its frames: a logistic regression on the objects' heights and pairwise distances, fitted
    /// on the frame judge's examples (the training episodes' last frames with their outcome,
    /// earlier ones not done, real and replayed), stops each ranked rollout as the frame judge
    /// does. Reported as a proxy of its own ([`OBJECTS_SOURCE`]) beside the frame judge's.
    /// Costs a second imagination of every ranked episode.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub object_judge: bool,
    /// Normalize the RSSM's actions (zero mean, unit deviation per dimension over the training
    /// clips) before they enter it.
    pub normalize_actions: bool,
    /// A world model served over `assay.v1.WorldModel` (any lab's model) instead of the RSSM
    /// the proxy trains on the training episodes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub external: Option<ExternalWorldModel>,
    /// The policy interface the batch's clips are recorded at, as policy-spec arguments
    /// (`space=ee_delta,cameras=scene:scene@64+wrist:wrist@32,state=ee_pos+ee_quat+gripper`;
    /// cameras without a size are `world_model.image_size` square): the ranked policies'
    /// interface, which the video model then learns and imagines at. Empty: the original
    /// interface (the task camera, tool position and holding, tool velocities).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub interface: String,
    /// The training policies whose episodes train the world model; empty: all of them. The
    /// frame judge and its calibration learn from every training policy's episodes whatever
    /// this says. The paper's ablation "without rollouts": `["oracle"]`, the demonstrations
    /// alone.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub world_model_policies: Vec<String>,
}

impl ProxyConfig {
    /// Whether `policy`'s episodes train the world model (see `world_model_policies`).
    pub fn trains_world_model(&self, policy: &str) -> bool {
        self.world_model_policies.is_empty()
            || self.world_model_policies.iter().any(|p| p == policy)
    }
}

/// A world model behind the `assay.v1.WorldModel` gRPC service.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ExternalWorldModel {
    /// `http://host:port` of the server.
    pub url: String,
    /// Deadline of every call, milliseconds (a late answer fails the call as unavailable).
    #[serde(default = "default_world_timeout_ms")]
    pub timeout_ms: u64,
}

/// The frame judge's "not done" examples by default: a quarter and half of each episode.
pub const JUDGE_NOT_DONE: [f64; 2] = [0.25, 0.5];

fn is_default_not_done(at: &Vec<f64>) -> bool {
    at.as_slice() == JUDGE_NOT_DONE
}

fn default_world_timeout_ms() -> u64 {
    30_000
}

impl Default for ProxyConfig {
    fn default() -> Self {
        Self {
            model: WorldModelKind::default(),
            video: VideoModelConfig::default(),
            world_model: DynamicsConfig::default(),
            judge_steps: 600,
            judge_lr: 1e-3,
            threshold: 0.5,
            completion_threshold: 5.0,
            done_frames: 2,
            judge_not_done: JUDGE_NOT_DONE.to_vec(),
            leak_ablation: false,
            cross_family_ablation: false,
            cross_fit_folds: 0,
            object_judge: false,
            normalize_actions: true,
            external: None,
            interface: String::new(),
            world_model_policies: Vec::new(),
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
        if self.done_frames == 0 {
            return Err("done_frames: must be at least 1".into());
        }
        if let Some(f) = self
            .judge_not_done
            .iter()
            .find(|f| !(0.0..1.0).contains(*f))
        {
            return Err(format!(
                "judge_not_done: {f} is outside [0, 1) (a fraction of the episode before its last \
                 frame)"
            ));
        }
        if self.external.is_none() && self.model == WorldModelKind::Video {
            self.video.validate().map_err(|e| format!("video: {e}"))?;
        }
        if let Some(e) = &self.external {
            if !(e.url.starts_with("http://") || e.url.starts_with("https://")) {
                return Err(format!(
                    "external.url: {:?} is not an http:// or https:// URL",
                    e.url
                ));
            }
            if e.timeout_ms == 0 {
                return Err("external.timeout_ms: must be at least 1".into());
            }
        }
        if self.object_judge
            && (self.external.is_some()
                || self.model != WorldModelKind::Video
                || self.video.object_weight <= 0.0)
        {
            return Err(
                "object_judge: it reads the objects' positions Assay's video model predicts; it \
                 needs model \"video\" with video.object_weight above 0"
                    .into(),
            );
        }
        if self.cross_family_ablation
            && (self.external.is_some() || self.model != WorldModelKind::Video)
        {
            return Err(
                "cross_family_ablation: the ablation fits Assay's video model again; it needs \
                 model = \"video\" and no external world model"
                    .into(),
            );
        }
        if self.cross_fit_folds == 1 {
            return Err(
                "cross_fit_folds: 1 fold would imagine every policy by a model that saw it; \
                 use 0 (off) or at least 2"
                    .into(),
            );
        }
        if self.cross_fit_folds > 0
            && (self.external.is_some() || self.model != WorldModelKind::Video)
        {
            return Err(
                "cross_fit_folds: cross-fitting fits Assay's video model again; it needs \
                 model = \"video\" and no external world model"
                    .into(),
            );
        }
        let interface = crate::interface::Interface::parse_args(&self.interface)
            .map_err(|e| format!("interface: {e}"))?;
        if !interface.is_legacy() && self.external.is_none() && self.model == WorldModelKind::Rssm {
            return Err(
                "interface: the RSSM (model = \"rssm\") learns only the original interface; \
                 use the video model or a served one"
                    .into(),
            );
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
    /// Learned policies the cluster trains to be ranked (a ladder of diffusion policies).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ladder: Option<LadderPlan>,
    /// The task groups ranked (their world models, frame judges and ladders); empty: every
    /// group of the batch. A ranking costs minutes per group, and only a group whose tasks one
    /// policy can learn gives a ladder that spreads.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub groups: Vec<String>,
}

impl RankingPlan {
    /// Whether `group` is ranked.
    pub fn covers(&self, group: &str) -> bool {
        self.groups.is_empty() || self.groups.iter().any(|g| g == group)
    }
}

/// A ladder of learned policies to rank, as the video-world-model paper ranks checkpoints:
/// per task group and per family in `backbones`, one diffusion policy is trained on the first `n`
/// episodes of `train_policy` for every `n` in `episodes`, and kept at every step in
/// `checkpoints` — `backbones.len() × episodes.len() × checkpoints.len()` policies of differing
/// skill (the paper's: CNN- and transformer-based diffusion policies at several lengths). Each
/// runs in the simulator on every (task, seed) of the group (its real success) and is ranked by
/// the proxy — except those kept at `train_checkpoints` and every one of the runs of
/// `train_episodes`, whose episodes only train the proxy. With `held_out_seeds`, the policies
/// run on that many seeds per task that no episode of the batch used instead (numbered from
/// `held_out_seed_base`): layouts none of their demonstrations had, nor any episode the world
/// model learnt from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct LadderPlan {
    /// Whose episodes the policies imitate.
    pub train_policy: String,
    /// Training episodes of each run (the group's first ones in planning order).
    pub episodes: Vec<u32>,
    /// Training steps at which each run's policy is kept and ranked (the run is as long as the
    /// last of these and `train_checkpoints`).
    pub checkpoints: Vec<u64>,
    /// Training steps at which each run's policy is kept for the proxy's **training** only: its
    /// episodes run in the simulator and join the training policies' (the world model learns
    /// their clips; the frame judge and its calibration their outcomes too), and it is never
    /// ranked. The paper's world model learns from rollouts of learned policies that are not
    /// evaluated with it; these are such policies, of the ranked ones' families. Disjoint from
    /// `checkpoints`. Empty (the default): every kept policy is ranked.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub train_checkpoints: Vec<u64>,
    /// Training episodes of more runs whose policies, at every kept step, only train the proxy
    /// (as `train_checkpoints`' do): rollouts of learned policies trained on other data than
    /// any ranked one. Disjoint from `episodes`. Empty (the default): none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub train_episodes: Vec<u32>,
    /// Horizon of the policies' episodes, physics steps (the task's own budget when smaller).
    pub max_steps: u32,
    /// The policy families: the denoiser each run is trained with (`config.backbone` is
    /// replaced by each in turn). Default: the U-Net alone.
    #[serde(skip_serializing_if = "LadderPlan::unet_only")]
    pub backbones: Vec<crate::diffusion::Backbone>,
    pub config: crate::diffusion::DiffusionConfig,
    /// Seeds per task the policies run on instead of the batch's, numbered from
    /// `held_out_seed_base`: their real success measured where they must generalise, not on
    /// their demonstrations' own layouts (the batch's first seeds, which they imitate). 0 (the
    /// default): the batch's seeds.
    #[serde(skip_serializing_if = "crate::video::is_zero")]
    pub held_out_seeds: u32,
    #[serde(skip_serializing_if = "LadderPlan::default_base")]
    pub held_out_seed_base: u64,
}

impl Default for LadderPlan {
    fn default() -> Self {
        Self {
            train_policy: "oracle".into(),
            episodes: vec![10, 40],
            checkpoints: vec![300, 1000, 3000],
            train_checkpoints: Vec::new(),
            train_episodes: Vec::new(),
            max_steps: 6000,
            backbones: vec![crate::diffusion::Backbone::Unet],
            config: crate::diffusion::DiffusionConfig::default(),
            held_out_seeds: 0,
            held_out_seed_base: LADDER_HELD_OUT_SEED_BASE,
        }
    }
}

/// Where a ladder's held-out seeds start by default: far from any batch's own seeds.
pub const LADDER_HELD_OUT_SEED_BASE: u64 = 1_000_000;

impl LadderPlan {
    pub fn validate(&self) -> Result<(), String> {
        if self.episodes.is_empty() || self.episodes.iter().any(|&n| n < 2) {
            return Err("ladder.episodes: one or more runs of at least 2 episodes".into());
        }
        if self.checkpoints.is_empty() || self.checkpoints.contains(&0) {
            return Err("ladder.checkpoints: one or more steps, each at least 1".into());
        }
        if self.train_episodes.iter().any(|&n| n < 2) {
            return Err("ladder.train_episodes: each run of at least 2 episodes".into());
        }
        if let Some(n) = self
            .train_episodes
            .iter()
            .find(|n| self.episodes.contains(n))
        {
            return Err(format!(
                "ladder.train_episodes: {n} is also in ladder.episodes (a policy that trained the \
                 proxy cannot be ranked by it)"
            ));
        }
        if self.train_checkpoints.contains(&0) {
            return Err("ladder.train_checkpoints: each step at least 1".into());
        }
        if let Some(step) = self
            .train_checkpoints
            .iter()
            .find(|s| self.checkpoints.contains(s))
        {
            return Err(format!(
                "ladder.train_checkpoints: step {step} is also in ladder.checkpoints (a policy \
                 that trained the proxy cannot be ranked by it)"
            ));
        }
        if self.max_steps == 0 {
            return Err("ladder.max_steps: must be at least 1".into());
        }
        if self.backbones.is_empty() {
            return Err("ladder.backbones: one or more families (unet, transformer)".into());
        }
        if self.held_out_seeds > 0
            && !crate::generalization::seeds_fit(self.held_out_seed_base, self.held_out_seeds)
        {
            return Err(format!(
                "ladder.held_out_seed_base: {} + {} held-out seeds passes the largest seed",
                self.held_out_seed_base, self.held_out_seeds
            ));
        }
        self.config
            .validate()
            .map_err(|e| format!("ladder.config.{e}"))
    }

    fn unet_only(backbones: &Vec<crate::diffusion::Backbone>) -> bool {
        backbones == &[crate::diffusion::Backbone::Unet]
    }

    fn default_base(base: &u64) -> bool {
        *base == LADDER_HELD_OUT_SEED_BASE
    }

    /// The seeds the ladder's policies run on: its held-out seeds, or else the batch's.
    pub fn episode_seeds(&self, batch_seeds: &[u64]) -> Vec<u64> {
        if self.held_out_seeds == 0 {
            return batch_seeds.to_vec();
        }
        (0..u64::from(self.held_out_seeds))
            .map(|k| self.held_out_seed_base + k)
            .collect()
    }

    /// Each family once, in the order given.
    pub fn families(&self) -> Vec<crate::diffusion::Backbone> {
        let mut out = Vec::new();
        for b in &self.backbones {
            if !out.contains(b) {
                out.push(*b);
            }
        }
        out
    }

    /// Every step a run keeps its policy at, ranked or training-only, ascending, each once; the
    /// last is the run's length.
    pub fn kept_steps(&self) -> Vec<u64> {
        let mut steps: Vec<u64> = self
            .checkpoints
            .iter()
            .chain(&self.train_checkpoints)
            .copied()
            .collect();
        steps.sort_unstable();
        steps.dedup();
        steps
    }

    /// Every run's training episodes, ranked or training-only, ascending, each once.
    pub fn runs(&self) -> Vec<u32> {
        let mut runs: Vec<u32> = self
            .episodes
            .iter()
            .chain(&self.train_episodes)
            .copied()
            .collect();
        runs.sort_unstable();
        runs.dedup();
        runs
    }

    /// Whether some kept policies only train the proxy (`train_checkpoints`, `train_episodes`).
    pub fn has_training_only(&self) -> bool {
        !self.train_checkpoints.is_empty() || !self.train_episodes.is_empty()
    }

    /// Whether the policy kept at `step` by the run that trained on `clips` clips only trains
    /// the proxy. A run asked for more episodes than its group has trains on all of them (and
    /// larger runs are left out), so the run of a fit is the smallest of [`Self::runs`] of at
    /// least `clips`.
    pub fn trains_only(&self, clips: u32, step: u64) -> bool {
        let run = self.runs().into_iter().find(|&n| n >= clips);
        self.train_checkpoints.contains(&step)
            || run.is_some_and(|n| self.train_episodes.contains(&n))
    }

    /// The policy name of a kept model's episodes (its horizon is the ladder's); the report's
    /// ladder labels name the policies by it.
    pub fn policy_name(&self, model: &str) -> String {
        format!("diffusion:model={model},max_steps={}", self.max_steps)
    }
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
    /// Physics steps the episode may run: the task's `physics.max_steps`, or the policy's
    /// `max_steps` when smaller. A ranked episode's imagination runs this long at most (in clip
    /// frames), whatever its real episode did.
    #[serde(default)]
    pub budget_steps: u32,
    /// The family of a ranked ladder policy (`unet`, `transformer`: its denoiser); empty for
    /// every other episode. The cross-family ablation groups the ranked episodes by it.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub family: String,
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
    /// Clip frames imagined (the first, real one included).
    #[serde(default)]
    pub imagined_frames: u32,
    /// Whether the frame judge stopped the imagination (`done_frames` frames in a row judged
    /// done) before the task's step budget ran out.
    #[serde(default)]
    pub done_by_judge: bool,
    /// `p_success` through the group's [`Calibration`] (fitted on the training policies'
    /// episodes only): a probability of real success. Absent without a calibration.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p_calibrated: Option<f64>,
    /// The ablation of `ProxyConfig::leak_ablation`: the verdict when imagining exactly as many
    /// frames as the real episode had.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub leak: Option<LeakVerdict>,
    /// The ablation of `ProxyConfig::cross_family_ablation`: the verdict when the episode is
    /// imagined by the world model trained with the other families' episodes (as the proxy
    /// imagines: until the judge calls it done or the step budget runs out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cross_family: Option<HeldOutVerdict>,
    /// The verdict of `ProxyConfig::cross_fit_folds`: the episode imagined by the model of its
    /// policy's fold, trained with the other folds' episodes (as the proxy imagines).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cross_fit: Option<HeldOutVerdict>,
    /// The verdict of `ProxyConfig::object_judge`: the episode imagined by the proxy's world
    /// model again, stopped and judged by the object judge on the predicted state and objects.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object_judge: Option<HeldOutVerdict>,
    /// The imagined rollout as the judge role sees it: [`IMAGINED_KEYFRAMES`] frames evenly
    /// spaced from the real first frame to the last imagined one, PNGs in the artifact store
    /// (`step` is the frame's index at the clip's rate, `camera` is `imagined`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub imagined_keyframes: Vec<Keyframe>,
}

/// The frame judge's verdict on the last frame of a rollout imagined for the real episode's
/// length (the leak ablation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LeakVerdict {
    pub p_success: f64,
    pub success: bool,
}

/// A verdict on one ranked episode beside the proxy's: of a world model that never saw its
/// policy's episodes (the cross-family ablation, cross-fitting), judged by that model's own
/// frame judge, or of the object judge (`p_success` is then the object judge's probability).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct HeldOutVerdict {
    /// The frame judge's probability on the last imagined frame.
    pub p_success: f64,
    /// Whether the judge called the imagined rollout done (`done_frames` in a row).
    pub success: bool,
    /// Clip frames imagined (the first, real one included).
    pub imagined_frames: u32,
}

/// One world model of the cross-family ablation: the family it ranks and what it learned from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CrossFamilyFit {
    /// The family whose episodes it imagines.
    pub family: String,
    /// The families whose ranked episodes it was trained on, besides the training episodes.
    pub trained_with: Vec<String>,
    /// Clips it was trained on: the world model's training clips and those families'.
    pub train_clips: u32,
    pub final_train_loss: f64,
    /// The training accuracy of its own frame judge (trained as the proxy's, on the training
    /// episodes' real frames and their replays in this model). Absent in reports before the
    /// ablation had its own judge (it used the proxy's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_train_accuracy: Option<f64>,
    /// Its action test on the ranked family's own clips (policies it never saw).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub action_test: Option<ActionTest>,
}

/// One fold's world model of cross-fitting (`ProxyConfig::cross_fit_folds`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CrossFitFold {
    /// The fold's index, from 0.
    pub fold: u32,
    /// The ranked policies it imagines (those of its fold).
    pub policies: Vec<String>,
    /// The ranked policies whose episodes it was trained on, besides the training episodes.
    pub trained_with: Vec<String>,
    /// Clips it was trained on: the world model's training clips and those policies'.
    pub train_clips: u32,
    pub final_train_loss: f64,
    /// The training accuracy of its own frame judge (on the training episodes' real frames and
    /// their replays in this model).
    pub judge_train_accuracy: f64,
    /// Its action test on its fold's clips (policies it never saw).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub action_test: Option<ActionTest>,
}

/// Whether the world model uses its actions, and how well it predicts video: on the ranked
/// episodes' real clips (policies the model never saw), cut into windows of `horizon` frames,
/// each imagined open loop from its real first frame and state with the window's true actions,
/// with the next episode's actions for the same window, and with zero actions. Errors are MSE
/// per pixel-channel in [0, 1] units over every imagined frame; PSNR and SSIM are those of the
/// true-action predictions (`assay_trainer::video_eval`). Reports before issue 44 imagined
/// each whole episode at once and had no zero-action, PSNR or SSIM figures (0 here).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ActionTest {
    pub episodes: u32,
    #[serde(default)]
    pub windows: u32,
    /// Imagined frames per window (0: the whole episode, before issue 44).
    #[serde(default)]
    pub horizon: u32,
    pub true_actions_mse: f64,
    pub shuffled_actions_mse: f64,
    #[serde(default)]
    pub zero_actions_mse: f64,
    #[serde(default)]
    pub psnr: f64,
    #[serde(default)]
    pub ssim: f64,
}

/// Keyframes of an imagined rollout: as many as the completion prompt shows of a real one.
pub const IMAGINED_KEYFRAMES: usize = 8;

/// The job name of a judge shard that judges an imagined rollout (not a real episode); its kind
/// is [`crate::job::JobKind::ImaginedJudging`].
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
    /// The completion score of each repeat that gave one, in repeat order (their mean is
    /// `completion`): their spread is the judge's repeat consistency on imagined rollouts.
    pub scores: Vec<f64>,
    /// Repeats asked (the judge's `repeats`, k); 0 when the shard gave no outcome.
    pub repeats: u32,
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
    /// The world model that imagined: Assay's RSSM, or the server's own name and URL.
    #[serde(default)]
    pub world_model_name: String,
    /// The world model's action test on the ranked episodes' real clips.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub action_test: Option<ActionTest>,
    /// The world model's fit (its one-step error measured on the ranked episodes); a served
    /// model's is empty, with `device` [`SERVED_DEVICE`]. For the video model, its training
    /// figures and one-step error, with `config` the (unused) RSSM settings; its own settings
    /// are in `video_model`.
    pub world_model: DynamicsFit,
    /// The video model's fit, when it imagined.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video_model: Option<VideoFit>,
    /// Frame-judge training examples (real and imagined last frames of the training episodes)
    /// and how many of them were successes.
    pub judge_examples: u32,
    pub judge_positives: u32,
    /// The judge's accuracy on its own training examples.
    pub judge_train_accuracy: f64,
    /// The object judge's accuracy on its own training examples (`ProxyConfig::object_judge`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object_judge_train_accuracy: Option<f64>,
    /// The latest clip frame (0 is the first) among the frame judge's "not done" examples: a
    /// failed training episode's last frame, or a frame a quarter or half through one. A judge
    /// that never saw a late frame of a failure may call any late imagined frame done (absent
    /// when it has no such example, and before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_latest_not_done: Option<u32>,
    /// The last clip frame a ranked rollout may reach: its step budget in clip frames, the
    /// longest of the group's ranked episodes (absent before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranked_last_frame: Option<u32>,
    /// The map from the frame judge's probability on an imagined last frame to a probability of
    /// real success, fitted on the training episodes only (absent when they are fewer than 4,
    /// all successes or all failures, or before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Calibration>,
    /// The cross-family ablation's world models, one per family ranked (empty without it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cross_family: Vec<CrossFamilyFit>,
    /// Cross-fitting's world models, one per fold that has policies (empty without it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cross_fit: Vec<CrossFitFold>,
    pub predictions: Vec<ProxyPrediction>,
    /// Seconds the whole job took (world model, judge, imagination). Measured, so not
    /// serialised: a report's results are the same for the same batch (the trainer logs it).
    #[serde(skip)]
    pub seconds: f64,
    /// Per prediction, the imagined keyframes' RGB bytes (of the first camera, at
    /// `imagined_frame_size`; frame index first), before the job runner stores them and names
    /// them in `imagined_keyframes`.
    #[serde(skip)]
    pub imagined_frames: Vec<Vec<(u64, Vec<u8>)>>,
    /// Width and height of `imagined_frames`.
    #[serde(skip)]
    pub imagined_frame_size: (u32, u32),
}

/// Platt scaling of the frame judge, fitted on the training policies' episodes only (the ranked
/// episodes' outcomes never reach the trainer): `P(real success) = σ(a + b · logit(p))`, where `p`
/// is the judge's probability on the last frame of the episode imagined in the world model.
/// Each training episode's `p` is **out of fold**: the episodes are split in `folds` by their
/// index, a judge is trained on the others' frames (as the proxy's own judge is, same settings)
/// and judges the fold's replays (the world model driven by the episode's real actions for its
/// real length). `a` and `b` maximise the likelihood of the real outcomes with Platt's (1999)
/// targets `(positives + 1) / (positives + 2)` and `1 / (negatives + 2)`, which keep them finite
/// when the judge separates the classes. A ranked policy's calibrated success is the mean of its
/// episodes' calibrated probabilities.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Calibration {
    pub a: f64,
    pub b: f64,
    /// Training episodes it was fitted on, and how many of them succeeded.
    pub episodes: u32,
    pub positives: u32,
    pub folds: u32,
    /// Mean |calibrated probability − outcome| and the same for the uncalibrated out-of-fold
    /// probabilities, over the training episodes (in sample for the calibration).
    pub train_error: f64,
    pub train_error_uncalibrated: f64,
    /// The reliability diagrams ([`RELIABILITY_BINS`] bins) of the training episodes it was
    /// fitted on, in sample: their out-of-fold probabilities and the same calibrated, against
    /// their real outcomes. Beside the ranked episodes' diagrams (the report's), they tell what
    /// the calibration does where it was fitted from what it does on policies it never saw.
    /// Absent in reports before they were kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_reliability: Option<TrainReliability>,
}

/// [`Calibration::train_reliability`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TrainReliability {
    /// The out-of-fold frame-judge probabilities.
    pub raw: assay_stats::calibration::Reliability,
    /// The same through the calibration.
    pub calibrated: assay_stats::calibration::Reliability,
}

/// Equal-width probability bins of the proxy's reliability diagrams.
pub const RELIABILITY_BINS: usize = 5;

impl Calibration {
    /// The calibrated probability of a judge probability `p`.
    pub fn apply(&self, p: f64) -> f64 {
        let p = p.clamp(1e-4, 1.0 - 1e-4);
        let z = self.a + self.b * (p / (1.0 - p)).ln();
        1.0 / (1.0 + (-z).exp())
    }
}

/// Source names of the ranking's success cells.
pub const REAL_SOURCE: &str = "sim";
pub const PROXY_SOURCE: &str = "world-model";
/// `ProxyResult.world_model.device` of a served world model: nothing was trained, so the fit's
/// steps and one-step error say nothing (the action test gives its errors).
pub const SERVED_DEVICE: &str = "served";
/// The leak ablation's source (imagined for the real episode's length).
pub const LEAK_SOURCE: &str = "world-model-leak";
/// The frame judge's verdicts through the group's [`Calibration`]: per (task, policy), the
/// expected successes (the sum of the calibrated probabilities), rounded, of its episodes.
pub const CALIBRATED_SOURCE: &str = "world-model-calibrated";
/// The cross-family ablation's source (`ProxyConfig::cross_family_ablation`).
pub const CROSS_FAMILY_SOURCE: &str = "world-model-cross-family";
/// Cross-fitting's source (`ProxyConfig::cross_fit_folds`): each policy imagined by a model
/// trained with the other folds' ranked episodes.
pub const CROSS_FIT_SOURCE: &str = "world-model-cross-fit";
/// The object judge's source (`ProxyConfig::object_judge`): each ranked episode judged by the
/// state and objects the world model predicts.
pub const OBJECTS_SOURCE: &str = "world-model-objects";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_judges_not_done_fractions_serialise_only_when_set_and_lie_before_the_last_frame() {
        let default = ProxyConfig::default();
        assert_eq!(default.validate(), Ok(()));
        let json = serde_json::to_value(&default).unwrap();
        assert!(json.get("judge_not_done").is_none(), "{json}");
        let early: ProxyConfig =
            serde_json::from_str(r#"{"judge_not_done": [0, 0.25, 0.5, 0.75]}"#).unwrap();
        assert_eq!(early.validate(), Ok(()));
        assert_eq!(
            serde_json::to_value(&early).unwrap()["judge_not_done"],
            serde_json::json!([0.0, 0.25, 0.5, 0.75])
        );
        let last = ProxyConfig {
            judge_not_done: vec![0.5, 1.0],
            ..ProxyConfig::default()
        };
        assert_eq!(
            last.validate().unwrap_err(),
            "judge_not_done: 1 is outside [0, 1) (a fraction of the episode before its last frame)"
        );
    }

    /// A fit's run is the smallest run of at least its clips: a run asked for more episodes
    /// than its group has trained on all of them, and larger runs were left out.
    #[test]
    fn a_ladder_policy_trains_only_when_its_step_or_its_run_says_so() {
        let plan = LadderPlan {
            episodes: vec![10, 40],
            train_episodes: vec![5, 20],
            checkpoints: vec![300, 1000],
            train_checkpoints: vec![500],
            ..LadderPlan::default()
        };
        plan.validate().unwrap();
        assert_eq!(plan.runs(), [5, 10, 20, 40]);
        assert_eq!(plan.kept_steps(), [300, 500, 1000]);
        assert!(plan.has_training_only());
        let only = |clips, step| plan.trains_only(clips, step);
        assert_eq!(
            [
                only(10, 300),
                only(10, 500),
                only(5, 1000),
                only(20, 300),
                only(40, 1000)
            ],
            [false, true, true, true, false]
        );
        // A group of 15 clips: the 20-run trained on 15 (training-only), the 40-run left out.
        assert!(only(15, 1000));
        // A group of 8: the 10-run trained on 8 (ranked).
        assert!(!only(8, 1000));
        assert!(!LadderPlan::default().has_training_only());
        assert!(!LadderPlan::default().trains_only(10, 300));
        let e = LadderPlan {
            train_episodes: vec![1],
            ..LadderPlan::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.starts_with("ladder.train_episodes: each run"), "{e}");
    }

    /// The ladder's policies run on the batch's seeds, or on its held-out seeds alone; held-out
    /// seeds past the largest seed a shard can hold are refused; the default plan serialises as
    /// before (no held-out field).
    #[test]
    fn a_ladder_runs_on_its_held_out_seeds_when_it_has_them() {
        assert_eq!(LadderPlan::default().episode_seeds(&[0, 1]), [0, 1]);
        let held_out = LadderPlan {
            held_out_seeds: 2,
            ..LadderPlan::default()
        };
        held_out.validate().unwrap();
        assert_eq!(held_out.episode_seeds(&[0, 1, 2]), [1_000_000, 1_000_001]);
        let e = LadderPlan {
            held_out_seed_base: i64::MAX as u64,
            ..held_out.clone()
        }
        .validate()
        .unwrap_err();
        assert!(e.starts_with("ladder.held_out_seed_base"), "{e}");
        let json = serde_json::to_value(LadderPlan::default()).unwrap();
        assert!(json.get("held_out_seeds").is_none() && json.get("held_out_seed_base").is_none());
        let back: LadderPlan =
            serde_json::from_value(serde_json::to_value(&held_out).unwrap()).unwrap();
        assert_eq!(back, held_out);
    }
}
