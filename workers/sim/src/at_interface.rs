//! A policy interface from the simulator's side: its cameras resolved against a task and placed
//! at a moment of the episode, its state vector, and the action in its space that takes the
//! robot from one recorded row to another. The driver of a learned policy ([`crate::learned`])
//! shows a policy what it asks for through these; a clip or an export at a policy's interface
//! ([`crate::recorded_states_at`]) reads the same from an episode's recorded rows, so that a
//! model trained on them sees what the policy will see and answers in its space.

use assay_model::policy::{ActionSpace, CameraSource, Interface, StatePart};
use assay_spec::spec::{Camera, EndEffector, TaskSpec};
use rapier3d::prelude::{Rotation, Vec3};

use crate::record::Recorder;
pub use crate::tabletop::{rpy_of_turn, tool_quaternion, turn_of_quaternion, turn_of_rpy};

/// Where the wrist camera is mounted, in the tool's frame (m; x the tool's heading, z up its
/// axis, the tool's face at z = −0.05): beside the tool, 2 cm out from its back and 1 cm above
/// its face, as a hand camera is, so that what the tool holds is seen from outside, in the
/// middle and upper part of its image, with the scene around it.
pub const WRIST_CAMERA_MOUNT: [f32; 3] = [-0.04, 0.0, -0.04];
/// How far the wrist camera looks forward (towards the tool's heading) from the tool's axis
/// (rad): 25°, so that the point on the axis 6 cm below the face is 5° from the image's centre.
pub const WRIST_CAMERA_TILT: f32 = 25.0 * std::f32::consts::PI / 180.0;

/// A policy camera, resolved against the task.
#[derive(Debug, Clone)]
pub struct PolicyCamera {
    /// The interface's name for it.
    pub name: String,
    /// Where it is, and its size (a wrist camera's eye and target are set by
    /// [`PolicyCamera::placed`]).
    pub camera: Camera,
    pub wrist: bool,
    pub depth: bool,
}

impl PolicyCamera {
    /// The camera with the tool at `tool` turned by `turn` (from pointing down; see
    /// [`tool_quaternion`]): a wrist camera rides on the tool ([`WRIST_CAMERA_MOUNT`]), looking
    /// along its axis tilted forward by [`WRIST_CAMERA_TILT`], the image's top towards the tool's
    /// heading; any other camera stays where the task put it.
    pub fn placed(&self, tool: [f32; 3], turn: Rotation) -> Camera {
        let mut camera = self.camera.clone();
        if self.wrist {
            let (sin, cos) = WRIST_CAMERA_TILT.sin_cos();
            let eye = Vec3::from(tool) + turn * Vec3::from(WRIST_CAMERA_MOUNT);
            let target = eye + turn * Vec3::new(sin, 0.0, -cos);
            let up = turn * Vec3::new(cos, 0.0, sin);
            camera.eye = eye.to_array().map(f64::from);
            camera.target = target.to_array().map(f64::from);
            camera.up = Some(up.to_array().map(f64::from));
        }
        camera
    }
}

/// Whether `spec` can fill `interface` (recording a clip or an export at it): the interface is
/// valid, the task has its cameras and the arm its action space needs. The error names the
/// task and the field.
pub fn check_task(interface: &Interface, spec: &TaskSpec) -> Result<(), String> {
    let refuse = |e: String| format!("interface does not fit task '{}': {e}", spec.id);
    interface.validate().map_err(refuse)?;
    interface.check_task(spec).map_err(refuse)?;
    let arm = spec.arm.as_ref().map(|a| a.model.as_str());
    interface
        .action
        .dims(arm)
        .map_err(|e| refuse(format!("action_space: {e}")))?;
    Ok(())
}

/// `interface`'s cameras on `spec`, those without a size at `frame` pixels square. The
/// interface must have passed `Interface::check_task` for `spec` (a named camera is one of the
/// task's or of Assay's standard views).
pub fn policy_cameras(interface: &Interface, spec: &TaskSpec, frame: u32) -> Vec<PolicyCamera> {
    let task_cameras = assay_spec::scene::task_cameras(&spec.cameras);
    let standard = assay_spec::scene::scene_views();
    interface
        .cameras
        .iter()
        .map(|c| {
            let (w, h) = if c.width == 0 {
                (frame, frame)
            } else {
                (c.width, c.height)
            };
            let (base, wrist) = match &c.source {
                CameraSource::Scene => (task_cameras[0].clone(), false),
                CameraSource::Wrist => (
                    Camera {
                        name: format!("{}-wrist", c.name),
                        eye: [0.0; 3],
                        target: [0.0; 3],
                        fovy_deg: 70.0,
                        width: w,
                        height: h,
                        up: None,
                    },
                    true,
                ),
                // A camera of the task, else one of Assay's standard views (a policy calibrated
                // for the top view finds it on every task).
                CameraSource::Named(n) => {
                    let found = task_cameras.iter().chain(&standard).find(|t| &t.name == n);
                    (found.expect("checked by check_task").clone(), false)
                }
            };
            PolicyCamera {
                name: c.name.clone(),
                camera: Camera {
                    width: w,
                    height: h,
                    ..base
                },
                wrist,
                depth: c.depth,
            }
        })
        .collect()
}

