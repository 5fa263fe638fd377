//! The world-model proxy of one task group (see `assay_model::proxy`): a world model — the video
//! model (the default) or the RSSM fitted on the training policies' clips, or a lab's model served
//! over `assay.v1.WorldModel` —,
//! a frame judge that tells a finished task from an unfinished one, and every ranked policy
//! acting closed loop inside the world model, judged frame by frame.
//!
//! # Frame judge
//! Four stride-2 convolutions (kernel 4; 8, 16, 32, 64 channels; GroupNorm(1) + SiLU) on the
//! 64×64 frame in [−0.5, 0.5], global average pooling, one linear layer to a logit. Trained with
//! the logistic loss, positives weighted by negatives/positives (successes can be rare), Adam, on
//! batches of 16 drawn from the training episodes' **real and imagined** frames — so the judge
//! has seen what the world model's blur looks like. A training episode's last frame is labelled
//! with its real outcome; its frames at a quarter and at half of its length are labelled not done
//! (the task is finished at the end of a successful episode, not before), so the judge can tell
//! *when* an imagined rollout is done, not only whether a last frame looks like a success.
//! Initial weights and batches come from `assay_spec::rng` streams: deterministic.
//!
//! # Calibration
//! The judge's probability on an imagined last frame is mapped to a probability of real success
//! by Platt scaling fitted on the **training** episodes only (`assay_model::proxy::Calibration`):
//! each one's probability comes from a judge trained without it (2 folds), on the last frame of
//! its replay in the world model. The ranked episodes' outcomes never reach the trainer.
//!
//! # What the ranked policies act on
//! Every ranked policy is a policy object (diffusion, TorchScript, remote, openpi) built again for
//! the episode (`ProxyRequest::policies`): it is shown the frame and state the world model gives
//! at each step and its actions drive the model ([`crate::imagination::closed_loop`]), from the
//! real first frame and state, until the frame judge calls `done_frames` frames in a row done or
//! the task's step budget (`ProxyEpisode::budget_steps`, in clip frames) runs out. The real
//! episode's length and outcome never reach the rollout. The scripted oracle cannot act outside
//! the simulator (its plan reads the scene's state) and is refused as a ranked policy; it may
//! train the world model.
//!
//! # Object judge
//! With `object_judge` (and a video model that predicts objects), every ranked episode is
//! imagined a second time and stopped and judged by a logistic regression on the predicted
//! state and objects (`object_judge.rs`), fitted on the frame judge's examples' states and
//! objects, real and replayed: a proxy of its own beside the frame judge's.
//!
//! # Held-out models
//! With `cross_fit_folds` or `cross_family_ablation`, more video models are trained, each on
//! the training clips and some ranked policies' clips, each with its own frame judge, and each
//! imagines only ranked policies whose episodes it never saw (`held_out.rs`).

use std::time::Instant;

use assay_model::clip::{CLIP_STRIDE_STEPS, Clip};
use assay_model::dynamics::DynamicsFit;
use assay_model::interface::Interface;
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicySpec};
use assay_model::proxy::{
    ActionTest, Calibration, ExternalWorldModel, HeldOutVerdict, IMAGINED_KEYFRAMES, LeakVerdict,
    ProxyConfig, ProxyEpisode, ProxyPrediction, ProxyResult, SERVED_DEVICE,
};
use assay_model::video::WorldModelKind;
use assay_model::world::{WorldError, WorldModelService, WorldStart, check_policy_interface};
use assay_spec::rng::Rng;
use tch::{Device, Kind, Tensor};

use crate::adam::Adam;
use crate::imagination::{self, Stop};
use crate::video_eval::{self, StartName};
use crate::video_model;
use crate::world_model::{Conv, FitRequest, Init, Linear, WorldModelError, fit_model};

mod calibration;
mod held_out;
mod object_judge;

use object_judge::ObjectJudge;

const JUDGE_BATCH: usize = 16;
const JUDGE_CHANNELS: [i64; 5] = [3, 8, 16, 32, 64];

/// A success classifier on single frames.
pub struct FrameJudge {
    convs: Vec<Conv>,
    head: Linear,
    params: Vec<Tensor>,
    size: i64,
    /// The frames it is given: width, height (resized to `size` square).
    frame: (i64, i64),
    device: Device,
    /// The answer of a judge trained on one class only (nothing to learn).
    constant: Option<f64>,
}

