//! The tool's full orientation: a policy that pitches or rolls the tool stands a lying block on
//! its end — free, on the UR5 and on the Panda (inverse kinematics with the whole orientation),
//! in `ee_delta` and in `ee_pose` — where the scripted oracle, whose tool points down, cannot; the
//! state, the recorded rows, the drawn tool and the wrist camera turn with it; a turn the arm
//! cannot reach is refused, noted naming the policy and the turn.

use assay_model::policy::{
    ActionSpace, CameraRequest, CameraSource, EpisodeContext, Interface, Policy, PolicyError,
    PolicyObservation, StatePart,
};
use assay_sim::at_interface::{
    WRIST_CAMERA_TILT, rpy_of_turn, tool_quaternion, turn_of_quaternion, turn_of_rpy,
};
use assay_sim::{Observer, SimError, SimOptions, simulate_with};
use assay_spec::scene::{Observation, SceneSnapshot};
use assay_spec::spec::{Camera, TaskSpec};
use rapier3d::prelude::{Rotation, Vec3};

mod common;
use common::column;

/// A block lying on its long side (along x, or along y), to be stood on its end on the green
/// square.
fn stand_task(arm: &str, along_y: bool) -> TaskSpec {
    let half = if along_y {
        "[0.02, 0.05, 0.02]"
    } else {
        "[0.05, 0.02, 0.02]"
    };
    let yaml = format!(
        r#"
spec_version: 1
id: stand-block-on-end
name: stand-block-on-end
description: Stand the red block upright on its end on the green square.
group: placement
scene:
  objects:
    - {{id: red_block, shape: {{box: {{half_extents: {half}}}}}, color: red, pose: {{position: [0.5, 0.1, 0.02]}}}}
  zones:
    - {{id: goal, center: [0.5, -0.1], half_extents: [0.05, 0.05], color: green}}
end_effector: {{type: suction}}
physics: {{max_steps: 4800}}
goals:
  - pose_within: {{object: red_block, position: [0.5, -0.1, 0.05], tolerance: 0.015}}
oracle:
  - pick: {{object: red_block}}
  - place: {{target: {{zone: goal}}}}
{arm}
"#
    );
    assay_spec::spec::parse_task(&yaml, assay_spec::spec::Format::Yaml, "t.yaml").unwrap()
}

/// A waypoint: the tool's centre, its turn from pointing down (roll, pitch, yaw), the gripper.
type Waypoint = ([f32; 3], [f32; 3], f32);

/// How the tool turns to stand the block: pitched by −90° (its axis along +x, away from the
/// arm's base; the block lying along x), or rolled by −90° (its axis along −y; the block lying
/// along y).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Tilt {
    Pitch,
    Roll,
}

impl Tilt {
    fn rpy(self) -> [f32; 3] {
        let q = -std::f32::consts::FRAC_PI_2;
        match self {
            Tilt::Pitch => [0.0, q, 0.0],
            Tilt::Roll => [q, 0.0, 0.0],
        }
    }

    /// The tool's axis so turned.
    fn axis(self) -> Vec3 {
        turn_of_rpy(self.rpy()) * -Vec3::Z
    }
}

/// Over the block, down onto its top, hold, up; turned (the block hanging from the tool's face
/// with its long side upright) over the square; down until the block's end is 6 mm above the
/// table, let go, back off along the tool's axis and up.
fn stand_up(tilt: Tilt) -> Vec<Waypoint> {
    let (turned, down) = (tilt.rpy(), [0.0; 3]);
    // The tool's centre is 0.05 behind its face; the block's centre 0.02 in front of it.
    let at = Vec3::new(0.5, -0.1, 0.056) - tilt.axis() * 0.07;
    let back = at - tilt.axis() * 0.08;
    vec![
        ([0.5, 0.1, 0.2], down, 0.0),
        ([0.5, 0.1, 0.09], down, 0.0),
        ([0.5, 0.1, 0.09], down, 1.0),
        ([0.5, 0.1, 0.25], down, 1.0),
        ([at.x, at.y, 0.25], turned, 1.0),
        (at.into(), turned, 1.0),
        (at.into(), turned, 0.0),
        (back.into(), turned, 0.0),
        ([back.x, back.y, 0.25], turned, 0.0),
    ]
}

/// Steers by its state (tool centre, `ee_quat`, holding) through waypoints, answering in `space`:
/// at most 3 cm and 0.2 rad a control step. Its turns are relative to the turn it last commanded
/// (as `ee_delta` is applied), so an arm that lags behind does not wind its goal up.
struct Tilting {
    interface: Interface,
    points: Vec<Waypoint>,
    phase: usize,
    /// The tool's turn it read from each state.
    turns: Vec<Rotation>,
    /// The turn it last commanded.
    commanded: Option<Rotation>,
}

