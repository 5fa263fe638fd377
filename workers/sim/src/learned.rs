//! The driver of a learned or served policy ([`assay_model::policy::Policy`]): every
//! [`CONTROL_STRIDE_STEPS`] physics steps it shows the policy what its [`Interface`] asks for
//! (named cameras, a state vector) and runs the actions it answers, one per control step, in the
//! policy's action space: the tool's velocity (the original space), an end-effector delta or
//! pose (the tool moves there and turns: yaw, roll and pitch, an arm's wrist following through
//! inverse kinematics), or the arm's joint targets. A change of the
//! gripper command grasps the object under the tool (by the same rule as the oracle's grasps)
//! or releases the one held.

use std::collections::VecDeque;

use assay_model::policy::{
    ActionSpace, CONTROL_STRIDE_STEPS, Interface, NamedImage, Policy, PolicyError,
    PolicyObservation,
};
use assay_spec::spec::TaskSpec;
use rapier3d::prelude::*;

use crate::at_interface::{
    PolicyCamera, ToolState, policy_cameras, rpy_of_turn, state_vector, turn_of_quaternion,
    turn_of_rpy,
};
use crate::controller::{Controller, Event, Note};
use crate::scene::{GRIPPER_HALF_EXTENTS, SimScene};
use crate::{Observer, SimError};

/// The most actions of one chunk that are run (a longer answer is cut here and noted).
pub const MAX_CHUNK: usize = 256;
/// Commanded tool speeds are clipped to this (m/s), as a real arm's controller would.
pub const MAX_SPEED: f32 = 2.0;
/// Commanded turns of the tool are clipped to this (rad/s).
pub const MAX_TURN_RATE: f32 = 2.0 * std::f32::consts::PI;
/// An arm's tool further than this (rad) from its commanded turn at a control step has not
/// followed it …
pub const TURN_MISS: f32 = 0.1;
/// … and after this many control steps in a row the turn is refused: the arm cannot reach the
/// orientation (its joints' limits, or the pose out of its reach). The episode notes it and
/// goes on from the orientation the arm did reach, as a real arm's controller would.
pub const TURN_MISS_STEPS: u32 = 15;
/// A hold is refused while the tool tilts further than this (rad) from pointing down: Assay's
/// grasps are made from above.
pub const GRASP_TILT: f32 = 0.1;
pub use crate::at_interface::{WRIST_CAMERA_MOUNT, WRIST_CAMERA_TILT, tool_quaternion};

pub struct Learned<'p> {
    policy: &'p mut dyn Policy,
    name: String,
    interface: Interface,
    cameras: Vec<PolicyCamera>,
    arm: Option<String>,
    action_dims: usize,
    chunk: VecDeque<Vec<f32>>,
    velocity: Vec3,
    /// The tool's commanded turn at the start and at the end of the current control step
    /// (`ee_delta` and `ee_pose`): the goal moves from the one to the other over its physics
    /// steps.
    turn_from: Rotation,
    turn_to: Rotation,
    /// Control steps in a row at which an arm's tool missed its commanded turn.
    missed_turns: u32,
    /// Turns refused so far (the first is noted in full).
    refused_turns: u32,
    /// Control steps taken.
    pub control: u32,
    /// The physics step of the first action.
    start: u64,
    /// Observations shown to the policy.
    pub frames: u64,
    /// Calls to the policy.
    pub calls: u64,
}

fn policy_error(step: u64, e: PolicyError) -> SimError {
    let msg = format!("at physics step {step}: {e}");
    if e.retryable() {
        SimError::Internal(msg)
    } else {
        SimError::Policy(msg)
    }
}

impl<'p> Learned<'p> {
    /// A driver for `policy` (named `name` in errors) on `spec`, its cameras without a size at
    /// `frame` pixels. An interface the task cannot fill (a camera it does not have, joints
    /// without an arm) is an error naming the policy and the field.
    pub fn new(
        policy: &'p mut dyn Policy,
        name: &str,
        spec: &TaskSpec,
        frame: u32,
    ) -> Result<Self, SimError> {
        let interface = policy.interface();
        let arm = spec.arm.as_ref().map(|a| a.model.clone());
        let refuse = |e: String| {
            SimError::Policy(format!(
                "policy '{name}' does not fit task '{}': {e}",
                spec.id
            ))
        };
        interface.validate().map_err(refuse)?;
        interface.check_task(spec).map_err(refuse)?;
        let action_dims = interface
            .action
            .dims(arm.as_deref())
            .map_err(|e| refuse(format!("action_space: {e}")))?;
        let cameras = policy_cameras(&interface, spec, frame);
        Ok(Learned {
            policy,
            name: name.to_owned(),
            interface,
            cameras,
            arm,
            action_dims,
            chunk: VecDeque::new(),
            velocity: Vec3::ZERO,
            turn_from: Rotation::IDENTITY,
            turn_to: Rotation::IDENTITY,
            missed_turns: 0,
            refused_turns: 0,
            control: 0,
            start: 0,
            frames: 0,
            calls: 0,
        })
    }