impl FrameJudge {
    fn new(frame: (u32, u32), size: u32, seed: u64, device: Device) -> Self {
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
            frame: (i64::from(frame.0), i64::from(frame.1)),
            device,
            constant: None,
        }
    }

    fn images(&self, frames: &[&[u8]]) -> Tensor {
        let (w, h) = self.frame;
        let flat: Vec<u8> = frames.iter().flat_map(|f| f.iter().copied()).collect();
        let x = Tensor::from_slice(&flat)
            .view([frames.len() as i64, h, w, 3])
            .to_device(self.device)
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Float)
            / 255.0;
        crate::video_model::resized(&x, self.size) - 0.5
    }

    fn logits(&self, x: &Tensor) -> Tensor {
        let mut x = x.shallow_clone();
        for c in &self.convs {
            x = c.forward(&x);
        }
        let pooled = x.mean_dim(&[2, 3][..], false, Kind::Float);
        self.head.forward(&pooled).squeeze_dim(-1)
    }

    /// Probability of success of each frame (RGB bytes at the judge's frame size).
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

/// Trains a frame judge on `examples` (frame, success) of `size`×`size`. Returns it with its
/// training accuracy.
pub fn train_frame_judge(
    examples: &[(&[u8], bool)],
    size: u32,
    steps: u32,
    lr: f64,
    seed: u64,
    device: Device,
) -> (FrameJudge, f64) {
    train_frame_judge_at(examples, (size, size), size, steps, lr, seed, device)
}

/// [`train_frame_judge`] on frames of `frame` (width, height), which it resizes to `size`
/// square.
pub fn train_frame_judge_at(
    examples: &[(&[u8], bool)],
    frame: (u32, u32),
    size: u32,
    steps: u32,
    lr: f64,
    seed: u64,
    device: Device,
) -> (FrameJudge, f64) {
    let mut judge = FrameJudge::new(frame, size, seed, device);
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

/// Connects to a served world model (`assay_policy::world_model::connect` in the binary).
pub type WorldModelLoader<'a> =
    dyn Fn(&ExternalWorldModel) -> Result<Box<dyn WorldModelService>, WorldError> + Sync + 'a;

/// The proxy of one group: its episodes with their loaded clips (same order). Of a ranked
/// episode's clip only the first frame and state reach its rollout; the rest serves the
/// diagnostics (the world model's errors, the judge on the real last frame) and the leak
/// ablation when asked.
pub struct ProxyRequest<'a> {
    pub group: &'a str,
    /// Builds the policy object a ranked episode names.
    pub policies: &'a PolicyLoader<'a>,
    /// Connects to `config.external` when it is set.
    pub world_models: &'a WorldModelLoader<'a>,
    pub train: &'a [ProxyEpisode],
    pub train_clips: &'a [Clip],
    pub eval: &'a [ProxyEpisode],
    pub eval_clips: &'a [Clip],
    pub config: &'a ProxyConfig,
    pub device: Device,
    /// The video model's diagnostics (one-step error, action test) on a copy of it in a thread
    /// of their own, beside the frame judge and the imagination; else inline, after the
    /// calibration. The figures are the same either way; the thread pays where a core would
    /// otherwise idle (the trainer sets it when the proxy is its only job).
    pub diagnostics_beside: bool,
}

fn start_name(e: &ProxyEpisode) -> StartName<'_> {
    StartName {
        task_id: &e.task_id,
        seed: e.seed,
        instruction: &e.instruction,
    }
}

fn context(e: &ProxyEpisode) -> EpisodeContext {
    EpisodeContext {
        task_id: e.task_id.clone(),
        seed: e.seed,
        instruction: e.instruction.clone(),
        arm: None,
    }
}

/// Clip frames a ranked episode may be imagined for: its step budget at the clip's rate, the
/// first frame included (an episode of `n` physics steps has `n / 24 + 1` clip frames).
pub fn horizon_frames(budget_steps: u32) -> usize {
    (u64::from(budget_steps) / CLIP_STRIDE_STEPS) as usize + 1
}

