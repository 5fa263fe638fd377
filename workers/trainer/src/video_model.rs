//! An action-conditioned video world model (issue 44): from a real frame and state, it predicts
//! the next frames and states open loop, one per action, the way the proxy imagines a policy's
//! rollout. Built so that it cannot do well without its actions (the RSSM of `world_model.rs`,
//! trained to filter observations one step ahead, scored the same with shuffled actions).
//!
//! # Model
//! - **Encoder** of the start frame (scaled to [0, 1] then −0.5): three stride-2 convolutions
//!   (kernel 4; channels `depth`, 2·`depth`, 4·`depth`; one-group GroupNorm and SiLU — the RSSM's
//!   layers), giving a latent map `z₀` at 1/8 of the frame size. The normalised state enters
//!   through a linear layer added to every position of `z₀`.
//! - **Actions**: each dimension normalised (zero mean, unit deviation over the training clips),
//!   then Fourier features `[a, sin(π·2^k·a), cos(π·2^k·a)]` for `k < fourier`, through
//!   Linear → SiLU → Linear to an embedding of `action_embed` values — the paper's recipe, where
//!   the embedding is added to the diffusion model's time embedding; here it conditions every
//!   block of the latent dynamics.
//! - **Latent dynamics**, one step per action: `blocks` residual blocks on the latent map, each
//!   3×3 conv → GroupNorm → FiLM from the action embedding (`x·(1 + scale) + shift`) → SiLU →
//!   3×3 conv, added to the map. The state moves by a delta from the pooled map and the
//!   embedding (Linear → SiLU → Linear). Autoregressive in the latent: the next step starts
//!   from this step's map, never from a re-encoded prediction.
//! - **Decoder** per step: transposed convolutions back to the frame size with skip connections
//!   from the *start frame's* encoder maps (a U-Net whose encoder side is the real start), ending
//!   in an RGB image and a mask `α`; the frame is `α·rgb + (1 − α)·start`. What does not move is
//!   copied from the real start, so the error left is where things moved — which only the
//!   actions can tell (Finn et al. 2016's compositing, with the start frame as the source).
//!   Beside the latent the decoder's first layer gets the predicted normalised state, broadcast,
//!   and each position's x and y; with `tool_heatmap`, every decoder layer also gets two heat
//!   maps, Gaussian bumps one cell wide at the tool's place now and at the start, the place a
//!   learned linear map of the state: where to draw the tool and where to paint it out.
//! - **Objects** (`object_weight` above 0, every training clip with the same objects' section,
//!   `Clip::objects`): the scene objects' positions join the state — normalised, through
//!   `state_in`, predicted by deltas, broadcast to the decoder — and the delta head also reads
//!   the state it predicted last, so that "the block moves with the tool while it is held" is a
//!   function it can learn. Imagined frames carry them (`WorldFrame::objects`) apart from the
//!   state a policy sees; a start must give them (`WorldStart::objects`).
//!
//! # Training
//! Windows of the training clips: every start `t₀` of a clip with a following frame, the next
//! `horizon` frames (fewer at a clip's end; masked). Each step draws `batch` windows uniformly
//! with replacement (stream `video-model/batch/{step}`) and rolls the model out **open loop**
//! from the window's real first frame and state with the clip's actions. Loss: the mean absolute
//! error of the predicted frames (in [0, 1]; `pixel_loss: l2` for the squared error), each pixel
//! that differs from the window's first frame weighted `1 + motion_weight`, plus `state_weight`
//! times the normalised state's mean squared error (and `object_weight` times the objects'),
//! over the window's real frames. Adam (`adam.rs`),
//! its learning rate decayed from `lr` to a tenth of it over the fit's steps (cosine), gradients
//! clipped at a global norm of 100.
//! Initial weights come from the stream `video-model/init`; nothing draws from libtorch's global
//! generator, so the same config and clips give the same weights (on one CPU thread, to the bit)
//! and a fit resumed from a checkpoint ends where an uninterrupted one does.
//!
//! # Checkpoints
//! The header `ASYVM001`, the hashes of the training settings and of the clips, the step and
//! Adam's step count, then the parameters, Adam's moments and the normalisation statistics
//! (libtorch's stream format). A checkpoint of another config or other clips is refused;
//! [`VideoModel::from_checkpoint`] loads one to imagine in without the clips.

use std::collections::HashMap;
use std::time::Instant;

use assay_model::clip::Clip;
use assay_model::interface::Interface;
use assay_model::video::{PixelLoss, VideoFit, VideoModelConfig};
use assay_model::world::{ImaginedEpisode, WorldError, WorldFrame, WorldModelService, WorldStart};
use assay_spec::rng::Rng;
use tch::{Device, Kind, Tensor};

use crate::adam::Adam;
use crate::world_model::{Conv, Init, Linear, WorldModelError, device_name, lookup, world_frames};

const GRAD_CLIP: f64 = 100.0;

mod checkpoint;
mod layout;

use checkpoint::{config_hash, read_checkpoint, read_layout, write_checkpoint};
pub(crate) use layout::resized;
use layout::{Layout, resized_to};

/// A trained (or training) video world model.
pub struct VideoModel {
    net: Net,
    size: i64,
    layout: Layout,
    device: Device,
}

/// Receives `(step, checkpoint bytes)`; an `Err` stops the fit.
pub type CheckpointSink<'a> = dyn FnMut(u64, &[u8]) -> Result<(), String> + 'a;