    /// Starts an episode whose first action is taken at physics step `start`.
    pub fn reset(
        &mut self,
        scene: &mut SimScene,
        spec: &TaskSpec,
        seed: u64,
        start: u64,
    ) -> Result<(), SimError> {
        self.start = start;
        match self.interface.action {
            ActionSpace::EeDelta | ActionSpace::EePose => {
                let now = scene.tool_turn();
                (self.turn_from, self.turn_to) = (now, now);
                scene.turn_goal = Some(now);
            }
            ActionSpace::JointPosition => {
                scene.joint_goal = scene.arm.as_ref().map(|a| a.joints().to_vec())
            }
            ActionSpace::ToolVelocity => {}
        }
        self.policy
            .reset(&assay_model::policy::EpisodeContext {
                task_id: spec.id.clone(),
                seed,
                instruction: spec.description.clone(),
                arm: self.arm.clone(),
            })
            .map_err(|e| policy_error(0, e))
    }

    /// The command of one physics step. At a control step it first takes the next action, asking
    /// the policy (with fresh observations from `observer`) when its last chunk is used up, and
    /// returns the grasp or release that a change of the gripper command asks for.
    pub fn step(
        &mut self,
        scene: &mut SimScene,
        spec: &TaskSpec,
        ctl: &mut Controller,
        observer: &mut dyn Observer,
        step: u64,
        dt: f32,
    ) -> Result<(Vec3, Event), SimError> {
        let mut ev = Event::None;
        let into_step = (step - self.start) % CONTROL_STRIDE_STEPS;
        if into_step == 0 {
            self.check_turn(scene, ctl, step);
            if self.chunk.is_empty() {
                self.ask(scene, spec, ctl, observer, step)?;
            }
            let a = self.chunk.pop_front().expect("a non-empty chunk");
            let hold = self.take(&a, scene, ctl, step, dt)?;
            let tilt = (scene.tool_turn() * -Vec3::Z).angle_between(-Vec3::Z);
            ev = match (hold, ctl.held.is_some()) {
                (true, false) if tilt > GRASP_TILT => {
                    ctl.notes.push(Note {
                        step,
                        text: format!(
                            "hold commanded with the tool tilted {tilt:.3} rad from pointing down: \
                             Assay grasps from above (within {GRASP_TILT} rad)"
                        ),
                    });
                    Event::None
                }
                (true, false) => match grasp_candidate(scene) {
                    Some(i) => Event::Grasp(i),
                    None => {
                        ctl.notes.push(Note {
                            step,
                            text: "hold commanded with no object under the tool".into(),
                        });
                        Event::None
                    }
                },
                (false, true) => Event::Release,
                _ => Event::None,
            };
            self.control += 1;
        }
        if scene.joint_goal.is_some() {
            // The arm follows its joint targets; the command is where the tool is.
            ctl.command = scene.gripper_position();
            return Ok((ctl.command, ev));
        }
        if let Some(goal) = scene.turn_goal.as_mut() {
            let t = (into_step + 1) as f32 / CONTROL_STRIDE_STEPS as f32;
            *goal = self.turn_from.slerp(self.turn_to, t).normalize();
        }
        let mut cmd = ctl.command + self.velocity * dt;
        // The tool stays above the surface and over the table's reach.
        cmd.z = cmd.z.clamp(GRIPPER_HALF_EXTENTS[2], 1.5);
        cmd.x = cmd.x.clamp(-1.5, 1.5);
        cmd.y = cmd.y.clamp(-1.5, 1.5);
        ctl.command = cmd;
        Ok((cmd, ev))
    }

