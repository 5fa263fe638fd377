//! A DreamerV3-style latent dynamics model p(o_{t+1} | o_t, a_t), sized for a CPU, whose one-step
//! prediction error on held-out episodes measures the dynamics diversity of a task group
//! (the paper's §3.4, §4.2 and A.3.3: train on 10, 20 and 40 episodes, evaluate on all 40).
//!
//! # Model
//! - Encoder: the frame scaled to [0, 1] then −0.5, four stride-2 convolutions (kernel 4,
//!   channels `depth`, 2·`depth`, 4·`depth`, 8·`depth`, each followed by a one-group GroupNorm —
//!   a layer norm over the whole feature map — and SiLU), flattened and concatenated with the
//!   proprioception through one dense layer (LayerNorm, SiLU). Any `image_size` divisible by 16.
//! - RSSM: a GRU state `h` of `deter` units (DreamerV3's layer-normed GRU), a stochastic state
//!   `z` of `stoch` categoricals of `classes` classes each, mixed with 1 % uniform (unimix) and
//!   sampled with straight-through gradients. Prior from `h_t`, posterior from `(h_t, embed_t)`,
//!   `h_{t+1} = GRU(h_t, dense([z_t, a_t]))`, `h_0 = 0`.
//! - Decoders from `[h, z]`: a linear layer and four transposed convolutions mirroring the encoder
//!   for the frame, a two-layer MLP for the proprioception.
//!
//! # Loss (per frame, averaged over the valid frames of a batch)
//! Image squared error **summed** over the pixels and channels of the frame (in [0, 1] units, as
//! DreamerV3: a mean would be swamped by the KL terms and their free nats), plus the proprio
//! squared error summed over its 4 dims, plus `0.5 · max(free_nats, KL[sg(post) ‖ prior])`
//! (dynamics) and `0.1 · max(free_nats, KL[post ‖ sg(prior)])` (representation), the KL summed
//! over the `stoch` variables.
//!
//! # Training
//! Each training clip is cut into non-overlapping chunks of `chunk` frames; a shorter tail of at
//! least 2 frames is kept (a 1-frame tail holds no transition and is dropped). The chunk order is
//! shuffled per epoch (`assay_spec::rng`, stream `world-model/epoch/{epoch}`), and each step takes
//! the next `batch` chunks (the last batch of an epoch may be smaller), padded to the longest with
//! a mask that removes padded frames from the loss. A fit trains `steps` steps whatever its
//! budget (epochs follow one another until then; the last may be partial), or, with `steps` 0,
//! `epochs` whole epochs (the paper's protocol). Adam (ours, see `adam.rs`) with gradients
//! clipped at a global norm of 1000 (DreamerV3's world-model setting).
//!
//! All randomness is ours, not libtorch's global generator: initial weights come from the stream
//! `world-model/init`, the Gumbel noise that samples the latents of step `s` from
//! `world-model/latents/{s}`. Fits running in parallel threads therefore cannot disturb each
//! other, and a run resumed from a checkpoint samples exactly what an uninterrupted one does: on
//! one CPU thread the resumed fit ends with the same numbers to the bit.
//!
//! # Checkpoints
//! Every `checkpoint_every` steps (not after the last) the caller receives the step and bytes:
//! the header `ASYWM001`, the hash of the training-relevant config, a hash of the training clips,
//! the step, Adam's step count and the running loss of the epoch, then every parameter and Adam
//! moment (libtorch's stream format). A checkpoint of another config or other clips is refused.
//!
//! # Evaluation
//! With no gradients, each evaluation clip is filtered with the posterior (teacher forcing) and
//! at each `t < T−1` the next frame is predicted one step ahead: `h_{t+1} = GRU(h_t, [z_t, a_t])`,
//! `z'` the mode of the prior at `h_{t+1}`, decoded from `[h_{t+1}, z']`, clamped to [0, 1] and
//! compared with frame `t+1`. Latents are the modes (argmax) of their distributions, so the
//! evaluation draws no random numbers. Errors are per pixel-channel (and per proprio dim);
//! the overall figures are means over all predicted frames of all clips, `per_episode` the mean
//! over each clip's frames.

use std::collections::HashMap;
use std::time::Instant;

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::dynamics::{DynamicsConfig, DynamicsFit};
use assay_spec::rng::Rng;
use tch::{Device, Kind, Tensor};
use thiserror::Error;

use crate::adam::Adam;

const UNIMIX: f64 = 0.01;
const GRAD_CLIP: f64 = 1000.0;
const DYN_SCALE: f64 = 0.5;
const REP_SCALE: f64 = 0.1;

/// One world-model fit: the training and evaluation clips of a task group at one budget.
pub struct FitRequest<'a> {
    pub config: &'a DynamicsConfig,
    pub group: &'a str,
    pub budget: u32,
    /// Episodes to train on (the first `budget` of the group, or fewer).
    pub train: &'a [Clip],
    /// Episodes to evaluate on, with their content addresses (same length and order).
    pub eval: &'a [Clip],
    pub eval_keys: &'a [String],
    pub device: Device,
    /// Scale every action dimension to zero mean and unit deviation over the training clips
    /// before it enters the model (the proxy's world model does; the dynamics-diversity fits,
    /// whose published figures were measured without, do not). Clip actions are tool
    /// velocities of about 0.15 m/s deviation: at that scale the RSSM can learn to ignore them
    /// (see `tests/proxy.rs`).
    pub normalize_actions: bool,
}

