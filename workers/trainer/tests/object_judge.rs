//! Objects in the world model (`VideoModelConfig::object_weight`) and the proxy's object judge
//! (`ProxyConfig::object_judge`), on a task where frames alone mislead: the tool moves right in
//! every episode, and the task is done only when it carried the block along (its hold command
//! on). The video model learns where the block goes from the actions; the object judge, fitted
//! on the training episodes only, tells a carrying policy from one that leaves the block behind.

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::dynamics::DynamicsConfig;
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_model::proxy::{OBJECTS_SOURCE, ProxyConfig, ProxyEpisode, ProxyResult};
use assay_model::video::VideoModelConfig;
use assay_model::world::WorldModelService;
use assay_trainer::imagination;
use assay_trainer::proxy::{ProxyRequest, run_proxy};
use assay_trainer::video_model::{VideoModel, fit, fit_to_checkpoint};
use tch::Device;

const SIZE: u32 = 16;

/// A grey frame with the tool, a red 3×3 square, at `tool` and the block, a green 3×3 square,
/// at `block` (x, y in pixels).
fn frame(tool: (i32, i32), block: (i32, i32)) -> Vec<u8> {
    let mut f = vec![100u8; (SIZE * SIZE * 3) as usize];
    for ((x, y), colour) in [(block, [30, 200, 30]), (tool, [220, 30, 30])] {
        for j in y..y + 3 {
            for i in x..x + 3 {
                let at = ((j as u32 * SIZE + i as u32) * 3) as usize;
                f[at..at + 3].copy_from_slice(&colour);
            }
        }
    }
    f
}

/// The tool starts at `x` above the block and moves 1 px right a frame for `len` frames; with
/// `carry` its hold command is on and the block moves with it, else the block stays. Objects:
/// the block, then a marker that never moves. The state is the tool's place, the same for both.
fn episode(x: i32, carry: bool, len: usize) -> Clip {
    let (mut tool, mut block) = (x, x);
    let (mut rgb, mut proprio, mut actions, mut objects) = (vec![], vec![], vec![], vec![]);
    let hold = f32::from(u8::from(carry));
    for t in 0..len {
        rgb.extend(frame((tool, 4), (block, 9)));
        // Holding is never in the state: only the block's place tells the outcome.
        proprio.extend([tool as f32 / 16.0, 0.25, 0.1, 0.0]);
        objects.extend([block as f32 / 16.0, 0.56, 0.02, 0.9, 0.9, 0.0]);
        let step = i32::from(t + 1 < len);
        actions.extend([step as f32 * 0.25, 0.0, 0.0, hold * step as f32]);
        tool = (tool + step).min(SIZE as i32 - 3);
        if carry {
            block = tool;
        }
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
        object_dims: 6,
        objects,
    }
}

fn small(steps: u64, object_weight: f64) -> VideoModelConfig {
    VideoModelConfig {
        depth: 4,
        action_embed: 16,
        steps,
        checkpoint_every: 0,
        object_weight,
        ..VideoModelConfig::default()
    }
}

/// Training episodes: carried and left blocks from a few starts.
fn training() -> Vec<Clip> {
    (0..12)
        .map(|i| episode(1 + (i / 2) % 3, i % 2 == 0, 8))
        .collect()
}

/// The block's x (pixels) in the last of `frames`' objects.
fn block_x(objects: &[f32]) -> f32 {
    objects[0] * 16.0
}

#[test]
fn the_video_model_moves_the_block_as_its_actions_say_and_keeps_it_in_its_checkpoint() {
    let train = training();
    let (model, _) = fit(&small(400, 1.0), &train, Device::Cpu, None, &mut |_, _| {
        Ok(())
    })
    .unwrap();
    assert!(model.name().contains("6 object"), "{}", model.name());
    // A start it never saw (x = 4), run with the hold command on and off.
    let start = imagination::start_of(&episode(4, true, 8), &context(0));
    assert_eq!(start.objects.len(), 6);
    let run = |hold: f32| {
        let actions = vec![vec![0.25, 0.0, 0.0, hold]; 6];
        imagination::replay_frames(&model, &start, &actions).unwrap()
    };
    let (carried, left) = (run(1.0), run(0.0));
    let (c, l) = (
        block_x(carried[5].objects.as_ref().unwrap()),
        block_x(left[5].objects.as_ref().unwrap()),
    );
    // Carried 6 px from x = 4, the block is near 10; left, it stays near 4.
    assert!(
        (c - 10.0).abs() < 1.5 && (l - 4.0).abs() < 1.5,
        "carried {c}, left {l}"
    );
    // The marker stays where it was; the state a policy sees is the interface's 4 floats.
    let marker = &carried[5].objects.as_ref().unwrap()[3..];
    assert!(
        marker
            .iter()
            .zip([0.9, 0.9, 0.0])
            .all(|(a, b)| (a - b).abs() < 0.1),
        "{marker:?}"
    );
    assert_eq!(carried[5].state.as_ref().unwrap().len(), 4);
    // Its checkpoint keeps the objects: loaded, it imagines the same positions.
    let (_, bytes) = fit_to_checkpoint(&small(400, 1.0), &train, Device::Cpu, None, &mut |_, _| {
        Ok(())
    })
    .unwrap();
    let loaded = VideoModel::from_checkpoint(&small(400, 1.0), SIZE, &bytes, Device::Cpu).unwrap();
    let again = imagination::replay_frames(&loaded, &start, &vec![vec![0.25, 0.0, 0.0, 1.0]; 6]);
    assert_eq!(again.unwrap()[5].objects, carried[5].objects);
    // A start without the objects is refused; a model without object_weight predicts none.
    let mut bare = start.clone();
    bare.objects.clear();
    let e = model.reset(&bare).err().unwrap().to_string();
    assert!(
        e.contains("0 object values") && e.contains("predicts 6"),
        "{e}"
    );
    let (plain, _) = fit(
        &small(2, 0.0),
        &train,
        Device::Cpu,
        None,
        &mut |_, _| Ok(()),
    )
    .unwrap();
    let frames = imagination::replay_frames(&plain, &bare, &[vec![0.25, 0.0, 0.0, 1.0]]).unwrap();
    assert_eq!(frames[0].objects, None);
}