/// The video model's fit in the RSSM's terms (what the report's proxy table reads): its
/// training figures, no evaluation yet, `config` the RSSM settings it did not use.
pub(crate) fn video_summary(
    group: &str,
    vfit: &assay_model::video::VideoFit,
    config: &ProxyConfig,
) -> DynamicsFit {
    DynamicsFit {
        group: group.to_owned(),
        budget: vfit.train_clips,
        train_episodes: vfit.train_clips,
        eval_episodes: 0,
        eval_image_mse: 0.0,
        eval_proprio_mse: 0.0,
        per_episode: Vec::new(),
        episodes: Vec::new(),
        final_train_loss: vfit.final_train_loss,
        steps: vfit.steps,
        epochs: 0.0,
        resumed_from_step: vfit.resumed_from_step,
        steps_per_s: vfit.steps_per_s,
        device: vfit.device.clone(),
        libtorch: crate::libtorch_version(),
        config: config.world_model.clone(),
    }
}

/// The fit summary of a served world model: nothing trained here; its ranked episodes' clips.
fn served_summary(group: &str, eval_keys: &[String], config: &ProxyConfig) -> DynamicsFit {
    DynamicsFit {
        group: group.to_owned(),
        budget: 0,
        train_episodes: 0,
        eval_episodes: eval_keys.len() as u32,
        eval_image_mse: 0.0,
        eval_proprio_mse: 0.0,
        per_episode: Vec::new(),
        episodes: eval_keys.to_vec(),
        final_train_loss: 0.0,
        steps: 0,
        epochs: 0.0,
        resumed_from_step: None,
        steps_per_s: 0.0,
        device: SERVED_DEVICE.into(),
        libtorch: String::new(),
        config: config.world_model.clone(),
    }
}

