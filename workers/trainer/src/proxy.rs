//! The world-model proxy of one task group (see `assay_model::proxy`): a world model fitted on
//! the training policies' clips, a frame judge that tells success from a last frame, and the
//! ranked episodes imagined open loop from their first frame and judged.
//!
//! # Frame judge
//! Four stride-2 convolutions (kernel 4; 8, 16, 32, 64 channels; GroupNorm(1) + SiLU) on the
//! 64×64 frame in [−0.5, 0.5], global average pooling, one linear layer to a logit. Trained with
//! the logistic loss, positives weighted by negatives/positives (successes can be rare), Adam, on
//! batches of 16 drawn from the training episodes' **real and imagined** last frames — so the
//! judge has seen what the world model's blur looks like — each labelled with the episode's real
//! outcome. Initial weights and batches come from `assay_spec::rng` streams: deterministic.
//!
//! # What the ranked policies act on
//! A policy object (diffusion, TorchScript, remote) acts on the imagined frames: it is built
//! again for the episode (`ProxyRequest::policies`), shown the frame and proprioception the world
//! model decodes at each step and its actions drive the model, for as many frames as its real
//! episode had ([`crate::world_model::WorldModel::imagine_policy`]). The scripted oracle cannot
//! run outside the simulator (its plan reads the scene's state), but it is open loop once it has
//! read the initial scene, which the world model is given too (the first real frame): its
//! episodes are imagined with the actions it took in the simulator
//! ([`crate::world_model::WorldModel::imagine`]).

use std::time::Instant;

use assay_model::clip::Clip;
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicySpec};
use assay_model::proxy::{
    IMAGINED_KEYFRAMES, ProxyConfig, ProxyEpisode, ProxyPrediction, ProxyResult,
};
use assay_spec::rng::Rng;
use tch::{Device, Kind, Tensor};

use crate::adam::Adam;
use crate::world_model::{Conv, FitRequest, Init, Linear, WorldModelError, fit_model};

const JUDGE_BATCH: usize = 16;
const JUDGE_CHANNELS: [i64; 5] = [3, 8, 16, 32, 64];

/// A success classifier on single frames.
pub struct FrameJudge {
    convs: Vec<Conv>,
    head: Linear,
    params: Vec<Tensor>,
    size: i64,
    device: Device,
    /// The answer of a judge trained on one class only (nothing to learn).
    constant: Option<f64>,
}

impl FrameJudge {
    fn new(size: u32, seed: u64, device: Device) -> Self {
        let mut init = Init {
            rng: Rng::new(seed, "frame-judge/init"),
            device,
            names: Vec::new(),
            params: Vec::new(),
        };
        let convs = (0..4)
            .map(|k| {
                Conv::new(
                    &mut init,
                    &format!("judge{k}"),
                    JUDGE_CHANNELS[k],
                    JUDGE_CHANNELS[k + 1],
                    false,
                    true,
                )
            })
            .collect();
        let head = Linear::new(&mut init, "judge_head", JUDGE_CHANNELS[4], 1, true);
        Self {
            convs,
            head,
            params: init.params,
            size: i64::from(size),
            device,
            constant: None,
        }
    }

    fn images(&self, frames: &[&[u8]]) -> Tensor {
        let s = self.size;
        let flat: Vec<u8> = frames.iter().flat_map(|f| f.iter().copied()).collect();
        Tensor::from_slice(&flat)
            .view([frames.len() as i64, s, s, 3])
            .to_device(self.device)
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Float)
            / 255.0
            - 0.5
    }

    fn logits(&self, x: &Tensor) -> Tensor {
        let mut x = x.shallow_clone();
        for c in &self.convs {
            x = c.forward(&x);
        }
        let pooled = x.mean_dim(&[2, 3][..], false, Kind::Float);
        self.head.forward(&pooled).squeeze_dim(-1)
    }

    /// Probability of success of each frame (`size · size · 3` RGB bytes).
    pub fn probabilities(&self, frames: &[&[u8]]) -> Vec<f64> {
        tch::no_grad(|| {
            let mut out = Vec::with_capacity(frames.len());
            for chunk in frames.chunks(64) {
                let p = self
                    .logits(&self.images(chunk))
                    .sigmoid()
                    .to_kind(Kind::Double)
                    .to_device(Device::Cpu);
                out.extend(Vec::<f64>::try_from(p).unwrap_or_default());
            }
            out
        })
    }
}

