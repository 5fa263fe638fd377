//! Clips at a policy's interface: from an episode's recorded rows, the state a policy of that
//! interface would have seen and the actions in its space that move the robot as it moved, with
//! its cameras placed at every frame. Checked against a policy that acted at that interface
//! (its own states and actions come back), by running the oracle's recorded actions through the
//! policy driver (the tool follows the oracle's path), and against the episode file.

use assay_model::policy::{EpisodeContext, Interface, Policy, PolicyError, PolicyObservation};
use assay_sim::at_interface::WRIST_CAMERA_MOUNT;
use assay_sim::{ClipStates, Observer, SimOptions, recorded_states_at, simulate_with};
use assay_spec::scene::{Observation, SceneSnapshot};
use assay_spec::spec::{Camera, Format, TaskSpec, parse_task};

mod common;

fn task() -> TaskSpec {
    common::turn_block_task("")
}

/// The interface of the clips and policies here: a scene and a wrist camera, the tool's pose
/// and holding, 7-D end-effector deltas.
const SEVEN: &str = "space=ee_delta,cameras=image:scene@32+wrist:wrist@16,\
                     state=ee_pos+ee_yaw+holding";

fn seven() -> Interface {
    Interface::parse_args(SEVEN).unwrap()
}

/// Grey frames.
struct Grey;

impl Observer for Grey {
    fn observe(&mut self, _: SceneSnapshot, _: u64, _: &Camera) -> Result<Observation, String> {
        Err("no depth here".into())
    }
    fn frame(&mut self, _: SceneSnapshot, _: u64, c: &Camera) -> Result<Vec<u8>, String> {
        Ok(vec![128; (c.width * c.height * 3) as usize])
    }
}

/// Steers by its state alone through waypoints (x, y, z, yaw, hold) in end-effector deltas,
/// one action per call; keeps what it saw and answered.
struct Waypoints {
    points: Vec<([f32; 3], f32, f32)>,
    phase: usize,
    states: Vec<Vec<f32>>,
    actions: Vec<Vec<f32>>,
}

impl Policy for Waypoints {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let s = &obs.state;
        self.states.push(s.clone());
        let (p, yaw) = ([s[0], s[1], s[2]], s[3]);
        let (to, to_yaw, hold) = self.points[self.phase.min(self.points.len() - 1)];
        let d = [to[0] - p[0], to[1] - p[1], to[2] - p[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let dyaw = assay_sim::tabletop::wrap_angle(to_yaw - yaw);
        if dist < 0.003 && dyaw.abs() < 0.01 {
            self.phase += 1;
        }
        let scale = (0.03 / dist.max(1e-6)).min(1.0);
        let a = vec![
            d[0] * scale,
            d[1] * scale,
            d[2] * scale,
            0.0,
            0.0,
            dyaw.clamp(-0.2, 0.2),
            hold,
        ];
        self.actions.push(a.clone());
        Ok(vec![a])
    }

    fn interface(&self) -> Interface {
        seven()
    }
}

/// Answers the actions it is given, one per call, then stands still.
struct Replay {
    actions: Vec<Vec<f32>>,
    next: usize,
    positions: Vec<[f32; 3]>,
}

impl Policy for Replay {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        self.positions
            .push([obs.state[0], obs.state[1], obs.state[2]]);
        let a = self.actions.get(self.next).cloned().unwrap_or_else(|| {
            let hold = self.actions.last().map_or(0.0, |a| a[6]);
            vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, hold]
        });
        self.next += 1;
        Ok(vec![a])
    }

    fn interface(&self) -> Interface {
        seven()
    }
}

fn frame(v: &[f32], dims: usize, k: usize) -> &[f32] {
    &v[k * dims..(k + 1) * dims]
}

fn clip_at(
    spec: &TaskSpec,
    policy_name: &str,
    policy: Option<&mut dyn Policy>,
) -> assay_sim::Episode {
    let mut grey = Grey;
    let options = SimOptions {
        clip: true,
        clip_interface: Some(seven()),
        observer: Some(&mut grey),
        policy: policy.map(|p| -> &mut dyn Policy { p }),
        ..Default::default()
    };
    simulate_with(spec, 0, policy_name, options).unwrap()
}

