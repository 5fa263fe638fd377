//! A diffusion policy (Chi et al. 2023) trained on Assay's dynamics clips, sized for a CPU: it
//! sees the last `obs_horizon` frames and proprioceptions and denoises a chunk of `pred_horizon`
//! actions, of which the caller runs `action_horizon` before asking again (receding horizon).
//! Owns the model, its training, its checkpoint bytes and its [`Policy`] implementation; never
//! touches the simulator, files or the network (the caller stores and fetches the bytes).
//!
//! # Model
//! - Observation encoder, shared by the observed frames: the frame scaled to [0, 1] then −0.5,
//!   three stride-2 convolutions (kernel 4; channels `encoder_depth`, 2·, 4·`encoder_depth`;
//!   each followed by a one-group GroupNorm and SiLU — the world model's layers), a 1×1
//!   convolution to `keypoints` maps at 1/8 of the frame size, and a spatial softmax (Chi et
//!   al.'s pooling, from robomimic): each map's expected x and y in [−1, 1], through a linear
//!   layer to `obs_features`. The conditioning vector is, for each observed step, those features
//!   and the step's normalised proprioception, concatenated. (Flattening the last feature map
//!   into the linear layer instead, on the synthetic reaching task of the tests, pointed at the
//!   target with a mean cosine of 0.36 where the spatial softmax reached 0.79 after the same
//!   training: keypoints carry positions, which is what these tasks are about.)
//! - Denoiser: Chi et al.'s `ConditionalUnet1D`, small: a 1-D temporal U-Net over the chunk
//!   (`pred_horizon` steps × 4 action dims as channels) with `down_dims` channels per level, two
//!   conditional residual blocks per level (conv `kernel_size` → GroupNorm(`groups`) → Mish, FiLM
//!   `scale · x + bias` from `Mish(cond)`, conv → GroupNorm → Mish, plus a 1×1 residual
//!   projection), stride-2 convolutions down and transposed convolutions up with skip
//!   connections, two middle blocks, and a final conv block and 1×1 projection. FiLM's `cond` is
//!   the diffusion step's sinusoidal embedding (`time_embed` wide, through Linear → Mish →
//!   Linear) concatenated with the observation conditioning. A U-Net rather than an MLP: it is
//!   fast enough on a CPU core (the figures below) and its temporal convolutions give the
//!   smooth chunks Chi et al. chose it for.
//! - Or, with `backbone: transformer`, Chi et al.'s `TransformerForDiffusion`
//!   ([`transformer`]): one token per action of the chunk attending, causally, to each other and
//!   to tokens of the diffusion step and of each observed step. The video-world-model paper
//!   ranks policies of both families; a ladder (`LadderPlan::backbones`) trains both.
//!
//! # Training
//! DDPM with `train_timesteps` steps and the squared-cosine schedule (betas capped at 0.999),
//! epsilon prediction, mean squared error. Actions are normalised per dimension to [−1, 1] from
//! the minimum and maximum of the training targets, proprioception from those of the training
//! frames (a dimension that never changes maps to 0); both ranges travel in the checkpoint.
//! One sample per (clip, step `t`) with a following frame (`t < T − 1`): observations of steps
//! `t − obs_horizon + 1 ..= t` (clamped at 0, so step 0 repeats the first frame) and the actions
//! of steps `t − obs_horizon + 1 .. t − obs_horizon + 1 + pred_horizon` — Chi et al.'s alignment,
//! the chunk starts at the first observed step. Steps before the clip are padded with zero
//! velocity and the first hold command, steps from the clip's last frame on (whose stored action
//! is all zeros by format) with zero velocity and the last real hold command. Each training step
//! draws `batch` samples uniformly with replacement. Adam (ours, `adam.rs`), gradients clipped at
//! a global norm of 10; an exponential moving average of the weights (decay
//! `min(ema_decay, 1 − (1 + step)^−0.75)`) is what the policy runs. [`train_keeping`] also keeps
//! that policy after given steps (a ranking ladder's checkpoints): the same seed and clips give
//! the same weights after as many steps, so each is the policy of a run that long.
//!
//! All randomness is ours, from `assay_spec::rng` streams of the config's seed, never libtorch's
//! global generator: initial weights (`diffusion/init`), the samples of training step `s`
//! (`diffusion/batch/{s}`), their diffusion steps and noise (`diffusion/noise/{s}`). The same
//! config and clips give the same weights (on one CPU thread, to the bit).
//!
//! # Inference
//! DDIM with eta 0 over `inference_steps` steps ("leading" spacing as in diffusers: with 100
//! training steps and 10 inference steps, timesteps 90, 80, …, 0, and ᾱ = 1 after the last), the
//! predicted clean chunk clamped to [−1, 1] at every step (Chi et al.'s `clip_sample`). The only
//! random draw is the initial noise, from the stream `diffusion/ddim` of the seed
//! [`DiffusionPolicy::predict`] is given. As a [`Policy`], [`Policy::reset`] starts the episode
//! stream `diffusion/episode/{episode seed}/{task id}` of the config's seed and every
//! [`Policy::act`] draws the next `predict` seed from it (`next_u64`), so an episode's actions
//! repeat for the same episode and differ between episodes.
//!
//! The observation window is looked up by step number in the observations the policy was shown
//! (it keeps the last `obs_horizon`; an observation whose step does not follow the last one
//! starts the history again). The simulator's driver asks only once per executed chunk, so at
//! step `t` the frame of `t − 1` is usually missing: a missing step takes the next later
//! observation of the window (at worst the current one), as training does before the first
//! frame. An observation of another size than `image_size` is [`PolicyError::Load`]: the model
//! does not fit the batch it was asked to run, which no retry changes and which is no fault of
//! an answer (`BadAnswer`).
//!
//! # Checkpoint bytes
//! `ASYDP001`, the length (u64, little endian) of a JSON header holding the format version and
//! the config, then libtorch's stream format with the normalisation ranges (`stats/…`) and the
//! EMA weights (`ema/…`). Anything else is refused with the reason.
//!
//! # Speed
//! The default config (1.3 M parameters, batch 64) on 40 synthetic clips of 100 frames
//! (`tests/diffusion.rs`, `bench_speed` and `bench_default_run`, ignored; test profile with
//! optimised dependencies) on the 2-core development machine, idle: one libtorch thread 10.8–11.1
//! training steps/s (0.093 CPU-s per step), so the default 3000 steps take 4.5 minutes; two
//! threads 14.7–15.1 steps/s (3.3 minutes, 0.135 CPU-s per step). With other builds running (load
//! 3–5) one thread still gave 9–10 steps/s (whole runs of 5.0 and 5.6 minutes) while two fell
//! to 0.7–1.5 steps/s — hence `threads: 1`. Sampling a chunk (10 DDIM steps) takes 10.4–11.2 ms
//! on one thread and no less on two. That run's policy pointed its first action at unseen
//! targets with a mean cosine of 0.986 and, driven closed loop through [`Policy`] (8 actions
//! per call), reached 20 of 20 unseen targets.