    /// Starts running action `a` for the next control step; returns its gripper command.
    fn take(
        &mut self,
        a: &[f32],
        scene: &mut SimScene,
        ctl: &mut Controller,
        step: u64,
        dt: f32,
    ) -> Result<bool, SimError> {
        let period = CONTROL_STRIDE_STEPS as f32 * dt;
        let cap = |v: Vec3| {
            if v.length() > MAX_SPEED {
                v * (MAX_SPEED / v.length())
            } else {
                v
            }
        };
        // The turn from where the last step's goal ended, at most MAX_TURN_RATE for the period.
        let from = self.turn_to;
        let mut turn_by = |by: Rotation| {
            // The short way round.
            let by = if by.w < 0.0 { -by } else { by };
            let (_, angle) = by.to_axis_angle();
            let most = MAX_TURN_RATE * period;
            let by = if angle > most {
                Rotation::IDENTITY.slerp(by, most / angle)
            } else {
                by
            };
            (self.turn_from, self.turn_to) = (from, (by * from).normalize());
        };
        match self.interface.action {
            ActionSpace::ToolVelocity => {
                self.velocity = cap(Vec3::new(a[0], a[1], a[2]));
            }
            ActionSpace::EeDelta => {
                self.velocity = cap(Vec3::new(a[0], a[1], a[2]) / period);
                turn_by(turn_of_rpy([a[3], a[4], a[5]]));
            }
            ActionSpace::EePose => {
                let q = Vec4::new(a[3], a[4], a[5], a[6]);
                if q.length() < 1e-6 {
                    return Err(policy_error(
                        step,
                        PolicyError::BadAnswer(format!(
                            "action of policy '{}': ee_pose quaternion {:?} has no direction",
                            self.name,
                            &a[3..7]
                        )),
                    ));
                }
                let q = q.normalize();
                let target = turn_of_quaternion([q.x, q.y, q.z, q.w]);
                self.velocity = cap((Vec3::new(a[0], a[1], a[2]) - ctl.command) / period);
                turn_by((target * from.inverse()).normalize());
            }
            ActionSpace::JointPosition => {
                let n = self.action_dims - 1;
                scene.joint_goal = Some(a[..n].iter().map(|&x| f64::from(x)).collect());
            }
        }
        Ok(a[self.action_dims - 1] >= 0.5)
    }

    /// At a control step: whether an arm's tool has followed the turn the policy commanded (see
    /// [`TURN_MISS`]). A turn it misses for [`TURN_MISS_STEPS`] control steps is refused: the
    /// goal comes back to the orientation the arm reached (so that the policy's next deltas start
    /// from there, not from a goal wound up beyond reach), and the episode notes it — the first
    /// time naming the policy, the turn, the arm and how far it got; then how often.
    fn check_turn(&mut self, scene: &mut SimScene, ctl: &mut Controller, step: u64) {
        let (Some(arm), Some(_)) = (&scene.arm, scene.turn_goal) else {
            return;
        };
        let reached = scene.tool_turn();
        let off = (reached * self.turn_to.inverse()).to_axis_angle().1;
        let off = off.min(std::f32::consts::TAU - off);
        self.missed_turns = if off > TURN_MISS {
            self.missed_turns + 1
        } else {
            0
        };
        if self.missed_turns < TURN_MISS_STEPS {
            return;
        }
        self.refused_turns += 1;
        let [roll, pitch, yaw] = rpy_of_turn(self.turn_to);
        let text = if self.refused_turns == 1 {
            format!(
                "policy '{}' commanded the tool turned to roll {roll:.3}, pitch {pitch:.3}, yaw \
                 {yaw:.3} rad; the arm '{}' cannot reach it (its tool stayed {off:.3} rad away for \
                 {TURN_MISS_STEPS} control steps): refused, the tool goes on from where it is",
                self.name, arm.model
            )
        } else {
            format!(
                "turn refused again ({} so far): roll {roll:.3}, pitch {pitch:.3}, yaw {yaw:.3} rad",
                self.refused_turns
            )
        };
        ctl.notes.push(Note { step, text });
        (self.turn_from, self.turn_to) = (reached, reached);
        scene.turn_goal = Some(reached);
        self.missed_turns = 0;
    }

