//! The world-model proxy's parts and its guarantees: the frame judge tells frames apart; the
//! world model imagines from a first frame alone, deterministically, and uses its actions; a
//! policy acts inside it closed loop; and nothing of a ranked episode's real outcome or length
//! reaches the proxy's verdict (shuffling them changes nothing; the leak ablation does change).

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::dynamics::DynamicsConfig;
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_model::proxy::{ProxyConfig, ProxyEpisode, ProxyResult};
use assay_model::video::{VideoModelConfig, WorldModelKind};
use assay_model::world::{WorldModelService, WorldStart};
use assay_spec::rng::Rng;
use assay_trainer::imagination::{self, Stop};
use assay_trainer::proxy::{ProxyRequest, run_proxy, train_frame_judge};
use assay_trainer::video_eval::{HORIZON, StartName, one_step_mse, open_loop};
use assay_trainer::video_model;
use assay_trainer::world_model::{FitRequest, WorldModel, fit_model};
use tch::Device;

const SIZE: u32 = 16;

/// A grey frame with a red 4×4 square at (x, y).
fn frame(x: u32, y: u32) -> Vec<u8> {
    let mut f = vec![100u8; (SIZE * SIZE * 3) as usize];
    for j in y..y + 4 {
        for i in x..x + 4 {
            let at = ((j * SIZE + i) * 3) as usize;
            f[at..at + 3].copy_from_slice(&[220, 30, 30]);
        }
    }
    f
}

#[test]
fn the_frame_judge_learns_where_the_object_ended_up() {
    // Success: the square ended in the left half.
    let mut rng = Rng::new(3, "test/frames");
    let mut draw = |n: usize| -> Vec<(Vec<u8>, bool)> {
        (0..n)
            .map(|_| {
                let x = (rng.unit() * f64::from(SIZE - 4)) as u32;
                let y = (rng.unit() * f64::from(SIZE - 4)) as u32;
                (frame(x, y), x + 2 < SIZE / 2)
            })
            .collect()
    };
    let train = draw(80);
    let test = draw(40);
    let examples: Vec<(&[u8], bool)> = train.iter().map(|(f, ok)| (f.as_slice(), *ok)).collect();
    let (judge, accuracy) = train_frame_judge(&examples, SIZE, 300, 3e-3, 0, Device::Cpu);
    assert!(accuracy >= 0.9, "training accuracy {accuracy}");
    let frames: Vec<&[u8]> = test.iter().map(|(f, _)| f.as_slice()).collect();
    let p = judge.probability_of(&frames);
    let right = p
        .iter()
        .zip(&test)
        .filter(|(p, t)| (**p >= 0.5) == t.1)
        .count();
    assert!(right >= 34, "{right}/40 held-out frames right");
    // One class only: nothing to learn, the judge answers it.
    let all_fail: Vec<(&[u8], bool)> = train.iter().map(|(f, _)| (f.as_slice(), false)).collect();
    let (judge, accuracy) = train_frame_judge(&all_fail, SIZE, 10, 1e-3, 0, Device::Cpu);
    assert_eq!(accuracy, 1.0);
    assert!(judge.probability_of(&frames).iter().all(|p| *p == 0.0));
}

/// A clip of the square moving `dx` pixels per frame from `start` (the action says so: 0.25 per
/// pixel), `len` frames.
fn moving(start: u32, dx: i32, len: u32) -> Clip {
    let mut rgb = Vec::new();
    let mut proprio = Vec::new();
    let mut actions = Vec::new();
    let mut x = start as i32;
    for t in 0..len {
        rgb.extend(frame(x as u32, 6));
        proprio.extend([x as f32 / 16.0, 0.4, 0.1, 0.0]);
        let step = if t + 1 < len { dx } else { 0 };
        actions.extend([step as f32 * 0.25, 0.0, 0.0, 0.0]);
        x = (x + step).clamp(0, (SIZE - 4) as i32);
    }
    Clip {
        height: SIZE,
        width: SIZE,
        interval_s: 0.1,
        proprio_dims: PROPRIO_DIMS as u32,
        action_dims: ACTION_DIMS as u32,
        rgb,
        proprio,
        actions,
        interface: String::new(),
        views: Vec::new(),
        object_dims: 0,
        objects: Vec::new(),
    }
}

/// A clip of the square moving right one pixel per frame.
fn clip(start: u32, len: u32) -> Clip {
    moving(start, 1, len)
}

fn small_config(steps: u64) -> DynamicsConfig {
    DynamicsConfig {
        image_size: SIZE,
        steps,
        chunk: 6,
        deter: 32,
        hidden: 32,
        depth: 4,
        ..Default::default()
    }
}