/// Runs the proxy of one group. `resume` and `on_checkpoint` are the trained world model's (the
/// video model's, see [`crate::video_model::fit`], or the RSSM's, [`crate::world_model::fit`]);
/// a served world model is not trained.
pub fn run_proxy(
    req: &ProxyRequest<'_>,
    resume: Option<&[u8]>,
    on_checkpoint: &mut crate::world_model::CheckpointSink<'_>,
) -> Result<ProxyResult, WorldModelError> {
    let ProxyRequest {
        group,
        policies,
        world_models,
        train,
        train_clips,
        eval,
        eval_clips,
        config,
        device,
        diagnostics_beside,
    } = *req;
    let started = Instant::now();
    config.validate().map_err(WorldModelError::Request)?;
    if train.len() != train_clips.len() || eval.len() != eval_clips.len() {
        return Err(WorldModelError::Request(
            "episodes and clips differ in number".into(),
        ));
    }
    for e in eval {
        let what = |reason: &str| {
            WorldModelError::Request(format!(
                "ranked policy '{}' on task {} seed {}: {reason}",
                e.policy, e.task_id, e.seed
            ))
        };
        match PolicySpec::parse(&e.policy) {
            Ok(p) if p.is_oracle() => {
                return Err(what(
                    "the scripted oracle reads the simulator's state and cannot act inside a world model; \
                     it may train the world model (name it in train_policies), not be ranked",
                ));
            }
            Err(err) => return Err(what(&err.to_string())),
            Ok(_) => {}
        }
        if e.budget_steps == 0 {
            return Err(what("no step budget (budget_steps is 0)"));
        }
    }
    let size = config.world_model.image_size;
    // Every ranked policy's interface, checked against the world model's before anything is
    // trained or imagined.
    let mut interfaces: Vec<(&str, Interface)> = Vec::new();
    for e in eval {
        if interfaces.iter().all(|(p, _)| *p != e.policy) {
            let policy = policies(&e.policy).map_err(|err| {
                WorldModelError::Request(format!("ranked policy '{}': {err}", e.policy))
            })?;
            interfaces.push((&e.policy, policy.interface()));
        }
    }
    let check_interfaces = |model: &str, accepted: &[Interface]| {
        for (policy, interface) in &interfaces {
            check_policy_interface(model, accepted, size, policy, interface)
                .map_err(WorldModelError::Request)?;
        }
        Ok::<(), WorldModelError>(())
    };
    let eval_keys: Vec<String> = eval.iter().map(|e| e.clip.clone()).collect();
    // The world model's clips: the training episodes of `world_model_policies` (all of them by
    // default); the frame judge below learns from every training episode.
    let subset: Vec<Clip>;
    let world_clips: &[Clip] = if config.world_model_policies.is_empty() {
        train_clips
    } else {
        subset = train
            .iter()
            .zip(train_clips)
            .filter(|(e, _)| config.trains_world_model(&e.policy))
            .map(|(_, c)| c.clone())
            .collect();
        if subset.is_empty() {
            return Err(WorldModelError::Request(format!(
                "world_model_policies {:?}: no training episode of theirs in group {group:?}",
                config.world_model_policies
            )));
        }
        &subset
    };
    let rssm_model;
    let rssm;
    let video;
    let external;
    let mut video_fit = None;
    // The video model's diagnostics (`diagnose`): on a copy of it in a thread of their own, or
    // on the model itself after the calibration.
    let mut diagnosed = None;
    let mut inline = None;
    let (world, mut fit): (&dyn WorldModelService, DynamicsFit) =
        match (&config.external, config.model) {
            (None, WorldModelKind::Rssm) => {
                check_interfaces("Assay's RSSM", &[Interface::legacy(size)])?;
                let req = FitRequest {
                    config: &config.world_model,
                    group,
                    budget: world_clips.len() as u32,
                    train: world_clips,
                    eval: eval_clips,
                    eval_keys: &eval_keys,
                    device,
                    normalize_actions: config.normalize_actions,
                };
                let (model, fit) = fit_model(&req, resume, on_checkpoint)?;
                rssm_model = model;
                rssm = rssm_model.service();
                (&rssm, fit)
            }
            (None, WorldModelKind::Video) => {
                // It imagines at the interface of the clips it is trained on.
                let clips_interface = world_clips
                    .first()
                    .map_or_else(|| Interface::legacy(size), imagination::clip_interface);
                check_interfaces("Assay's video model", &[clips_interface])?;
                let (model, vfit) =
                    video_model::fit(&config.video, world_clips, device, resume, on_checkpoint)?;
                video = model;
                if diagnostics_beside {
                    diagnosed = Some(video.copy(&config.video)?);
                } else {
                    inline = Some(&video);
                }
                let mut fit = video_summary(group, &vfit, config);
                fit.eval_episodes = eval_clips.len() as u32;
                fit.episodes = eval_keys.clone();
                video_fit = Some(vfit);
                (&video, fit)
            }
            (Some(server), _) => {
                external = world_models(server)?;
                check_interfaces(&external.name(), &external.interfaces())?;
                (external.as_ref(), served_summary(group, &eval_keys, config))
            }
        };
    let fitted_s = started.elapsed().as_secs_f64();
    std::thread::scope(|scope| -> Result<ProxyResult, WorldModelError> {
        let diagnostics =
            diagnosed.map(|m| scope.spawn(move || diagnose(&m, eval, eval_clips, started)));
        let train_ctx: Vec<EpisodeContext> = train.iter().map(context).collect();
        let eval_ctx: Vec<EpisodeContext> = eval.iter().map(context).collect();

        // The judge reads the first camera (the task's scene camera for the original interface),
        // resized to the proxy's frame size.
        let judged = train_clips
            .first()
            .or(eval_clips.first())
            .map_or((size, size), |c| (c.width, c.height));
        let training = TrainingEpisodes {
            episodes: train,
            clips: train_clips,
            contexts: &train_ctx,
            judged,
        };
        let JudgeFit {
            judge,
            accuracy: judge_train_accuracy,
            examples: owned,
            spans,
            latest_not_done,
            objects: object_judge,
        } = fit_judge(world, &training, config, device)?;
        let judged_s = started.elapsed().as_secs_f64();
        let judge_one = |f: &[u8]| judge.probability_of(&[f])[0];
        let calibration = calibration::fit(&owned, &spans, judged, size, config, device);
        let calibrated_s = started.elapsed().as_secs_f64();

        // The world model's use of its actions and its video prediction, open loop over windows
        // of the ranked episodes' real clips (a diagnostic): the video model's in its thread.
        let mut action_test = match (&diagnostics, inline) {
            (Some(_), _) => None,
            (None, Some(m)) => {
                let (one_step, test, _) = diagnose(m, eval, eval_clips, started)?;
                fit.eval_image_mse = one_step;
                test
            }
            (None, None) => action_test(world, eval.iter().zip(eval_clips).collect())?,
        };
        let mut action_tested_s = started.elapsed().as_secs_f64();

        let ranked = RankedEpisodes {
            episodes: eval,
            clips: eval_clips,
            contexts: &eval_ctx,
        };
        let (mut predictions, imagined_frames) = imagine_ranked(
            world,
            policies,
            &ranked,
            &judge_one,
            object_judge.as_ref().map(|(j, _)| j),
            calibration.as_ref(),
            config,
        )?;
        let imagined_s = started.elapsed().as_secs_f64();
        if let Some(thread) = diagnostics {
            // A panic there goes on here, as it would have without the thread.
            let diagnosed = thread
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
            (fit.eval_image_mse, action_test, action_tested_s) = diagnosed;
        }
        let held_out = held_out::Inputs {
            policies,
            world_clips,
            training: &training,
            eval,
            eval_clips,
            eval_ctx: &eval_ctx,
            config,
            device,
        };
        let mut cross_family = Vec::new();
        if config.cross_family_ablation {
            let (fits, verdicts) = held_out::cross_family(&held_out)?;
            for (p, v) in predictions.iter_mut().zip(verdicts) {
                p.cross_family = v;
            }
            cross_family = fits;
        }
        let mut cross_fit = Vec::new();
        if config.cross_fit_folds > 0 {
            let (fits, verdicts) = held_out::cross_fit(&held_out, config.cross_fit_folds)?;
            for (p, v) in predictions.iter_mut().zip(verdicts) {
                p.cross_fit = v;
            }
            cross_fit = fits;
        }
        tracing::info!(
            group,
            seconds = started.elapsed().as_secs_f64(),
            fitted_s,
            judged_s,
            calibrated_s,
            action_tested_s,
            imagined_s,
            train = train.len(),
            eval = eval.len(),
            judge_train_accuracy,
            "world-model proxy done"
        );
        Ok(ProxyResult {
            group: group.to_owned(),
            world_model_name: world.name(),
            action_test,
            world_model: fit,
            video_model: video_fit,
            judge_examples: owned.len() as u32,
            judge_positives: owned.iter().filter(|e| e.1).count() as u32,
            judge_train_accuracy,
            object_judge_train_accuracy: object_judge.as_ref().map(|(_, a)| *a),
            judge_latest_not_done: latest_not_done,
            ranked_last_frame: eval
                .iter()
                .map(|e| horizon_frames(e.budget_steps).saturating_sub(1) as u32)
                .max(),
            calibration,
            cross_family,
            cross_fit,
            predictions,
            seconds: started.elapsed().as_secs_f64(),
            imagined_frames,
            imagined_frame_size: judged,
        })
    })
}

