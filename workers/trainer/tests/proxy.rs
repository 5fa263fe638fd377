//! The world-model proxy's parts: the frame judge tells frames apart, and the world model imagines
//! whole clips from their first frame alone, deterministically.

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::dynamics::DynamicsConfig;
use assay_spec::rng::Rng;
use assay_trainer::proxy::train_frame_judge;
use assay_trainer::world_model::{FitRequest, fit_model};
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

/// A clip of the square moving right one pixel per frame (the action says so).
fn clip(start: u32, len: u32) -> Clip {
    let mut rgb = Vec::new();
    let mut proprio = Vec::new();
    let mut actions = Vec::new();
    for t in 0..len {
        rgb.extend(frame(start + t, 6));
        proprio.extend([(start + t) as f32 / 16.0, 0.4, 0.1, 0.0]);
        actions.extend([if t + 1 < len { 0.1 } else { 0.0 }, 0.0, 0.0, 0.0]);
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
    }
}

#[test]
fn the_world_model_imagines_every_frame_after_the_first_deterministically() {
    let config = DynamicsConfig {
        image_size: SIZE,
        steps: 20,
        chunk: 6,
        deter: 32,
        hidden: 32,
        depth: 4,
        ..Default::default()
    };
    let clips: Vec<Clip> = (0..4).map(|i| clip(i, 6 + i)).collect();
    let keys: Vec<String> = (0..4).map(|i| format!("c{i}")).collect();
    let req = FitRequest {
        config: &config,
        group: "g",
        budget: 4,
        train: &clips,
        eval: &clips,
        eval_keys: &keys,
        device: Device::Cpu,
    };
    let (model, fit) = fit_model(&req, None, &mut |_, _| Ok(())).unwrap();
    assert_eq!(fit.steps, 20);
    // Batches of 3 pad the shorter clips; each clip still gets exactly its own frames.
    let imagined = model.imagine(&clips, 3).unwrap();
    assert_eq!(imagined.len(), 4);
    for (im, c) in imagined.iter().zip(&clips) {
        assert_eq!(im.frames.len(), c.len() - 1);
        assert!(
            im.frames
                .iter()
                .all(|f| f.len() == (SIZE * SIZE * 3) as usize)
        );
        assert!(im.last_frame_mse.is_finite() && im.last_frame_mse > 0.0);
    }
    // The same clips, one at a time, give the same pictures: imagination draws no random numbers.
    let again = model.imagine(&clips, 1).unwrap();
    for (a, b) in imagined.iter().zip(&again) {
        assert_eq!(a.frames, b.frames);
    }
    let mut bad = clip(0, 1);
    bad.proprio_dims = PROPRIO_DIMS as u32;
    let e = model.imagine(&[bad], 1).unwrap_err().to_string();
    assert!(
        e.contains("imagined clip 0") && e.contains("2 are needed"),
        "{e}"
    );
}

/// Always moves right, in chunks of 3; remembers what it saw.
#[derive(Default)]
struct Rightwards {
    seen: Vec<assay_model::policy::PolicyObservation>,
    resets: u32,
}

impl assay_model::policy::Policy for Rightwards {
    fn reset(
        &mut self,
        _: &assay_model::policy::EpisodeContext,
    ) -> Result<(), assay_model::policy::PolicyError> {
        self.resets += 1;
        Ok(())
    }
    fn act(
        &mut self,
        obs: &assay_model::policy::PolicyObservation,
    ) -> Result<Vec<assay_model::policy::Action>, assay_model::policy::PolicyError> {
        self.seen.push(obs.clone());
        Ok(vec![[0.1, 0.0, 0.0, 0.0]; 3])
    }
}

#[test]
fn a_policy_acts_inside_the_world_model_on_the_frames_it_imagines() {
    let config = DynamicsConfig {
        image_size: SIZE,
        steps: 20,
        chunk: 6,
        deter: 32,
        hidden: 32,
        depth: 4,
        ..Default::default()
    };
    let clips: Vec<Clip> = (0..3).map(|i| clip(i, 8)).collect();
    let keys: Vec<String> = (0..3).map(|i| format!("c{i}")).collect();
    let req = FitRequest {
        config: &config,
        group: "g",
        budget: 3,
        train: &clips,
        eval: &clips,
        eval_keys: &keys,
        device: Device::Cpu,
    };
    let (model, _) = fit_model(&req, None, &mut |_, _| Ok(())).unwrap();
    let episode = assay_model::policy::EpisodeContext {
        task_id: "t".into(),
        seed: 0,
        instruction: "move right".into(),
        arm: None,
    };
    let mut policy = Rightwards::default();
    let im = model
        .imagine_policy(&clips[1], 8, &mut policy, &episode)
        .unwrap();
    assert_eq!(policy.resets, 1);
    assert_eq!(im.frames.len(), 7);
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
    let im2 = model
        .imagine_policy(&clips[1], 8, &mut again, &episode)
        .unwrap();
    assert_eq!(im.frames, im2.frames);
}