    /// The state vector the interface asks for.
    fn state(&self, scene: &SimScene, ctl: &Controller) -> Vec<f32> {
        let tool = ToolState {
            position: scene.gripper_position().into(),
            turn: scene.tool_turn(),
            holding: ctl.held.is_some(),
            opening: scene
                .fingers
                .as_ref()
                .map(|f| f.opening(&scene.world) / f.max_opening),
            joints: scene
                .arm
                .as_ref()
                .map_or_else(Vec::new, |a| a.joints().to_vec()),
        };
        state_vector(&self.interface.state, &tool)
    }

    fn ask(
        &mut self,
        scene: &SimScene,
        spec: &TaskSpec,
        ctl: &mut Controller,
        observer: &mut dyn Observer,
        step: u64,
    ) -> Result<(), SimError> {
        let snapshot = crate::record::live_snapshot(scene, spec);
        let tool = scene.gripper_position();
        let turn = scene.tool_turn();
        let mut images = Vec::with_capacity(self.cameras.len());
        for c in &self.cameras {
            let camera = c.placed(tool.into(), turn);
            let camera_error = |e: String| {
                SimError::internal(format!("policy camera '{}' at step {step}: {e}", c.name))
            };
            let rgb = observer
                .frame(snapshot.clone(), step, &camera)
                .map_err(camera_error)?;
            let depth = if c.depth {
                observer
                    .observe(snapshot.clone(), step, &camera)
                    .map_err(camera_error)?
                    .depth
            } else {
                Vec::new()
            };
            images.push(NamedImage {
                name: c.name.clone(),
                width: camera.width,
                height: camera.height,
                rgb,
                depth,
            });
        }
        self.frames += 1;
        let first = &images[0];
        let obs = PolicyObservation {
            step: self.control,
            width: first.width,
            height: first.height,
            rgb: first.rgb.clone(),
            proprio: [
                tool.x,
                tool.y,
                tool.z,
                f32::from(u8::from(ctl.held.is_some())),
            ],
            state: self.state(scene, ctl),
            images,
        };
        self.calls += 1;
        let mut chunk = self
            .policy
            .act_any(&obs)
            .map_err(|e| policy_error(step, e))?;
        let bad = |msg: String| policy_error(step, PolicyError::BadAnswer(msg));
        if chunk.is_empty() {
            return Err(bad(format!(
                "policy '{}' answered an empty chunk of actions",
                self.name
            )));
        }
        if let Some(k) = chunk.iter().position(|a| a.len() != self.action_dims) {
            return Err(bad(format!(
                "policy '{}': action {k} of the chunk has {} floats; its action space {} takes {} \
                 on this task",
                self.name,
                chunk[k].len(),
                self.interface.action,
                self.action_dims
            )));
        }
        if let Some(k) = chunk.iter().position(|a| a.iter().any(|x| !x.is_finite())) {
            return Err(bad(format!(
                "policy '{}': action {k} of the chunk is not finite: {:?}",
                self.name, chunk[k]
            )));
        }
        let run = self
            .interface
            .execute
            .map_or(MAX_CHUNK, |h| (h as usize).min(MAX_CHUNK));
        if chunk.len() > MAX_CHUNK {
            ctl.notes.push(Note {
                step,
                text: format!(
                    "the policy answered {} actions; the first {MAX_CHUNK} were run",
                    chunk.len()
                ),
            });
        }
        chunk.truncate(run);
        self.chunk = chunk.into();
        Ok(())
    }
}

/// The object a hold command grasps: among the movable objects whose footprint is under the
/// tool, the one with the highest top (the one the tool's face is on); else the movable object
/// nearest the tool horizontally (whose grasp then fails with the reason noted).
pub fn grasp_candidate(scene: &SimScene) -> Option<usize> {
    let tool = scene.gripper_position();
    let mut under: Option<(usize, f32)> = None;
    let mut nearest: Option<(usize, f32)> = None;
    for (i, o) in scene.objects.iter().enumerate() {
        if o.fixed {
            continue;
        }
        let p = scene.pose(o).translation;
        let horizontal = Vec3::new(p.x - tool.x, p.y - tool.y, 0.0).length();
        if horizontal <= o.half.x.max(o.half.y) {
            let top = p.z + o.half.z;
            if under.is_none_or(|(_, t)| top > t) {
                under = Some((i, top));
            }
        }
        if nearest.is_none_or(|(_, d)| horizontal < d) {
            nearest = Some((i, horizontal));
        }
    }
    under.or(nearest).map(|(i, _)| i)
}
