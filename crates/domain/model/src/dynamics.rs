//! Dynamics diversity: the settings of the world model the trainer role fits per task group, and
//! what one fit reports. The model itself lives in `assay-trainer` (libtorch); these are plain
//! data so the coordinator and reports need no torch.

use serde::{Deserialize, Serialize};

/// World-model settings. The defaults take about 2½ minutes per fit on one CPU core with 64×64
/// frames; raise `deter`, `hidden`, `depth` and `steps` on a GPU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DynamicsConfig {
    /// Frame size the clips are rendered at (square), pixels.
    pub image_size: u32,
    /// Sequence length of a training chunk (the paper: 40 for GenSim and RoboGen, 20 for BBSEA).
    pub chunk: usize,
    /// Chunks per training step (the paper: 8).
    pub batch: usize,
    /// Training steps of every fit, whatever its budget (chunk order reshuffled at each pass over
    /// the training chunks). 0: `epochs` passes instead, the paper's protocol, under which a
    /// larger budget also trains longer, so the error falls with the budget even for identical
    /// episodes.
    pub steps: u64,
    /// Passes over the training chunks when `steps` is 0 (the paper: 10).
    pub epochs: usize,
    /// Deterministic (GRU) state size.
    pub deter: i64,
    /// Stochastic state: `stoch` categorical variables of `classes` classes each (DreamerV3).
    pub stoch: i64,
    pub classes: i64,
    /// Width of the MLPs.
    pub hidden: i64,
    /// Channels of the first convolution (doubled at each of the 4 stride-2 stages).
    pub depth: i64,
    /// Adam learning rate.
    pub lr: f64,
    /// Free nats of the KL terms (DreamerV3: 1).
    pub free_nats: f64,
    /// Seed of initialisation, chunk order and latent sampling.
    pub seed: u64,
    /// Training steps between checkpoints written to the artifact store.
    pub checkpoint_every: usize,
    /// Intra-op threads of libtorch on a CPU (1 is fastest for models this small on 2 cores).
    /// Keep one count for every model a trainer runs (the defaults are all 1): beside a fit
    /// at another count, a fit's weights can change from run to run (measured in
    /// `workers/trainer/tests/diffusion.rs`).
    pub threads: usize,
}

impl Default for DynamicsConfig {
    fn default() -> Self {
        Self {
            image_size: 64,
            chunk: 20,
            batch: 4,
            steps: 2000,
            epochs: 10,
            deter: 128,
            stoch: 8,
            classes: 8,
            hidden: 128,
            depth: 8,
            lr: 1e-3,
            free_nats: 1.0,
            seed: 0,
            checkpoint_every: 20,
            threads: 1,
        }
    }
}

/// The episode budgets of the paper's Table 2.
pub const DEFAULT_BUDGETS: [u32; 3] = [10, 20, 40];

/// One world-model fit: trained on the first `train_episodes` episodes of a group, evaluated on
/// `eval_episodes` (the first `max(budgets)` episodes of the group).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DynamicsFit {
    pub group: String,
    /// The budget asked for.
    pub budget: u32,
    /// Episodes trained on (the budget, or fewer when the group has fewer episodes with clips).
    pub train_episodes: u32,
    pub eval_episodes: u32,
    /// Prediction error on the evaluation episodes: mean squared error of the one-step prediction
    /// of the next frame (pixels in [0, 1]) from the prior, filtering the observations so far.
    pub eval_image_mse: f64,
    /// Same for proprioception (tool position in metres, holding 0/1).
    pub eval_proprio_mse: f64,
    /// Per evaluation episode, `eval_image_mse` of that episode (same order as `episodes`).
    pub per_episode: Vec<f64>,
    /// The clips evaluated, as content addresses (the first `train_episodes` were trained on).
    pub episodes: Vec<String>,
    /// Training loss (reconstruction + KL) averaged over the last pass over the chunks.
    pub final_train_loss: f64,
    pub steps: u64,
    /// Passes over the training chunks (`steps` / steps per pass; the last may be partial).
    pub epochs: f64,
    /// Training step the fit resumed from (a checkpoint left by an earlier attempt), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resumed_from_step: Option<u64>,
    /// Training steps per second of this fit (wall clock). Measured, so not serialised: a
    /// report's results are the same for the same batch (the trainer logs it; the shard's wall
    /// time is in the job store).
    #[serde(skip)]
    pub steps_per_s: f64,
    /// The device it ran on (`cpu`, `cuda:0`).
    pub device: String,
    /// The libtorch it ran with (`2.13.0`; empty in reports written before it was kept).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub libtorch: String,
    pub config: DynamicsConfig,
}