impl Tilting {
    fn new(space: ActionSpace, points: Vec<Waypoint>) -> Self {
        Tilting {
            interface: Interface {
                cameras: vec![CameraRequest {
                    name: "wrist_image".into(),
                    source: CameraSource::Wrist,
                    width: 32,
                    height: 32,
                    depth: false,
                }],
                state: vec![StatePart::EePos, StatePart::EeQuat, StatePart::Holding],
                action: space,
                execute: None,
            },
            points,
            phase: 0,
            turns: Vec::new(),
            commanded: None,
        }
    }
}

impl Policy for Tilting {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let s = &obs.state;
        let p = Vec3::new(s[0], s[1], s[2]);
        let seen = turn_of_quaternion([s[3], s[4], s[5], s[6]]);
        self.turns.push(seen);
        let now = *self.commanded.get_or_insert(seen);
        let (to, rpy, grip) = self.points[self.phase.min(self.points.len() - 1)];
        let want = turn_of_rpy(rpy);
        let d = Vec3::from(to) - p;
        let mut by = want * now.inverse();
        if by.w < 0.0 {
            by = -by;
        }
        let angle = by.to_axis_angle().1;
        let lag = (seen * want.inverse()).to_axis_angle().1;
        let lag = lag.min(std::f32::consts::TAU - lag);
        if d.length() < 0.003 && angle < 0.01 && lag < 0.01 {
            self.phase += 1;
        }
        let step = d * (0.03 / d.length().max(1e-6)).min(1.0);
        let by = Rotation::IDENTITY.slerp(by, (0.2 / angle.max(1e-6)).min(1.0));
        self.commanded = Some((by * now).normalize());
        Ok(vec![match self.interface.action {
            ActionSpace::EeDelta => {
                let [r, pi, y] = rpy_of_turn(by);
                vec![step.x, step.y, step.z, r, pi, y, grip]
            }
            ActionSpace::EePose => {
                let at = p + step;
                let q = tool_quaternion(by * now);
                vec![at.x, at.y, at.z, q[0], q[1], q[2], q[3], grip]
            }
            _ => unreachable!(),
        }])
    }

    fn interface(&self) -> Interface {
        self.interface.clone()
    }
}

/// Keeps the cameras it is asked to draw.
#[derive(Default)]
struct Cameras(Vec<Camera>);

impl Observer for Cameras {
    fn observe(&mut self, _: SceneSnapshot, _: u64, c: &Camera) -> Result<Observation, String> {
        Err(format!("no depth asked for, yet {} was", c.name))
    }
    fn frame(&mut self, _: SceneSnapshot, _: u64, c: &Camera) -> Result<Vec<u8>, String> {
        self.0.push(c.clone());
        Ok(vec![90; (c.width * c.height * 3) as usize])
    }
}

fn run(
    spec: &TaskSpec,
    policy: &mut dyn Policy,
) -> (Result<assay_sim::Episode, SimError>, Cameras) {
    let mut cameras = Cameras::default();
    let options = SimOptions {
        observer: Some(&mut cameras),
        policy: Some(policy),
        video_frames: 40,
        ..Default::default()
    };
    (
        simulate_with(spec, 0, "remote:url=http://lab:1", options),
        cameras,
    )
}

/// The angle between two directions (rad).
fn angle(a: Vec3, b: Vec3) -> f32 {
    a.normalize().dot(b.normalize()).clamp(-1.0, 1.0).acos()
}

