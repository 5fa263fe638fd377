//! Diffusion policies (Chi et al. 2023, "Diffusion Policy: Visuomotor Policy Learning via Action
//! Diffusion"): the settings the trainer role fits one with, and what a fit reports. The model
//! itself lives in `assay-trainer` (libtorch); these are plain data so the coordinator, the
//! simulator and reports need no torch.
//!
//! Time runs at the dynamics clips' control rate (10 Hz). At control step `t` the policy sees the
//! frames and proprioception of steps `t − obs_horizon + 1 ..= t` and predicts `pred_horizon`
//! actions starting at step `t − obs_horizon + 1` (Chi et al.'s alignment: the chunk begins with
//! the first observed step); the `action_horizon` of them from step `t` on (index
//! `obs_horizon − 1` of the chunk) are executed before it looks again (receding horizon).

use serde::{Deserialize, Serialize};

/// Diffusion-policy settings. The defaults are sized for a 2-core CPU: a small conv encoder
/// with a spatial softmax, a 1-D temporal U-Net of 1.3 M parameters (Chi et al.'s has about 65 M
/// at 256/512/1024), and 3000 training steps of 64 samples — about 0.1 CPU-seconds per step on
/// one core, 5 minutes for a run; a chunk takes about 12 ms to sample (10 DDIM steps). Raise
/// `down_dims`, `batch` and `steps` on a GPU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DiffusionConfig {
    /// Observed control steps per prediction, the current one included (Chi et al.: 2).
    pub obs_horizon: usize,
    /// Actions predicted per chunk (Chi et al.: 16). A multiple of 2^(levels − 1) of the U-Net
    /// (`down_dims.len()` levels), and at least `obs_horizon − 1 + action_horizon`.
    pub pred_horizon: usize,
    /// Actions executed per chunk, from the current step on (Chi et al.: 8).
    pub action_horizon: usize,
    /// Frame size of the clips and observations (square), pixels; a multiple of 8.
    pub image_size: u32,
    /// Diffusion steps of the training (DDPM) schedule (Chi et al.: 100).
    pub train_timesteps: usize,
    /// Denoising steps at inference (DDIM, eta 0; Chi et al. used 10 for real-time control).
    pub inference_steps: usize,
    /// Training steps (one batch each).
    pub steps: u64,
    /// Samples (clip, step) per training step, drawn uniformly with replacement.
    pub batch: usize,
    /// Adam learning rate.
    pub lr: f64,
    /// Ceiling of the EMA decay of the weights used for inference; the decay warms up as
    /// `1 − (1 + step)^−0.75` (Chi et al.'s EMA schedule) until it reaches this.
    pub ema_decay: f64,
    /// Seed of initialisation, batch sampling, training noise and (with the episode) inference.
    pub seed: u64,
    /// Channels of the image encoder's first convolution (doubled at each of its 3 stride-2
    /// stages).
    pub encoder_depth: i64,
    /// Keypoints of the encoder's spatial softmax (Chi et al.: 32), each an expected (x, y).
    pub keypoints: i64,
    /// Image features per observed frame (the encoder's output, before the proprioception is
    /// appended).
    pub obs_features: i64,
    /// Channels of the U-Net's levels (Chi et al.: 256, 512, 1024); each a multiple of `groups`.
    pub down_dims: Vec<i64>,
    /// Width of the diffusion-step embedding (Chi et al.: 256).
    pub time_embed: i64,
    /// Temporal kernel size of the U-Net's convolutions (odd; Chi et al.: 5).
    pub kernel_size: i64,
    /// GroupNorm groups in the U-Net (Chi et al.: 8).
    pub groups: i64,
    /// Intra-op threads of libtorch while training on a CPU (1 is fastest for models this small
    /// on 2 cores).
    /// Keep one count for every model a trainer runs (the defaults are all 1): beside a fit
    /// at another count, a fit's weights can change from run to run (measured in
    /// `workers/trainer/tests/diffusion.rs`).
    pub threads: usize,
    /// The denoiser's family: Chi et al.'s 1-D temporal U-Net (the default; `down_dims`,
    /// `kernel_size`, `groups`) or their transformer (`transformer`). The video-world-model
    /// paper ranks policies of both.
    #[serde(skip_serializing_if = "Backbone::is_unet")]
    pub backbone: Backbone,
    /// The transformer denoiser's size (read when `backbone` is `transformer`).
    #[serde(skip_serializing_if = "TransformerSize::is_default")]
    pub transformer: TransformerSize,
}

/// The denoiser of a diffusion policy.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Backbone {
    /// Chi et al.'s `ConditionalUnet1D`: temporal convolutions with FiLM conditioning.
    #[default]
    Unet,
    /// Chi et al.'s `TransformerForDiffusion`: one token per action of the chunk, causal
    /// self-attention among them and cross-attention to a token of the diffusion step and one per
    /// observed step.
    Transformer,
}

impl Backbone {
    pub fn is_unet(&self) -> bool {
        *self == Backbone::Unet
    }