fn small_video(steps: u64) -> VideoModelConfig {
    VideoModelConfig {
        depth: 4,
        action_embed: 16,
        steps,
        ..Default::default()
    }
}

fn train(clips: &[Clip], config: &DynamicsConfig) -> WorldModel {
    let keys: Vec<String> = (0..clips.len()).map(|i| format!("c{i}")).collect();
    let req = FitRequest {
        config,
        group: "g",
        budget: clips.len() as u32,
        train: clips,
        eval: clips,
        eval_keys: &keys,
        device: Device::Cpu,
        normalize_actions: false,
    };
    fit_model(&req, None, &mut |_, _| Ok(())).unwrap().0
}

fn context(seed: u64) -> EpisodeContext {
    EpisodeContext {
        task_id: "t".into(),
        seed,
        instruction: "move the square".into(),
        arm: None,
    }
}

#[test]
fn the_world_model_imagines_every_frame_after_the_first_deterministically() {
    let clips: Vec<Clip> = (0..4).map(|i| clip(i, 6 + i)).collect();
    let model = train(&clips, &small_config(20));
    let world = model.service();
    assert!(world.name().contains("RSSM"), "{}", world.name());
    for (i, c) in clips.iter().enumerate() {
        let start = imagination::start_of(c, &context(i as u64));
        let actions = imagination::actions_of(c);
        let frames = imagination::replay(&world, &start, &actions).unwrap();
        assert_eq!(frames.len(), c.len() - 1);
        assert!(frames.iter().all(|f| f.len() == (SIZE * SIZE * 3) as usize));
        // Imagination draws no random numbers.
        assert_eq!(
            frames,
            imagination::replay(&world, &start, &actions).unwrap()
        );
    }
    // A start the model cannot take is refused, saying why.
    let mut start = imagination::start_of(&clips[0], &context(0));
    start.width = 32;
    let e = world.reset(&start).err().unwrap().to_string();
    assert!(e.contains("frames of 32x16") && e.contains("16x16"), "{e}");
    let start = imagination::start_of(&clips[0], &context(0));
    let e = world
        .reset(&start)
        .unwrap()
        .step(&[vec![0.0; 7]])
        .unwrap_err()
        .to_string();
    assert!(e.contains("an action of 7 values"), "{e}");
}

#[test]
fn the_trained_world_model_uses_its_actions() {
    // Squares moving left, staying or moving right from the same starts, as their actions say:
    // a model that ignored the actions could not tell these episodes apart after their first
    // frame.
    let clips: Vec<Clip> = (0..12)
        .map(|i| moving(5 + (i / 3) % 3, [-2, 0, 2][i as usize % 3], 7))
        .collect();
    // Below its free nats the prior has no reason to follow the actions: in frames this small
    // the whole episode's KL is under the default 1 nat, so the test trains without them.
    let config = DynamicsConfig {
        free_nats: 0.0,
        ..small_config(1500)
    };
    let model = train(&clips, &config);
    let world = model.service();
    // Same start, different actions: different frames.
    let start = imagination::start_of(&clips[1], &context(1));
    let right = imagination::replay(&world, &start, &vec![vec![0.5, 0.0, 0.0, 0.0]; 3]).unwrap();
    let left = imagination::replay(&world, &start, &vec![vec![-0.5, 0.0, 0.0, 0.0]; 3]).unwrap();
    let apart = imagination::mse(&right[2], &left[2]);
    assert!(
        apart > 1e-3,
        "3 steps right and 3 steps left differ by {apart}"
    );
    // Its error with the true actions is clearly below its error with another episode's.
    let refs: Vec<&Clip> = clips.iter().collect();
    let names: Vec<StartName<'_>> = (0..12)
        .map(|i| StartName {
            task_id: "t",
            seed: i,
            instruction: "",
        })
        .collect();
    let test = open_loop(&world, &refs, &names, 16).unwrap();
    assert_eq!((test.clips, test.windows), (12, 12));
    assert!(
        test.mse_true * 4.0 < test.mse_shuffled,
        "true actions {} against shuffled {}",
        test.mse_true,
        test.mse_shuffled
    );
}

/// Always moves right, in chunks of 3; remembers what it saw.
#[derive(Default)]
struct Rightwards {
    seen: Vec<PolicyObservation>,
    resets: u32,
}

impl Policy for Rightwards {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        self.resets += 1;
        Ok(())
    }
    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        self.seen.push(obs.clone());
        Ok(vec![[0.25, 0.0, 0.0, 0.0]; 3])
    }
}