/// The video model's diagnostics, on its copy `model`: the one-step error, as the RSSM's fit
/// reports it (each next frame predicted from the real one before it, on the ranked episodes'
/// clips), the action test, and when they ended (seconds since `started`). libtorch computes
/// every op here with the process's intra-op threads (one, as the fit set them), as it would
/// on the proxy's thread: the figures are those of running both one after the other.
fn diagnose(
    model: &video_model::VideoModel,
    eval: &[ProxyEpisode],
    clips: &[Clip],
    started: Instant,
) -> Result<(f64, Option<ActionTest>, f64), WorldModelError> {
    // OpenMP keeps its thread count per thread: this one's, before any op, as the process's.
    tch::set_num_threads(tch::get_num_threads());
    let refs: Vec<&Clip> = clips.iter().collect();
    let names: Vec<StartName<'_>> = eval.iter().map(start_name).collect();
    let one_step = tch::no_grad(|| video_eval::one_step_mse(model, &refs, &names))?;
    let test = action_test(model, eval.iter().zip(clips).collect())?;
    Ok((one_step, test, started.elapsed().as_secs_f64()))
}

/// The training episodes as the frame judge learns from them: their clips and contexts (same
/// order), and the size of the frames it judges (width, height).
struct TrainingEpisodes<'a> {
    episodes: &'a [ProxyEpisode],
    clips: &'a [Clip],
    contexts: &'a [EpisodeContext],
    judged: (u32, u32),
}

