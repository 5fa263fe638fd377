//! The action spaces and observation contracts of real policies, in the simulator: an
//! end-effector-delta policy moves and turns the free tool and the Panda's (inverse kinematics
//! with orientation) and carries a block turned into a yaw goal; absolute poses and joint targets
//! are followed; the wrist camera rides on the tool; a space the task cannot fill, or answers
//! of the wrong length, fail the episode naming the policy and the field.

use assay_model::policy::{
    ActionSpace, CameraRequest, CameraSource, EpisodeContext, Interface, Policy, PolicyError,
    PolicyObservation, StatePart,
};
use assay_sim::{Observer, SimError, SimOptions, simulate_with};
use assay_spec::scene::{Observation, SceneSnapshot};
use assay_spec::spec::{Camera, TaskSpec};

mod common;
use common::{carry_and_turn, turn_block_task as task};

/// A camera drawn: its name, eye, target, up and size.
type Drawn = (String, [f64; 3], [f64; 3], Option<[f64; 3]>, u32, u32);

/// Records what it was asked to draw.
#[derive(Default)]
struct Cameras {
    drawn: Vec<Drawn>,
    depths: u32,
}

impl Observer for Cameras {
    fn observe(&mut self, _: SceneSnapshot, _: u64, c: &Camera) -> Result<Observation, String> {
        self.depths += 1;
        Ok(Observation {
            camera: c.clone(),
            depth: vec![0.5; (c.width * c.height) as usize],
            segments: vec![0; (c.width * c.height) as usize],
        })
    }
    fn frame(&mut self, _: SceneSnapshot, _: u64, c: &Camera) -> Result<Vec<u8>, String> {
        self.drawn
            .push((c.name.clone(), c.eye, c.target, c.up, c.width, c.height));
        Ok(vec![90; (c.width * c.height * 3) as usize])
    }
}

fn camera(name: &str, source: CameraSource, side: u32, depth: bool) -> CameraRequest {
    CameraRequest {
        name: name.into(),
        source,
        width: side,
        height: side,
        depth,
    }
}

/// Steers by its state alone through waypoints (x, y, z, yaw, gripper), answering in `space`.
struct Waypoints {
    interface: Interface,
    points: Vec<([f32; 3], f32, f32)>,
    phase: usize,
    states: Vec<Vec<f32>>,
    images: Vec<Vec<(String, u32, u32, usize)>>,
    context: Option<EpisodeContext>,
}

impl Waypoints {
    fn new(space: ActionSpace, points: Vec<([f32; 3], f32, f32)>) -> Self {
        Waypoints {
            interface: Interface {
                cameras: vec![
                    camera("image", CameraSource::Scene, 48, false),
                    camera("wrist_image", CameraSource::Wrist, 48, true),
                ],
                state: vec![StatePart::EePos, StatePart::EeYaw, StatePart::Holding],
                action: space,
                execute: None,
            },
            points,
            phase: 0,
            states: Vec::new(),
            images: Vec::new(),
            context: None,
        }
    }
}

use assay_sim::tabletop::wrap_angle as wrap;

