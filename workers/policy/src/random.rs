//! `random:speed=S,hold=P` — exploration ("play") episodes for training world models: the tool
//! wanders at random, and the gripper closes and opens at random. A world model trained only on a
//! scripted oracle's episodes can predict the next frame from the frames alone (the oracle's plan
//! is a function of the scene), so it has no reason to follow its actions; episodes whose actions
//! are not predictable from what is seen make it learn what an action does. Never a policy to
//! rank: it is there to train a proxy's world model (name it in `--rank-train-policies`).
//!
//! Each call returns a chunk of [`CHUNK`] equal actions in the clips' space (tool velocity x, y, z
//! in m/s and the hold command): a fresh velocity uniform in ±`speed` per axis, pulled back toward
//! a box around the tool's start (±0.2 m in x and y; from 0.02 m above the table to 0.05 m above
//! the start in z) when the tool has left it; the hold command flips with probability `hold`.
//! Its draws come from Assay's generator, seeded by the episode's task and seed: the same episode
//! wanders the same way.

use assay_model::clip::ACTION_DIMS;
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_spec::rng::Rng;

/// Control steps one drawn action lasts.
pub const CHUNK: usize = 5;
const REACH_XY: f32 = 0.2;
const FLOOR_Z: f32 = 0.02;
const ABOVE_START_Z: f32 = 0.05;

pub struct RandomPolicy {
    speed: f32,
    hold_probability: f64,
    rng: Rng,
    start: Option<[f32; 3]>,
    hold: bool,
}

impl RandomPolicy {
    pub fn new(speed: f64, hold_probability: f64) -> Self {
        Self {
            speed: speed as f32,
            hold_probability,
            rng: Rng::new(0, "policy/random"),
            start: None,
            hold: false,
        }
    }
}

impl Policy for RandomPolicy {
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.rng = Rng::new(episode.seed, &format!("policy/random/{}", episode.task_id));
        self.start = None;
        self.hold = false;
        Ok(())
    }

    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        let pos = [obs.proprio[0], obs.proprio[1], obs.proprio[2]];
        let start = *self.start.get_or_insert(pos);
        let mut action: Action = [0.0; ACTION_DIMS];
        for (k, v) in action.iter_mut().take(3).enumerate() {
            let drawn = (self.rng.unit() as f32 * 2.0 - 1.0) * self.speed;
            let (low, high) = match k {
                2 => (FLOOR_Z, start[2] + ABOVE_START_Z),
                _ => (start[k] - REACH_XY, start[k] + REACH_XY),
            };
            *v = if pos[k] < low {
                drawn.abs()
            } else if pos[k] > high {
                -drawn.abs()
            } else {
                drawn
            };
        }
        if self.rng.unit() < self.hold_probability {
            self.hold = !self.hold;
        }
        action[3] = if self.hold { 1.0 } else { 0.0 };
        Ok(vec![action; CHUNK])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(step: u32, pos: [f32; 3]) -> PolicyObservation {
        PolicyObservation::legacy(step, 4, 4, vec![0; 48], [pos[0], pos[1], pos[2], 0.0])
    }

    fn episode(seed: u64) -> EpisodeContext {
        EpisodeContext {
            task_id: "t".into(),
            seed,
            instruction: String::new(),
            arm: None,
        }
    }

    #[test]
    fn wanders_within_its_speed_back_toward_its_box_and_repeats_per_episode() {
        let mut p = RandomPolicy::new(0.2, 0.3);
        p.reset(&episode(1)).unwrap();
        let start = [0.0, 0.0, 0.2];
        let a = p.act(&obs(0, start)).unwrap();
        assert_eq!(a.len(), CHUNK);
        assert!(a.iter().all(|x| x == &a[0]));
        assert!(a[0][..3].iter().all(|v| v.abs() <= 0.2));
        // Far off to +x and below the floor: pulled back in x, up in z.
        for step in 1..50 {
            let a = p.act(&obs(step, [0.5, 0.0, 0.0])).unwrap();
            assert!(a[0][0] <= 0.0 && a[0][2] >= 0.0, "{a:?}");
        }
        let run = |seed| {
            let mut p = RandomPolicy::new(0.2, 0.3);
            p.reset(&episode(seed)).unwrap();
            (0..20)
                .map(|s| p.act(&obs(s, start)).unwrap()[0])
                .collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
        // The hold command flips now and then.
        let holds: Vec<f32> = run(3).iter().map(|a| a[3]).collect();
        assert!(holds.contains(&1.0) && holds.contains(&0.0), "{holds:?}");
    }
}