fn never(_: &[u8]) -> f64 {
    0.0
}

#[test]
fn a_policy_acts_inside_the_world_model_on_the_frames_it_imagines() {
    let clips: Vec<Clip> = (0..3).map(|i| clip(i, 8)).collect();
    let model = train(&clips, &small_config(20));
    let world = model.service();
    let episode = context(0);
    let start = imagination::start_of(&clips[1], &episode);
    let stop = Stop {
        horizon: 8,
        judge: &never,
        objects: None,
        threshold: 0.5,
        done_frames: 2,
        leak_at: None,
    };
    let mut policy = Rightwards::default();
    let im = imagination::closed_loop(&world, &start, &mut policy, &episode, &stop).unwrap();
    assert_eq!(policy.resets, 1);
    // Never judged done: the whole budget of 8 frames, the real first one and 7 imagined.
    assert_eq!(im.frames.len(), 7);
    assert!(!im.done_by_judge);
    // Asked at steps 0, 3 and 6 (chunks of 3): first the real frame, then imagined ones.
    let steps: Vec<u32> = policy.seen.iter().map(|o| o.step).collect();
    assert_eq!(steps, [0, 3, 6]);
    let frame = (SIZE * SIZE * 3) as usize;
    assert_eq!(policy.seen[0].rgb, clips[1].rgb[..frame]);
    assert_eq!(policy.seen[0].proprio, [1.0 / 16.0, 0.4, 0.1, 0.0]);
    assert_eq!(policy.seen[1].rgb, im.frames[2]);
    assert_eq!(policy.seen[2].rgb, im.frames[5]);
    assert!(
        policy
            .seen
            .iter()
            .all(|o| o.proprio[3] == 0.0 || o.proprio[3] == 1.0)
    );
    // The same policy again imagines the same episode.
    let mut again = Rightwards::default();
    let im2 = imagination::closed_loop(&world, &start, &mut again, &episode, &stop).unwrap();
    assert_eq!(im.frames, im2.frames);
    // A judge that calls every frame done stops the rollout after `done_frames` frames.
    let always = |_: &[u8]| 0.9;
    let stop = Stop {
        judge: &always,
        ..stop
    };
    let done =
        imagination::closed_loop(&world, &start, &mut Rightwards::default(), &episode, &stop)
            .unwrap();
    assert!(done.done_by_judge);
    assert_eq!((done.frames.len(), done.p_success), (2, 0.9));
}

/// A world model with no model in it: a served one that refuses every start.
struct Refusing;

impl WorldModelService for Refusing {
    fn name(&self) -> String {
        "refusing".into()
    }
    fn reset(
        &self,
        _: &WorldStart,
    ) -> Result<Box<dyn assay_model::world::ImaginedEpisode + '_>, assay_model::world::WorldError>
    {
        Err(assay_model::world::WorldError::Unavailable(
            "http://127.0.0.1:9: connection refused".into(),
        ))
    }
}

fn proxy_episode(policy: &str, seed: u64, success: Option<bool>) -> ProxyEpisode {
    ProxyEpisode {
        task_id: "t".into(),
        policy: policy.into(),
        seed,
        clip: format!("clips/{policy}-{seed}"),
        instruction: "move the square".into(),
        success,
        budget_steps: 24 * 11,
        family: String::new(),
    }
}

const RANKED: &str = "remote:url=http://127.0.0.1:1";

fn run(
    train: &[ProxyEpisode],
    train_clips: &[Clip],
    eval: &[ProxyEpisode],
    eval_clips: &[Clip],
    config: &ProxyConfig,
) -> Result<ProxyResult, assay_trainer::world_model::WorldModelError> {
    let episodes = (train, train_clips, eval, eval_clips);
    run_with(episodes, config, true)
}

/// Training episodes and their clips, then ranked ones and theirs.
type Episodes<'a> = (
    &'a [ProxyEpisode],
    &'a [Clip],
    &'a [ProxyEpisode],
    &'a [Clip],
);

/// [`run`], the video model's diagnostics beside the ranking or inline.
fn run_with(
    (train, train_clips, eval, eval_clips): Episodes<'_>,
    config: &ProxyConfig,
    diagnostics_beside: bool,
) -> Result<ProxyResult, assay_trainer::world_model::WorldModelError> {
    let policies =
        |_: &str| -> Result<Box<dyn Policy>, PolicyError> { Ok(Box::new(Rightwards::default())) };
    let world_models = |_: &assay_model::proxy::ExternalWorldModel| {
        Ok(Box::new(Refusing) as Box<dyn WorldModelService>)
    };
    run_proxy(
        &ProxyRequest {
            group: "g",
            policies: &policies,
            world_models: &world_models,
            train,
            train_clips,
            eval,
            eval_clips,
            config,
            device: Device::Cpu,
            diagnostics_beside,
        },
        None,
        &mut |_, _| Ok(()),
    )
}