mod checkpoint;
mod service;

pub(crate) use service::world_frames;

use checkpoint::{config_hash, data_hash, load_checkpoint, save_checkpoint};

/// A fast fingerprint of training clips (their shapes and contents), for checkpoints.
pub(crate) fn clips_hash(clips: &[Clip]) -> u64 {
    data_hash(clips)
}

#[derive(Debug, Error)]
pub enum WorldModelError {
    /// A clip that cannot be trained or evaluated on; `clip` names it (`train clip 3`,
    /// `eval clip 2 (key)`).
    #[error("{clip}: {reason}")]
    BadClip { clip: String, reason: String },
    #[error("invalid world-model request: {0}")]
    Request(String),
    #[error("checkpoint refused: {0}")]
    CheckpointRefused(String),
    /// The caller's checkpoint callback failed; the fit stops there (its bytes may have been
    /// stored, so a later attempt can resume from them).
    #[error("storing the checkpoint of step {step} failed: {reason}")]
    Checkpoint { step: u64, reason: String },
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    #[error("{0}")]
    World(#[from] assay_model::world::WorldError),
}

/// Fits the world model on `req.train` and evaluates its one-step prediction error on `req.eval`.
/// `resume`: the bytes of a checkpoint an earlier attempt left (see the module docs).
/// Receives `(step, checkpoint bytes)`; an `Err` stops the fit.
pub type CheckpointSink<'a> = dyn FnMut(u64, &[u8]) -> Result<(), String> + 'a;

/// `on_checkpoint(step, bytes)` is called every `checkpoint_every` steps; an `Err` stops the fit.
pub fn fit(
    req: &FitRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<DynamicsFit, WorldModelError> {
    fit_model(req, resume, on_checkpoint).map(|(_, fit)| fit)
}

/// A trained world model, kept to imagine rollouts in ([`WorldModel::imagine`]).
pub struct WorldModel {
    model: Model,
    size: i64,
    device: Device,
}

/// [`fit`], keeping the trained model.
pub fn fit_model(
    req: &FitRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<(WorldModel, DynamicsFit), WorldModelError> {
    fit_keeping(req, resume, on_checkpoint, false).map(|(m, f, _)| (m, f))
}

/// [`fit`], returning the fit and a checkpoint of its last step: resuming from it trains no
/// further, so a later job gets this model without fitting it again (the proxy's world
/// model, fitted while a ladder trains).
pub fn fit_to_checkpoint(
    req: &FitRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<(DynamicsFit, Vec<u8>), WorldModelError> {
    let (_, fit, last) = fit_keeping(req, resume, on_checkpoint, true)?;
    Ok((fit, last.expect("asked for the last checkpoint")))
}

fn fit_keeping(
    req: &FitRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
    keep_last: bool,
) -> Result<(WorldModel, DynamicsFit, Option<Vec<u8>>), WorldModelError> {
    let cfg = req.config;
    validate(req)?;
    if req.device == Device::Cpu {
        tch::set_num_threads(cfg.threads.max(1) as i32);
    }
    let device = req.device;
    let size = i64::from(cfg.image_size);

    let mut model = Model::new(cfg, device);
    if req.normalize_actions {
        model.normalize_actions_of(req.train, device);
    }
    let mut adam = Adam::new(&model.params, cfg.lr, GRAD_CLIP);

    let chunks = make_chunks(req.train, cfg.chunk);
    let steps_per_epoch = chunks.len().div_ceil(cfg.batch) as u64;
    let total_steps = if cfg.steps > 0 {
        cfg.steps
    } else {
        steps_per_epoch * cfg.epochs as u64
    };
    if chunks.is_empty() && total_steps > 0 {
        return Err(WorldModelError::Request(format!(
            "{} training clips hold no chunk of 2 frames or more to train {total_steps} steps on",
            req.train.len()
        )));
    }
    let config_hash = config_hash(cfg);
    let data_hash = data_hash(req.train);

    let mut step = 0u64;
    let mut epoch_loss = (0.0f64, 0u64);
    let mut resumed_from_step = None;
    if let Some(bytes) = resume {
        let state = load_checkpoint(bytes, config_hash, data_hash, total_steps, device)?;
        model.restore(&state.tensors, "p")?;
        restore_moments(&mut adam.m, &model.names, &state.tensors, "m")?;
        restore_moments(&mut adam.v, &model.names, &state.tensors, "v")?;
        adam.t = state.adam_t;
        step = state.step;
        epoch_loss = (state.loss_sum, state.loss_count);
        resumed_from_step = Some(step);
        tracing::info!(
            group = req.group,
            budget = req.budget,
            step,
            "world model resumed"
        );
    }

    let started = Instant::now();
    let first_step = step;
    let mut order: (Option<u64>, Vec<usize>) = (None, Vec::new());
    while step < total_steps {
        let epoch = step / steps_per_epoch;
        let in_epoch = (step % steps_per_epoch) as usize;
        if in_epoch == 0 {
            epoch_loss = (0.0, 0);
        }
        if order.0 != Some(epoch) {
            order = (Some(epoch), shuffled(chunks.len(), cfg.seed, epoch));
        }
        let picked: Vec<&Chunk> = order.1
            [in_epoch * cfg.batch..((in_epoch + 1) * cfg.batch).min(chunks.len())]
            .iter()
            .map(|&i| &chunks[i])
            .collect();
        let batch = Batch::new(req.train, &picked, size, device);
        let noise = gumbel_noise(cfg, step, batch.len, batch.batch, device);
        let loss = model.loss(&batch, &noise);
        loss.backward();
        adam.step(&mut model.params);
        let value = loss.double_value(&[]);
        epoch_loss.0 += value;
        epoch_loss.1 += 1;
        step += 1;
        if cfg.checkpoint_every > 0
            && step.is_multiple_of(cfg.checkpoint_every as u64)
            && step < total_steps
        {
            let bytes = save_checkpoint(&model, &adam, config_hash, data_hash, step, epoch_loss)?;
            tracing::debug!(step, bytes = bytes.len(), "world model checkpoint");
            on_checkpoint(step, &bytes)
                .map_err(|reason| WorldModelError::Checkpoint { step, reason })?;
        }
    }
    let train_s = started.elapsed().as_secs_f64();
    let done = step - first_step;
    let last = if keep_last {
        Some(save_checkpoint(
            &model,
            &adam,
            config_hash,
            data_hash,
            step,
            epoch_loss,
        )?)
    } else {
        None
    };

    let eval = tch::no_grad(|| model.evaluate(req.eval, cfg.batch, size, device));
    let frames: usize = eval.iter().map(|e| e.frames).sum();
    let eval_image_mse = eval.iter().map(|e| e.image_sse).sum::<f64>() / frames as f64;
    let eval_proprio_mse = eval.iter().map(|e| e.proprio_sse).sum::<f64>() / frames as f64;
    let fit = DynamicsFit {
        group: req.group.to_string(),
        budget: req.budget,
        train_episodes: req.train.len() as u32,
        eval_episodes: req.eval.len() as u32,
        eval_image_mse,
        eval_proprio_mse,
        per_episode: eval.iter().map(|e| e.image_sse / e.frames as f64).collect(),
        episodes: req.eval_keys.to_vec(),
        final_train_loss: if epoch_loss.1 > 0 {
            epoch_loss.0 / epoch_loss.1 as f64
        } else {
            0.0
        },
        steps: step,
        epochs: step as f64 / steps_per_epoch.max(1) as f64,
        resumed_from_step,
        steps_per_s: if done > 0 && train_s > 0.0 {
            done as f64 / train_s
        } else {
            0.0
        },
        device: device_name(device),
        libtorch: crate::libtorch_version(),
        config: cfg.clone(),
    };
    tracing::info!(
        group = req.group,
        budget = req.budget,
        steps = fit.steps,
        image_mse = fit.eval_image_mse,
        loss = fit.final_train_loss,
        steps_per_s = fit.steps_per_s,
        "world model fitted"
    );
    Ok((
        WorldModel {
            model,
            size,
            device,
        },
        fit,
        last,
    ))
}

impl WorldModel {
    /// Frame size (square) the model works at.
    pub fn image_size(&self) -> u32 {
        self.size as u32
    }

    /// The model as a [`assay_model::world::WorldModelService`]: what the proxy imagines in.
    pub fn service(&self) -> service::Rssm<'_> {
        service::Rssm { model: self }
    }
}

/// `cpu` or `cuda:N`.
pub fn device_name(device: Device) -> String {
    match device {
        Device::Cpu => "cpu".into(),
        Device::Cuda(i) => format!("cuda:{i}"),
        Device::Mps => "mps".into(),
        Device::Vulkan => "vulkan".into(),
    }
}

fn validate(req: &FitRequest<'_>) -> Result<(), WorldModelError> {
    let c = req.config;
    let bad = |s: String| Err(WorldModelError::Request(s));
    if c.image_size == 0 || !c.image_size.is_multiple_of(16) {
        return bad(format!(
            "image_size {} is not a positive multiple of 16 (four stride-2 stages)",
            c.image_size
        ));
    }
    if c.chunk < 2 {
        return bad(format!("chunk {} is below 2 frames", c.chunk));
    }
    if c.batch == 0 {
        return bad("batch is 0".into());
    }
    if c.deter < 1 || c.stoch < 1 || c.classes < 2 || c.hidden < 1 || c.depth < 1 {
        return bad(format!(
            "deter {}, stoch {}, classes {}, hidden {}, depth {}: all must be positive (classes ≥ 2)",
            c.deter, c.stoch, c.classes, c.hidden, c.depth
        ));
    }
    if !(c.lr.is_finite() && c.lr > 0.0 && c.free_nats.is_finite() && c.free_nats >= 0.0) {
        return bad(format!("lr {} / free_nats {}", c.lr, c.free_nats));
    }
    if req.eval.is_empty() {
        return bad("no evaluation clips".into());
    }
    if req.eval_keys.len() != req.eval.len() {
        return bad(format!(
            "{} evaluation keys for {} evaluation clips",
            req.eval_keys.len(),
            req.eval.len()
        ));
    }
    let named = req
        .train
        .iter()
        .enumerate()
        .map(|(i, c)| (format!("train clip {i}"), c))
        .chain(
            req.eval
                .iter()
                .enumerate()
                .map(|(i, c)| (format!("eval clip {i} ({})", req.eval_keys[i]), c)),
        );
    for (name, clip) in named {
        check_clip(clip, c.image_size)
            .map_err(|reason| WorldModelError::BadClip { clip: name, reason })?;
    }
    Ok(())
}

fn check_clip(clip: &Clip, size: u32) -> Result<(), String> {
    check_clip_frames(clip, size, 2)
}

/// What a world model (the RSSM, the video model) needs of a clip: frames of `size`×`size`,
/// the clip interface's state and action widths, arrays that agree with the header, at least
/// `min_frames` frames, finite values.
/// Why `clip`'s proprioception (state) or actions cannot be trained on: a value that is not
/// finite.
pub(crate) fn finite_values(clip: &Clip) -> Result<(), String> {
    if clip
        .proprio
        .iter()
        .chain(&clip.actions)
        .all(|v| v.is_finite())
    {
        Ok(())
    } else {
        Err("non-finite proprioception or action values".into())
    }
}

pub(crate) fn check_clip_frames(clip: &Clip, size: u32, min_frames: usize) -> Result<(), String> {
    if clip.width != size || clip.height != size {
        return Err(format!(
            "frames of {}x{}, the world model wants {size}x{size}",
            clip.width, clip.height
        ));
    }
    if clip.proprio_dims as usize != PROPRIO_DIMS || clip.action_dims as usize != ACTION_DIMS {
        return Err(format!(
            "{} proprioception and {} action dims, the world model wants {PROPRIO_DIMS} and {ACTION_DIMS}",
            clip.proprio_dims, clip.action_dims
        ));
    }
    clip.validate().map_err(|e| e.to_string())?;
    if clip.len() < min_frames {
        return Err(format!(
            "{} frame(s): at least {min_frames} are needed for a transition",
            clip.len()
        ));
    }
    finite_values(clip)
}

// ---------------------------------------------------------------------------------------------
// Data.

struct Chunk {
    clip: usize,
    start: usize,
    len: usize,
}

fn make_chunks(clips: &[Clip], chunk: usize) -> Vec<Chunk> {
    let mut out = Vec::new();
    for (i, clip) in clips.iter().enumerate() {
        let t = clip.len();
        let mut start = 0;
        while t - start >= 2 {
            let len = chunk.min(t - start);
            out.push(Chunk {
                clip: i,
                start,
                len,
            });
            start += len;
        }
    }
    out
}

fn shuffled(n: usize, seed: u64, epoch: u64) -> Vec<usize> {
    let mut rng = Rng::new(seed, &format!("world-model/epoch/{epoch}"));
    let mut idx: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        idx.swap(i, j);
    }
    idx
}

/// A batch, time-major: `len` steps of `batch` sequences.
struct Batch {
    len: i64,
    batch: i64,
    /// `[len·batch, 3, H, W]`, pixels in [−0.5, 0.5].
    images: Tensor,
    /// `[len, batch, 4]`.
    proprio: Tensor,
    actions: Tensor,
    /// `[len, batch]`, 1 for real frames, 0 for padding.
    mask: Tensor,
}

impl Batch {
    /// Sequences `(clip, start, len)`, padded at the end to the longest.
    fn from_spans(
        clips: &[Clip],
        spans: &[(usize, usize, usize)],
        size: i64,
        device: Device,
    ) -> Self {
        let b = spans.len();
        let l = spans.iter().map(|s| s.2).max().unwrap_or(0);
        let frame = (size * size * 3) as usize;
        let mut rgb = vec![0u8; l * b * frame];
        let mut proprio = vec![0f32; l * b * PROPRIO_DIMS];
        let mut actions = vec![0f32; l * b * ACTION_DIMS];
        let mut mask = vec![0f32; l * b];
        for (j, &(ci, start, len)) in spans.iter().enumerate() {
            let clip = &clips[ci];
            for t in 0..len {
                let src = start + t;
                let dst = t * b + j;
                rgb[dst * frame..(dst + 1) * frame]
                    .copy_from_slice(&clip.rgb[src * frame..(src + 1) * frame]);
                proprio[dst * PROPRIO_DIMS..(dst + 1) * PROPRIO_DIMS]
                    .copy_from_slice(&clip.proprio[src * PROPRIO_DIMS..(src + 1) * PROPRIO_DIMS]);
                actions[dst * ACTION_DIMS..(dst + 1) * ACTION_DIMS]
                    .copy_from_slice(&clip.actions[src * ACTION_DIMS..(src + 1) * ACTION_DIMS]);
                mask[dst] = 1.0;
            }
        }
        let (l, b) = (l as i64, b as i64);
        let images = Tensor::from_slice(&rgb)
            .view([l * b, size, size, 3])
            .to_device(device)
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Float)
            / 255.0
            - 0.5;
        let f = |v: &[f32], d: usize| {
            Tensor::from_slice(v)
                .view([l, b, d as i64])
                .to_device(device)
        };
        Self {
            len: l,
            batch: b,
            images,
            proprio: f(&proprio, PROPRIO_DIMS),
            actions: f(&actions, ACTION_DIMS),
            mask: Tensor::from_slice(&mask).view([l, b]).to_device(device),
        }
    }

    fn new(clips: &[Clip], chunks: &[&Chunk], size: i64, device: Device) -> Self {
        let spans: Vec<_> = chunks.iter().map(|c| (c.clip, c.start, c.len)).collect();
        Self::from_spans(clips, &spans, size, device)
    }
}

/// Gumbel noise `[len, batch, stoch, classes]` for the latents of training step `step`.
fn gumbel_noise(cfg: &DynamicsConfig, step: u64, len: i64, batch: i64, device: Device) -> Tensor {
    let mut rng = Rng::new(cfg.seed, &format!("world-model/latents/{step}"));
    let n = (len * batch * cfg.stoch * cfg.classes) as usize;
    let g: Vec<f32> = (0..n)
        .map(|_| {
            let u = rng.unit().max(1e-12);
            (-(-u.ln()).ln()) as f32
        })
        .collect();
    Tensor::from_slice(&g)
        .view([len, batch, cfg.stoch, cfg.classes])
        .to_device(device)
}

// ---------------------------------------------------------------------------------------------
// Model.

/// Creates parameters from our own random stream, so initialisation is independent of libtorch's
/// global generator.
pub(crate) struct Init {
    pub(crate) rng: Rng,
    pub(crate) device: Device,
    pub(crate) names: Vec<String>,
    pub(crate) params: Vec<Tensor>,
}

impl Init {
    fn tensor(&mut self, name: String, shape: &[i64], values: Vec<f32>) -> Tensor {
        let t = Tensor::from_slice(&values)
            .view(shape)
            .to_device(self.device)
            .set_requires_grad(true);
        self.names.push(name);
        self.params.push(t.shallow_clone());
        t
    }