/// A world model's frame judge, with its training accuracy, its examples and, per training
/// episode, where they lie (for the calibration).
struct JudgeFit {
    judge: FrameJudge,
    accuracy: f64,
    examples: Vec<(Vec<u8>, bool)>,
    spans: Vec<calibration::Span>,
    /// The latest clip frame among its "not done" examples.
    latest_not_done: Option<u32>,
    /// The object judge (`ProxyConfig::object_judge`), fitted on the same examples' states and
    /// objects, with its training accuracy.
    objects: Option<(ObjectJudge, f64)>,
}

/// Trains the frame judge of `world` on the training episodes' real and imagined (replayed in
/// `world` with the real actions) frames: last frames labelled with the outcome, those at
/// `config.judge_not_done` of the episode (by default a quarter and half) not done.
fn fit_judge(
    world: &dyn WorldModelService,
    training: &TrainingEpisodes<'_>,
    config: &ProxyConfig,
    device: Device,
) -> Result<JudgeFit, WorldModelError> {
    let at = |c: &Clip, t: usize| c.frame(t).to_vec();
    let mut owned: Vec<(Vec<u8>, bool)> = Vec::new();
    // The object judge's examples: the same frames' real and imagined states and objects.
    let mut by_objects: Vec<(Vec<f64>, bool)> = Vec::new();
    let mut spans: Vec<calibration::Span> = Vec::with_capacity(training.episodes.len());
    let mut latest_not_done: Option<usize> = None;
    let mut not_done_at = |t: usize| latest_not_done = latest_not_done.max(Some(t));
    for (i, e) in training.episodes.iter().enumerate() {
        let clip = &training.clips[i];
        let ok = e.success.unwrap_or(false);
        let imagined = imagination::replay_frames(
            world,
            &imagination::start_of(clip, &training.contexts[i]),
            &imagination::actions_of(clip),
        )?;
        let last = clip.len() - 1;
        let first = owned.len();
        let mut example = |t: usize, done: bool| -> Result<(), WorldModelError> {
            owned.push((at(clip, t), done));
            owned.push((imagined[t - 1].rgb.clone(), done));
            if config.object_judge {
                let p = clip.proprio_dims as usize;
                let real =
                    object_judge::features(&clip.proprio[t * p..(t + 1) * p], clip.objects_at(t));
                let dreamt =
                    object_judge::imagined_features(&imagined[t - 1]).ok_or_else(|| {
                        WorldModelError::Request(
                            "object_judge: the world model predicts no objects (the video model \
                         with object_weight above 0, trained on clips with the objects' \
                         section, does)"
                                .into(),
                        )
                    })?;
                by_objects.push((real, done));
                by_objects.push((dreamt, done));
            }
            Ok(())
        };
        example(last, ok)?;
        if !ok {
            not_done_at(last);
        }
        for t in not_done_frames(last, &config.judge_not_done) {
            not_done_at(t);
            example(t, false)?;
        }
        spans.push(calibration::Span {
            examples: first..owned.len(),
            imagined_last: first + 1,
            success: ok,
        });
    }
    let examples: Vec<(&[u8], bool)> = owned.iter().map(|(f, ok)| (f.as_slice(), *ok)).collect();
    let (judge, accuracy) = train_frame_judge_at(
        &examples,
        training.judged,
        config.world_model.image_size,
        config.judge_steps,
        config.judge_lr,
        config.world_model.seed,
        device,
    );
    // Every example of one width: the same objects in every training clip (the video model
    // predicts objects only then).
    if let Some(f) = by_objects.first()
        && by_objects.iter().any(|e| e.0.len() != f.0.len())
    {
        return Err(WorldModelError::Request(
            "object_judge: the training clips hold different numbers of objects".into(),
        ));
    }
    let objects = config.object_judge.then(|| ObjectJudge::fit(&by_objects));
    Ok(JudgeFit {
        judge,
        accuracy,
        examples: owned,
        spans,
        latest_not_done: latest_not_done.map(|t| t as u32),
        objects,
    })
}

