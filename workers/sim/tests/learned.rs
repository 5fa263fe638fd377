//! A policy object in the loop: it sees frames and proprioception every 24 physics steps and its
//! actions (velocity, hold) move the tool, grasp and release.

use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_sim::{Observer, SimError, SimOptions, simulate_with};
use assay_spec::scene::{Observation, SceneSnapshot};
use assay_spec::spec::{Camera, Format, TaskSpec, parse_task};

const TASK: &str = assay_testkit::tasks::PUT_BLOCK_IN_ZONE;

fn task() -> TaskSpec {
    parse_task(TASK, Format::Yaml, "t.yaml").unwrap()
}

/// Draws grey frames and counts them.
#[derive(Default)]
struct Grey {
    frames: u32,
    size: Option<(u32, u32)>,
}

impl Observer for Grey {
    fn observe(&mut self, _: SceneSnapshot, _: u64, _: &Camera) -> Result<Observation, String> {
        Err("no depth here".into())
    }
    fn frame(&mut self, _: SceneSnapshot, _: u64, camera: &Camera) -> Result<Vec<u8>, String> {
        self.frames += 1;
        self.size = Some((camera.width, camera.height));
        Ok(vec![128; (camera.width * camera.height * 3) as usize])
    }
}

/// Knows where the block and the zone are and steers by proprioception alone: over the block,
/// down to its top, hold, up, over the zone, down, let go. Answers chunks of two actions.
#[derive(Default)]
struct Scripted {
    phase: usize,
    resets: u32,
    steps_seen: Vec<u32>,
}

impl Policy for Scripted {
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        assert_eq!(episode.instruction, "Put the red block in the green zone.");
        self.resets += 1;
        self.phase = 0;
        Ok(())
    }

    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        assert_eq!(obs.rgb.len(), (obs.width * obs.height * 3) as usize);
        self.steps_seen.push(obs.step);
        let p = obs.proprio;
        // Tool centre when its face touches the block's top: 0.04 + 0.05.
        let waypoints = [
            ([0.5, 0.1, 0.2], 0.0),
            ([0.5, 0.1, 0.09], 0.0),
            ([0.5, 0.1, 0.09], 1.0),
            ([0.5, 0.1, 0.2], 1.0),
            ([0.5, -0.1, 0.2], 1.0),
            ([0.5, -0.1, 0.095], 1.0),
            ([0.5, -0.1, 0.095], 0.0),
            ([0.5, -0.1, 0.2], 0.0),
        ];
        let phase = self.phase.min(waypoints.len() - 1);
        let (to, hold) = waypoints[phase];
        let d = [to[0] - p[0], to[1] - p[1], to[2] - p[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if dist < 0.002 {
            self.phase += 1;
        }
        // Reach the waypoint in one control step (0.1 s) at most 0.5 m/s.
        let scale = (0.5 / (dist / 0.1).max(1e-6)).min(1.0) / 0.1;
        let a = [d[0] * scale, d[1] * scale, d[2] * scale, hold];
        Ok(vec![a, [0.0, 0.0, 0.0, hold]])
    }
}

#[test]
fn a_policy_object_moves_grasps_and_places_through_its_actions() {
    let spec = task();
    let mut policy = Scripted::default();
    let mut grey = Grey::default();
    let options = SimOptions {
        observer: Some(&mut grey),
        policy: Some(&mut policy),
        clip: true,
        ..Default::default()
    };
    let ep = simulate_with(&spec, 0, "torchscript:path=scripted.pt", options).unwrap();
    assert!(ep.outcome.success, "notes: {:?}", ep.notes);
    assert_eq!(policy.resets, 1);
    assert!(policy.phase >= 6, "stopped in phase {}", policy.phase);
    // One call per two control steps (chunks of two), the frames at the default 64 pixels.
    assert_eq!(grey.size, Some((64, 64)));
    assert_eq!(u64::from(grey.frames), ep.observations);
    assert_eq!(policy.steps_seen.len() as u32, grey.frames);
    assert!(policy.steps_seen.windows(2).all(|w| w[1] == w[0] + 2));
    // The episode ends when the goal holds with nothing held, long before max_steps.
    assert!(ep.outcome.steps < 2000, "{} steps", ep.outcome.steps);
    // The clip shows the hold command the policy gave.
    let clip = ep.clip.unwrap();
    assert!(clip.actions.chunks(4).any(|a| a[3] == 1.0));
}

struct Answer(Result<Vec<Action>, PolicyError>);

impl Policy for Answer {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act(&mut self, _: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        self.0.clone()
    }
}

fn err<T>(r: Result<T, SimError>) -> SimError {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e,
    }
}

fn run(answer: Result<Vec<Action>, PolicyError>) -> Result<assay_sim::Episode, SimError> {
    let mut policy = Answer(answer);
    let mut grey = Grey::default();
    let options = SimOptions {
        observer: Some(&mut grey),
        policy: Some(&mut policy),
        frame_size: 32,
        ..Default::default()
    };
    simulate_with(&task(), 0, "remote:url=http://127.0.0.1:9", options)
}

#[test]
fn bad_or_missing_answers_fail_the_episode_with_the_reason() {
    let e = err(run(Ok(vec![[0.0, f32::NAN, 0.0, 0.0]])));
    assert!(matches!(e, SimError::Policy(_)), "{e:?}");
    assert!(e.to_string().contains("not finite"), "{e}");
    let e = err(run(Ok(vec![])));
    assert!(e.to_string().contains("empty chunk"), "{e}");
    // A server that is down: retryable, with the policy's message.
    let e = err(run(Err(PolicyError::Unavailable(
        "server at X is down".into(),
    ))));
    assert!(e.retryable(), "{e:?}");
    assert!(e.to_string().contains("server at X is down"), "{e}");
    // Standing still is allowed: the episode runs to max_steps and fails.
    let ep = run(Ok(vec![[0.0; 4]])).unwrap();
    assert!(!ep.outcome.success);
    assert!(ep.outcome.steps >= u64::from(task().physics.max_steps));
    // A horizon in the policy's name ends it sooner: settle, 480 steps of policy, settle.
    let mut policy = Answer(Ok(vec![[0.0; 4]]));
    let mut grey = Grey::default();
    let options = SimOptions {
        observer: Some(&mut grey),
        policy: Some(&mut policy),
        ..Default::default()
    };
    let spec = task();
    let ep = simulate_with(&spec, 0, "remote:url=http://h:1,max_steps=480", options).unwrap();
    let settle = u64::from(spec.physics.settle_steps);
    assert_eq!(ep.outcome.steps, 480 + 2 * settle);
    assert_eq!(grey.frames, 480 / 24);
}

#[test]
fn a_policy_object_needs_an_observer_and_a_learned_policy_needs_an_object() {
    let mut policy = Answer(Ok(vec![[0.0; 4]]));
    let options = SimOptions {
        policy: Some(&mut policy),
        ..Default::default()
    };
    let e = err(simulate_with(&task(), 0, "diffusion:model=m", options));
    assert!(e.to_string().contains("render role"), "{e}");
    let mut grey = Grey::default();
    let options = SimOptions {
        observer: Some(&mut grey),
        ..Default::default()
    };
    let e = err(simulate_with(&task(), 0, "diffusion:model=m", options));
    assert!(e.to_string().contains("no policy object"), "{e}");
}