    /// Xavier-uniform.
    pub(crate) fn uniform(
        &mut self,
        name: String,
        shape: &[i64],
        fan_in: i64,
        fan_out: i64,
    ) -> Tensor {
        let bound = (6.0 / (fan_in + fan_out) as f64).sqrt();
        let n: i64 = shape.iter().product();
        let values = (0..n)
            .map(|_| self.rng.uniform(-bound, bound) as f32)
            .collect();
        self.tensor(name, shape, values)
    }

    pub(crate) fn constant(&mut self, name: String, shape: &[i64], value: f32) -> Tensor {
        let n: i64 = shape.iter().product();
        self.tensor(name, shape, vec![value; n as usize])
    }
}

pub(crate) struct Linear {
    w: Tensor,
    b: Option<Tensor>,
}

impl Linear {
    pub(crate) fn new(init: &mut Init, name: &str, i: i64, o: i64, bias: bool) -> Self {
        Self {
            w: init.uniform(format!("{name}/w"), &[i, o], i, o),
            b: bias.then(|| init.constant(format!("{name}/b"), &[o], 0.0)),
        }
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Tensor {
        let y = x.matmul(&self.w);
        match &self.b {
            Some(b) => y + b,
            None => y,
        }
    }
}

/// Layer norm over the last dimension.
pub(crate) struct Norm {
    w: Tensor,
    b: Tensor,
    n: i64,
}

impl Norm {
    pub(crate) fn new(init: &mut Init, name: &str, n: i64) -> Self {
        Self {
            w: init.constant(format!("{name}/norm_w"), &[n], 1.0),
            b: init.constant(format!("{name}/norm_b"), &[n], 0.0),
            n,
        }
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Tensor {
        x.layer_norm([self.n], Some(&self.w), Some(&self.b), 1e-3, true)
    }
}

/// Linear (no bias) → LayerNorm → SiLU.
struct Dense {
    lin: Linear,
    norm: Norm,
}

impl Dense {
    fn new(init: &mut Init, name: &str, i: i64, o: i64) -> Self {
        Self {
            lin: Linear::new(init, name, i, o, false),
            norm: Norm::new(init, name, o),
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        self.norm.forward(&self.lin.forward(x)).silu()
    }
}

/// A stride-2, kernel-4 convolution (or transposed convolution) with an optional
/// GroupNorm(1) + SiLU after it (no bias then).
pub(crate) struct Conv {
    w: Tensor,
    b: Option<Tensor>,
    norm: Option<(Tensor, Tensor)>,
    transposed: bool,
}

impl Conv {
    pub(crate) fn new(
        init: &mut Init,
        name: &str,
        i: i64,
        o: i64,
        transposed: bool,
        norm: bool,
    ) -> Self {
        let shape = if transposed {
            [i, o, 4, 4]
        } else {
            [o, i, 4, 4]
        };
        Self {
            w: init.uniform(format!("{name}/w"), &shape, i * 16, o * 16),
            b: (!norm).then(|| init.constant(format!("{name}/b"), &[o], 0.0)),
            norm: norm.then(|| {
                (
                    init.constant(format!("{name}/norm_w"), &[o], 1.0),
                    init.constant(format!("{name}/norm_b"), &[o], 0.0),
                )
            }),
            transposed,
        }
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Tensor {
        let y = if self.transposed {
            x.conv_transpose2d(&self.w, self.b.as_ref(), [2, 2], [1, 1], [0, 0], 1, [1, 1])
        } else {
            x.conv2d(&self.w, self.b.as_ref(), [2, 2], [1, 1], [1, 1], 1)
        };
        match &self.norm {
            Some((w, b)) => y.group_norm(1, Some(w), Some(b), 1e-3, true).silu(),
            None => y,
        }
    }
}

/// DreamerV3's GRU: one layer-normed linear map of `[x, h]` to reset, candidate and update.
struct Gru {
    lin: Linear,
    norm: Norm,
}

impl Gru {
    fn new(init: &mut Init, name: &str, input: i64, deter: i64) -> Self {
        Self {
            lin: Linear::new(init, name, input + deter, 3 * deter, false),
            norm: Norm::new(init, name, 3 * deter),
        }
    }