/// The frames of a clip whose last frame is `last` that the frame judge learns as not done:
/// each fraction of the episode rounded down (0: frame 1, the first imagined one), those from
/// frame 1 to before the last, each once, in order.
fn not_done_frames(last: usize, fractions: &[f64]) -> Vec<usize> {
    let mut at: Vec<usize> = fractions
        .iter()
        .map(|&f| match f {
            0.0 => 1,
            f => (f * last as f64).floor() as usize,
        })
        .filter(|&t| t >= 1 && t < last)
        .collect();
    at.sort_unstable();
    at.dedup();
    at
}

/// An imagined rollout's keyframes: (frame index, RGB bytes).
type Keyframes = Vec<(u64, Vec<u8>)>;

/// The ranked episodes: their real clips and contexts, in the same order.
struct RankedEpisodes<'a> {
    episodes: &'a [ProxyEpisode],
    clips: &'a [Clip],
    contexts: &'a [EpisodeContext],
}

/// Each ranked episode's policy imagined in `world` from the episode's real start and judged by
/// `judge`: its prediction (calibrated by `calibration` when there is one) and its imagined
/// keyframes, in the episodes' order. With an object judge (`objects`), each is imagined once
/// more, judged by it (`ProxyPrediction::object_judge`).
fn imagine_ranked(
    world: &dyn WorldModelService,
    policies: &PolicyLoader<'_>,
    ranked: &RankedEpisodes<'_>,
    judge: &dyn Fn(&[u8]) -> f64,
    object_judge: Option<&ObjectJudge>,
    calibration: Option<&Calibration>,
    config: &ProxyConfig,
) -> Result<(Vec<ProxyPrediction>, Vec<Keyframes>), WorldModelError> {
    let by_objects = object_judge.map(|j| move |s: &[f32], o: &[f32]| j.probability(s, o));
    let eval = ranked.episodes;
    let mut predictions = Vec::with_capacity(eval.len());
    let mut imagined_frames = Vec::with_capacity(eval.len());
    for (i, e) in eval.iter().enumerate() {
        let clip = &ranked.clips[i];
        let leak_at = config.leak_ablation.then(|| clip.len() - 1);
        let start = imagination::start_of(clip, &ranked.contexts[i]);
        let one = Ranked {
            episode: e,
            context: &ranked.contexts[i],
            start: &start,
        };
        let judging = Judging {
            frames: judge,
            objects: None,
            leak_at,
        };
        let rollout = imagine(world, policies, &one, &judging, config, "")?;
        let object_judge = match &by_objects {
            Some(j) => {
                let judging = Judging {
                    frames: judge,
                    objects: Some(j),
                    leak_at: None,
                };
                let r = imagine(world, policies, &one, &judging, config, "object judge: ")?;
                Some(HeldOutVerdict {
                    p_success: r.p_success,
                    success: r.done_by_judge,
                    imagined_frames: r.frames.len() as u32 + 1,
                })
            }
            None => None,
        };
        let real_last = clip.frame(clip.len() - 1).to_vec();
        let last_imagined = rollout.frames.last().unwrap_or(&start.rgb);
        predictions.push(ProxyPrediction {
            task_id: e.task_id.clone(),
            policy: e.policy.clone(),
            seed: e.seed,
            p_success: rollout.p_success,
            success: rollout.done_by_judge,
            p_success_real_frame: judge(&real_last),
            last_frame_mse: imagination::mse(last_imagined, &real_last),
            imagined_frames: rollout.frames.len() as u32 + 1,
            done_by_judge: rollout.done_by_judge,
            p_calibrated: calibration.map(|c| c.apply(rollout.p_success)),
            leak: rollout.leak.map(|p| LeakVerdict {
                p_success: p,
                success: p >= config.threshold,
            }),
            cross_family: None,
            cross_fit: None,
            object_judge,
            // Named by the job runner once it has stored `imagined_frames`.
            imagined_keyframes: Vec::new(),
        });
        imagined_frames.push(keyframes_of(&start.rgb, &rollout.frames));
    }
    Ok((predictions, imagined_frames))
}

/// One ranked episode as a rollout starts from it.
struct Ranked<'a> {
    episode: &'a ProxyEpisode,
    context: &'a EpisodeContext,
    start: &'a WorldStart,
}