/// The video model's diagnostics, which the proxy computes on a copy of its model in a thread
/// of their own, equal those of the same fit computed here one after the other, and the proxy
/// with them inline gives the same result.
fn diagnostics_as_alone(config: &ProxyConfig, episodes: Episodes<'_>, base: &ProxyResult) {
    let (_, train_clips, eval_eps, eval_clips) = episodes;
    let (model, _) = video_model::fit(
        &config.video,
        train_clips,
        Device::Cpu,
        None,
        &mut |_, _| Ok(()),
    )
    .unwrap();
    let refs: Vec<&Clip> = eval_clips.iter().collect();
    let names: Vec<StartName<'_>> = eval_eps
        .iter()
        .map(|e| StartName {
            task_id: &e.task_id,
            seed: e.seed,
            instruction: &e.instruction,
        })
        .collect();
    let one_step = tch::no_grad(|| one_step_mse(&model, &refs, &names)).unwrap();
    assert_eq!(base.world_model.eval_image_mse, one_step);
    let o = tch::no_grad(|| open_loop(&model, &refs, &names, HORIZON)).unwrap();
    let test = base.action_test.as_ref().unwrap();
    assert_eq!(
        (
            test.true_actions_mse,
            test.shuffled_actions_mse,
            test.zero_actions_mse
        ),
        (o.mse_true, o.mse_shuffled, o.mse_zero)
    );
    assert_eq!(
        (test.psnr, test.ssim, test.windows),
        (o.psnr, o.ssim, o.windows as u32)
    );
    let inline = run_with(episodes, config, false).unwrap();
    assert_eq!(inline.world_model.eval_image_mse, one_step);
    assert_eq!(
        serde_json::to_value(&inline.action_test).unwrap(),
        serde_json::to_value(&base.action_test).unwrap()
    );
    assert_eq!(
        serde_json::to_value(&inline.predictions).unwrap(),
        serde_json::to_value(&base.predictions).unwrap()
    );
    assert_eq!(inline.imagined_frames, base.imagined_frames);
}

#[test]
fn the_real_episodes_length_and_outcome_change_nothing_of_the_proxy() {
    real_length_and_outcome_change_nothing(WorldModelKind::Video, "video model");
    real_length_and_outcome_change_nothing(WorldModelKind::Rssm, "RSSM");
}