/// What the state parts of an interface are read from, at one moment.
pub struct ToolState {
    /// The tool's centre (m).
    pub position: [f32; 3],
    /// Its turn from pointing down (world frame).
    pub turn: Rotation,
    /// Whether it holds an object.
    pub holding: bool,
    /// A friction gripper's opening as a fraction of its widest, `None` without pads.
    pub opening: Option<f32>,
    /// The arm's joint positions (rad; empty without an arm).
    pub joints: Vec<f64>,
}

/// The state vector `parts` ask for, in their order.
pub fn state_vector(parts: &[StatePart], t: &ToolState) -> Vec<f32> {
    let holding = f32::from(u8::from(t.holding));
    let mut state = Vec::new();
    for part in parts {
        match part {
            StatePart::EePos => state.extend(t.position),
            StatePart::EeQuat => state.extend(tool_quaternion(t.turn)),
            StatePart::EeYaw => state.push(crate::tabletop::yaw_of(&t.turn)),
            // Open 1, closed 0; a tool without pads is open unless it holds something.
            StatePart::Gripper => state.push(match t.opening {
                Some(o) => o.clamp(0.0, 1.0),
                None => 1.0 - holding,
            }),
            StatePart::Joints => state.extend(t.joints.iter().map(|&q| q as f32)),
            StatePart::Holding => state.push(holding),
        }
    }
    state
}

/// The widest opening of `spec`'s gripper (m), `None` for a suction tool.
fn max_opening(spec: &TaskSpec) -> Option<f32> {
    match spec.end_effector {
        EndEffector::Suction => None,
        EndEffector::ParallelGripper { max_opening, .. } => Some(max_opening as f32),
    }
}

/// The tool's state recorded at `row` of `rec` (an episode of `spec`).
pub(crate) fn recorded_tool(rec: &Recorder, spec: &TaskSpec, row: usize) -> ToolState {
    ToolState {
        position: rec.ee_at(row),
        turn: rec.turn_at(row),
        holding: rec.grasped_at(row) >= 0,
        opening: rec
            .opening_at(row)
            .zip(max_opening(spec))
            .map(|(o, max)| o / max),
        joints: rec.arm_at(row),
    }
}

/// The action in `space` that takes the recorded robot from `row` to `next`, `interval` seconds
/// later, as a policy of that space would command it ([`crate::learned`] runs it): the
/// commanded tool centre's velocity (`tool_velocity`) or change (`ee_delta`, its turn as roll,
/// pitch and yaw of the rotation from the one to the other, in the world frame: see
/// [`turn_of_rpy`]), the commanded centre and the tool's orientation at `next` (`ee_pose`), or the
/// arm's joints at `next` (`joint_position`); last, the hold command (1 while it holds at
/// `next`).
pub(crate) fn recorded_action(
    space: ActionSpace,
    rec: &Recorder,
    row: usize,
    next: usize,
    interval: f64,
) -> Vec<f32> {
    let (from, to) = (rec.cmd_at(row), rec.cmd_at(next));
    let hold = f32::from(u8::from(rec.grasped_at(next) >= 0));
    let delta = |i: usize| f64::from(to[i]) - f64::from(from[i]);
    let mut a = match space {
        ActionSpace::ToolVelocity => (0..3).map(|i| (delta(i) / interval) as f32).collect(),
        ActionSpace::EeDelta => {
            let [roll, pitch, yaw] = rpy_of_turn(rec.turn_at(next) * rec.turn_at(row).inverse());
            vec![
                delta(0) as f32,
                delta(1) as f32,
                delta(2) as f32,
                roll,
                pitch,
                yaw,
            ]
        }
        ActionSpace::EePose => {
            let mut a = to.to_vec();
            a.extend(tool_quaternion(rec.turn_at(next)));
            a
        }
        ActionSpace::JointPosition => rec.arm_at(next).iter().map(|&q| q as f32).collect(),
    };
    a.push(hold);
    a
}