    fn forward(&self, x: &Tensor, h: &Tensor) -> Tensor {
        let parts = self
            .norm
            .forward(&self.lin.forward(&Tensor::cat(&[x, h], -1)));
        let parts = parts.chunk(3, -1);
        let reset = parts[0].sigmoid();
        let cand = (&reset * &parts[1]).tanh();
        let update = (&parts[2] - 1.0).sigmoid();
        &update * cand + (1.0 - &update) * h
    }
}

struct Model {
    free_nats: f64,
    stoch: i64,
    classes: i64,
    deter: i64,
    depth: i64,
    /// Spatial size of the smallest feature map (`image_size / 16`).
    s: i64,
    enc: Vec<Conv>,
    enc_proprio: Dense,
    img_in: Dense,
    gru: Gru,
    prior_hidden: Dense,
    prior_out: Linear,
    /// The posterior's first layer, split into its `h` and `embed` parts (the `embed` part is
    /// applied to a whole sequence at once).
    post_h: Linear,
    post_e: Linear,
    post_norm: Norm,
    post_out: Linear,
    dec_in: Linear,
    dec: Vec<Conv>,
    dec_proprio: [Dense; 2],
    dec_proprio_out: Linear,
    names: Vec<String>,
    params: Vec<Tensor>,
    /// What an action is shifted by and multiplied with before it enters the model (0 and 1
    /// unless the fit normalizes actions); derived from the training clips, so a resumed fit
    /// derives the same.
    act_shift: Tensor,
    act_scale: Tensor,
}

impl Model {
    fn new(cfg: &DynamicsConfig, device: Device) -> Self {
        let mut init = Init {
            rng: Rng::new(cfg.seed, "world-model/init"),
            device,
            names: Vec::new(),
            params: Vec::new(),
        };
        let (d, h, deter) = (cfg.depth, cfg.hidden, cfg.deter);
        let zdim = cfg.stoch * cfg.classes;
        let s = i64::from(cfg.image_size) / 16;
        let conv_out = 8 * d * s * s;
        let embed = conv_out + h;
        let feat = deter + zdim;
        let chans = [3, d, 2 * d, 4 * d, 8 * d];
        let enc = (0..4)
            .map(|k| {
                Conv::new(
                    &mut init,
                    &format!("enc{k}"),
                    chans[k],
                    chans[k + 1],
                    false,
                    true,
                )
            })
            .collect();
        let enc_proprio = Dense::new(&mut init, "enc_proprio", PROPRIO_DIMS as i64, h);
        let img_in = Dense::new(&mut init, "img_in", zdim + ACTION_DIMS as i64, h);
        let gru = Gru::new(&mut init, "gru", h, deter);
        let prior_hidden = Dense::new(&mut init, "prior_hidden", deter, h);
        let prior_out = Linear::new(&mut init, "prior_out", h, zdim, true);
        let post_h = Linear::new(&mut init, "post_h", deter, h, false);
        let post_e = Linear::new(&mut init, "post_e", embed, h, false);
        let post_norm = Norm::new(&mut init, "post", h);
        let post_out = Linear::new(&mut init, "post_out", h, zdim, true);
        let dec_in = Linear::new(&mut init, "dec_in", feat, conv_out, true);
        let dec = (0..4)
            .map(|k| {
                let (i, o) = (chans[4 - k], chans[3 - k]);
                Conv::new(&mut init, &format!("dec{k}"), i, o, true, k < 3)
            })
            .collect();
        let dec_proprio = [
            Dense::new(&mut init, "dec_proprio0", feat, h),
            Dense::new(&mut init, "dec_proprio1", h, h),
        ];
        let dec_proprio_out =
            Linear::new(&mut init, "dec_proprio_out", h, PROPRIO_DIMS as i64, true);
        Self {
            free_nats: cfg.free_nats,
            stoch: cfg.stoch,
            classes: cfg.classes,
            deter,
            depth: d,
            s,
            enc,
            enc_proprio,
            img_in,
            gru,
            prior_hidden,
            prior_out,
            post_h,
            post_e,
            post_norm,
            post_out,
            dec_in,
            dec,
            dec_proprio,
            dec_proprio_out,
            names: init.names,
            params: init.params,
            act_shift: Tensor::zeros([ACTION_DIMS as i64], (Kind::Float, device)),
            act_scale: Tensor::ones([ACTION_DIMS as i64], (Kind::Float, device)),
        }
    }