use std::collections::VecDeque;
use std::io::Cursor;
use std::time::Instant;

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::diffusion::{Backbone, DiffusionConfig, DiffusionFit};
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_spec::rng::Rng;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};
use thiserror::Error;

use crate::adam::Adam;
use crate::world_model::{Conv, Init, Linear, device_name};

mod transformer;

use transformer::TransformerDenoiser;

const MAGIC: &[u8; 8] = b"ASYDP001";
const FORMAT: u32 = 1;
const GRAD_CLIP: f64 = 10.0;
/// Chi et al.'s EMA warm-up power.
const EMA_POWER: f64 = 0.75;
const A: i64 = ACTION_DIMS as i64;
const P: i64 = PROPRIO_DIMS as i64;

#[derive(Debug, Error)]
pub enum DiffusionError {
    #[error("invalid diffusion config: {0}")]
    Config(String),
    #[error("no training clips")]
    NoClips,
    /// A training clip that cannot be used; `index` is its position in the slice given.
    #[error("training clip {index}: {reason}")]
    BadClip { index: usize, reason: String },
    /// An observation the policy cannot take (wrong frame size, no observation at all, …).
    #[error("observation: {0}")]
    BadObservation(String),
    #[error("checkpoint refused: {0}")]
    Checkpoint(String),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
}

/// Trains a diffusion policy on `clips`. `progress(step, loss)` is called after every training
/// step (steps count from 1).
pub fn train(
    clips: &[Clip],
    cfg: &DiffusionConfig,
    device: Device,
    progress: &mut dyn FnMut(u64, f64),
) -> Result<(DiffusionPolicy, DiffusionFit), DiffusionError> {
    let (policy, fit, _) = train_keeping(clips, cfg, &[], device, progress)?;
    Ok((policy, fit))
}

/// A trained policy, its fit, and the policies kept on the way (step, policy).
pub type Trained = (DiffusionPolicy, DiffusionFit, Vec<(u64, DiffusionPolicy)>);

/// [`train`], also keeping the policy after each of the `checkpoints` steps below `cfg.steps`
/// (a ladder of policies of differing skill from one run): each runs the EMA weights of that
/// moment, as the final policy does, and its config says the steps it was trained for (the
/// same seed and data give the same weights after as many steps, so it is the policy of a run
/// that long). Returned in step order, each step once.
pub fn train_keeping(
    clips: &[Clip],
    cfg: &DiffusionConfig,
    checkpoints: &[u64],
    device: Device,
    progress: &mut dyn FnMut(u64, f64),
) -> Result<Trained, DiffusionError> {
    cfg.validate().map_err(DiffusionError::Config)?;
    if clips.is_empty() {
        return Err(DiffusionError::NoClips);
    }
    for (index, clip) in clips.iter().enumerate() {
        check_clip(clip, cfg.image_size)
            .map_err(|reason| DiffusionError::BadClip { index, reason })?;
    }
    if device == Device::Cpu {
        tch::set_num_threads(cfg.threads.max(1) as i32);
    }
    let data = Data::new(clips, cfg, device);
    let mut net = Net::new(cfg, device);
    let mut adam = Adam::new(&net.params, cfg.lr, GRAD_CLIP);
    let ema: Vec<Tensor> = tch::no_grad(|| net.params.iter().map(|p| p.detach().copy()).collect());
    let schedule = Schedule::new(cfg.train_timesteps);
    let alpha_bar = Tensor::from_slice(
        &schedule
            .alpha_bar
            .iter()
            .map(|&v| v as f32)
            .collect::<Vec<_>>(),
    )
    .to_device(device);
    let parameters: i64 = net.params.iter().map(Tensor::numel).map(|n| n as i64).sum();

    let started = Instant::now();
    let mut kept = Vec::new();
    let mut losses = Vec::with_capacity(cfg.steps as usize);
    let b = cfg.batch as i64;
    let ph = cfg.pred_horizon as i64;
    for step in 0..cfg.steps {
        let picked = data.pick(cfg, step);
        let (timesteps, noise) = training_noise(cfg, step, device);
        let idx = Tensor::from_slice(&picked).to_device(device);
        let frame_idx = Tensor::from_slice(&data.frames_of(&picked)).to_device(device);
        let images = to_float_images(&data.frames.index_select(0, &frame_idx));
        let proprio = data.proprio.index_select(0, &idx);
        let x0 = data.targets.index_select(0, &idx);
        let ab = alpha_bar.index_select(0, &timesteps).view([b, 1, 1]);
        let noisy = &ab.sqrt() * &x0 + (-&ab + 1.0).sqrt() * &noise;
        let cond = net.condition(&images, &proprio, b);
        let pred = net.denoise(&noisy, &timesteps.to_kind(Kind::Float), &cond);
        debug_assert_eq!(pred.size(), [b, ph, A]);
        let loss = (pred - &noise).square().mean(Kind::Float);
        loss.backward();
        adam.step(&mut net.params);
        let decay = cfg
            .ema_decay
            .min(1.0 - (1.0 + step as f64).powf(-EMA_POWER))
            .max(0.0);
        tch::no_grad(|| {
            for (e, p) in ema.iter().zip(&net.params) {
                let mut e = e.shallow_clone();
                let _ = e.g_mul_scalar_(decay);
                let _ = e.g_add_(&(p * (1.0 - decay)));
            }
        });
        let value = loss.double_value(&[]);
        losses.push(value);
        progress(step + 1, value);
        if step + 1 < cfg.steps && checkpoints.contains(&(step + 1)) {
            let at = DiffusionConfig {
                steps: step + 1,
                ..cfg.clone()
            };
            let mut copy = Net::new(&at, device);
            tch::no_grad(|| {
                for (p, e) in copy.params.iter_mut().zip(&ema) {
                    p.f_copy_(e)?;
                }
                Ok::<(), tch::TchError>(())
            })?;
            kept.push((
                step + 1,
                DiffusionPolicy::from_parts(at, data.stats, copy, device),
            ));
        }
    }
    let train_seconds = started.elapsed().as_secs_f64();

    let tail = &losses[losses.len().saturating_sub(100)..];
    let fit = DiffusionFit {
        steps: cfg.steps,
        // `validate` asks for one step or more.
        final_loss: losses.last().copied().unwrap_or_default(),
        mean_last_100_loss: tail.iter().sum::<f64>() / tail.len().max(1) as f64,
        train_seconds,
        parameters: parameters as u64,
        clips: clips.len() as u32,
        samples: data.samples.len() as u64,
        device: device_name(device),
        libtorch: crate::libtorch_version(),
        config: cfg.clone(),
    };
    tracing::info!(
        steps = fit.steps,
        loss = fit.mean_last_100_loss,
        seconds = fit.train_seconds,
        samples = fit.samples,
        "diffusion policy trained"
    );
    // The policy runs the averaged weights.
    tch::no_grad(|| {
        for (p, e) in net.params.iter_mut().zip(&ema) {
            p.f_copy_(e)?;
        }
        Ok::<(), tch::TchError>(())
    })?;
    let policy = DiffusionPolicy::from_parts(cfg.clone(), data.stats, net, device);
    Ok((policy, fit, kept))
}