/// Trains the model on `train` (clips of the config's frame size, 4 state and 4 action dims).
/// `resume`: a checkpoint of an earlier attempt of the same fit.
pub fn fit(
    cfg: &VideoModelConfig,
    train: &[Clip],
    device: Device,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<(VideoModel, VideoFit), WorldModelError> {
    fit_keeping(cfg, train, device, resume, on_checkpoint, false).map(|(m, f, _)| (m, f))
}

/// [`fit`], also returning a checkpoint of its last step: resuming from it trains no further
/// (the proxy's world model fitted ahead, while a ladder trains).
pub fn fit_to_checkpoint(
    cfg: &VideoModelConfig,
    train: &[Clip],
    device: Device,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<(VideoFit, Vec<u8>), WorldModelError> {
    let (_, fit, last) = fit_keeping(cfg, train, device, resume, on_checkpoint, true)?;
    Ok((fit, last.expect("asked for the last checkpoint")))
}

fn fit_keeping(
    cfg: &VideoModelConfig,
    train: &[Clip],
    device: Device,
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
    keep_last: bool,
) -> Result<(VideoModel, VideoFit, Option<Vec<u8>>), WorldModelError> {
    cfg.validate().map_err(WorldModelError::Request)?;
    let Some(first) = train.first() else {
        return Err(WorldModelError::Request("no training clips".into()));
    };
    let layout = Layout::of_training(train, cfg.object_weight > 0.0);
    let size = if cfg.image_size > 0 {
        cfg.image_size
    } else if first.width == first.height {
        first.width
    } else {
        return Err(WorldModelError::Request(format!(
            "frames of {}x{}: give the video model an image_size (the clips' frames are not square)",
            first.width, first.height
        )));
    };
    if size == 0 || !size.is_multiple_of(8) {
        return Err(WorldModelError::Request(format!(
            "frames of {size} pixels: the video model needs a positive multiple of 8 (three stride-2 stages)"
        )));
    }
    for (i, clip) in train.iter().enumerate() {
        layout
            .check(clip)
            .map_err(|reason| WorldModelError::BadClip {
                clip: format!("train clip {i}"),
                reason,
            })?;
    }
    let windows = windows(train, cfg.horizon);
    if windows.is_empty() {
        return Err(WorldModelError::Request(format!(
            "{} training clips hold no window of 2 frames or more",
            train.len()
        )));
    }
    if device == Device::Cpu {
        tch::set_num_threads(cfg.threads.max(1) as i32);
    }
    let size = i64::from(size);
    let mut net = Net::new(cfg, &layout, device);
    net.stats = Stats::of(train, &layout, device);
    let mut adam = Adam::new(&net.params, cfg.lr, GRAD_CLIP);
    let (config_hash, data_hash) = (config_hash(cfg), crate::world_model::clips_hash(train));

    let mut step = 0u64;
    let mut resumed_from_step = None;
    if let Some(bytes) = resume {
        let saved = read_checkpoint(bytes, Some((config_hash, data_hash)), device)?;
        if saved.step > cfg.steps {
            return Err(WorldModelError::CheckpointRefused(format!(
                "it is at step {}, beyond this fit's {} steps",
                saved.step, cfg.steps
            )));
        }
        net.restore(&saved.tensors, "p")?;
        for (prefix, moments) in [("m", &mut adam.m), ("v", &mut adam.v)] {
            for (name, m) in net.names.iter().zip(moments.iter_mut()) {
                *m = lookup(&saved.tensors, prefix, name, m)?.copy();
            }
        }
        adam.t = saved.adam_t;
        step = saved.step;
        resumed_from_step = Some(step);
    }

    let started = Instant::now();
    let first_step = step;
    let mut recent = (0.0f64, 0u64);
    while step < cfg.steps {
        let mut rng = Rng::new(cfg.seed, &format!("video-model/batch/{step}"));
        let picked: Vec<&Window> = (0..cfg.batch)
            .map(|_| &windows[(rng.next_u64() % windows.len() as u64) as usize])
            .collect();
        let batch = Batch::new(train, &picked, &layout, size, device);
        let loss = net.loss(&batch, cfg);
        loss.backward();
        adam.lr = learning_rate(cfg, step);
        adam.step(&mut net.params);
        let value = loss.double_value(&[]);
        if cfg.steps - step <= 100 {
            recent.0 += value;
            recent.1 += 1;
        }
        step += 1;
        if cfg.checkpoint_every > 0
            && step.is_multiple_of(cfg.checkpoint_every as u64)
            && step < cfg.steps
        {
            let bytes = write_checkpoint(&net, &adam, &layout, size, config_hash, data_hash, step)?;
            on_checkpoint(step, &bytes)
                .map_err(|reason| WorldModelError::Checkpoint { step, reason })?;
        }
    }
    let done = step - first_step;
    let seconds = started.elapsed().as_secs_f64();
    let last = if keep_last {
        Some(write_checkpoint(
            &net,
            &adam,
            &layout,
            size,
            config_hash,
            data_hash,
            step,
        )?)
    } else {
        None
    };
    let fit = VideoFit {
        train_clips: train.len() as u32,
        windows: windows.len() as u64,
        steps: step,
        resumed_from_step,
        final_train_loss: if recent.1 > 0 {
            recent.0 / recent.1 as f64
        } else {
            0.0
        },
        steps_per_s: if done > 0 && seconds > 0.0 {
            done as f64 / seconds
        } else {
            0.0
        },
        device: device_name(device),
        config: cfg.clone(),
    };
    tracing::info!(
        steps = fit.steps,
        loss = fit.final_train_loss,
        steps_per_s = fit.steps_per_s,
        "video world model fitted"
    );
    Ok((
        VideoModel {
            net,
            size,
            layout,
            device,
        },
        fit,
        last,
    ))
}

impl VideoModel {
    /// The model a checkpoint holds (of any fit), to imagine in. `size`: the side of the frames
    /// it works at, for a checkpoint that does not say (one of the original interface).
    pub fn from_checkpoint(
        cfg: &VideoModelConfig,
        size: u32,
        bytes: &[u8],
        device: Device,
    ) -> Result<Self, WorldModelError> {
        cfg.validate().map_err(WorldModelError::Request)?;
        let saved = read_checkpoint(bytes, None, device)?;
        if saved.config_hash != config_hash(cfg) {
            return Err(WorldModelError::CheckpointRefused(
                "it was written for another video-model config".into(),
            ));
        }
        let (layout, size) = read_layout(&saved.tensors, size)?;
        let mut net = Net::new(cfg, &layout, device);
        net.restore(&saved.tensors, "p")?;
        net.stats = Stats::restore(&saved.tensors, device)?;
        Ok(Self {
            net,
            size: i64::from(size),
            layout,
            device,
        })
    }

    /// A checkpoint of the model as it is (Adam's moments zero): what
    /// [`VideoModel::from_checkpoint`] reads.
    pub fn to_checkpoint(&self, cfg: &VideoModelConfig) -> Result<Vec<u8>, WorldModelError> {
        let adam = Adam::new(&self.net.params, cfg.lr, GRAD_CLIP);
        write_checkpoint(
            &self.net,
            &adam,
            &self.layout,
            self.size,
            config_hash(cfg),
            0,
            cfg.steps,
        )
    }

    /// The same model with tensors of its own (its checkpoint read back), to imagine in on
    /// another thread (tensors are not `Sync`).
    pub fn copy(&self, cfg: &VideoModelConfig) -> Result<Self, WorldModelError> {
        let size = self.size as u32;
        Self::from_checkpoint(cfg, size, &self.to_checkpoint(cfg)?, self.device)
    }

    pub fn image_size(&self) -> u32 {
        self.size as u32
    }

    /// Trained parameters (weights and biases), as PyTorch's `sum(p.numel())` counts them.
    pub fn parameters(&self) -> i64 {
        self.net.params.iter().map(Tensor::numel).sum::<usize>() as i64
    }
}

/// Cosine decay from `lr` to a tenth of it over the fit's steps.
fn learning_rate(cfg: &VideoModelConfig, step: u64) -> f64 {
    let progress = step as f64 / cfg.steps.max(1) as f64;
    cfg.lr * (0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos()))
}

// ---------------------------------------------------------------------------------------------
// Data.

struct Window {
    clip: usize,
    start: usize,
    /// Predicted frames (1..=horizon).
    len: usize,
}

fn windows(clips: &[Clip], horizon: usize) -> Vec<Window> {
    let mut out = Vec::new();
    for (i, clip) in clips.iter().enumerate() {
        let t = clip.len();
        for start in 0..t.saturating_sub(1) {
            out.push(Window {
                clip: i,
                start,
                len: horizon.min(t - 1 - start),
            });
        }
    }
    out
}

/// A batch of windows: first frames and states, then `len` steps, time-major. Every camera is
/// at the model's `size`, the cameras stacked on the channels.
struct Batch {
    /// `[B, 3·cams, S, S]` in [0, 1].
    first: Tensor,
    /// `[B, P]`, raw.
    state: Tensor,
    /// `[L, B, A]`, raw.
    actions: Tensor,
    /// `[L, B, 3·cams, S, S]` in [0, 1].
    targets: Tensor,
    /// `[L, B, P]`, raw.
    target_states: Tensor,
    /// `[L, B]`.
    mask: Tensor,
}

impl Batch {
    fn new(clips: &[Clip], picked: &[&Window], layout: &Layout, size: i64, device: Device) -> Self {
        let b = picked.len();
        let l = picked.iter().map(|w| w.len).max().unwrap_or(1);
        let (p, a) = (layout.width(), layout.action);
        let mut state = vec![0f32; b * p];
        let mut actions = vec![0f32; l * b * a];
        let mut target_states = vec![0f32; l * b * p];
        let mut mask = vec![0f32; l * b];
        // Per camera: the first frames and the targets at the camera's size.
        let mut firsts = Vec::with_capacity(layout.cameras.len());
        let mut targets = Vec::with_capacity(layout.cameras.len());
        for (k, (_, cw, ch)) in layout.cameras.iter().enumerate() {
            let frame = (cw * ch * 3) as usize;
            fn at(c: &Clip, k: usize, t: usize) -> &[u8] {
                if k == 0 {
                    c.frame(t)
                } else {
                    c.views[k - 1].frame(t)
                }
            }
            let mut first = vec![0u8; b * frame];
            let mut target = vec![0u8; l * b * frame];
            for (j, w) in picked.iter().enumerate() {
                let c = &clips[w.clip];
                first[j * frame..(j + 1) * frame].copy_from_slice(at(c, k, w.start));
                for t in 0..w.len {
                    let dst = t * b + j;
                    target[dst * frame..(dst + 1) * frame].copy_from_slice(at(
                        c,
                        k,
                        w.start + t + 1,
                    ));
                }
            }
            let (cw, ch) = (i64::from(*cw), i64::from(*ch));
            firsts.push(resized(&pixels(&first, b as i64, ch, cw, device), size));
            targets.push(resized(
                &pixels(&target, (l * b) as i64, ch, cw, device),
                size,
            ));
        }
        for (j, w) in picked.iter().enumerate() {
            let c = &clips[w.clip];
            for (x, v) in state[j * p..(j + 1) * p]
                .iter_mut()
                .zip(layout.state_at(c, w.start))
            {
                *x = *v;
            }
            for t in 0..w.len {
                let (src, dst) = (w.start + t, t * b + j);
                actions[dst * a..(dst + 1) * a].copy_from_slice(&c.actions[src * a..(src + 1) * a]);
                for (x, v) in target_states[dst * p..(dst + 1) * p]
                    .iter_mut()
                    .zip(layout.state_at(c, src + 1))
                {
                    *x = *v;
                }
                mask[dst] = 1.0;
            }
        }
        let (l, b) = (l as i64, b as i64);
        let channels = layout.channels();
        Self {
            first: Tensor::cat(&firsts, 1),
            state: Tensor::from_slice(&state).view([b, -1]).to_device(device),
            actions: Tensor::from_slice(&actions)
                .view([l, b, -1])
                .to_device(device),
            targets: Tensor::cat(&targets, 1).view([l, b, channels, size, size]),
            target_states: Tensor::from_slice(&target_states)
                .view([l, b, -1])
                .to_device(device),
            mask: Tensor::from_slice(&mask).view([l, b]).to_device(device),
        }
    }
}

/// `n` RGB frames (HWC bytes) of `h`×`w` as `[n, 3, h, w]` floats in [0, 1].
fn pixels(rgb: &[u8], n: i64, h: i64, w: i64, device: Device) -> Tensor {
    Tensor::from_slice(rgb)
        .view([n, h, w, 3])
        .to_device(device)
        .permute([0, 3, 1, 2])
        .to_kind(Kind::Float)
        / 255.0
}

/// Per-dimension shift and scale of actions and states, from the training clips (the last
/// frame's action, all zeros by format, left out). A dimension that never changes maps to 0.
struct Stats {
    act_mean: Tensor,
    act_dev: Tensor,
    state_mean: Tensor,
    state_dev: Tensor,
}

impl Stats {
    fn identity(layout: &Layout, device: Device) -> Self {
        let z = |n: usize| Tensor::zeros([n as i64], (Kind::Float, device));
        let o = |n: usize| Tensor::ones([n as i64], (Kind::Float, device));
        Self {
            act_mean: z(layout.action),
            act_dev: o(layout.action),
            state_mean: z(layout.width()),
            state_dev: o(layout.width()),
        }
    }

    fn of(clips: &[Clip], layout: &Layout, device: Device) -> Self {
        let (p, a) = (layout.width(), layout.action);
        let moments = |rows: &mut dyn Iterator<Item = &[f32]>, d: usize| {
            let (mut s, mut s2, mut n) = (vec![0f64; d], vec![0f64; d], 0f64);
            for row in rows {
                for k in 0..d {
                    let v = f64::from(row[k]);
                    s[k] += v;
                    s2[k] += v * v;
                }
                n += 1.0;
            }
            let n = n.max(1.0);
            let mean: Vec<f32> = s.iter().map(|v| (v / n) as f32).collect();
            let dev: Vec<f32> = (0..d)
                .map(|k| {
                    let var = (s2[k] / n - (s[k] / n).powi(2)).max(0.0);
                    if var.sqrt() < 1e-6 {
                        1.0
                    } else {
                        var.sqrt() as f32
                    }
                })
                .collect();
            (
                Tensor::from_slice(&mean).to_device(device),
                Tensor::from_slice(&dev).to_device(device),
            )
        };
        let (act_mean, act_dev) = moments(
            &mut clips
                .iter()
                .flat_map(|c| c.actions.chunks(a).take(c.len().saturating_sub(1))),
            a,
        );
        let states: Vec<f32> = clips
            .iter()
            .flat_map(|c| (0..c.len()).flat_map(move |t| layout.state_at(c, t)))
            .copied()
            .collect();
        let (state_mean, state_dev) = moments(&mut states.chunks(p), p);
        Self {
            act_mean,
            act_dev,
            state_mean,
            state_dev,
        }
    }

    fn named(&self) -> [(&'static str, &Tensor); 4] {
        [
            ("stats/act_mean", &self.act_mean),
            ("stats/act_dev", &self.act_dev),
            ("stats/state_mean", &self.state_mean),
            ("stats/state_dev", &self.state_dev),
        ]
    }

    fn restore(saved: &HashMap<String, Tensor>, device: Device) -> Result<Self, WorldModelError> {
        let get = |k: &str| {
            saved
                .get(k)
                .map(|t| t.to_device(device))
                .ok_or_else(|| WorldModelError::CheckpointRefused(format!("it has no tensor {k}")))
        };
        Ok(Self {
            act_mean: get("stats/act_mean")?,
            act_dev: get("stats/act_dev")?,
            state_mean: get("stats/state_mean")?,
            state_dev: get("stats/state_dev")?,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Model.

/// 3×3 convolution, stride 1, with bias.
struct Conv3 {
    w: Tensor,
    b: Tensor,
}

impl Conv3 {
    fn new(init: &mut Init, name: &str, i: i64, o: i64) -> Self {
        Self {
            w: init.uniform(format!("{name}/w"), &[o, i, 3, 3], i * 9, o * 9),
            b: init.constant(format!("{name}/b"), &[o], 0.0),
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        x.conv2d(&self.w, Some(&self.b), [1, 1], [1, 1], [1, 1], 1)
    }
}

/// conv → GroupNorm → FiLM(action) → SiLU → conv, added to the input.
struct Block {
    c: i64,
    groups: i64,
    conv1: Conv3,
    film: Linear,
    conv2: Conv3,
}

impl Block {
    fn new(init: &mut Init, name: &str, c: i64, embed: i64) -> Self {
        Self {
            c,
            groups: (1..=8).rev().find(|g| c % g == 0).unwrap_or(1),
            conv1: Conv3::new(init, &format!("{name}/conv1"), c, c),
            film: Linear::new(init, &format!("{name}/film"), embed, 2 * c, true),
            conv2: Conv3::new(init, &format!("{name}/conv2"), c, c),
        }
    }

    fn forward(&self, z: &Tensor, emb: &Tensor) -> Tensor {
        let h = self.conv1.forward(z).group_norm(
            self.groups,
            None::<Tensor>,
            None::<Tensor>,
            1e-5,
            true,
        );
        let film = self.film.forward(emb).view([-1, 2, self.c, 1, 1]);
        let h = (h * (film.select(1, 0) + 1.0) + film.select(1, 1)).silu();
        z + self.conv2.forward(&h)
    }
}

struct Net {
    c: i64,
    fourier: usize,
    /// Cameras stacked on the channels, and the state's floats (the objects' last).
    cams: i64,
    state_dims: i64,
    /// Of the state's floats, the objects' (0: none; else the delta head reads the state).
    objects: i64,
    enc: Vec<Conv>,
    state_in: Linear,
    act_in: Linear,
    act_out: Linear,
    blocks: Vec<Block>,
    head_hidden: Linear,
    head_out: Linear,
    /// The tool's place in the frame from the normalised state (learned): where the heat maps
    /// beside the decoder's inputs peak.
    proj: Option<Linear>,
    /// Transposed convolutions: latent → 1/4, (1/4 + skip) → 1/2, (1/2 + skip) → RGB + mask.
    dec: Vec<Conv>,
    names: Vec<String>,
    params: Vec<Tensor>,
    stats: Stats,
}

impl Net {
    fn new(cfg: &VideoModelConfig, layout: &Layout, device: Device) -> Self {
        let mut init = Init {
            rng: Rng::new(cfg.seed, "video-model/init"),
            device,
            names: Vec::new(),
            params: Vec::new(),
        };
        let d = cfg.depth;
        let c = 4 * d;
        let e = cfg.action_embed;
        let (cams, p) = (layout.cameras.len() as i64, layout.width() as i64);
        let objects = layout.objects as i64;
        // The maps beside the latent at the decoder's input: the predicted normalised state,
        // broadcast, and the x and y coordinates of each position in [−1, 1].
        let guides = p + 2;
        let features = (layout.action * (1 + 2 * cfg.fourier)) as i64;
        let enc = vec![
            Conv::new(&mut init, "enc0", 3 * cams, d, false, true),
            Conv::new(&mut init, "enc1", d, 2 * d, false, true),
            Conv::new(&mut init, "enc2", 2 * d, c, false, true),
        ];
        let state_in = Linear::new(&mut init, "state_in", p, c, true);
        let act_in = Linear::new(&mut init, "act_in", features, e, true);
        let act_out = Linear::new(&mut init, "act_out", e, e, true);
        let blocks = (0..cfg.blocks)
            .map(|i| Block::new(&mut init, &format!("block{i}"), c, e))
            .collect();
        let head_in = c + e + if objects > 0 { p } else { 0 };
        let head_hidden = Linear::new(&mut init, "head_hidden", head_in, 64, true);
        let head_out = Linear::new(&mut init, "head_out", 64, p, true);
        let heat = if cfg.tool_heatmap { 2 } else { 0 };
        let proj = cfg
            .tool_heatmap
            .then(|| Linear::new(&mut init, "proj", p, 2, true));
        let dec = vec![
            Conv::new(&mut init, "dec0", c + guides + heat, 2 * d, true, true),
            Conv::new(&mut init, "dec1", 4 * d + heat, d, true, true),
            Conv::new(&mut init, "dec2", 2 * d + heat, 4 * cams, true, false),
        ];
        Self {
            c,
            fourier: cfg.fourier,
            cams,
            state_dims: p,
            objects,
            enc,
            state_in,
            act_in,
            act_out,
            blocks,
            head_hidden,
            head_out,
            proj,
            dec,
            names: init.names,
            params: init.params,
            stats: Stats::identity(layout, device),
        }
    }

    /// Raw actions `[..., A]` → embeddings `[..., E]`.
    fn embed(&self, actions: &Tensor) -> Tensor {
        let a = ((actions - &self.stats.act_mean) / &self.stats.act_dev).clamp(-10.0, 10.0);
        let mut feats = vec![a.shallow_clone()];
        for k in 0..self.fourier {
            let x = &a * (std::f64::consts::PI * f64::from(1u32 << k));
            feats.push(x.sin());
            feats.push(x.cos());
        }
        let f = Tensor::cat(&feats, -1);
        self.act_out.forward(&self.act_in.forward(&f).silu())
    }

    /// The start of a rollout: the first frames `[B, 3·cams, S, S]` in [0, 1] and the raw state
    /// `[B, P]`.
    fn start(&self, first: &Tensor, state: &Tensor) -> Rollout {
        let s1 = self.enc[0].forward(&(first - 0.5));
        let s2 = self.enc[1].forward(&s1);
        let sn = (state - &self.stats.state_mean) / &self.stats.state_dev;
        let z = self.enc[2].forward(&s2) + self.state_in.forward(&sn).view([-1, self.c, 1, 1]);
        let m = z.size()[2];
        let line = Tensor::linspace(-1.0, 1.0, m, (Kind::Float, z.device()));
        let coords = Tensor::stack(
            &[
                line.view([1, m]).expand([m, m], false),
                line.view([m, 1]).expand([m, m], false),
            ],
            0,
        )
        .unsqueeze(0);
        let uv0 = self.proj.as_ref().map(|p| p.forward(&sn));
        Rollout {
            coords,
            uv0,
            first: first.shallow_clone(),
            skips: [s1, s2],
            z,
            state: sn,
        }
    }

    /// One step with embedded actions `[B, E]`: the next frames `[B, 3·cams, S, S]` in [0, 1]
    /// (each camera's RGB composited over its start through its mask), the next normalised
    /// state, and the RGB `[B, 3·cams, S, S]` and masks `[B, cams, S, S]` before compositing.
    fn step(&self, r: &mut Rollout, emb: &Tensor) -> Step {
        let mut z = r.z.shallow_clone();
        for block in &self.blocks {
            z = block.forward(&z, emb);
        }
        let pooled = z.mean_dim([2i64, 3].as_slice(), false, Kind::Float);
        let head_in = if self.objects > 0 {
            Tensor::cat(&[&pooled, emb, &r.state], -1)
        } else {
            Tensor::cat(&[&pooled, emb], -1)
        };
        let delta = self
            .head_out
            .forward(&self.head_hidden.forward(&head_in).silu());
        r.state = &r.state + delta;
        let (b, m) = (z.size()[0], z.size()[2]);
        let guides = Tensor::cat(
            &[
                r.state
                    .view([b, -1, 1, 1])
                    .expand([b, self.state_dims, m, m], false),
                r.coords.expand([b, 2, m, m], false),
            ],
            1,
        );
        // The heat maps of the tool now and at the start, at a decoder input's size `m`.
        let uv = self.proj.as_ref().map(|p| p.forward(&r.state));
        let with_heat = |x: Tensor, parts: &[&Tensor]| -> Tensor {
            let m = x.size()[2];
            let mut all: Vec<Tensor> = vec![x];
            all.extend(parts.iter().map(|t| t.shallow_clone()));
            if let (Some(uv), Some(uv0)) = (&uv, &r.uv0) {
                all.push(heat(uv, m));
                all.push(heat(uv0, m));
            }
            Tensor::cat(&all, 1)
        };
        let u = self.dec[0].forward(&with_heat(z.shallow_clone(), &[&guides]));
        let u = self.dec[1].forward(&with_heat(u, &[&r.skips[1]]));
        let out = self.dec[2].forward(&with_heat(u, &[&r.skips[0]]));
        let k = self.cams;
        let rgb = out.narrow(1, 0, 3 * k).sigmoid();
        let alpha = out.narrow(1, 3 * k, k).sigmoid();
        let frame = if k == 1 {
            &alpha * &rgb + (1.0 - &alpha) * &r.first
        } else {
            let a3 = alpha.repeat_interleave_self_int(3, Some(1), None);
            &a3 * &rgb + (1.0 - &a3) * &r.first
        };
        r.z = z;
        Step {
            frame,
            state: r.state.shallow_clone(),
            rgb,
            alpha,
        }
    }

    fn loss(&self, batch: &Batch, cfg: &VideoModelConfig) -> Tensor {
        let (state_weight, motion_weight, pixel_loss) =
            (cfg.state_weight, cfg.motion_weight, cfg.pixel_loss);
        let mut r = self.start(&batch.first, &batch.state);
        let emb = self.embed(&batch.actions);
        let target_sn = (&batch.target_states - &self.stats.state_mean) / &self.stats.state_dev;
        let steps = batch.mask.size()[0];
        let mut terms = Vec::with_capacity(steps as usize);
        for t in 0..steps {
            let Step {
                frame, state: sn, ..
            } = self.step(&mut r, &emb.get(t));
            let target = batch.targets.get(t);
            // Where a camera's picture changed from its start (by more than 0.1 in a channel).
            let changed = (&target - &batch.first).abs();
            let moved = if self.cams == 1 {
                changed.amax([1i64].as_slice(), true)
            } else {
                let sz = changed.size();
                changed
                    .view([sz[0], self.cams, 3, sz[2], sz[3]])
                    .amax([2i64].as_slice(), false)
                    .repeat_interleave_self_int(3, Some(1), None)
            }
            .gt(0.1)
            .to_kind(Kind::Float);
            let diff = frame - &target;
            let err = match pixel_loss {
                PixelLoss::L1 => diff.abs(),
                PixelLoss::L2 => diff.square(),
            };
            let image = (err * (moved * motion_weight + 1.0)).mean_dim(
                [1i64, 2, 3].as_slice(),
                false,
                Kind::Float,
            );
            let err = (sn - target_sn.get(t)).square();
            let o = self.objects;
            let state = if o > 0 {
                let q = self.state_dims - o;
                let mean = |x: Tensor| x.mean_dim([1i64].as_slice(), false, Kind::Float);
                mean(err.narrow(1, 0, q)) * state_weight
                    + mean(err.narrow(1, q, o)) * cfg.object_weight
            } else {
                err.mean_dim([1i64].as_slice(), false, Kind::Float) * state_weight
            };
            terms.push(((image + state) * batch.mask.get(t)).sum(Kind::Float));
        }
        let zero = Tensor::zeros([], (Kind::Float, batch.first.device()));
        terms.into_iter().fold(zero, |total, t| total + t)
            / batch.mask.sum(Kind::Float).clamp_min(1.0)
    }

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

/// A Gaussian bump `[B, 1, m, m]` at `uv` (`[B, 2]`, x and y in [−1, 1] across the map), one
/// cell wide.
fn heat(uv: &Tensor, m: i64) -> Tensor {
    let line = Tensor::linspace(-1.0, 1.0, m, (Kind::Float, uv.device())).view([1, m]);
    let sigma = 2.0 / m as f64;
    let bump = |c: i64| {
        (-(line.shallow_clone() - uv.narrow(1, c, 1)).square() / (2.0 * sigma * sigma)).exp()
    };
    let (x, y) = (bump(0), bump(1));
    (y.unsqueeze(2) * x.unsqueeze(1)).unsqueeze(1)
}

/// One step's output ([`Net::step`]).
struct Step {
    frame: Tensor,
    state: Tensor,
    rgb: Tensor,
    alpha: Tensor,
}

struct Rollout {
    /// `[1, 2, m, m]`: x and y of each latent position.
    coords: Tensor,
    /// The tool's place in the start frame (with `tool_heatmap`).
    uv0: Option<Tensor>,
    first: Tensor,
    skips: [Tensor; 2],
    z: Tensor,
    state: Tensor,
}

// ---------------------------------------------------------------------------------------------
// As a world-model service.

impl WorldModelService for VideoModel {
    fn name(&self) -> String {
        format!(
            "Assay video model ({s}x{s} frames, latent {c}x{m}x{m}, {b} FiLM blocks{cams})",
            s = self.size,
            c = self.net.c,
            m = self.size / 8,
            b = self.net.blocks.len(),
            cams = if self.layout.cameras.len() > 1
                || !self.layout.interface.is_empty()
                || self.layout.objects > 0
            {
                format!("; {}", self.layout.describe())
            } else {
                String::new()
            },
        )
    }

    /// The interface of the clips it was trained on, each camera at its size.
    fn interfaces(&self) -> Vec<Interface> {
        vec![self.layout.interface()]
    }

    fn reset(&self, start: &WorldStart) -> Result<Box<dyn ImaginedEpisode + '_>, WorldError> {
        self.check_start(start)?;
        let (rollout, full) = tch::no_grad(|| self.start_of(&[start]));
        Ok(Box::new(Imagined {
            model: self,
            rollout,
            full,
        }))
    }

    /// The runs in batches of [`REPLAY_BATCH`]: each sample of a batch is imagined on its own
    /// (no layer mixes samples), so the frames are those of one run at a time.
    fn replay_many(
        &self,
        runs: &[(&WorldStart, &[Vec<f32>])],
    ) -> Result<Vec<Vec<WorldFrame>>, WorldError> {
        for (start, actions) in runs {
            self.check_start(start)?;
            actions.iter().try_for_each(|a| self.check_action(a))?;
        }
        let mut out = Vec::with_capacity(runs.len());
        for batch in runs.chunks(REPLAY_BATCH) {
            out.extend(
                tch::no_grad(|| self.replay_batch(batch))
                    .map_err(|e| WorldError::BadAnswer(format!("libtorch: {e}")))?,
            );
        }
        Ok(out)
    }
}

/// Runs imagined at once by [`VideoModel`]'s `replay_many`.
const REPLAY_BATCH: usize = 64;

impl VideoModel {
    /// Refuses a start whose frames or state do not fit the model.
    fn check_start(&self, start: &WorldStart) -> Result<(), WorldError> {
        let layout = &self.layout;
        let mut sizes = vec![(start.width, start.height, start.rgb.len())];
        sizes.extend(start.views.iter().map(|v| (v.width, v.height, v.rgb.len())));
        let fits = sizes.len() == layout.cameras.len()
            && sizes
                .iter()
                .zip(&layout.cameras)
                .all(|((w, h, n), (_, cw, ch))| (w, h) == (cw, ch) && *n == (w * h * 3) as usize);
        if !fits {
            let given: Vec<String> = sizes
                .iter()
                .map(|(w, h, n)| format!("{w}x{h} ({n} bytes)"))
                .collect();
            return Err(WorldError::Refused(format!(
                "first frames of {}: this video model was trained on {}",
                given.join(", "),
                layout.describe()
            )));
        }
        if start.state.len() != layout.state || start.state.iter().any(|v| !v.is_finite()) {
            return Err(WorldError::Refused(format!(
                "a first state of {} values: the video model takes {} finite ones",
                start.state.len(),
                layout.state
            )));
        }
        if layout.objects > 0
            && (start.objects.len() != layout.objects
                || start.objects.iter().any(|v| !v.is_finite()))
        {
            return Err(WorldError::Refused(format!(
                "first positions of {} object values: the video model predicts {} finite ones \
                 (clips with the objects' section give them)",
                start.objects.len(),
                layout.objects
            )));
        }
        Ok(())
    }

    /// Refuses an action the model does not take.
    fn check_action(&self, a: &[f32]) -> Result<(), WorldError> {
        if a.len() != self.layout.action || a.iter().any(|v| !v.is_finite()) {
            return Err(WorldError::Refused(format!(
                "an action of {} values: the video model takes {} finite ones",
                a.len(),
                self.layout.action
            )));
        }
        Ok(())
    }

    /// The rollout of `starts` (checked) as one batch, and each camera's real start frames
    /// `[B, 3, h, w]` at their own size.
    fn start_of(&self, starts: &[&WorldStart]) -> (Rollout, Vec<Tensor>) {
        let b = starts.len() as i64;
        let camera = |k: usize| {
            let (_, w, h) = &self.layout.cameras[k];
            let mut rgb = Vec::new();
            for s in starts {
                rgb.extend_from_slice(if k == 0 { &s.rgb } else { &s.views[k - 1].rgb });
            }
            pixels(&rgb, b, i64::from(*h), i64::from(*w), self.device)
        };
        let full: Vec<Tensor> = (0..self.layout.cameras.len()).map(camera).collect();
        let small: Vec<Tensor> = full.iter().map(|f| resized(f, self.size)).collect();
        let objects = self.layout.objects > 0;
        let state: Vec<f32> = starts
            .iter()
            .flat_map(|s| {
                s.state
                    .iter()
                    .chain(if objects { &s.objects[..] } else { &[] })
            })
            .copied()
            .collect();
        let state = Tensor::from_slice(&state)
            .view([b, -1])
            .to_device(self.device);
        (self.net.start(&Tensor::cat(&small, 1), &state), full)
    }

    /// The next frames of a rollout of `full.len()`-camera starts after `actions` (`[B, A]`),
    /// each camera composited at its own size over its real start, one answer per sample.
    fn next_frames(
        &self,
        rollout: &mut Rollout,
        full: &[Tensor],
        actions: &Tensor,
    ) -> Result<Vec<WorldFrame>, tch::TchError> {
        let net = &self.net;
        let emb = net.embed(actions);
        let step = net.step(rollout, &emb);
        let raw = &step.state * &net.stats.state_dev + &net.stats.state_mean;
        // Each camera composited at its own size over its real start: what did not move keeps
        // the camera's detail.
        let mut frames = Vec::with_capacity(full.len());
        for (k, start) in full.iter().enumerate() {
            let k = k as i64;
            let (h, w) = (start.size()[2], start.size()[3]);
            let picture = if (h, w) == (self.size, self.size) {
                step.frame.narrow(1, 3 * k, 3)
            } else {
                let rgb = resized_to(&step.rgb.narrow(1, 3 * k, 3), h, w);
                let alpha = resized_to(&step.alpha.narrow(1, k, 1), h, w);
                &alpha * rgb + (1.0 - &alpha) * start
            };
            frames.push(picture);
        }
        world_frames(
            &frames,
            &raw,
            self.layout.holding_last(),
            self.layout.objects,
        )
    }

    /// One batch of checked runs; a run whose actions ended is stepped with zeros beside the
    /// others, its frames dropped.
    fn replay_batch(
        &self,
        runs: &[(&WorldStart, &[Vec<f32>])],
    ) -> Result<Vec<Vec<WorldFrame>>, tch::TchError> {
        let starts: Vec<&WorldStart> = runs.iter().map(|(s, _)| *s).collect();
        let (mut rollout, full) = self.start_of(&starts);
        let a = self.layout.action;
        let steps = runs.iter().map(|(_, x)| x.len()).max().unwrap_or(0);
        let mut out: Vec<Vec<WorldFrame>> = vec![Vec::new(); runs.len()];
        for t in 0..steps {
            let mut actions = vec![0f32; runs.len() * a];
            for (j, (_, x)) in runs.iter().enumerate() {
                if let Some(row) = x.get(t) {
                    actions[j * a..(j + 1) * a].copy_from_slice(row);
                }
            }
            let actions = Tensor::from_slice(&actions)
                .view([runs.len() as i64, a as i64])
                .to_device(self.device);
            let answers = self.next_frames(&mut rollout, &full, &actions)?;
            for (j, frame) in answers.into_iter().enumerate() {
                if t < runs[j].1.len() {
                    out[j].push(frame);
                }
            }
        }
        Ok(out)
    }
}

struct Imagined<'a> {
    model: &'a VideoModel,
    rollout: Rollout,
    /// Each camera's real start frame `[1, 3, h, w]` at its own size.
    full: Vec<Tensor>,
}

impl ImaginedEpisode for Imagined<'_> {
    fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<WorldFrame>, WorldError> {
        let (model, device) = (self.model, self.model.device);
        let mut out = Vec::with_capacity(actions.len());
        for a in actions {
            model.check_action(a)?;
            let frame = tch::no_grad(|| -> Result<WorldFrame, tch::TchError> {
                let a = Tensor::from_slice(a).view([1, -1]).to_device(device);
                Ok(model
                    .next_frames(&mut self.rollout, &self.full, &a)?
                    .remove(0))
            })
            .map_err(|e| WorldError::BadAnswer(format!("libtorch: {e}")))?;
            out.push(frame);
        }
        Ok(out)
    }
}