fn real_length_and_outcome_change_nothing(model: WorldModelKind, name: &str) {
    // Training episodes: the square ends on the right (success) or stays left (failure).
    let mut train_eps = Vec::new();
    let mut train_clips = Vec::new();
    for i in 0..8u64 {
        let right = i % 2 == 0;
        train_clips.push(moving(1, if right { 1 } else { 0 }, 10));
        train_eps.push(proxy_episode("oracle:noise=0.01", i, Some(right)));
    }
    // Ranked episodes: real clips of various lengths and endings; the proxy sees their first
    // frame only.
    let real = |i: u64| moving(1 + (i % 2) as u32, [1, 0, -1][i as usize % 3], 4 + i as u32);
    let eval_clips: Vec<Clip> = (0..6).map(real).collect();
    let eval_eps: Vec<ProxyEpisode> = (0..6).map(|i| proxy_episode(RANKED, i, None)).collect();
    let config = ProxyConfig {
        model,
        video: small_video(150),
        world_model: small_config(150),
        judge_steps: 150,
        judge_lr: 3e-3,
        leak_ablation: true,
        ..Default::default()
    };
    let base = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    assert_eq!(base.predictions.len(), 6);
    assert!(
        base.world_model_name.contains(name),
        "{}",
        base.world_model_name
    );
    assert_eq!(base.video_model.is_some(), model == WorldModelKind::Video);
    let test = base.action_test.as_ref().unwrap();
    assert_eq!((test.episodes, test.horizon), (6, 16));
    assert!(
        test.zero_actions_mse > 0.0 && test.psnr > 0.0 && test.ssim > 0.0,
        "{test:?}"
    );
    if model == WorldModelKind::Video {
        let episodes = (
            &train_eps[..],
            &train_clips[..],
            &eval_eps[..],
            &eval_clips[..],
        );
        diagnostics_as_alone(&config, episodes, &base);
    }
    // Shuffled: each ranked episode's real clip keeps its first frame and state but gets
    // another length and another ending, and the episodes claim outcomes.
    let shuffled_clips: Vec<Clip> = (0..6u64)
        .map(|i| {
            let mut other = real((i + 3) % 6);
            let own = &eval_clips[i as usize];
            let (frame, p) = ((SIZE * SIZE * 3) as usize, PROPRIO_DIMS);
            other.rgb[..frame].copy_from_slice(&own.rgb[..frame]);
            other.proprio[..p].copy_from_slice(&own.proprio[..p]);
            other
        })
        .collect();
    assert!(
        shuffled_clips
            .iter()
            .zip(&eval_clips)
            .any(|(a, b)| a.len() != b.len())
    );
    let claimed: Vec<ProxyEpisode> = (0..6)
        .map(|i| proxy_episode(RANKED, i, Some(i % 2 == 1)))
        .collect();
    let shuffled = run(&train_eps, &train_clips, &claimed, &shuffled_clips, &config).unwrap();
    for (a, b) in base.predictions.iter().zip(&shuffled.predictions) {
        assert_eq!(
            (a.p_success, a.success, a.done_by_judge, a.imagined_frames),
            (b.p_success, b.success, b.done_by_judge, b.imagined_frames),
            "{a:?}\n{b:?}"
        );
    }
    assert_eq!(base.imagined_frames, shuffled.imagined_frames);
    // The calibration is fitted on the training episodes only: the ranked episodes' other
    // lengths, endings and claimed outcomes leave it and every calibrated probability as they
    // were.
    let calibration = base
        .calibration
        .as_ref()
        .expect("a calibration: 4 successes, 4 failures");
    assert_eq!(
        (
            calibration.episodes,
            calibration.positives,
            calibration.folds
        ),
        (8, 4, 2)
    );
    assert!(
        calibration.a.is_finite() && calibration.b.is_finite(),
        "{calibration:?}"
    );
    assert_eq!(base.calibration, shuffled.calibration);
    for (a, b) in base.predictions.iter().zip(&shuffled.predictions) {
        assert_eq!(a.p_calibrated, b.p_calibrated);
        assert_eq!(a.p_calibrated, Some(calibration.apply(a.p_success)));
    }
    // …while the training episodes' outcomes are what it is fitted on: other outcomes, another
    // calibration (this test would see a calibration that ignored them).
    if model == WorldModelKind::Video {
        let relabelled: Vec<ProxyEpisode> = train_eps
            .iter()
            .enumerate()
            .map(|(i, e)| ProxyEpisode {
                success: Some(i < 2 || i == 5),
                ..e.clone()
            })
            .collect();
        let other = run(&relabelled, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
        let other = other.calibration.expect("3 successes, 5 failures");
        assert_eq!(other.positives, 3);
        assert_ne!((other.a, other.b), (calibration.a, calibration.b));
    }
    // The leak ablation reads the judge at the real length: it does move (which is why it is
    // an ablation), so this test would see a leak into the verdict.
    let leak_at = |r: &ProxyResult| -> Vec<f64> {
        r.predictions
            .iter()
            .map(|p| p.leak.as_ref().unwrap().p_success)
            .collect()
    };
    assert_ne!(leak_at(&base), leak_at(&shuffled));
    // Every rollout runs the episode's step budget (11 clip frames) unless judged done.
    for p in &base.predictions {
        assert!(p.done_by_judge || p.imagined_frames == 11, "{p:?}");
    }
}

#[test]
fn a_scripted_oracle_is_refused_as_a_ranked_policy_and_a_dead_world_model_is_unavailable() {
    let train_clips: Vec<Clip> = (0..2).map(|i| clip(i, 6)).collect();
    let train_eps: Vec<ProxyEpisode> = (0..2)
        .map(|i| proxy_episode("oracle:noise=0.01", i, Some(i == 0)))
        .collect();
    let config = ProxyConfig {
        video: small_video(5),
        world_model: small_config(5),
        judge_steps: 5,
        ..Default::default()
    };
    let eval = [proxy_episode("oracle:noise=0.02", 0, None)];
    let e = run(&train_eps, &train_clips, &eval, &train_clips[..1], &config)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("ranked policy 'oracle:noise=0.02'")
            && e.contains("cannot act inside a world model"),
        "{e}"
    );
    let served = ProxyConfig {
        external: Some(assay_model::proxy::ExternalWorldModel {
            url: "http://127.0.0.1:9".into(),
            timeout_ms: 100,
        }),
        ..config
    };
    let eval = [proxy_episode(RANKED, 0, None)];
    let e = run(&train_eps, &train_clips, &eval, &train_clips[..1], &served).unwrap_err();
    assert!(
        matches!(
            e,
            assay_trainer::world_model::WorldModelError::World(
                assay_model::world::WorldError::Unavailable(_)
            )
        ),
        "{e}"
    );
}