fn check_clip(clip: &Clip, size: u32) -> Result<(), String> {
    if clip.width != size || clip.height != size {
        return Err(format!(
            "frames of {}x{}, the diffusion policy wants {size}x{size} (image_size)",
            clip.width, clip.height
        ));
    }
    if clip.proprio_dims as usize != PROPRIO_DIMS || clip.action_dims as usize != ACTION_DIMS {
        return Err(format!(
            "{} proprioception and {} action dims, the diffusion policy wants {PROPRIO_DIMS} and {ACTION_DIMS}",
            clip.proprio_dims, clip.action_dims
        ));
    }
    clip.validate().map_err(|e| e.to_string())?;
    if clip.len() < 2 {
        return Err(format!(
            "{} frame(s): at least 2 are needed (the last frame has no action)",
            clip.len()
        ));
    }
    crate::world_model::finite_values(clip)
}

// ---------------------------------------------------------------------------------------------
// Data.

/// Per-dimension ranges that map values to [−1, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
struct Range<const N: usize> {
    min: [f32; N],
    max: [f32; N],
}

impl<const N: usize> Range<N> {
    fn of<'a>(rows: impl Iterator<Item = &'a [f32]>) -> Self {
        let mut r = Range {
            min: [f32::INFINITY; N],
            max: [f32::NEG_INFINITY; N],
        };
        for row in rows {
            for (d, &v) in row[..N].iter().enumerate() {
                r.min[d] = r.min[d].min(v);
                r.max[d] = r.max[d].max(v);
            }
        }
        r
    }

    fn normalise(&self, v: &[f32], out: &mut Vec<f32>) {
        for (d, &v) in v[..N].iter().enumerate() {
            let span = self.max[d] - self.min[d];
            out.push(if span > 0.0 {
                2.0 * (v - self.min[d]) / span - 1.0
            } else {
                0.0
            });
        }
    }

    fn denormalise(&self, v: &[f32]) -> [f32; N] {
        std::array::from_fn(|d| {
            let span = self.max[d] - self.min[d];
            if span > 0.0 {
                (v[d] + 1.0) * 0.5 * span + self.min[d]
            } else {
                self.min[d]
            }
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Stats {
    action: Range<ACTION_DIMS>,
    proprio: Range<PROPRIO_DIMS>,
}

/// One training sample: the first frame of its clip in the frame table and its step.
struct Sample {
    clip_first: usize,
    t: usize,
}

/// The training set on the device: every frame once, the samples' normalised targets and
/// observed proprioception.
struct Data {
    /// `[frames, H, W, 3]` u8.
    frames: Tensor,
    /// `[samples, pred_horizon, 4]`, normalised.
    targets: Tensor,
    /// `[samples, obs_horizon · 4]`, normalised.
    proprio: Tensor,
    samples: Vec<Sample>,
    obs_horizon: usize,
    stats: Stats,
}

impl Data {
    fn new(clips: &[Clip], cfg: &DiffusionConfig, device: Device) -> Self {
        let (o, ph) = (cfg.obs_horizon, cfg.pred_horizon);
        let mut samples = Vec::new();
        let mut raw_targets: Vec<f32> = Vec::new();
        let mut raw_proprio: Vec<f32> = Vec::new();
        let mut rgb = Vec::with_capacity(clips.iter().map(|c| c.rgb.len()).sum());
        let mut first = 0;
        for clip in clips {
            let len = clip.len();
            let action = |k: usize| &clip.actions[k * ACTION_DIMS..(k + 1) * ACTION_DIMS];
            let (hold_first, hold_last) = (action(0)[3], action(len - 2)[3]);
            for t in 0..len - 1 {
                samples.push(Sample {
                    clip_first: first,
                    t,
                });
                for j in 0..o {
                    let s = (t + j).saturating_sub(o - 1);
                    raw_proprio
                        .extend_from_slice(&clip.proprio[s * PROPRIO_DIMS..(s + 1) * PROPRIO_DIMS]);
                }
                for j in 0..ph {
                    // Step t − o + 1 + j of the clip.
                    let k = (t + j) as i64 - (o as i64 - 1);
                    if k < 0 {
                        raw_targets.extend_from_slice(&[0.0, 0.0, 0.0, hold_first]);
                    } else if k as usize > len - 2 {
                        raw_targets.extend_from_slice(&[0.0, 0.0, 0.0, hold_last]);
                    } else {
                        raw_targets.extend_from_slice(action(k as usize));
                    }
                }
            }
            rgb.extend_from_slice(&clip.rgb);
            first += len;
        }
        let stats = Stats {
            action: Range::of(raw_targets.chunks_exact(ACTION_DIMS)),
            proprio: Range::of(
                clips
                    .iter()
                    .flat_map(|c| c.proprio.chunks_exact(PROPRIO_DIMS)),
            ),
        };
        let mut targets = Vec::with_capacity(raw_targets.len());
        for row in raw_targets.chunks_exact(ACTION_DIMS) {
            stats.action.normalise(row, &mut targets);
        }
        let mut proprio = Vec::with_capacity(raw_proprio.len());
        for row in raw_proprio.chunks_exact(PROPRIO_DIMS) {
            stats.proprio.normalise(row, &mut proprio);
        }
        let size = i64::from(cfg.image_size);
        let n = samples.len() as i64;
        Self {
            frames: Tensor::from_slice(&rgb)
                .view([first as i64, size, size, 3])
                .to_device(device),
            targets: Tensor::from_slice(&targets)
                .view([n, ph as i64, A])
                .to_device(device),
            proprio: Tensor::from_slice(&proprio)
                .view([n, o as i64 * P])
                .to_device(device),
            samples,
            obs_horizon: o,
            stats,
        }
    }

    /// The samples of training step `step`.
    fn pick(&self, cfg: &DiffusionConfig, step: u64) -> Vec<i64> {
        let mut rng = Rng::new(cfg.seed, &format!("diffusion/batch/{step}"));
        let n = self.samples.len() as u64;
        (0..cfg.batch)
            .map(|_| (rng.next_u64() % n) as i64)
            .collect()
    }

    /// Frame-table indices of the picked samples' observations, sample-major.
    fn frames_of(&self, picked: &[i64]) -> Vec<i64> {
        let o = self.obs_horizon;
        let mut out = Vec::with_capacity(picked.len() * o);
        for &i in picked {
            let s = &self.samples[i as usize];
            for j in 0..o {
                out.push((s.clip_first + (s.t + j).saturating_sub(o - 1)) as i64);
            }
        }
        out
    }
}

/// Standard normal values from our own stream (Box–Muller).
fn normals(rng: &mut Rng, n: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(n + 1);
    while out.len() < n {
        let u1 = rng.unit().max(1e-12);
        let u2 = rng.unit();
        let r = (-2.0 * u1.ln()).sqrt();
        let a = std::f64::consts::TAU * u2;
        out.push((r * a.cos()) as f32);
        out.push((r * a.sin()) as f32);
    }
    out.truncate(n);
    out
}

/// Diffusion steps `[batch]` (i64) and noise `[batch, pred_horizon, 4]` of training step `step`.
fn training_noise(cfg: &DiffusionConfig, step: u64, device: Device) -> (Tensor, Tensor) {
    let mut rng = Rng::new(cfg.seed, &format!("diffusion/noise/{step}"));
    let t: Vec<i64> = (0..cfg.batch)
        .map(|_| (rng.next_u64() % cfg.train_timesteps as u64) as i64)
        .collect();
    let n = normals(&mut rng, cfg.batch * cfg.pred_horizon * ACTION_DIMS);
    (
        Tensor::from_slice(&t).to_device(device),
        Tensor::from_slice(&n)
            .view([cfg.batch as i64, cfg.pred_horizon as i64, A])
            .to_device(device),
    )
}

/// `[N, H, W, 3]` u8 → `[N, 3, H, W]` float in [−0.5, 0.5].
fn to_float_images(frames: &Tensor) -> Tensor {
    frames.permute([0, 3, 1, 2]).to_kind(Kind::Float) / 255.0 - 0.5
}

/// The squared-cosine schedule's ᾱ_t (Nichol & Dhariwal; diffusers' `squaredcos_cap_v2`).
struct Schedule {
    alpha_bar: Vec<f64>,
}

impl Schedule {
    fn new(steps: usize) -> Self {
        let f = |t: f64| {
            ((t / steps as f64 + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2)
                .cos()
                .powi(2)
        };
        let mut ab = 1.0;
        let alpha_bar = (0..steps)
            .map(|i| {
                let beta = (1.0 - f(i as f64 + 1.0) / f(i as f64)).min(0.999);
                ab *= 1.0 - beta;
                ab
            })
            .collect();
        Self { alpha_bar }
    }

    /// DDIM's (t, ᾱ_t, ᾱ_prev) from noisiest to cleanest ("leading" spacing, ᾱ = 1 after 0).
    fn ddim(&self, inference_steps: usize) -> Vec<(usize, f64, f64)> {
        let ratio = self.alpha_bar.len() / inference_steps;
        (0..inference_steps)
            .rev()
            .map(|i| {
                let t = i * ratio;
                let prev = if i == 0 {
                    1.0
                } else {
                    self.alpha_bar[t - ratio]
                };
                (t, self.alpha_bar[t], prev)
            })
            .collect()
    }
}

// ---------------------------------------------------------------------------------------------
// Model.

/// A 1-D convolution (or transposed convolution) with a bias.
struct Conv1d {
    w: Tensor,
    b: Tensor,
    stride: i64,
    padding: i64,
    transposed: bool,
}

impl Conv1d {
    fn new(init: &mut Init, name: &str, i: i64, o: i64, k: i64, stride: i64) -> Self {
        Self {
            w: init.uniform(format!("{name}/w"), &[o, i, k], i * k, o * k),
            b: init.constant(format!("{name}/b"), &[o], 0.0),
            stride,
            padding: k / 2,
            transposed: false,
        }
    }

    /// Doubles the length (kernel 4, stride 2, padding 1: Chi et al.'s `Upsample1d`).
    fn upsample(init: &mut Init, name: &str, c: i64) -> Self {
        Self {
            w: init.uniform(format!("{name}/w"), &[c, c, 4], c * 4, c * 4),
            b: init.constant(format!("{name}/b"), &[c], 0.0),
            stride: 2,
            padding: 1,
            transposed: true,
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        if self.transposed {
            x.conv_transpose1d(
                &self.w,
                Some(&self.b),
                [self.stride],
                [self.padding],
                [0],
                1,
                [1],
            )
        } else {
            x.conv1d(
                &self.w,
                Some(&self.b),
                [self.stride],
                [self.padding],
                [1],
                1,
            )
        }
    }
}

/// Conv1d → GroupNorm → Mish (Chi et al.'s `Conv1dBlock`).
struct Block1d {
    conv: Conv1d,
    norm_w: Tensor,
    norm_b: Tensor,
    groups: i64,
}

impl Block1d {
    fn new(init: &mut Init, name: &str, i: i64, o: i64, cfg: &DiffusionConfig) -> Self {
        Self {
            conv: Conv1d::new(init, name, i, o, cfg.kernel_size, 1),
            norm_w: init.constant(format!("{name}/norm_w"), &[o], 1.0),
            norm_b: init.constant(format!("{name}/norm_b"), &[o], 0.0),
            groups: cfg.groups,
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        self.conv
            .forward(x)
            .group_norm(
                self.groups,
                Some(&self.norm_w),
                Some(&self.norm_b),
                1e-5,
                true,
            )
            .mish()
    }
}

/// Chi et al.'s `ConditionalResidualBlock1D` with FiLM scale and bias.
struct ResBlock {
    first: Block1d,
    second: Block1d,
    film: Linear,
    residual: Option<Conv1d>,
    out: i64,
}

impl ResBlock {
    fn new(init: &mut Init, name: &str, i: i64, o: i64, cond: i64, cfg: &DiffusionConfig) -> Self {
        Self {
            first: Block1d::new(init, &format!("{name}/first"), i, o, cfg),
            second: Block1d::new(init, &format!("{name}/second"), o, o, cfg),
            film: Linear::new(init, &format!("{name}/film"), cond, 2 * o, true),
            residual: (i != o).then(|| Conv1d::new(init, &format!("{name}/residual"), i, o, 1, 1)),
            out: o,
        }
    }

    /// `x` `[B, C, L]`, `cond` `[B, cond]` (already through Mish).
    fn forward(&self, x: &Tensor, cond: &Tensor) -> Tensor {
        let h = self.first.forward(x);
        let film = self.film.forward(cond).view([-1, 2, self.out, 1]);
        let h = film.select(1, 0) * h + film.select(1, 1);
        let h = self.second.forward(&h);
        match &self.residual {
            Some(r) => h + r.forward(x),
            None => h + x,
        }
    }
}

struct Level {
    blocks: [ResBlock; 2],
    /// Downsampling (stride-2 conv) or upsampling (transposed conv); none at the last level.
    resample: Option<Conv1d>,
}

/// The U-Net denoiser (Chi et al.'s `ConditionalUnet1D`).
struct Unet {
    time1: Linear,
    time2: Linear,
    time_embed: i64,
    down: Vec<Level>,
    mid: [ResBlock; 2],
    up: Vec<Level>,
    final_block: Block1d,
    final_conv: Conv1d,
}

/// The denoiser of the config's [`Backbone`].
enum Denoiser {
    Unet(Box<Unet>),
    Transformer(Box<TransformerDenoiser>),
}

/// The encoder and the denoiser, with their parameters in creation order.
struct Net {
    enc: Vec<Conv>,
    /// 1×1 convolution to the keypoint maps.
    keypoints_w: Tensor,
    keypoints_b: Tensor,
    /// x and y in [−1, 1] of each cell of the keypoint maps (row-major), not trained.
    grid: (Tensor, Tensor),
    enc_out: Linear,
    denoiser: Denoiser,
    obs_horizon: i64,
    names: Vec<String>,
    params: Vec<Tensor>,
}

impl Unet {
    fn new(init: &mut Init, cfg: &DiffusionConfig) -> Self {
        let te = cfg.time_embed;
        let time1 = Linear::new(init, "time/1", te, 4 * te, true);
        let time2 = Linear::new(init, "time/2", 4 * te, te, true);
        let cond = te + cfg.obs_horizon as i64 * (cfg.obs_features + P);
        let dims: Vec<i64> = std::iter::once(A)
            .chain(cfg.down_dims.iter().copied())
            .collect();
        let levels = cfg.down_dims.len();
        let mut down = Vec::new();
        for k in 0..levels {
            let (i, o) = (dims[k], dims[k + 1]);
            let name = format!("unet/down{k}");
            down.push(Level {
                blocks: [
                    ResBlock::new(init, &format!("{name}/0"), i, o, cond, cfg),
                    ResBlock::new(init, &format!("{name}/1"), o, o, cond, cfg),
                ],
                resample: (k + 1 < levels)
                    .then(|| Conv1d::new(init, &format!("{name}/down"), o, o, 3, 2)),
            });
        }
        let m = dims[levels];
        let mid = [
            ResBlock::new(init, "unet/mid/0", m, m, cond, cfg),
            ResBlock::new(init, "unet/mid/1", m, m, cond, cfg),
        ];
        // Chi et al.: for each level but the first, from the deepest: a block from
        // (the level's channels + its skip) to the level below's channels, then upsampling.
        let mut up = Vec::new();
        for k in (1..levels).rev() {
            let (i, o) = (dims[k], dims[k + 1]);
            let name = format!("unet/up{k}");
            up.push(Level {
                blocks: [
                    ResBlock::new(init, &format!("{name}/0"), 2 * o, i, cond, cfg),
                    ResBlock::new(init, &format!("{name}/1"), i, i, cond, cfg),
                ],
                resample: Some(Conv1d::upsample(init, &format!("{name}/up"), i)),
            });
        }
        let start = dims[1];
        let final_block = Block1d::new(init, "unet/final", start, start, cfg);
        let final_conv = Conv1d::new(init, "unet/out", start, A, 1, 1);
        Self {
            time1,
            time2,
            time_embed: te,
            down,
            mid,
            up,
            final_block,
            final_conv,
        }
    }

    /// The predicted noise `[B, pred_horizon, 4]` of `noisy` `[B, pred_horizon, 4]` at
    /// diffusion steps `t` `[B]` (float), given the flat observation conditioning.
    fn forward(&self, noisy: &Tensor, t: &Tensor, obs_cond: &Tensor) -> Tensor {
        let temb = self
            .time2
            .forward(&self.time1.forward(&sinusoid(t, self.time_embed)).mish());
        // FiLM's encoders all start with Mish (Chi et al.'s `cond_encoder`).
        let cond = Tensor::cat(&[temb, obs_cond.shallow_clone()], -1).mish();
        let mut x = noisy.permute([0, 2, 1]);
        let mut skips = Vec::new();
        for level in &self.down {
            x = level.blocks[0].forward(&x, &cond);
            x = level.blocks[1].forward(&x, &cond);
            skips.push(x.shallow_clone());
            if let Some(r) = &level.resample {
                x = r.forward(&x);
            }
        }
        for block in &self.mid {
            x = block.forward(&x, &cond);
        }
        for level in &self.up {
            let skip = skips.pop().expect("one skip per level");
            x = Tensor::cat(&[x, skip], 1);
            x = level.blocks[0].forward(&x, &cond);
            x = level.blocks[1].forward(&x, &cond);
            if let Some(r) = &level.resample {
                x = r.forward(&x);
            }
        }
        self.final_conv
            .forward(&self.final_block.forward(&x))
            .permute([0, 2, 1])
    }
}

/// Chi et al.'s `SinusoidalPosEmb`: `[B]` → `[B, width]`.
fn sinusoid(t: &Tensor, width: i64) -> Tensor {
    let half = width / 2;
    let scale = (10000f64).ln() / (half - 1).max(1) as f64;
    let freqs = (Tensor::arange(half, (Kind::Float, t.device())) * -scale).exp();
    let x = t.unsqueeze(1) * freqs.unsqueeze(0);
    Tensor::cat(&[x.sin(), x.cos()], -1)
}

impl Net {
    fn new(cfg: &DiffusionConfig, device: Device) -> Self {
        let mut init = Init {
            rng: Rng::new(cfg.seed, "diffusion/init"),
            device,
            names: Vec::new(),
            params: Vec::new(),
        };
        let d = cfg.encoder_depth;
        let chans = [3, d, 2 * d, 4 * d];
        let enc = (0..3)
            .map(|k| {
                Conv::new(
                    &mut init,
                    &format!("enc/conv{k}"),
                    chans[k],
                    chans[k + 1],
                    false,
                    true,
                )
            })
            .collect();
        let k = cfg.keypoints;
        let keypoints_w = init.uniform("enc/keypoints/w".into(), &[k, 4 * d, 1, 1], 4 * d, k);
        let keypoints_b = init.constant("enc/keypoints/b".into(), &[k], 0.0);
        let s = i64::from(cfg.image_size) / 8;
        let cells = Tensor::linspace(-1.0, 1.0, s, (Kind::Float, device));
        let grid = (
            cells.repeat([s]),
            cells.unsqueeze(1).expand([s, s], false).reshape([s * s]),
        );
        let enc_out = Linear::new(&mut init, "enc/out", 2 * k, cfg.obs_features, true);
        let denoiser = match cfg.backbone {
            Backbone::Unet => Denoiser::Unet(Box::new(Unet::new(&mut init, cfg))),
            Backbone::Transformer => Denoiser::Transformer(Box::new(TransformerDenoiser::new(
                &mut init,
                &cfg.transformer,
                cfg.pred_horizon as i64,
                A,
                cfg.obs_horizon as i64,
                cfg.obs_features + P,
            ))),
        };
        Self {
            enc,
            keypoints_w,
            keypoints_b,
            grid,
            enc_out,
            denoiser,
            obs_horizon: cfg.obs_horizon as i64,
            names: init.names,
            params: init.params,
        }
    }

    /// Observation conditioning `[B, obs_horizon · (features + 4)]` from `images`
    /// `[B · obs_horizon, 3, H, W]` (sample-major) and normalised `proprio`
    /// `[B, obs_horizon · 4]`.
    fn condition(&self, images: &Tensor, proprio: &Tensor, b: i64) -> Tensor {
        let mut x = images.shallow_clone();
        for c in &self.enc {
            x = c.forward(&x);
        }
        // Spatial softmax: each keypoint map's expected x and y.
        let attention = x
            .conv2d(
                &self.keypoints_w,
                Some(&self.keypoints_b),
                [1, 1],
                [0, 0],
                [1, 1],
                1,
            )
            .flatten(2, -1)
            .softmax(-1, Kind::Float);
        let kx = (&attention * &self.grid.0).sum_dim_intlist(&[-1][..], false, Kind::Float);
        let ky = (&attention * &self.grid.1).sum_dim_intlist(&[-1][..], false, Kind::Float);
        let features =
            self.enc_out
                .forward(&Tensor::cat(&[kx, ky], -1))
                .view([b, self.obs_horizon, -1]);
        let proprio = proprio.view([b, self.obs_horizon, P]);
        Tensor::cat(&[features, proprio], -1).view([b, -1])
    }

    /// The predicted noise `[B, pred_horizon, 4]` of `noisy` `[B, pred_horizon, 4]` at
    /// diffusion steps `t` `[B]` (float).
    fn denoise(&self, noisy: &Tensor, t: &Tensor, obs_cond: &Tensor) -> Tensor {
        match &self.denoiser {
            Denoiser::Unet(unet) => unet.forward(noisy, t, obs_cond),
            Denoiser::Transformer(transformer) => {
                let b = obs_cond.size()[0];
                transformer.forward(noisy, t, &obs_cond.view([b, self.obs_horizon, -1]))
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The policy.

/// A trained diffusion policy: the EMA weights, the normalisation ranges and the config.
pub struct DiffusionPolicy {
    cfg: DiffusionConfig,
    stats: Stats,
    net: Net,
    device: Device,
    schedule: Schedule,
    /// The observations of the episode so far (at most `obs_horizon`, by step).
    history: VecDeque<PolicyObservation>,
    /// The episode's sampling stream ([`Policy::reset`]).
    episode: Rng,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: u32,
    config: DiffusionConfig,
}

impl DiffusionPolicy {
    fn from_parts(cfg: DiffusionConfig, stats: Stats, net: Net, device: Device) -> Self {
        Self {
            schedule: Schedule::new(cfg.train_timesteps),
            episode: Rng::new(cfg.seed, "diffusion/episode"),
            history: VecDeque::new(),
            cfg,
            stats,
            net,
            device,
        }
    }

    pub fn config(&self) -> &DiffusionConfig {
        &self.cfg
    }

    /// The checkpoint bytes (see the module docs).
    pub fn to_bytes(&self) -> Vec<u8> {
        let header = serde_json::to_vec(&Header {
            format: FORMAT,
            config: self.cfg.clone(),
        })
        .expect("the header serialises");
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(&header);
        let s = &self.stats;
        let mut named: Vec<(String, Tensor)> = [
            ("stats/action_min", &s.action.min[..]),
            ("stats/action_max", &s.action.max[..]),
            ("stats/proprio_min", &s.proprio.min[..]),
            ("stats/proprio_max", &s.proprio.max[..]),
        ]
        .into_iter()
        .map(|(n, v)| (n.to_string(), Tensor::from_slice(v)))
        .collect();
        for (name, p) in self.net.names.iter().zip(&self.net.params) {
            named.push((format!("ema/{name}"), p.to_device(Device::Cpu)));
        }
        Tensor::save_multi_to_stream(&named, &mut out).expect("tensors serialise into memory");
        out
    }

    /// Reads checkpoint bytes onto `device`; a file of another kind, format or shape is refused
    /// with the reason.
    pub fn from_bytes(bytes: &[u8], device: Device) -> Result<Self, DiffusionError> {
        let refuse = |s: String| DiffusionError::Checkpoint(s);
        if bytes.len() < 16 || &bytes[..8] != MAGIC {
            return Err(refuse(
                "not a diffusion-policy checkpoint (no ASYDP001 header)".into(),
            ));
        }
        let len = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")) as usize;
        let header = bytes
            .get(16..16usize.saturating_add(len))
            .ok_or_else(|| refuse(format!("truncated: a {len}-byte header is promised")))?;
        let header: Header = serde_json::from_slice(header)
            .map_err(|e| refuse(format!("unreadable header: {e}")))?;
        if header.format != FORMAT {
            return Err(refuse(format!(
                "format {} (this build reads {FORMAT})",
                header.format
            )));
        }
        let cfg = header.config;
        cfg.validate()
            .map_err(|e| refuse(format!("its config is invalid: {e}")))?;
        let tensors = Tensor::load_multi_from_stream_with_device(
            Cursor::new(&bytes[16 + len..]),
            Device::Cpu,
        )
        .map_err(|e| refuse(format!("unreadable tensors: {e}")))?;
        let tensors: std::collections::HashMap<String, Tensor> = tensors
            .into_iter()
            .map(|(k, v)| (k.replace('|', "."), v))
            .collect();
        let get = |key: &str, shape: &[i64]| -> Result<&Tensor, DiffusionError> {
            let t = tensors
                .get(key)
                .ok_or_else(|| refuse(format!("it has no tensor {key}")))?;
            if t.size() != shape {
                return Err(refuse(format!(
                    "tensor {key} has shape {:?}, the model {shape:?}",
                    t.size()
                )));
            }
            if t.kind() != Kind::Float {
                return Err(refuse(format!("tensor {key} is {:?}, not f32", t.kind())));
            }
            Ok(t)
        };
        let four = |key: &str| -> Result<[f32; 4], DiffusionError> {
            let v = Vec::<f32>::try_from(get(key, &[4])?)
                .map_err(|e| refuse(format!("tensor {key}: {e}")))?;
            Ok([v[0], v[1], v[2], v[3]])
        };
        let stats = Stats {
            action: Range {
                min: four("stats/action_min")?,
                max: four("stats/action_max")?,
            },
            proprio: Range {
                min: four("stats/proprio_min")?,
                max: four("stats/proprio_max")?,
            },
        };
        let mut net = Net::new(&cfg, device);
        tch::no_grad(|| {
            for (name, p) in net.names.iter().zip(net.params.iter_mut()) {
                let src = get(&format!("ema/{name}"), &p.size())?;
                p.f_copy_(src)?;
            }
            Ok::<(), DiffusionError>(())
        })?;
        let expected = net.names.len() + 4;
        if tensors.len() != expected {
            return Err(refuse(format!(
                "it holds {} tensors, the model {expected}",
                tensors.len()
            )));
        }
        Ok(Self::from_parts(cfg, stats, net, device))
    }

    fn check_observation(&self, obs: &PolicyObservation) -> Result<(), DiffusionError> {
        let size = self.cfg.image_size;
        if obs.width != size || obs.height != size {
            return Err(DiffusionError::BadObservation(format!(
                "step {}: a {}x{} frame, the policy was trained on {size}x{size}",
                obs.step, obs.width, obs.height
            )));
        }
        let want = (size * size * 3) as usize;
        if obs.rgb.len() != want {
            return Err(DiffusionError::BadObservation(format!(
                "step {}: {} RGB bytes for a {size}x{size} frame ({want})",
                obs.step,
                obs.rgb.len()
            )));
        }
        if !obs.proprio.iter().all(|v| v.is_finite()) {
            return Err(DiffusionError::BadObservation(format!(
                "step {}: non-finite proprioception {:?}",
                obs.step, obs.proprio
            )));
        }
        Ok(())
    }

    /// The full predicted chunk (`pred_horizon` actions, de-normalised) for the observations of
    /// an episode so far (the last is the current step; earlier ones fill the observation
    /// window by step number, see the module docs), with the DDIM noise drawn from `seed`.
    /// Index `obs_horizon − 1` is the action of the current step.
    pub fn predict(
        &self,
        history: &[PolicyObservation],
        seed: u64,
    ) -> Result<Vec<Action>, DiffusionError> {
        let current = history
            .last()
            .ok_or_else(|| DiffusionError::BadObservation("no observation to act on".into()))?;
        for obs in history {
            self.check_observation(obs)?;
        }
        let o = self.cfg.obs_horizon;
        let t = i64::from(current.step);
        // For each step of the window, the observation of that step, else the next later one.
        let window: Vec<&PolicyObservation> = (0..o)
            .map(|j| {
                let want = t - (o - 1 - j) as i64;
                history
                    .iter()
                    .filter(|h| i64::from(h.step) >= want && h.step <= current.step)
                    .min_by_key(|h| h.step)
                    .unwrap_or(current)
            })
            .collect();
        let size = i64::from(self.cfg.image_size);
        let mut rgb = Vec::with_capacity(o * (size * size * 3) as usize);
        let mut proprio = Vec::with_capacity(o * PROPRIO_DIMS);
        for obs in &window {
            rgb.extend_from_slice(&obs.rgb);
            self.stats.proprio.normalise(&obs.proprio, &mut proprio);
        }
        let ph = self.cfg.pred_horizon;
        let out = tch::no_grad(|| {
            let images = to_float_images(
                &Tensor::from_slice(&rgb)
                    .view([o as i64, size, size, 3])
                    .to_device(self.device),
            );
            let proprio = Tensor::from_slice(&proprio)
                .view([1, o as i64 * P])
                .to_device(self.device);
            let cond = self.net.condition(&images, &proprio, 1);
            let mut rng = Rng::new(seed, "diffusion/ddim");
            let mut x = Tensor::from_slice(&normals(&mut rng, ph * ACTION_DIMS))
                .view([1, ph as i64, A])
                .to_device(self.device);
            for (step, ab, ab_prev) in self.schedule.ddim(self.cfg.inference_steps) {
                let ts = Tensor::from_slice(&[step as f32]).to_device(self.device);
                let eps = self.net.denoise(&x, &ts, &cond);
                let x0 = ((&x - &eps * (1.0 - ab).sqrt()) / ab.sqrt()).clamp(-1.0, 1.0);
                x = x0 * ab_prev.sqrt() + eps * (1.0 - ab_prev).sqrt();
            }
            Vec::<f32>::try_from(x.to_device(Device::Cpu).contiguous().view([-1]))
        })?;
        Ok(out
            .chunks_exact(ACTION_DIMS)
            .map(|row| self.stats.action.denormalise(row))
            .collect())
    }
}

impl Policy for DiffusionPolicy {
    fn frame_size(&self) -> Option<u32> {
        Some(self.cfg.image_size)
    }

    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.history.clear();
        self.episode = Rng::new(
            self.cfg.seed,
            &format!("diffusion/episode/{}/{}", episode.seed, episode.task_id),
        );
        Ok(())
    }

    /// Observations the model cannot take (another frame size than it was trained on) are
    /// [`PolicyError::Load`]: the checkpoint does not fit the batch it was asked to run, which no
    /// retry can change and which is no fault of an answer.
    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        self.check_observation(obs)
            .map_err(|e| PolicyError::Load(format!("diffusion policy: {e}")))?;
        // A step that does not follow the last one starts the history again.
        if self.history.back().is_some_and(|h| h.step >= obs.step) {
            self.history.clear();
        }
        self.history.push_back(obs.clone());
        while self.history.len() > self.cfg.obs_horizon {
            self.history.pop_front();
        }
        let seed = self.episode.next_u64();
        self.history.make_contiguous();
        let chunk = self
            .predict(self.history.as_slices().0, seed)
            .map_err(|e| PolicyError::Load(format!("diffusion policy: {e}")))?;
        let start = self.cfg.obs_horizon - 1;
        Ok(chunk[start..start + self.cfg.action_horizon].to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` clips of 6 frames of 16×16: a bright pixel moving right, the tool's x in step.
    fn clips(n: usize) -> Vec<Clip> {
        (0..n)
            .map(|k| {
                let (mut rgb, mut proprio, mut actions) = (Vec::new(), Vec::new(), Vec::new());
                for t in 0..6usize {
                    let mut frame = vec![10u8; 16 * 16 * 3];
                    frame[(4 * 16 + t + k) * 3] = 250;
                    rgb.extend(frame);
                    proprio.extend_from_slice(&[0.01 * t as f32, 0.02 * k as f32, 0.1, 0.0]);
                    let a = if t < 5 {
                        [0.1, 0.0, 0.0, 0.0]
                    } else {
                        [0.0; 4]
                    };
                    actions.extend_from_slice(&a);
                }
                Clip {
                    height: 16,
                    width: 16,
                    interval_s: 0.1,
                    proprio_dims: 4,
                    action_dims: 4,
                    rgb,
                    proprio,
                    actions,
                    interface: String::new(),
                    views: Vec::new(),
                    object_dims: 0,
                    objects: Vec::new(),
                }
            })
            .collect()
    }

    #[test]
    fn a_training_keeps_a_distinct_loadable_policy_at_each_checkpoint() {
        let cfg = DiffusionConfig {
            image_size: 16,
            steps: 3,
            batch: 2,
            encoder_depth: 4,
            keypoints: 4,
            obs_features: 8,
            down_dims: vec![8, 16],
            time_embed: 8,
            groups: 4,
            ..DiffusionConfig::default()
        };
        // Steps at or past the end are the final policy's, not checkpoints.
        let (last, fit, kept) = train_keeping(
            &clips(2),
            &cfg,
            &[2, 1, 3, 9, 2],
            Device::Cpu,
            &mut |_, _| {},
        )
        .unwrap();
        assert_eq!(fit.steps, 3);
        let steps: Vec<u64> = kept.iter().map(|(s, _)| *s).collect();
        assert_eq!(steps, [1, 2]);
        let mut bytes: Vec<Vec<u8>> = kept.iter().map(|(_, p)| p.to_bytes()).collect();
        bytes.push(last.to_bytes());
        for (i, b) in bytes.iter().enumerate() {
            assert!(bytes[..i].iter().all(|a| a != b), "policy {i} repeats one");
            let back = DiffusionPolicy::from_bytes(b, Device::Cpu).unwrap();
            assert_eq!(&back.to_bytes(), b);
        }
        assert_eq!(kept[0].1.config().steps, 1);
        assert_eq!(last.config().steps, 3);
        // A kept policy acts.
        let clip = &clips(1)[0];
        let obs = PolicyObservation::legacy(0, 16, 16, clip.rgb[..16 * 16 * 3].to_vec(), [0.0; 4]);
        let chunk = kept[1].1.predict(&[obs], 7).unwrap();
        assert_eq!(chunk.len(), cfg.pred_horizon);
    }
}