    /// Normalizes actions by the per-dimension mean and deviation of `clips`' actions (a
    /// deviation under 1e-3 counts as 1e-3).
    fn normalize_actions_of(&mut self, clips: &[Clip], device: Device) {
        let (mut sum, mut sq, mut n) = ([0f64; ACTION_DIMS], [0f64; ACTION_DIMS], 0usize);
        for c in clips {
            for a in c.actions.chunks_exact(ACTION_DIMS) {
                for (k, v) in a.iter().enumerate() {
                    sum[k] += f64::from(*v);
                    sq[k] += f64::from(*v) * f64::from(*v);
                }
                n += 1;
            }
        }
        if n == 0 {
            return;
        }
        let mean: Vec<f32> = sum.iter().map(|s| (s / n as f64) as f32).collect();
        let scale: Vec<f32> = (0..ACTION_DIMS)
            .map(|k| {
                let m = sum[k] / n as f64;
                let var = (sq[k] / n as f64 - m * m).max(0.0);
                (1.0 / var.sqrt().max(1e-3)) as f32
            })
            .collect();
        self.act_shift = Tensor::from_slice(&mean).to_device(device);
        self.act_scale = Tensor::from_slice(&scale).to_device(device);
    }

    /// `[N, 3, H, W]` and `[N, 4]` → `[N, embed]`.
    fn encode(&self, images: &Tensor, proprio: &Tensor) -> Tensor {
        let mut x = images.shallow_clone();
        for c in &self.enc {
            x = c.forward(&x);
        }
        Tensor::cat(&[x.flatten(1, -1), self.enc_proprio.forward(proprio)], -1)
    }