    pub fn as_str(&self) -> &'static str {
        match self {
            Backbone::Unet => "unet",
            Backbone::Transformer => "transformer",
        }
    }
}

/// The transformer denoiser's size (Chi et al.: 8 layers, 4 heads, 256 wide; here sized for a
/// CPU core, about the U-Net's training cost per step).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct TransformerSize {
    /// Decoder layers (self-attention, cross-attention, MLP; pre-norm).
    pub layers: i64,
    /// Attention heads; `width` is a multiple of it.
    pub heads: i64,
    /// Token width.
    pub width: i64,
}

impl Default for TransformerSize {
    fn default() -> Self {
        Self {
            layers: 4,
            heads: 4,
            width: 64,
        }
    }
}

impl TransformerSize {
    pub fn is_default(&self) -> bool {
        *self == TransformerSize::default()
    }
}

impl Default for DiffusionConfig {
    fn default() -> Self {
        Self {
            obs_horizon: 2,
            pred_horizon: 16,
            action_horizon: 8,
            image_size: 64,
            train_timesteps: 100,
            inference_steps: 10,
            steps: 3000,
            batch: 64,
            lr: 1e-3,
            ema_decay: 0.999,
            seed: 0,
            encoder_depth: 8,
            keypoints: 32,
            obs_features: 64,
            down_dims: vec![32, 64, 128],
            time_embed: 32,
            kernel_size: 5,
            groups: 8,
            threads: 1,
            backbone: Backbone::Unet,
            transformer: TransformerSize::default(),
        }
    }
}

impl DiffusionConfig {
    /// Checks the settings; the error names the field and why it is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if self.obs_horizon == 0 {
            return Err("obs_horizon: must be at least 1".into());
        }
        if self.action_horizon == 0 {
            return Err("action_horizon: must be at least 1".into());
        }
        if self.pred_horizon < self.obs_horizon - 1 + self.action_horizon {
            return Err(format!(
                "pred_horizon: {} is shorter than obs_horizon − 1 + action_horizon = {}",
                self.pred_horizon,
                self.obs_horizon - 1 + self.action_horizon
            ));
        }
        if self.down_dims.is_empty() {
            return Err("down_dims: at least one U-Net level is needed".into());
        }
        let factor = 1usize << (self.down_dims.len() - 1).min(16);
        if self.backbone == Backbone::Unet && !self.pred_horizon.is_multiple_of(factor) {
            return Err(format!(
                "pred_horizon: {} is not a multiple of {factor} (the U-Net halves it {} times)",
                self.pred_horizon,
                self.down_dims.len() - 1
            ));
        }
        if self.image_size == 0 || !self.image_size.is_multiple_of(8) {
            return Err(format!(
                "image_size: {} is not a positive multiple of 8 (three stride-2 stages)",
                self.image_size
            ));
        }
        if self.train_timesteps < 2 {
            return Err(format!(
                "train_timesteps: {} (at least 2)",
                self.train_timesteps
            ));
        }
        if self.inference_steps == 0 || self.inference_steps > self.train_timesteps {
            return Err(format!(
                "inference_steps: {} is not between 1 and train_timesteps ({})",
                self.inference_steps, self.train_timesteps
            ));
        }
        if self.steps == 0 {
            return Err("steps: must be at least 1".into());
        }
        if self.batch == 0 {
            return Err("batch: must be at least 1".into());
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(format!("lr: {} is not a positive number", self.lr));
        }
        if !(self.ema_decay.is_finite() && (0.0..1.0).contains(&self.ema_decay)) {
            return Err(format!("ema_decay: {} is not in [0, 1)", self.ema_decay));
        }
        if self.encoder_depth < 1 {
            return Err(format!(
                "encoder_depth: {} (must be positive)",
                self.encoder_depth
            ));
        }
        if self.keypoints < 1 {
            return Err(format!("keypoints: {} (must be positive)", self.keypoints));
        }
        if self.obs_features < 1 {
            return Err(format!(
                "obs_features: {} (must be positive)",
                self.obs_features
            ));
        }
        if self.groups < 1 {
            return Err(format!("groups: {} (must be positive)", self.groups));
        }
        if let Some(d) = self
            .down_dims
            .iter()
            .find(|&&d| d < 1 || d % self.groups != 0)
        {
            return Err(format!(
                "down_dims: {d} is not a positive multiple of groups ({})",
                self.groups
            ));
        }
        if self.time_embed < 2 || self.time_embed % 2 != 0 {
            return Err(format!(
                "time_embed: {} is not a positive even number (sines and cosines)",
                self.time_embed
            ));
        }
        if self.kernel_size < 1 || self.kernel_size % 2 == 0 {
            return Err(format!(
                "kernel_size: {} is not a positive odd number",
                self.kernel_size
            ));
        }
        let t = &self.transformer;
        if t.layers < 1 || t.heads < 1 || t.width < 1 {
            return Err(format!(
                "transformer: layers {}, heads {} and width {} must each be positive",
                t.layers, t.heads, t.width
            ));
        }
        if t.width % 2 != 0 {
            return Err(format!(
                "transformer.width: {} is not even (the diffusion step's sines and cosines)",
                t.width
            ));
        }
        if t.width % t.heads != 0 {
            return Err(format!(
                "transformer.width: {} is not a multiple of heads ({})",
                t.width, t.heads
            ));
        }
        Ok(())
    }
}