/// Trains a frame judge on `examples` (frame, success). Returns it with its training accuracy.
pub fn train_frame_judge(
    examples: &[(&[u8], bool)],
    size: u32,
    steps: u32,
    lr: f64,
    seed: u64,
    device: Device,
) -> (FrameJudge, f64) {
    let mut judge = FrameJudge::new(size, seed, device);
    let positives = examples.iter().filter(|e| e.1).count();
    let negatives = examples.len() - positives;
    if positives > 0 && negatives > 0 {
        let pos_weight =
            Tensor::from_slice(&[negatives as f32 / positives as f32]).to_device(device);
        let mut adam = Adam::new(&judge.params, lr, 100.0);
        let mut rng = Rng::new(seed, "frame-judge/batches");
        for _ in 0..steps {
            let picked: Vec<usize> = (0..JUDGE_BATCH.min(examples.len()))
                .map(|_| ((rng.unit() * examples.len() as f64) as usize).min(examples.len() - 1))
                .collect();
            let frames: Vec<&[u8]> = picked.iter().map(|&i| examples[i].0).collect();
            let labels: Vec<f32> = picked
                .iter()
                .map(|&i| f32::from(u8::from(examples[i].1)))
                .collect();
            let y = Tensor::from_slice(&labels).to_device(device);
            let logits = judge.logits(&judge.images(&frames));
            let loss = logits.binary_cross_entropy_with_logits::<&Tensor>(
                &y,
                None,
                Some(&pos_weight),
                tch::Reduction::Mean,
            );
            loss.backward();
            adam.step(&mut judge.params);
        }
    }
    // With one class only there is nothing to learn: the judge answers the base rate.
    let frames: Vec<&[u8]> = examples.iter().map(|e| e.0).collect();
    let p = if positives > 0 && negatives > 0 {
        judge.probabilities(&frames)
    } else {
        vec![if positives > 0 { 1.0 } else { 0.0 }; frames.len()]
    };
    let correct = p
        .iter()
        .zip(examples)
        .filter(|(p, e)| (**p >= 0.5) == e.1)
        .count();
    let accuracy = correct as f64 / examples.len().max(1) as f64;
    if positives == 0 || negatives == 0 {
        judge.constant = Some(if positives > 0 { 1.0 } else { 0.0 });
    }
    (judge, accuracy)
}

/// Builds a policy object from its name (`assay_policy::load_with` in the binary).
pub type PolicyLoader<'a> = dyn Fn(&str) -> Result<Box<dyn Policy>, PolicyError> + Sync + 'a;

/// The proxy of one group: its episodes with their loaded clips (same order).
pub struct ProxyRequest<'a> {
    pub group: &'a str,
    /// Builds the policy object a ranked episode names (not called for the oracle).
    pub policies: &'a PolicyLoader<'a>,
    pub train: &'a [ProxyEpisode],
    pub train_clips: &'a [Clip],
    pub eval: &'a [ProxyEpisode],
    pub eval_clips: &'a [Clip],
    pub config: &'a ProxyConfig,
    pub device: Device,
}