    /// `[N, feat]` → image `[N, 3, H, W]` (in [−0.5, 0.5] units) and proprio `[N, 4]`.
    fn decode(&self, feat: &Tensor) -> (Tensor, Tensor) {
        let n = feat.size()[0];
        let mut x = self
            .dec_in
            .forward(feat)
            .view([n, 8 * self.depth, self.s, self.s]);
        for c in &self.dec {
            x = c.forward(&x);
        }
        let p = self.dec_proprio[1].forward(&self.dec_proprio[0].forward(feat));
        (x, self.dec_proprio_out.forward(&p))
    }

    /// Raw logits `[..., stoch·classes]` → unimix log-probabilities `[..., stoch, classes]`.
    fn unimix(&self, logits: &Tensor) -> Tensor {
        let mut shape = logits.size();
        shape.pop();
        shape.extend([self.stoch, self.classes]);
        let probs = logits.view(shape.as_slice()).softmax(-1, Kind::Float);
        (probs * (1.0 - UNIMIX) + UNIMIX / self.classes as f64).log()
    }

    fn prior(&self, h: &Tensor) -> Tensor {
        self.unimix(&self.prior_out.forward(&self.prior_hidden.forward(h)))
    }

    /// `e_proj`: the embedding already through `post_e`.
    fn posterior(&self, h: &Tensor, e_proj: &Tensor) -> Tensor {
        let x = self
            .post_norm
            .forward(&(self.post_h.forward(h) + e_proj))
            .silu();
        self.unimix(&self.post_out.forward(&x))
    }

