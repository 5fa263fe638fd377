//! The action-conditioned video world model's settings (issue 44): the model itself lives in
//! `assay-trainer` (`video_model.rs`, libtorch); these are plain data so the coordinator and the
//! reports need no torch.

use serde::{Deserialize, Serialize};

/// Settings of the video world model. It works at the clips' frame size (square, a multiple of
/// 8). The defaults train in about 10 minutes on one CPU core with 64×64 frames; raise `depth`
/// and `steps` on a GPU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct VideoModelConfig {
    /// Channels of the first convolution (doubled at each of the 3 stride-2 stages).
    pub depth: i64,
    /// Width of the action embedding (Fourier features of each normalised action dimension
    /// through a two-layer MLP).
    pub action_embed: i64,
    /// Fourier frequencies per action dimension (`sin` and `cos` of `π·2^k·a`, k < this).
    pub fourier: usize,
    /// FiLM-conditioned residual blocks of the latent dynamics, per step.
    pub blocks: usize,
    /// Heat maps beside the decoder's inputs at the tool's place now and at the start, the
    /// place a learned linear map of the (predicted) state: where to draw the tool and where to
    /// paint it out.
    pub tool_heatmap: bool,
    /// Frames predicted open loop from each training window's real first frame.
    pub horizon: usize,
    /// Windows per training step.
    pub batch: usize,
    /// Training steps.
    pub steps: u64,
    /// Adam learning rate.
    pub lr: f64,
    /// The frames' error: `l1` (absolute, the default: sharper, where the squared error blurs
    /// what it is unsure of) or `l2` (squared).
    pub pixel_loss: PixelLoss,
    /// Weight of the state's squared error (normalised units) beside the frames'.
    pub state_weight: f64,
    /// Extra weight of the pixels that differ from the window's first frame (by more than 0.1
    /// in a channel) in the frame loss: what moved is a few percent of a frame, and the
    /// actions are what tells where it went (0: every pixel alike).
    pub motion_weight: f64,
    /// Seed of initialisation and of the windows each step draws.
    pub seed: u64,
    /// Training steps between checkpoints written to the artifact store (0: none).
    pub checkpoint_every: usize,
    /// Intra-op threads of libtorch on a CPU.
    /// Keep one count for every model a trainer runs (the defaults are all 1): beside a fit
    /// at another count, a fit's weights can change from run to run (measured in
    /// `workers/trainer/tests/diffusion.rs`).
    pub threads: usize,
    /// The side of the square frames the model works at (a multiple of 8): every camera of the
    /// clips is resized to it (area averaging) and its predictions back to the camera's size,
    /// composited over the camera's real start frame. 0: the first camera's size, which must
    /// then be square.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub image_size: u32,
    /// Weight of the scene objects' positions in the loss (their normalised squared error, as
    /// the state's): with a weight above 0 and clips that carry the objects' section
    /// (`Clip::objects`, the same objects in every clip), the model also predicts where each
    /// object is, from the real start and the actions, and its delta head reads the state it
    /// predicted last. What the proxy's object judge reads (`ProxyConfig::object_judge`).
    /// 0 (the default): frames and state only, as before.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub object_weight: f64,
}

pub(crate) fn is_zero(v: &u32) -> bool {
    *v == 0
}

fn is_zero_f64(v: &f64) -> bool {
    *v == 0.0
}

impl Default for VideoModelConfig {
    fn default() -> Self {
        Self {
            depth: 16,
            action_embed: 64,
            fourier: 4,
            blocks: 2,
            tool_heatmap: true,
            horizon: 8,
            batch: 8,
            steps: 6000,
            lr: 1e-3,
            pixel_loss: PixelLoss::L1,
            state_weight: 0.01,
            motion_weight: 10.0,
            seed: 0,
            checkpoint_every: 100,
            threads: 1,
            image_size: 0,
            object_weight: 0.0,
        }
    }
}

impl VideoModelConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.depth < 1 || self.action_embed < 1 || self.blocks == 0 {
            return Err(format!(
                "depth {}, action_embed {}, blocks {}: all must be at least 1",
                self.depth, self.action_embed, self.blocks
            ));
        }
        if !self.image_size.is_multiple_of(8) {
            return Err(format!(
                "image_size {}: a multiple of 8 (three stride-2 stages), or 0 for the clips' size",
                self.image_size
            ));
        }
        if self.horizon == 0 || self.batch == 0 {
            return Err(format!(
                "horizon {} and batch {} must be at least 1",
                self.horizon, self.batch
            ));
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(format!("lr {} is not a positive number", self.lr));
        }
        for (name, v) in [
            ("state_weight", self.state_weight),
            ("motion_weight", self.motion_weight),
            ("object_weight", self.object_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} {v} is not a number ≥ 0"));
            }
        }
        Ok(())
    }
}

/// The frame loss of the video model.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum PixelLoss {
    #[default]
    L1,
    L2,
}

/// The world model a proxy trains.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum WorldModelKind {
    /// The action-conditioned video model (`assay_trainer::video_model`).
    #[default]
    Video,
    /// The RSSM of dynamics diversity (`assay_trainer::world_model`).
    Rssm,
}

/// What one fit of the video model did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VideoFit {
    pub train_clips: u32,
    /// Training windows (every start with a following frame).
    pub windows: u64,
    pub steps: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resumed_from_step: Option<u64>,
    /// Mean loss of the last 100 steps trained in this run.
    pub final_train_loss: f64,
    pub steps_per_s: f64,
    pub device: String,
    pub config: VideoModelConfig,
}