fn context(seed: u64) -> EpisodeContext {
    EpisodeContext {
        task_id: "t".into(),
        seed,
        instruction: "carry the block right".into(),
        arm: None,
    }
}

/// Moves right in chunks of 3, its hold command on (`carry`) or off.
struct Mover {
    carry: bool,
}

impl Policy for Mover {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act(&mut self, _: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        Ok(vec![[0.25, 0.0, 0.0, f32::from(u8::from(self.carry))]; 3])
    }
}

const CARRIER: &str = "remote:url=http://127.0.0.1:1";
const LEAVER: &str = "remote:url=http://127.0.0.1:2";

fn proxy_episode(policy: &str, seed: u64, success: Option<bool>) -> ProxyEpisode {
    ProxyEpisode {
        task_id: "t".into(),
        policy: policy.into(),
        seed,
        clip: format!("clips/{policy}-{seed}"),
        instruction: "carry the block right".into(),
        success,
        budget_steps: 24 * 8,
        family: String::new(),
    }
}

fn rank(eval: &[ProxyEpisode], eval_clips: &[Clip], config: &ProxyConfig) -> ProxyResult {
    let train_clips = training();
    // Carried blocks end on the right: successes; left ones: failures.
    let train: Vec<ProxyEpisode> = (0..12)
        .map(|i| proxy_episode("oracle", i, Some(i % 2 == 0)))
        .collect();
    let policies = |name: &str| -> Result<Box<dyn Policy>, PolicyError> {
        Ok(Box::new(Mover {
            carry: name == CARRIER,
        }))
    };
    let world_models = |_: &assay_model::proxy::ExternalWorldModel| {
        Err(assay_model::world::WorldError::Unavailable("none".into()))
    };
    run_proxy(
        &ProxyRequest {
            group: "g",
            policies: &policies,
            world_models: &world_models,
            train: &train,
            train_clips: &train_clips,
            eval,
            eval_clips,
            config,
            device: Device::Cpu,
            diagnostics_beside: false,
        },
        None,
        &mut |_, _| Ok(()),
    )
    .unwrap()
}

#[test]
fn the_object_judge_tells_a_carrying_policy_from_one_that_leaves_the_block() {
    // Ranked: each policy from starts the world model never saw; their real clips give the
    // first frame, state and objects only.
    let eval: Vec<ProxyEpisode> = (0..4)
        .map(|i| proxy_episode(if i % 2 == 0 { CARRIER } else { LEAVER }, 10 + i, None))
        .collect();
    let eval_clips: Vec<Clip> = (0..4).map(|i| episode(4 + i / 2, i % 2 == 0, 8)).collect();
    let config = ProxyConfig {
        video: small(400, 1.0),
        // The proxy's frame size (the RSSM's settings carry it).
        world_model: DynamicsConfig {
            image_size: SIZE,
            ..Default::default()
        },
        judge_steps: 100,
        object_judge: true,
        ..Default::default()
    };
    assert_eq!(config.validate(), Ok(()));
    let result = rank(&eval, &eval_clips, &config);
    let accuracy = result.object_judge_train_accuracy.unwrap();
    assert!(
        accuracy >= 0.95,
        "object judge training accuracy {accuracy}"
    );
    for (p, e) in result.predictions.iter().zip(&eval) {
        let v = p.object_judge.as_ref().expect("an object judge's verdict");
        assert_eq!(v.success, e.policy == CARRIER, "{}: {v:?}", e.policy);
    }
    // Nothing of the ranked episodes' real outcomes or lengths reaches it: other endings and
    // claimed outcomes, the same verdicts.
    let claimed: Vec<ProxyEpisode> = eval
        .iter()
        .map(|e| ProxyEpisode {
            success: Some(e.policy != CARRIER),
            ..e.clone()
        })
        .collect();
    let other_clips: Vec<Clip> = eval_clips
        .iter()
        .map(|c| {
            let mut o = episode(4, c.actions[3] == 0.0, 5);
            let (f, p, k) = ((SIZE * SIZE * 3) as usize, PROPRIO_DIMS, 6);
            o.rgb[..f].copy_from_slice(&c.rgb[..f]);
            o.proprio[..p].copy_from_slice(&c.proprio[..p]);
            o.objects[..k].copy_from_slice(&c.objects[..k]);
            o
        })
        .collect();
    let other = rank(&claimed, &other_clips, &config);
    for (a, b) in result.predictions.iter().zip(&other.predictions) {
        assert_eq!(a.object_judge, b.object_judge);
    }
    // Asked of a model that predicts no objects, the object judge is refused before anything
    // is trained.
    let bare = ProxyConfig {
        video: small(2, 0.0),
        ..config.clone()
    };
    let e = bare.validate().unwrap_err();
    assert!(
        e.contains("object_judge") && e.contains("object_weight"),
        "{e}"
    );
    assert_eq!(OBJECTS_SOURCE, "world-model-objects");
}