#[test]
fn a_clip_at_a_policys_interface_gives_back_what_the_policy_saw_and_answered() {
    let spec = task();
    let mut policy = Waypoints {
        points: common::carry_and_turn(),
        phase: 0,
        states: Vec::new(),
        actions: Vec::new(),
    };
    let ep = clip_at(&spec, "openpi:url=ws://h:1", Some(&mut policy));
    assert!(ep.outcome.success, "{:?}", ep.notes);
    let c: &ClipStates = ep.clip.as_ref().unwrap();
    assert_eq!(c.interface, Some(seven()));
    assert_eq!(c.proprio.len(), c.len() * 5);
    assert_eq!(c.actions.len(), c.len() * 7);
    // One clip frame per control step: frame k is what the policy saw at its k-th call, and the
    // clip's action k is what it answered then.
    let n = policy.actions.len().min(c.len() - 1);
    assert!(n > 30, "{n} control steps");
    let mut worst = [0f32; 3];
    for k in 0..n {
        let (state, action) = (frame(&c.proprio, 5, k), frame(&c.actions, 7, k));
        for (a, b) in state.iter().zip(&policy.states[k]) {
            worst[0] = worst[0].max((a - b).abs());
        }
        for (a, b) in action[..3].iter().zip(&policy.actions[k]) {
            worst[1] = worst[1].max((a - b).abs());
        }
        worst[2] = worst[2].max((action[5] - policy.actions[k][5]).abs());
        assert_eq!(action[6], policy.actions[k][6], "hold command at {k}");
        assert_eq!((action[3], action[4]), (0.0, 0.0));
    }
    println!("{n} control steps; worst state, translation and turn differences {worst:?}");
    assert!(
        worst[0] < 1e-6 && worst[1] < 1e-5 && worst[2] < 1e-5,
        "worst state, translation and turn differences {worst:?}"
    );
    // The last frame has no action.
    assert!(frame(&c.actions, 7, c.len() - 1).iter().all(|&x| x == 0.0));

    // The cameras at every frame: the scene camera where the task put it at 32², the wrist
    // camera 16² on the tool, beside it, looking down and forward along its heading.
    assert_eq!(c.cameras.len(), 2);
    let (scene, wrist) = (&c.cameras[0], &c.cameras[1]);
    assert_eq!(
        (scene.name.as_str(), wrist.name.as_str()),
        ("image", "wrist")
    );
    let task_camera = &assay_spec::scene::task_cameras(&spec.cameras)[0];
    for k in 0..c.len() {
        let s = &scene.frames[k];
        assert_eq!(
            (s.eye, s.target, s.width, s.height),
            (task_camera.eye, task_camera.target, 32, 32)
        );
        let w = &wrist.frames[k];
        let ee = frame(&c.proprio, 5, k);
        assert_eq!((w.width, w.height), (16, 16));
        let [mx, _, mz] = WRIST_CAMERA_MOUNT;
        let (sin, cos) = ee[3].sin_cos();
        let mount = [ee[0] + mx * cos, ee[1] + mx * sin, ee[2] + mz].map(f64::from);
        for (got, want) in w.eye.iter().zip(mount) {
            assert!(
                (got - want).abs() < 1e-5,
                "eye {:?}, wanted {mount:?}",
                w.eye
            );
        }
        let heading = (w.target[1] - w.eye[1]).atan2(w.target[0] - w.eye[0]) as f32;
        assert!(assay_sim::tabletop::wrap_angle(heading - ee[3]).abs() < 1e-3);
    }

    // The episode file read again at the interface gives the same clip.
    let again = recorded_states_at(&spec, 0, &ep.file, &seven()).unwrap();
    assert_eq!(&again, c);
}

#[test]
fn the_oracles_actions_recorded_at_a_policys_interface_retrace_its_path() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../examples/tasks/placement/put-block-in-bowl.yaml"
    );
    let text = std::fs::read_to_string(path).unwrap();
    let spec = parse_task(&text, Format::Yaml, path).unwrap();
    let oracle = clip_at(&spec, "oracle", None);
    assert!(oracle.outcome.success);
    let c = oracle.clip.as_ref().unwrap();
    let actions: Vec<Vec<f32>> = c.actions.chunks(7).map(<[f32]>::to_vec).collect();
    let mut replay = Replay {
        actions: actions[..c.len() - 1].to_vec(),
        next: 0,
        positions: Vec::new(),
    };
    let ep = clip_at(&spec, "openpi:url=ws://h:1", Some(&mut replay));
    // Run through the policy driver, the oracle's actions in end-effector deltas move the tool
    // along the oracle's path, frame for frame.
    // (A policy's episode ends once its goals hold; the oracle's clip runs on through the final
    // settle.)
    let n = (c.len() - 1).min(replay.positions.len());
    assert!(n > 20, "{n} of {} frames replayed", c.len());
    let worst = (0..n)
        .map(|k| {
            let (a, b) = (frame(&c.proprio, 5, k), replay.positions[k]);
            (0..3).map(|i| (a[i] - b[i]).abs()).fold(0f32, f32::max)
        })
        .fold(0f32, f32::max);
    println!("{n} frames replayed; the tool strays at most {worst} m from the oracle's");
    assert!(
        worst < 1e-4,
        "the replayed tool strays {worst} m from the oracle's"
    );
    // The hold commands grasp and release as the oracle did.
    assert_eq!(
        ep.outcome.success, oracle.outcome.success,
        "replay {:?}",
        ep.notes
    );
}

#[test]
fn an_interface_the_task_cannot_fill_refuses_the_clip_naming_the_task_and_field() {
    let spec = task();
    let run = |args: &str| {
        let options = SimOptions {
            clip: true,
            clip_interface: Some(Interface::parse_args(args).unwrap()),
            ..Default::default()
        };
        simulate_with(&spec, 0, "oracle", options)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    let e = run("space=ee_delta,cameras=side:no_such_camera,state=ee_pos");
    assert!(
        e.contains("turn-block-into-zone") && e.contains("no_such_camera"),
        "{e}"
    );
    let e = run("space=joint_position,cameras=image,state=ee_pos");
    assert!(
        e.contains("turn-block-into-zone") && e.contains("action_space"),
        "{e}"
    );
    let file = simulate_with(&spec, 0, "oracle", SimOptions::default())
        .unwrap()
        .file;
    let e = recorded_states_at(
        &spec,
        0,
        &file,
        &Interface::parse_args("space=joint_position,cameras=image,state=ee_pos").unwrap(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("action_space"), "{e}");
}