    fn flat(&self, z: &Tensor) -> Tensor {
        let mut shape = z.size();
        shape.truncate(shape.len() - 2);
        shape.push(self.stoch * self.classes);
        z.view(shape.as_slice())
    }

    /// A straight-through sample `[B, stoch·classes]` from log-probabilities `[B, S, C]`.
    fn sample(&self, logp: &Tensor, gumbel: &Tensor) -> Tensor {
        let idx = (logp.detach() + gumbel).argmax(-1, false);
        let onehot = idx.one_hot(self.classes).to_kind(Kind::Float);
        let probs = logp.exp();
        self.flat(&(onehot + &probs - probs.detach()))
    }

    fn mode(&self, logp: &Tensor) -> Tensor {
        self.flat(
            &logp
                .argmax(-1, false)
                .one_hot(self.classes)
                .to_kind(Kind::Float),
        )
    }

    fn step_h(&self, h: &Tensor, z: &Tensor, a: &Tensor) -> Tensor {
        let a = (a - &self.act_shift) * &self.act_scale;
        self.gru
            .forward(&self.img_in.forward(&Tensor::cat(&[z, &a], -1)), h)
    }

    /// The training loss of a batch (mean over its valid frames).
    fn loss(&self, batch: &Batch, gumbel: &Tensor) -> Tensor {
        let (l, b) = (batch.len, batch.batch);
        let embed = self.encode(&batch.images, &batch.proprio.view([l * b, -1]));
        let e_proj = self.post_e.forward(&embed).view([l, b, -1]);
        let mut h = Tensor::zeros([b, self.deter], (Kind::Float, batch.images.device()));
        let (mut hs, mut zs, mut posts) = (Vec::new(), Vec::new(), Vec::new());
        for t in 0..l {
            let post = self.posterior(&h, &e_proj.get(t));
            let z = self.sample(&post, &gumbel.get(t));
            let next = (t + 1 < l).then(|| self.step_h(&h, &z, &batch.actions.get(t)));
            hs.push(h);
            zs.push(z);
            posts.push(post);
            if let Some(next) = next {
                h = next;
            } else {
                break;
            }
        }
        let h_all = Tensor::stack(&hs, 0);
        let z_all = Tensor::stack(&zs, 0);
        let post = Tensor::stack(&posts, 0);
        let prior = self.prior(&h_all);
        let feat = Tensor::cat(&[h_all, z_all], -1).view([l * b, -1]);
        let (img, prop) = self.decode(&feat);
        let img_sse = (img - &batch.images)
            .square()
            .sum_dim_intlist(&[1, 2, 3][..], false, Kind::Float)
            .view([l, b]);
        let prop_sse = (prop.view([l, b, -1]) - &batch.proprio)
            .square()
            .sum_dim_intlist(&[-1][..], false, Kind::Float);
        let kl = |p: &Tensor, q: &Tensor| {
            (p.exp() * (p - q)).sum_dim_intlist(&[-2, -1][..], false, Kind::Float)
        };
        let dyn_kl = kl(&post.detach(), &prior).clamp_min(self.free_nats);
        let rep_kl = kl(&post, &prior.detach()).clamp_min(self.free_nats);
        let per_frame = img_sse + prop_sse + dyn_kl * DYN_SCALE + rep_kl * REP_SCALE;
        (per_frame * &batch.mask).sum(Kind::Float) / batch.mask.sum(Kind::Float)
    }