/// Acts in 7-D end-effector deltas with a scene and a wrist camera at 224 pixels.
struct SevenD;

impl Policy for SevenD {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act(&mut self, _: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        Err(PolicyError::BadAnswer("never asked".into()))
    }
    fn interface(&self) -> assay_model::interface::Interface {
        assay_model::interface::Interface::from_args(&[
            ("space", "ee_delta"),
            ("cameras", "image:scene@224+wrist_image:wrist@224"),
            ("state", "ee_pos+ee_quat+gripper"),
        ])
        .unwrap()
        .unwrap()
    }
}

#[test]
fn a_policy_at_an_interface_the_world_model_cannot_imagine_is_refused_before_training() {
    let train_clips: Vec<Clip> = (0..2).map(|i| clip(i, 6)).collect();
    let train_eps: Vec<ProxyEpisode> = (0..2)
        .map(|i| proxy_episode("oracle:noise=0.01", i, Some(i == 0)))
        .collect();
    let ranked = "remote:url=http://127.0.0.1:1,space=ee_delta";
    let eval = [proxy_episode(ranked, 0, None)];
    let policies = |name: &str| -> Result<Box<dyn Policy>, PolicyError> {
        Ok(if name == ranked {
            Box::new(SevenD)
        } else {
            Box::new(Rightwards::default())
        })
    };
    let world_models = |_: &assay_model::proxy::ExternalWorldModel| {
        Ok(Box::new(Refusing) as Box<dyn WorldModelService>)
    };
    for (model, name) in [
        (WorldModelKind::Video, "Assay's video model"),
        (WorldModelKind::Rssm, "Assay's RSSM"),
    ] {
        let mut video = small_video(50);
        video.checkpoint_every = 1;
        let mut world = small_config(50);
        world.checkpoint_every = 1;
        let config = ProxyConfig {
            model,
            video,
            world_model: world,
            judge_steps: 5,
            ..Default::default()
        };
        let mut checkpoints = 0;
        let e = run_proxy(
            &ProxyRequest {
                group: "g",
                policies: &policies,
                world_models: &world_models,
                train: &train_eps,
                train_clips: &train_clips,
                eval: &eval,
                eval_clips: &train_clips[..1],
                config: &config,
                device: Device::Cpu,
                diagnostics_beside: true,
            },
            None,
            &mut |_, _| {
                checkpoints += 1;
                Ok(())
            },
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains(&format!(
                "world model '{name}' cannot imagine policy '{ranked}'"
            )) && e.contains(
                "action_space: the policy answers in ee_delta, the model takes tool_velocity"
            ),
            "{e}"
        );
        assert_eq!(checkpoints, 0, "{name} trained before refusing");
    }
}

#[test]
fn the_world_model_learns_from_its_policies_and_the_judge_from_every_training_episode() {
    // Half the training episodes are the oracle's, half another policy's.
    let mut train_eps = Vec::new();
    let mut train_clips = Vec::new();
    for i in 0..8u64 {
        let policy = if i % 2 == 0 {
            "oracle"
        } else {
            "oracle:noise=0.01"
        };
        train_clips.push(moving(1, if i < 4 { 1 } else { 0 }, 10));
        train_eps.push(proxy_episode(policy, i, Some(i < 4)));
    }
    let eval_clips: Vec<Clip> = (0..2).map(|i| moving(1, 1, 5 + i)).collect();
    let eval_eps: Vec<ProxyEpisode> = (0..2).map(|i| proxy_episode(RANKED, i, None)).collect();
    let mut config = ProxyConfig {
        video: small_video(5),
        world_model: small_config(5),
        judge_steps: 5,
        world_model_policies: vec!["oracle".into()],
        ..Default::default()
    };
    let r = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    // The video model saw the oracle's 4 clips; the judge every episode's frames (6 each: real
    // and imagined last frames, at a quarter and at half).
    assert_eq!(r.video_model.as_ref().map(|v| v.train_clips), Some(4));
    assert_eq!(r.judge_examples, 8 * 6);
    assert_eq!(r.calibration.as_ref().map(|c| c.episodes), Some(8));
    // Its latest "not done" example: a failure's last frame (9 of 10 frames); a ranked rollout
    // may run to its step budget's last frame (24 × 11 steps: frame 11).
    assert_eq!(r.judge_latest_not_done, Some(9));
    assert_eq!(r.ranked_last_frame, Some(11));
    // With successes only, the latest is half way through one.
    let successes: Vec<ProxyEpisode> = (0..8u64)
        .map(|i| proxy_episode("oracle", i, Some(true)))
        .collect();
    let all = run(&successes, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    assert_eq!(all.judge_latest_not_done, Some(4));
    // A policy with no training episode in the group leaves the world model nothing to learn.
    config.world_model_policies = vec!["random".into()];
    let err = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config)
        .map(|_| ())
        .expect_err("refused");
    assert!(
        err.to_string().contains("world_model_policies") && err.to_string().contains("\"g\""),
        "{err}"
    );
}