/// How a ranked rollout is judged: by the frame judge, or by the object judge when it is set
/// (on the predicted state and objects); `leak_at`: the leak ablation's frame (read by the
/// frame judge).
struct Judging<'a> {
    frames: &'a dyn Fn(&[u8]) -> f64,
    objects: Option<imagination::ObjectsJudge<'a>>,
    leak_at: Option<usize>,
}

/// `ranked`'s policy acting closed loop inside `world` from its real start, until `judging`
/// calls it done or its step budget runs out. Errors name the policy, task and seed, after
/// `what` (the ablation's name, or empty).
fn imagine(
    world: &dyn WorldModelService,
    policies: &PolicyLoader<'_>,
    ranked: &Ranked<'_>,
    judging: &Judging<'_>,
    config: &ProxyConfig,
    what: &str,
) -> Result<imagination::ClosedLoop, WorldModelError> {
    let e = ranked.episode;
    let error = |err: String| {
        WorldModelError::Request(format!(
            "{what}policy '{}' on task {} seed {}: {err}",
            e.policy, e.task_id, e.seed
        ))
    };
    let mut policy = policies(&e.policy).map_err(|err| error(err.to_string()))?;
    let stop = Stop {
        horizon: horizon_frames(e.budget_steps),
        judge: judging.frames,
        objects: judging.objects,
        threshold: config.threshold,
        done_frames: config.done_frames as usize,
        leak_at: judging.leak_at,
    };
    imagination::closed_loop(world, ranked.start, policy.as_mut(), ranked.context, &stop)
        .map_err(|err| error(err.to_string()))
}

/// The action test of `world` on ranked episodes' clips (all of them, or some; `None` with
/// fewer than 2).
fn action_test(
    world: &dyn WorldModelService,
    ranked: Vec<(&ProxyEpisode, &Clip)>,
) -> Result<Option<ActionTest>, WorldModelError> {
    if ranked.len() < 2 {
        return Ok(None);
    }
    let (episodes, clips): (Vec<&ProxyEpisode>, Vec<&Clip>) = ranked.into_iter().unzip();
    let names: Vec<StartName<'_>> = episodes.into_iter().map(start_name).collect();
    let o = tch::no_grad(|| video_eval::open_loop(world, &clips, &names, video_eval::HORIZON))?;
    Ok(Some(ActionTest {
        episodes: o.clips as u32,
        windows: o.windows as u32,
        horizon: o.horizon as u32,
        true_actions_mse: o.mse_true,
        shuffled_actions_mse: o.mse_shuffled,
        zero_actions_mse: o.mse_zero,
        psnr: o.psnr,
        ssim: o.ssim,
    }))
}

/// [`IMAGINED_KEYFRAMES`] frames of an imagined rollout, evenly spaced from the real first
/// frame (what the world model was given) to the last imagined one, with their indices.
fn keyframes_of(first: &[u8], imagined: &[Vec<u8>]) -> Keyframes {
    let last = imagined.len();
    (0..IMAGINED_KEYFRAMES)
        .map(|k| {
            let t = (last as f64 * k as f64 / (IMAGINED_KEYFRAMES - 1) as f64).round() as usize;
            let rgb = match t {
                0 => first.to_vec(),
                t => imagined[t - 1].clone(),
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

#[cfg(test)]
mod tests {
    use super::not_done_frames;
    use assay_model::proxy::JUDGE_NOT_DONE;

    #[test]
    fn the_default_not_done_frames_are_a_quarter_and_half_of_every_episode() {
        for last in 0..400 {
            let old: Vec<usize> = [last / 4, last / 2]
                .into_iter()
                .filter(|&t| t >= 1 && t < last)
                .collect();
            assert_eq!(not_done_frames(last, &JUDGE_NOT_DONE), old, "last {last}");
        }
        // The first imagined frame, three quarters, each once and never the last frame.
        assert_eq!(
            not_done_frames(40, &[0.75, 0.0, 0.25, 0.5, 0.5]),
            vec![1, 10, 20, 30]
        );
        assert_eq!(not_done_frames(2, &[0.0, 0.75]), vec![1]);
        assert_eq!(not_done_frames(1, &[0.0]), Vec::<usize>::new());
    }
}