#[test]
fn a_policy_that_pitches_the_tool_stands_a_block_on_end_where_the_oracle_cannot() {
    // The Panda's joints cannot point its tool forward (see the next test): it rolls.
    for (arm, space, tilt) in [
        ("", ActionSpace::EeDelta, Tilt::Pitch),
        ("arm: {model: ur5}", ActionSpace::EeDelta, Tilt::Pitch),
        ("arm: {model: panda}", ActionSpace::EeDelta, Tilt::Roll),
        ("arm: {model: ur5}", ActionSpace::EePose, Tilt::Roll),
    ] {
        let spec = stand_task(arm, tilt == Tilt::Roll);
        let mut policy = Tilting::new(space, stand_up(tilt));
        let (ep, cameras) = run(&spec, &mut policy);
        let ep = ep.unwrap_or_else(|e| panic!("{arm} {space}: {e}"));
        println!(
            "{arm:>20} {space}: success {}, phase {}, {:?}",
            ep.outcome.success, policy.phase, ep.outcome.predicates[0].detail
        );
        assert!(
            ep.outcome.success,
            "{arm} {space}: {:?}, notes {:?}, phase {}",
            ep.outcome.predicates, ep.notes, policy.phase
        );
        assert!(policy.phase >= 7, "{arm} {space}: phase {}", policy.phase);
        // The block stands: its long axis upright.
        let stood = ep.video.last().unwrap().1.objects[0].rotation;
        let long = if tilt == Tilt::Roll { Vec3::Y } else { Vec3::X };
        let long = Rotation::from_xyzw(stood[0], stood[1], stood[2], stood[3]) * long;
        assert!(long.z.abs() > 0.99, "{arm} {space}: long axis {long:?}");
        // The state it read showed the turn: the tool's axis along +x or −y.
        let along = tilt.axis();
        let most = policy
            .turns
            .iter()
            .map(|t| angle(*t * -Vec3::Z, along))
            .fold(f32::MAX, f32::min);
        assert!(most < 0.02, "{arm} {space}: axis {most} rad from {along}");
        // The episode file records the roll or the pitch.
        let name = if tilt == Tilt::Roll {
            "ee_roll"
        } else {
            "ee_pitch"
        };
        let angles = column(&ep, name);
        let lowest = angles.iter().copied().fold(f32::MAX, f32::min);
        assert!(
            (lowest + std::f32::consts::FRAC_PI_2).abs() < 0.02,
            "{arm} {space}: {name} down to {lowest}"
        );
        // The drawn tool and the wrist camera turned with it: at the end the tool's box lies
        // along its axis and the wrist camera looks along it, tilted towards its heading.
        let last = &ep.video.last().unwrap().1;
        let r = last.tool_rotation.expect("a turned tool is drawn turned");
        let r = Rotation::from_xyzw(r[0], r[1], r[2], r[3]);
        assert!(angle(r * -Vec3::Z, along) < 0.02, "{arm} {space}");
        let wrist = cameras.0.last().unwrap();
        let (eye, target) = (
            Vec3::from(wrist.eye.map(|x| x as f32)),
            Vec3::from(wrist.target.map(|x| x as f32)),
        );
        let turn = turn_of_rpy(tilt.rpy());
        let (sin, cos) = WRIST_CAMERA_TILT.sin_cos();
        let forward = turn * Vec3::new(sin, 0.0, -cos);
        assert!(angle(target - eye, forward) < 0.02, "{arm} {space}");
        assert!(
            (angle(target - eye, along) - WRIST_CAMERA_TILT).abs() < 0.02,
            "{arm} {space}"
        );
        let up = Vec3::from(wrist.up.unwrap().map(|x| x as f32));
        let want_up = turn * Vec3::new(cos, 0.0, sin);
        assert!(angle(up, want_up) < 0.02, "{arm} {space}: up {up:?}");
    }
    // The oracle's tool points down: it carries the block flat into the square, on no seed
    // standing it up.
    let spec = stand_task("arm: {model: ur5}", false);
    let oracle: Vec<bool> = (0..4)
        .map(|seed| {
            assay_sim::simulate(&spec, seed, "oracle")
                .unwrap()
                .outcome
                .success
        })
        .collect();
    println!("oracle on seeds 0..4: {oracle:?}");
    assert!(oracle.iter().all(|s| !s), "{oracle:?}");
}

#[test]
fn a_turn_the_arm_cannot_reach_is_refused_and_noted_naming_the_policy_and_the_turn() {
    // Pointing forward (along +x, away from its base): beyond the Panda's joints' limits.
    let forward = [0.0, -std::f32::consts::FRAC_PI_2, 0.0];
    let there = vec![
        ([0.5, 0.0, 0.2], [0.0; 3], 0.0),
        ([0.5, 0.0, 0.2], forward, 0.0),
    ];
    let mut spec = stand_task("arm: {model: panda}", false);
    spec.physics.max_steps = 1200;
    let mut policy = Tilting::new(ActionSpace::EeDelta, there.clone());
    let (ep, _) = run(&spec, &mut policy);
    let ep = ep.unwrap();
    let refused: Vec<&String> = ep.notes.iter().filter(|n| n.contains("refused")).collect();
    println!("{refused:?}");
    assert!(!refused.is_empty(), "{:?}", ep.notes);
    assert!(
        refused[0].contains("remote:url=http://lab:1")
            && refused[0].contains("pitch -1.571")
            && refused[0].contains("the arm 'panda' cannot reach it"),
        "{}",
        refused[0]
    );
    // The episode went on, the tool as far round as the arm could take it, and never reached.
    assert_eq!(policy.phase, 1);
    let best = policy
        .turns
        .iter()
        .map(|t| angle(*t * -Vec3::Z, Vec3::X))
        .fold(f32::MAX, f32::min);
    assert!(best > 0.2 && best < 1.3, "{best}");
    // The free tool turns anywhere.
    let mut policy = Tilting::new(ActionSpace::EeDelta, there);
    let mut spec = stand_task("", false);
    spec.physics.max_steps = 1200;
    let ep = run(&spec, &mut policy).0.unwrap();
    assert!(policy.phase >= 2, "{}", policy.phase);
    assert!(!ep.notes.iter().any(|n| n.contains("refused")));
}