/// Six oracle training episodes, every other one moving and a success.
fn six_training_episodes() -> (Vec<ProxyEpisode>, Vec<Clip>) {
    (0..6u64)
        .map(|i| {
            (
                proxy_episode("oracle", i, Some(i % 2 == 0)),
                moving(1, if i % 2 == 0 { 1 } else { 0 }, 8),
            )
        })
        .unzip()
}

#[test]
fn the_cross_family_ablation_imagines_each_family_by_a_model_that_never_saw_it() {
    let (train_eps, train_clips) = six_training_episodes();
    // Ranked: three episodes of each family and one of a policy of none.
    let family_of = |i: u64| match i {
        0..3 => "unet",
        3..6 => "transformer",
        _ => "",
    };
    let eval_clips: Vec<Clip> = (0..7u64)
        .map(|i| moving(1 + (i % 3) as u32, [1, 0, -1][i as usize % 3], 6))
        .collect();
    let eval_eps: Vec<ProxyEpisode> = (0..7u64)
        .map(|i| ProxyEpisode {
            family: family_of(i).into(),
            ..proxy_episode(RANKED, i, None)
        })
        .collect();
    let mut config = ProxyConfig {
        video: small_video(40),
        world_model: small_config(40),
        judge_steps: 20,
        cross_family_ablation: true,
        ..Default::default()
    };
    let base = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    // One model per family, each trained on the training clips and the other family's.
    let fits: Vec<(&str, Vec<String>, u32)> = base
        .cross_family
        .iter()
        .map(|f| (f.family.as_str(), f.trained_with.clone(), f.train_clips))
        .collect();
    assert_eq!(
        fits,
        [
            ("unet", vec!["transformer".to_owned()], 6 + 3),
            ("transformer", vec!["unet".to_owned()], 6 + 3),
        ]
    );
    assert!(base.cross_family.iter().all(|f| f.action_test.is_some()));
    // Each model has its own frame judge, trained on its replays of the training episodes.
    for f in &base.cross_family {
        let accuracy = f.judge_train_accuracy.expect("the ablation's own judge");
        assert!((0.0..=1.0).contains(&accuracy), "{f:?}");
    }
    for (e, p) in eval_eps.iter().zip(&base.predictions) {
        assert_eq!(p.cross_family.is_some(), !e.family.is_empty(), "{e:?}");
    }
    // The proxy itself is what it is without the ablation.
    config.cross_family_ablation = false;
    let plain = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    assert!(plain.cross_family.is_empty());
    for (a, b) in base.predictions.iter().zip(&plain.predictions) {
        assert_eq!(
            (a.p_success, a.imagined_frames),
            (b.p_success, b.imagined_frames)
        );
    }
    // The U-Net's own clips after their first frame reach the transformer's model only: other
    // endings for them change the transformer's fit and leave the U-Net's verdicts as they were
    // (this test would see a family imagined by a model trained on its own episodes).
    config.cross_family_ablation = true;
    let mut changed = eval_clips.clone();
    for (i, c) in changed.iter_mut().enumerate().take(3) {
        let mut other = moving(1 + (i % 3) as u32, 2, 6);
        let (frame, p) = ((SIZE * SIZE * 3) as usize, PROPRIO_DIMS);
        other.rgb[..frame].copy_from_slice(&c.rgb[..frame]);
        other.proprio[..p].copy_from_slice(&c.proprio[..p]);
        *c = other;
    }
    assert_ne!(changed[..3], eval_clips[..3]);
    let other = run(&train_eps, &train_clips, &eval_eps, &changed, &config).unwrap();
    for i in 0..3 {
        assert_eq!(
            base.predictions[i].cross_family,
            other.predictions[i].cross_family
        );
    }
    assert_eq!(
        (
            base.cross_family[0].final_train_loss,
            base.cross_family[0].judge_train_accuracy
        ),
        (
            other.cross_family[0].final_train_loss,
            other.cross_family[0].judge_train_accuracy
        )
    );
    assert_ne!(
        base.cross_family[1].final_train_loss,
        other.cross_family[1].final_train_loss
    );
}