    /// One-step prediction errors of each clip (see the module docs). Run under `no_grad`.
    fn evaluate(&self, clips: &[Clip], group: usize, size: i64, device: Device) -> Vec<EvalClip> {
        let mut out = Vec::with_capacity(clips.len());
        for first in (0..clips.len()).step_by(group.max(1)) {
            let last = (first + group.max(1)).min(clips.len());
            let spans: Vec<_> = (first..last).map(|i| (i, 0, clips[i].len())).collect();
            let batch = Batch::from_spans(clips, &spans, size, device);
            let (l, b) = (batch.len, batch.batch);
            let embed = self.encode(&batch.images, &batch.proprio.view([l * b, -1]));
            let e_proj = self.post_e.forward(&embed).view([l, b, -1]);
            let mut h = Tensor::zeros([b, self.deter], (Kind::Float, device));
            let mut next_hs = Vec::new();
            for t in 0..l - 1 {
                let z = self.mode(&self.posterior(&h, &e_proj.get(t)));
                h = self.step_h(&h, &z, &batch.actions.get(t));
                next_hs.push(h.shallow_clone());
            }
            let h_next = Tensor::stack(&next_hs, 0);
            let z_next = self.mode(&self.prior(&h_next));
            let feat = Tensor::cat(&[h_next, z_next], -1).view([(l - 1) * b, -1]);
            let (img, prop) = self.decode(&feat);
            let target = batch.images.view([l, b, 3, size, size]).narrow(0, 1, l - 1);
            let img = img.clamp(-0.5, 0.5).view([l - 1, b, 3, size, size]);
            let img_err = (img - target)
                .square()
                .mean_dim(&[2, 3, 4][..], false, Kind::Float);
            let prop_err = (prop.view([l - 1, b, -1]) - batch.proprio.narrow(0, 1, l - 1))
                .square()
                .mean_dim(&[-1][..], false, Kind::Float);
            let mask = batch.mask.narrow(0, 1, l - 1);
            let img_sum = (img_err * &mask)
                .sum_dim_intlist(&[0][..], false, Kind::Double)
                .to_device(Device::Cpu);
            let prop_sum = (prop_err * &mask)
                .sum_dim_intlist(&[0][..], false, Kind::Double)
                .to_device(Device::Cpu);
            for (j, i) in (first..last).enumerate() {
                out.push(EvalClip {
                    frames: clips[i].len() - 1,
                    image_sse: img_sum.double_value(&[j as i64]),
                    proprio_sse: prop_sum.double_value(&[j as i64]),
                });
            }
        }
        out
    }

    /// Copies saved parameters (`{prefix}/{name}`) into the model.
    fn restore(
        &mut self,
        saved: &HashMap<String, Tensor>,
        prefix: &str,
    ) -> Result<(), WorldModelError> {
        tch::no_grad(|| {
            for (name, p) in self.names.iter().zip(self.params.iter_mut()) {
                let src = lookup(saved, prefix, name, p)?;
                p.f_copy_(src)?;
            }
            Ok(())
        })
    }
}

struct EvalClip {
    frames: usize,
    /// Sums over the clip's predicted frames of the per-frame mean squared errors.
    image_sse: f64,
    proprio_sse: f64,
}

pub(crate) fn lookup<'a>(
    saved: &'a HashMap<String, Tensor>,
    prefix: &str,
    name: &str,
    like: &Tensor,
) -> Result<&'a Tensor, WorldModelError> {
    let key = format!("{prefix}/{name}");
    let t = saved
        .get(&key)
        .ok_or_else(|| WorldModelError::CheckpointRefused(format!("it has no tensor {key}")))?;
    if t.size() != like.size() {
        return Err(WorldModelError::CheckpointRefused(format!(
            "tensor {key} has shape {:?}, the model {:?}",
            t.size(),
            like.size()
        )));
    }
    Ok(t)
}

fn restore_moments(
    moments: &mut [Tensor],
    names: &[String],
    saved: &HashMap<String, Tensor>,
    prefix: &str,
) -> Result<(), WorldModelError> {
    for (name, m) in names.iter().zip(moments.iter_mut()) {
        let src = lookup(saved, prefix, name, m)?;
        *m = src.f_to_device(m.device())?.f_contiguous()?.copy();
    }
    Ok(())
}
