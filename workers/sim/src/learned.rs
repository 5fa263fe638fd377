//! The driver of a learned or served policy ([`assay_model::policy::Policy`]): every
//! [`CONTROL_STRIDE_STEPS`] physics steps it shows the policy the task camera's RGB frame and the
//! tool's proprioception, and runs the actions it answers one per control step — the tool moves
//! at the commanded velocity, and a change of the hold command grasps the object under the tool
//! (by the same rule as the oracle's grasps) or releases the one held.

use std::collections::VecDeque;

use assay_model::policy::{Action, CONTROL_STRIDE_STEPS, Policy, PolicyError, PolicyObservation};
use assay_spec::spec::{Camera, TaskSpec};
use rapier3d::prelude::*;

use crate::controller::{Controller, Event, Note};
use crate::scene::{GRIPPER_HALF_EXTENTS, SimScene};
use crate::{Observer, SimError};

/// The most actions of one chunk that are run (a longer answer is cut here and noted).
pub const MAX_CHUNK: usize = 256;
/// Commanded tool speeds are clipped to this (m/s), as a real arm's controller would.
pub const MAX_SPEED: f32 = 2.0;

pub struct Learned<'p> {
    policy: &'p mut dyn Policy,
    camera: Camera,
    chunk: VecDeque<Action>,
    velocity: Vec3,
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
    /// A driver for `policy`, showing it frames of `camera` (already at the policy's frame size).
    pub fn new(policy: &'p mut dyn Policy, camera: Camera) -> Self {
        Learned {
            policy,
            camera,
            chunk: VecDeque::new(),
            velocity: Vec3::ZERO,
            control: 0,
            start: 0,
            frames: 0,
            calls: 0,
        }
    }

    /// Starts an episode whose first action is taken at physics step `start`.
    pub fn reset(&mut self, spec: &TaskSpec, seed: u64, start: u64) -> Result<(), SimError> {
        self.start = start;
        self.policy
            .reset(&assay_model::policy::EpisodeContext {
                task_id: spec.id.clone(),
                seed,
                instruction: spec.description.clone(),
            })
            .map_err(|e| policy_error(0, e))
    }

    /// The command of one physics step. At a control step it first takes the next action, asking
    /// the policy (with a fresh frame from `observer`) when its last chunk is used up, and
    /// returns the grasp or release that a change of the hold command asks for.
    pub fn step(
        &mut self,
        scene: &SimScene,
        spec: &TaskSpec,
        ctl: &mut Controller,
        observer: &mut dyn Observer,
        step: u64,
        dt: f32,
    ) -> Result<(Vec3, Event), SimError> {
        let mut ev = Event::None;
        if (step - self.start).is_multiple_of(CONTROL_STRIDE_STEPS) {
            if self.chunk.is_empty() {
                self.ask(scene, spec, ctl, observer, step)?;
            }
            let a = self.chunk.pop_front().expect("a non-empty chunk");
            let v = Vec3::new(a[0], a[1], a[2]);
            self.velocity = if v.length() > MAX_SPEED {
                v * (MAX_SPEED / v.length())
            } else {
                v
            };
            let hold = a[3] >= 0.5;
            ev = match (hold, ctl.held.is_some()) {
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
        let mut cmd = ctl.command + self.velocity * dt;
        // The tool stays above the surface and over the table's reach.
        cmd.z = cmd.z.clamp(GRIPPER_HALF_EXTENTS[2], 1.5);
        cmd.x = cmd.x.clamp(-1.5, 1.5);
        cmd.y = cmd.y.clamp(-1.5, 1.5);
        ctl.command = cmd;
        Ok((cmd, ev))
    }

    fn ask(
        &mut self,
        scene: &SimScene,
        spec: &TaskSpec,
        ctl: &mut Controller,
        observer: &mut dyn Observer,
        step: u64,
    ) -> Result<(), SimError> {
        let rgb = observer
            .frame(
                crate::record::live_snapshot(scene, spec),
                step,
                &self.camera,
            )
            .map_err(|e| SimError::internal(format!("policy camera at step {step}: {e}")))?;
        self.frames += 1;
        let tool = scene.gripper_position();
        let obs = PolicyObservation {
            step: self.control,
            width: self.camera.width,
            height: self.camera.height,
            rgb,
            proprio: [
                tool.x,
                tool.y,
                tool.z,
                f32::from(u8::from(ctl.held.is_some())),
            ],
        };
        self.calls += 1;
        let mut chunk = self.policy.act(&obs).map_err(|e| policy_error(step, e))?;
        if chunk.is_empty() {
            return Err(policy_error(
                step,
                PolicyError::BadAnswer("an empty chunk of actions".into()),
            ));
        }
        if let Some(k) = chunk.iter().position(|a| a.iter().any(|x| !x.is_finite())) {
            return Err(policy_error(
                step,
                PolicyError::BadAnswer(format!(
                    "action {k} of the chunk is not finite: {:?}",
                    chunk[k]
                )),
            ));
        }
        if chunk.len() > MAX_CHUNK {
            ctl.notes.push(Note {
                step,
                text: format!(
                    "the policy answered {} actions; the first {MAX_CHUNK} were run",
                    chunk.len()
                ),
            });
            chunk.truncate(MAX_CHUNK);
        }
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