impl Policy for Waypoints {
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.context = Some(episode.clone());
        Ok(())
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        self.states.push(obs.state.clone());
        self.images.push(
            obs.images
                .iter()
                .map(|i| (i.name.clone(), i.width, i.height, i.depth.len()))
                .collect(),
        );
        let s = &obs.state;
        let (p, yaw) = ([s[0], s[1], s[2]], s[3]);
        let (to, to_yaw, grip) = self.points[self.phase.min(self.points.len() - 1)];
        let d = [to[0] - p[0], to[1] - p[1], to[2] - p[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let dyaw = wrap(to_yaw - yaw);
        if dist < 0.003 && dyaw.abs() < 0.01 {
            self.phase += 1;
        }
        // At most 3 cm and 0.2 rad per control step.
        let scale = (0.03 / dist.max(1e-6)).min(1.0);
        let step = [d[0] * scale, d[1] * scale, d[2] * scale];
        let turn = dyaw.clamp(-0.2, 0.2);
        Ok(vec![match self.interface.action {
            ActionSpace::EeDelta => vec![step[0], step[1], step[2], 0.0, 0.0, turn, grip],
            ActionSpace::EePose => {
                let [x, y, z] = [p[0] + step[0], p[1] + step[1], p[2] + step[2]];
                let q = assay_sim::learned::tool_quaternion(
                    rapier3d::prelude::Rotation::from_rotation_z(yaw + turn),
                );
                vec![x, y, z, q[0], q[1], q[2], q[3], grip]
            }
            _ => unreachable!(),
        }])
    }

    fn interface(&self) -> Interface {
        self.interface.clone()
    }
}

fn run(
    spec: &TaskSpec,
    policy: &mut dyn Policy,
    name: &str,
) -> (Result<assay_sim::Episode, SimError>, Cameras) {
    let mut cameras = Cameras::default();
    let options = SimOptions {
        observer: Some(&mut cameras),
        policy: Some(policy),
        ..Default::default()
    };
    let ep = simulate_with(spec, 0, name, options);
    (ep, cameras)
}

#[test]
fn an_ee_delta_policy_turns_the_block_it_carries_into_a_yaw_goal_free_and_on_the_panda() {
    for arm in ["", "arm: {model: panda}"] {
        let spec = task(arm);
        let mut policy = Waypoints::new(ActionSpace::EeDelta, carry_and_turn());
        let (ep, cameras) = run(&spec, &mut policy, "openpi:url=ws://h:1");
        let ep = ep.unwrap();
        assert!(
            ep.outcome.success,
            "{arm}: {:?}, notes {:?}, phase {}, last state {:?}",
            ep.outcome.predicates,
            ep.notes,
            policy.phase,
            policy.states.last()
        );
        assert!(policy.phase >= 7, "{arm}: phase {}", policy.phase);
        // It saw both cameras at its size, depth from the wrist one; the instruction and the arm.
        let seen = &policy.images[0];
        assert_eq!(seen[0], ("image".to_string(), 48, 48, 0));
        assert_eq!(seen[1], ("wrist_image".to_string(), 48, 48, 48 * 48));
        assert_eq!(cameras.depths as usize, policy.images.len());
        let context = policy.context.as_ref().unwrap();
        assert!(context.instruction.contains("turned by 45"));
        assert_eq!(context.arm.as_deref(), (!arm.is_empty()).then_some("panda"));
        // The wrist camera rides beside the tool, 1 cm above its face, looking down and forward,
        // its view turned with it (the image's top along the tool's heading).
        let wrist: Vec<_> = cameras
            .drawn
            .iter()
            .filter(|c| c.0.ends_with("-wrist"))
            .collect();
        assert_eq!(wrist.len(), policy.images.len());
        for ((_, eye, target, up, _, _), state) in wrist.iter().zip(&policy.states) {
            assert!((eye[2] - (f64::from(state[2]) - 0.04)).abs() < 1e-4);
            let up = up.expect("a wrist camera turns with the tool");
            let heading = up[1].atan2(up[0]) as f32;
            assert!(
                wrap(heading - state[3]).abs() < 1e-3,
                "{heading} vs {}",
                state[3]
            );
            assert!(target[2] < eye[2] - 0.9 && target[2] > eye[2] - 0.91);
        }
        // The yaw it reports turned to 45° while it carried the block, and the episode file
        // records it.
        let turned = policy.states.iter().map(|s| s[3]).fold(0.0f32, f32::max);
        assert!(
            (turned - std::f32::consts::FRAC_PI_4).abs() < 0.02,
            "{turned}"
        );
        let recorded = column(&ep.file, "ee_yaw").expect("an ee_yaw column");
        let last = *recorded.last().unwrap();
        assert!((last - std::f32::consts::FRAC_PI_4).abs() < 0.02, "{last}");
    }
    // The oracle never turns the tool: its files have no such column.
    let oracle = assay_sim::simulate(&task(""), 0, "oracle").unwrap();
    assert!(column(&oracle.file, "ee_yaw").is_none());
}

/// A float column of an episode file, if it has one.
fn column(file: &[u8], name: &str) -> Option<Vec<f32>> {
    let reader = arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(file), None).unwrap();
    let k = reader.schema().index_of(name).ok()?;
    Some(
        reader
            .flat_map(|b| {
                b.unwrap()
                    .column(k)
                    .as_any()
                    .downcast_ref::<arrow_array::Float32Array>()
                    .unwrap()
                    .values()
                    .to_vec()
            })
            .collect(),
    )
}