/// What one diffusion-policy training run reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DiffusionFit {
    pub steps: u64,
    /// Training loss (MSE of the predicted noise) of the last step.
    pub final_loss: f64,
    /// Mean training loss over the last 100 steps (all of them when fewer).
    pub mean_last_100_loss: f64,
    /// Wall-clock seconds of the training loop. Measured, so not serialised: a report's results
    /// are the same for the same batch (the trainer logs it).
    #[serde(skip)]
    pub train_seconds: f64,
    /// Trainable parameters (image encoder, step embedding and U-Net).
    pub parameters: u64,
    /// Clips trained on.
    pub clips: u32,
    /// Training samples: every (clip, step) pair with a following frame.
    pub samples: u64,
    /// The device it ran on (`cpu`, `cuda:0`).
    pub device: String,
    /// The libtorch it ran with (`2.13.0`; empty in reports written before it was kept).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub libtorch: String,
    pub config: DiffusionConfig,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_errors_name_the_field() {
        DiffusionConfig::default().validate().unwrap();
        let with = |f: fn(&mut DiffusionConfig)| {
            let mut c = DiffusionConfig::default();
            f(&mut c);
            c.validate().unwrap_err()
        };
        assert!(with(|c| c.obs_horizon = 0).starts_with("obs_horizon"));
        assert!(with(|c| c.action_horizon = 16).starts_with("pred_horizon"));
        assert!(with(|c| c.pred_horizon = 18).starts_with("pred_horizon"));
        assert!(with(|c| c.image_size = 60).starts_with("image_size"));
        assert!(with(|c| c.inference_steps = 101).starts_with("inference_steps"));
        assert!(with(|c| c.ema_decay = 1.0).starts_with("ema_decay"));
        assert!(with(|c| c.down_dims = vec![32, 60]).starts_with("down_dims"));
        assert!(with(|c| c.down_dims.clear()).starts_with("down_dims"));
        assert!(with(|c| c.kernel_size = 4).starts_with("kernel_size"));
        assert!(with(|c| c.lr = f64::NAN).starts_with("lr"));
        assert!(with(|c| c.batch = 0).starts_with("batch"));
        assert!(with(|c| c.steps = 0).starts_with("steps"));
        assert!(with(|c| c.keypoints = 0).starts_with("keypoints"));
        assert!(with(|c| c.time_embed = 31).starts_with("time_embed"));
        assert!(with(|c| c.transformer.heads = 0).starts_with("transformer"));
        assert!(with(|c| c.transformer.width = 30).starts_with("transformer.width"));
        // The U-Net's halving constrains the chunk; the transformer's tokens do not.
        let mut c = DiffusionConfig {
            pred_horizon: 10,
            ..DiffusionConfig::default()
        };
        assert!(c.validate().unwrap_err().starts_with("pred_horizon"));
        c.backbone = Backbone::Transformer;
        c.validate().unwrap();
    }

    #[test]
    fn the_u_net_default_serialises_as_before_and_the_transformer_is_named() {
        // A U-Net policy's config (and so its checkpoint bytes and artifact key) is what it was
        // before the transformer family existed.
        let json = serde_json::to_string(&DiffusionConfig::default()).unwrap();
        assert!(
            !json.contains("backbone") && !json.contains("transformer"),
            "{json}"
        );
        let c: DiffusionConfig =
            serde_json::from_str(r#"{"backbone": "transformer", "transformer": {"layers": 2}}"#)
                .unwrap();
        assert_eq!(c.backbone, Backbone::Transformer);
        assert_eq!((c.transformer.layers, c.transformer.heads), (2, 4));
        let json = serde_json::to_string(&c).unwrap();
        assert!(json.contains(r#""backbone":"transformer""#), "{json}");
        let err = serde_json::from_str::<DiffusionConfig>(r#"{"backbone": "mlp"}"#).unwrap_err();
        assert!(err.to_string().contains("unknown variant `mlp`"), "{err}");
    }

    #[test]
    fn partial_configs_take_the_defaults_and_unknown_fields_are_refused() {
        let c: DiffusionConfig = serde_json::from_str(r#"{"steps": 10, "seed": 3}"#).unwrap();
        assert_eq!(c.steps, 10);
        assert_eq!(c.seed, 3);
        assert_eq!(c.pred_horizon, 16);
        let err = serde_json::from_str::<DiffusionConfig>(r#"{"step": 10}"#).unwrap_err();
        assert!(err.to_string().contains("unknown field `step`"), "{err}");
    }
}