/// Runs the proxy of one group. `resume` and `on_checkpoint` are the world model's (see
/// [`crate::world_model::fit`]).
pub fn run_proxy(
    req: &ProxyRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut crate::world_model::CheckpointSink<'_>,
) -> Result<ProxyResult, WorldModelError> {
    let ProxyRequest {
        group,
        policies,
        train,
        train_clips,
        eval,
        eval_clips,
        config,
        device,
    } = *req;
    let started = Instant::now();
    config.validate().map_err(WorldModelError::Request)?;
    if train.len() != train_clips.len() || eval.len() != eval_clips.len() {
        return Err(WorldModelError::Request(
            "episodes and clips differ in number".into(),
        ));
    }
    let eval_keys: Vec<String> = eval.iter().map(|e| e.clip.clone()).collect();
    let req = FitRequest {
        config: &config.world_model,
        group,
        budget: train_clips.len() as u32,
        train: train_clips,
        eval: eval_clips,
        eval_keys: &eval_keys,
        device,
    };
    let (model, fit) = fit_model(&req, resume, on_checkpoint)?;
    let batch = config.world_model.batch.max(1);
    let imagined_train = model.imagine(train_clips, batch)?;
    // The oracle's episodes open loop, in batches; policy objects closed loop, one by one.
    let oracle: Vec<bool> = eval
        .iter()
        .map(|e| PolicySpec::parse(&e.policy).is_ok_and(|p| p.is_oracle()))
        .collect();
    let open: Vec<Clip> = eval_clips
        .iter()
        .zip(&oracle)
        .filter(|(_, o)| **o)
        .map(|(c, _)| c.clone())
        .collect();
    let mut open = model.imagine(&open, batch)?.into_iter();
    let mut imagined_eval = Vec::with_capacity(eval.len());
    for (i, e) in eval.iter().enumerate() {
        if oracle[i] {
            imagined_eval.push(open.next().expect("one per oracle episode"));
            continue;
        }
        let what = |err: String| {
            WorldModelError::Request(format!(
                "policy '{}' on task {} seed {}: {err}",
                e.policy, e.task_id, e.seed
            ))
        };
        let mut policy = policies(&e.policy).map_err(|err| what(err.to_string()))?;
        let episode = EpisodeContext {
            task_id: e.task_id.clone(),
            seed: e.seed,
            instruction: e.instruction.clone(),
            arm: None,
        };
        let im = model
            .imagine_policy(
                &eval_clips[i],
                eval_clips[i].len(),
                policy.as_mut(),
                &episode,
            )
            .map_err(|err| what(err.to_string()))?;
        imagined_eval.push(im);
    }

    let size = config.world_model.image_size;
    let frame = (size * size * 3) as usize;
    let last = |c: &Clip| -> Vec<u8> { c.rgb[(c.len() - 1) * frame..c.len() * frame].to_vec() };
    let real_train: Vec<Vec<u8>> = train_clips.iter().map(last).collect();
    let mut examples: Vec<(&[u8], bool)> = Vec::new();
    for (i, e) in train.iter().enumerate() {
        let ok = e.success.unwrap_or(false);
        examples.push((&real_train[i], ok));
        let im = imagined_train[i].frames.last().expect("2 frames or more");
        examples.push((im, ok));
    }
    let (judge, judge_train_accuracy) = train_frame_judge(
        &examples,
        size,
        config.judge_steps,
        config.judge_lr,
        config.world_model.seed,
        device,
    );
    let imagined_last: Vec<&[u8]> = imagined_eval
        .iter()
        .map(|i| i.frames.last().expect("2 frames or more").as_slice())
        .collect();
    let real_eval: Vec<Vec<u8>> = eval_clips.iter().map(last).collect();
    let real_refs: Vec<&[u8]> = real_eval.iter().map(|v| v.as_slice()).collect();
    let p_imagined = judge.probability_of(&imagined_last);
    let p_real = judge.probability_of(&real_refs);
    let predictions = eval
        .iter()
        .enumerate()
        .map(|(i, e)| ProxyPrediction {
            task_id: e.task_id.clone(),
            policy: e.policy.clone(),
            seed: e.seed,
            p_success: p_imagined[i],
            success: p_imagined[i] >= config.threshold,
            p_success_real_frame: p_real[i],
            last_frame_mse: imagined_eval[i].last_frame_mse,
            // Named by the job runner once it has stored `imagined_frames`.
            imagined_keyframes: Vec::new(),
        })
        .collect();
    let imagined_frames = imagined_eval
        .iter()
        .zip(eval_clips)
        .map(|(im, clip)| keyframes_of(clip, im, frame))
        .collect();
    tracing::info!(
        group,
        seconds = started.elapsed().as_secs_f64(),
        train = train.len(),
        eval = eval.len(),
        judge_train_accuracy,
        "world-model proxy done"
    );
    Ok(ProxyResult {
        group: group.to_owned(),
        world_model: fit,
        judge_examples: examples.len() as u32,
        judge_positives: examples.iter().filter(|e| e.1).count() as u32,
        judge_train_accuracy,
        predictions,
        seconds: started.elapsed().as_secs_f64(),
        imagined_frames,
    })
}

/// [`IMAGINED_KEYFRAMES`] frames of an imagined rollout, evenly spaced from the clip's real
/// first frame (what the world model was given) to the last imagined one, with their indices.
fn keyframes_of(
    clip: &Clip,
    imagined: &crate::world_model::Imagined,
    frame: usize,
) -> Vec<(u64, Vec<u8>)> {
    let last = imagined.frames.len();
    (0..IMAGINED_KEYFRAMES)
        .map(|k| {
            let t = (last as f64 * k as f64 / (IMAGINED_KEYFRAMES - 1) as f64).round() as usize;
            let rgb = match t {
                0 => clip.rgb[..frame].to_vec(),
                t => imagined.frames[t - 1].clone(),
            };
            (t as u64, rgb)
        })
        .collect()
}

impl FrameJudge {
    /// [`FrameJudge::probabilities`], or the constant answer of a judge that saw one class only.
    pub fn probability_of(&self, frames: &[&[u8]]) -> Vec<f64> {
        match self.constant {
            Some(c) => vec![c; frames.len()],
            None => self.probabilities(frames),
        }
    }
}