#[test]
fn cross_fitting_imagines_each_policy_by_a_model_trained_on_the_other_folds_only() {
    let (train_eps, train_clips) = six_training_episodes();
    // Four ranked policies, two of each family, two episodes each, interleaved.
    let policy = |k: u64| format!("remote:url=http://127.0.0.1:{}", k + 1);
    let family = |k: u64| if k < 2 { "unet" } else { "transformer" };
    let order = [0u64, 2, 1, 3, 0, 2, 1, 3];
    let eval_eps: Vec<ProxyEpisode> = order
        .iter()
        .enumerate()
        .map(|(i, &k)| ProxyEpisode {
            family: family(k).into(),
            ..proxy_episode(&policy(k), i as u64, None)
        })
        .collect();
    let eval_clips: Vec<Clip> = (0..8u64)
        .map(|i| moving(1 + (i % 3) as u32, [1, 0, -1][i as usize % 3], 6))
        .collect();
    let mut config = ProxyConfig {
        video: small_video(40),
        world_model: small_config(40),
        judge_steps: 20,
        cross_fit_folds: 2,
        ..Default::default()
    };
    let base = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    // Each family's policies dealt in turn in order of first appearance: fold 0 holds the
    // first of each family, fold 1 the second; each model trained on the 6 training clips and
    // the other fold's 4 ranked clips.
    let folds: Vec<(u32, Vec<String>, Vec<String>, u32)> = base
        .cross_fit
        .iter()
        .map(|f| {
            (
                f.fold,
                f.policies.clone(),
                f.trained_with.clone(),
                f.train_clips,
            )
        })
        .collect();
    assert_eq!(
        folds,
        [
            (
                0,
                vec![policy(0), policy(2)],
                vec![policy(1), policy(3)],
                6 + 4
            ),
            (
                1,
                vec![policy(1), policy(3)],
                vec![policy(0), policy(2)],
                6 + 4
            ),
        ]
    );
    for f in &base.cross_fit {
        assert!(f.action_test.is_some(), "{f:?}");
        assert!((0.0..=1.0).contains(&f.judge_train_accuracy), "{f:?}");
    }
    assert!(base.predictions.iter().all(|p| p.cross_fit.is_some()));
    // The proxy itself is what it is without cross-fitting.
    config.cross_fit_folds = 0;
    let plain = run(&train_eps, &train_clips, &eval_eps, &eval_clips, &config).unwrap();
    assert!(plain.cross_fit.is_empty());
    assert!(plain.predictions.iter().all(|p| p.cross_fit.is_none()));
    for (a, b) in base.predictions.iter().zip(&plain.predictions) {
        assert_eq!(
            (a.p_success, a.imagined_frames),
            (b.p_success, b.imagined_frames)
        );
    }
    // Fold 0's clips after their first frame reach fold 1's model only: other endings for them
    // leave fold 0's model, judge and verdicts as they were and change fold 1's model (this
    // test would see a policy imagined by a model trained on its own episodes).
    config.cross_fit_folds = 2;
    let in_fold_0 = |i: usize| order[i] == 0 || order[i] == 2;
    let mut changed = eval_clips.clone();
    for (i, c) in changed.iter_mut().enumerate() {
        if in_fold_0(i) {
            let mut other = moving(1 + (i % 3) as u32, 2, 6);
            let (frame, p) = ((SIZE * SIZE * 3) as usize, PROPRIO_DIMS);
            other.rgb[..frame].copy_from_slice(&c.rgb[..frame]);
            other.proprio[..p].copy_from_slice(&c.proprio[..p]);
            *c = other;
        }
    }
    assert_ne!(changed, eval_clips);
    let other = run(&train_eps, &train_clips, &eval_eps, &changed, &config).unwrap();
    for i in (0..8).filter(|&i| in_fold_0(i)) {
        assert_eq!(
            base.predictions[i].cross_fit,
            other.predictions[i].cross_fit
        );
    }
    let model = |r: &ProxyResult, k: usize| {
        (
            r.cross_fit[k].final_train_loss,
            r.cross_fit[k].judge_train_accuracy,
        )
    };
    assert_eq!(model(&base, 0), model(&other, 0));
    assert_ne!(
        base.cross_fit[1].final_train_loss,
        other.cross_fit[1].final_train_loss
    );
}