#[test]
fn an_ee_pose_policy_reaches_and_turns_to_absolute_poses() {
    let spec = task("arm: {model: panda}");
    let mut policy = Waypoints::new(ActionSpace::EePose, carry_and_turn());
    let (ep, _) = run(&spec, &mut policy, "remote:url=http://h:1");
    let ep = ep.unwrap();
    assert!(
        ep.outcome.success,
        "{:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
}

/// Answers joint targets: the arm's home plus `offset` on every joint, gripper open.
struct Joints {
    offset: f32,
    seen: Vec<Vec<f32>>,
}

impl Policy for Joints {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        self.seen.push(obs.state.clone());
        let first = &self.seen[0];
        let mut a: Vec<f32> = first.iter().map(|q| q + self.offset).collect();
        a.push(0.0);
        Ok(vec![a])
    }
    fn interface(&self) -> Interface {
        Interface {
            state: vec![StatePart::Joints],
            action: ActionSpace::JointPosition,
            ..Interface::default()
        }
    }
}

#[test]
fn a_joint_position_policy_drives_the_panda_and_a_task_without_an_arm_refuses_it() {
    let mut spec = task("arm: {model: panda}");
    spec.physics.max_steps = 480;
    let mut policy = Joints {
        offset: 0.1,
        seen: Vec::new(),
    };
    let (ep, _) = run(&spec, &mut policy, "remote:url=http://h:1");
    ep.unwrap();
    // Seven joints; 2 rad/s reaches +0.1 rad within a control step or two.
    let (first, last) = (&policy.seen[0], policy.seen.last().unwrap());
    assert_eq!(first.len(), 7);
    for (a, b) in first.iter().zip(last) {
        assert!(
            (b - a - 0.1).abs() < 1e-3 || b == a,
            "joint moved {a} → {b}"
        );
    }
    assert!(
        first
            .iter()
            .zip(last)
            .filter(|(a, b)| (*b - *a - 0.1).abs() < 1e-3)
            .count()
            >= 5
    );
    // On a task without an arm the space does not fit: the episode fails before any action,
    // naming the policy and the field.
    let mut policy = Joints {
        offset: 0.1,
        seen: Vec::new(),
    };
    let (ep, _) = run(&task(""), &mut policy, "openpi:url=ws://lab:8000");
    let e = ep.err().expect("a space the task cannot fill");
    assert!(matches!(e, SimError::Policy(_)), "{e:?}");
    let msg = e.to_string();
    assert!(
        msg.contains("openpi:url=ws://lab:8000") && msg.contains("action_space joint_position"),
        "{msg}"
    );
    assert!(policy.seen.is_empty());
}

/// Answers one fixed action.
struct Fixed(Vec<f32>, Interface);

impl Policy for Fixed {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }
    fn act_any(&mut self, _: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        Ok(vec![self.0.clone()])
    }
    fn interface(&self) -> Interface {
        self.1.clone()
    }
}

#[test]
fn answers_of_the_wrong_length_or_not_finite_and_unknown_cameras_fail_with_the_reason() {
    let ee = Interface {
        action: ActionSpace::EeDelta,
        ..Interface::default()
    };
    let spec = task("");
    let (ep, _) = run(
        &spec,
        &mut Fixed(vec![0.0; 4], ee.clone()),
        "openpi:url=ws://h:1",
    );
    let msg = ep.err().unwrap().to_string();
    assert!(
        msg.contains("has 4 floats; its action space ee_delta takes 7"),
        "{msg}"
    );
    let mut nan = vec![0.0; 7];
    nan[5] = f32::NAN;
    let (ep, _) = run(&spec, &mut Fixed(nan, ee.clone()), "openpi:url=ws://h:1");
    let msg = ep.err().unwrap().to_string();
    assert!(msg.contains("not finite"), "{msg}");
    let mut far = ee;
    far.cameras[0].source = CameraSource::Named("overhead_left".into());
    let (ep, _) = run(&spec, &mut Fixed(vec![0.0; 7], far), "openpi:url=ws://h:1");
    let msg = ep.err().unwrap().to_string();
    assert!(
        msg.contains("interface.cameras[0].source") && msg.contains("overhead_left"),
        "{msg}"
    );
    // An ee_pose whose quaternion has no direction.
    let pose = Interface {
        action: ActionSpace::EePose,
        ..Interface::default()
    };
    let (ep, _) = run(
        &spec,
        &mut Fixed(vec![0.5, 0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0], pose),
        "openpi:url=ws://h:1",
    );
    let msg = ep.err().unwrap().to_string();
    assert!(msg.contains("quaternion"), "{msg}");
}
