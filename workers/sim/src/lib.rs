//! `assay-sim`: the sim role. Builds a rapier3d scene from a task spec and a seed, runs a policy
//! in the loop (the oracle plan through a primitive controller), evaluates the goal predicates
//! on the final state, and records the episode as an Arrow IPC file in the artifact store.
//!
//! Owns physics. Never does networking: the worker binary feeds it assignments. Runs on the
//! caller's thread (a shard thread), never on an async executor.

pub mod arm;
pub mod at_interface;
pub mod controller;
pub mod learned;
pub mod perception;
mod placing;
pub mod predicates;
pub mod record;
pub mod reference;
pub mod scene;
pub mod tabletop;

use std::collections::{BTreeMap, HashMap};

use assay_model::clip::CLIP_STRIDE_STEPS;
use assay_model::episode::ClipCamera;
use assay_model::episode::{EpisodeOutcome, LabelSource};
use assay_model::policy::{Interface, OBSERVE_EVERY_STEPS, Policy, PolicySpec, Sense};
use assay_spec::scene::{Observation, SceneSnapshot};
use assay_spec::spec::{Camera, TaskSpec};

use crate::controller::Controller;
use crate::perception::Tracker;
use crate::record::Recorder;

/// The rapier3d release this crate is built against (pinned in Cargo.lock).
pub const RAPIER_VERSION: &str = "0.36.1";

/// Record one row every this many physics steps (60 Hz at the default dt of 1/240 s).
pub const RECORD_STRIDE: u64 = 4;

#[derive(Debug, Clone, thiserror::Error)]
pub enum SimError {
    /// The spec cannot be simulated as written (names the field).
    #[error("{path}: {reason}")]
    Spec { path: String, reason: String },
    #[error("{0}")]
    Policy(String),
    #[error("{0}")]
    Internal(String),
}

impl SimError {
    pub fn spec(path: impl Into<String>, reason: impl Into<String>) -> Self {
        SimError::Spec {
            path: path.into(),
            reason: reason.into(),
        }
    }
    pub fn internal(msg: impl Into<String>) -> Self {
        SimError::Internal(msg.into())
    }
    /// Whether running the shard again could give a different answer.
    pub fn retryable(&self) -> bool {
        matches!(self, SimError::Internal(_))
    }
}

/// The versions recorded with every episode.
pub fn versions() -> BTreeMap<String, String> {
    BTreeMap::from([
        ("assay-sim".to_owned(), env!("CARGO_PKG_VERSION").to_owned()),
        ("rapier3d".to_owned(), RAPIER_VERSION.to_owned()),
        (
            "episode-format".to_owned(),
            record::EPISODE_FORMAT_VERSION.to_owned(),
        ),
    ])
}

/// What one episode produced, before it is stored.
pub struct Episode {
    pub outcome: EpisodeOutcome,
    pub file: Vec<u8>,
    pub notes: Vec<String>,
    /// The scene after the initial settle, before the policy acts (for scene views).
    pub initial: SceneSnapshot,
    /// The physics step of `initial`.
    pub initial_step: u64,
    /// `KEYFRAMES` states evenly spaced from the first policy step to the end, with their steps.
    pub keyframes: Vec<(u64, SceneSnapshot)>,
    /// How many of the task's goal predicates held at each keyframe (the ground truth an offline
    /// judge reads; the last keyframe is the final state, so it matches `outcome.predicates`).
    pub keyframe_goals: Vec<u32>,
    /// Per goal (in the spec's order), when it last held with nothing in the tool and when it
    /// then stopped holding: a goal that fails at the end but held before was undone (the plan
    /// knocked off what it had placed).
    pub goals_held: Vec<GoalHeld>,
    /// States evenly spaced over the same span for an episode video (empty unless asked for).
    pub video: Vec<(u64, SceneSnapshot)>,
    /// Camera frames the policy looked at (0 for a policy that reads the sim's state).
    pub observations: u64,
    /// The states of a dynamics clip (`None` unless [`SimOptions::clip`] asked for them).
    pub clip: Option<ClipStates>,
}

/// What a dynamics clip is drawn from (`assay_model::clip::Clip` less its pixels): the recorded
/// state every [`CLIP_STRIDE_STEPS`] physics steps from the first policy step to the end of the
/// episode (the final settle included; a last stretch shorter than the stride has no frame).
///
/// At the original interface (`interface` `None`) the state is the tool position and holding
/// and the action the tool velocity; at a policy's interface they are that interface's state
/// parts and action space ([`at_interface`]), and `cameras` are its cameras at every frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ClipStates {
    /// Seconds between frames: [`CLIP_STRIDE_STEPS`] · dt.
    pub interval_s: f32,
    /// Physics step of each frame.
    pub steps: Vec<u64>,
    /// The scene at each frame, tool included.
    pub scenes: Vec<SceneSnapshot>,
    /// Per frame, the state vector. At the original interface,
    /// [`PROPRIO_DIMS`](assay_model::clip::PROPRIO_DIMS) values: the recorded tool position x,
    /// y, z (`ee`) and 1 while it holds an object (`grasped >= 0`), else 0.
    pub proprio: Vec<f32>,
    /// Per frame, the action to the next frame; all zeros for the last frame. At the original
    /// interface, [`ACTION_DIMS`](assay_model::clip::ACTION_DIMS) values: the tool's mean
    /// commanded velocity until the next frame (m/s: the change of the recorded `ee_cmd` target
    /// over the interval) and the hold command (the next frame's holding).
    pub actions: Vec<f32>,
    /// The policy interface of `proprio`, `actions` and `cameras`; `None`: the original one.
    pub interface: Option<Interface>,
    /// The interface's cameras in its order, each placed at every frame (empty for the original
    /// interface, which the render role draws from the task's camera).
    pub cameras: Vec<ClipCamera>,
}

impl ClipStates {
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }
}

/// What [`simulate_with`] does besides simulating: what else it keeps, and who draws the frames
/// of a policy that sees. `SimOptions::default()` is [`simulate`].
#[derive(Default)]
pub struct SimOptions<'a> {
    /// Keep this many states evenly spaced over the rollout for an episode video
    /// ([`VIDEO_FRAMES`] is the default count; 0: none).
    pub video_frames: usize,
    /// Keep the states of a dynamics clip ([`Episode::clip`]).
    pub clip: bool,
    /// The policy interface the clip is recorded at, its cameras sized (`None`: the original
    /// one). An interface the task cannot fill refuses the episode before it runs.
    pub clip_interface: Option<Interface>,
    /// Renders the frames of a policy that sees (`oracle:sense=camera`: every
    /// [`OBSERVE_EVERY_STEPS`] physics steps while it acts, and once before); such a policy
    /// fails without one.
    pub observer: Option<&'a mut dyn Observer>,
    /// The policy object of a policy that is not the built-in oracle (TorchScript, remote,
    /// diffusion): it acts every [`assay_model::policy::CONTROL_STRIDE_STEPS`] physics steps on
    /// RGB frames that `observer` draws.
    pub policy: Option<&'a mut dyn Policy>,
    /// Side of the square RGB frames a policy object sees (0: [`DEFAULT_FRAME_SIZE`]).
    pub frame_size: u32,
}

/// Side of a learned policy's frames unless the policy asks for another: the dynamics clips'.
pub const DEFAULT_FRAME_SIZE: u32 = 64;

/// Renders what a seeing policy's camera sees, while the episode runs: the render role on the
/// worker, or a renderer in the same thread.
pub trait Observer {
    /// Depth and segments of `scene` (physics step `step`) from `camera`.
    fn observe(
        &mut self,
        scene: SceneSnapshot,
        step: u64,
        camera: &Camera,
    ) -> Result<Observation, String>;

    /// RGB of `scene` from `camera` (`height · width · 3` bytes, top row first), for a policy
    /// object.
    fn frame(
        &mut self,
        scene: SceneSnapshot,
        step: u64,
        camera: &Camera,
    ) -> Result<Vec<u8>, String> {
        let _ = (scene, step, camera);
        Err("this observer draws no RGB frames".into())
    }
}

/// Keyframes per episode (task completion is judged on these).
pub const KEYFRAMES: usize = 8;
/// Frames of an episode video (4 s at 12 frames/s, whatever the episode's length).
pub const VIDEO_FRAMES: usize = 48;

/// The first object whose pose is not finite: physics that blew up. (Distance is no sign: an
/// object that falls off the table keeps falling, kilometres in a long episode, and that is an
/// outcome the goals judge.)
pub fn blown_up(scene: &SimScene) -> Option<&str> {
    scene
        .objects
        .iter()
        .find(|o| {
            let pose = scene.pose(o);
            let (p, q) = (pose.translation, pose.rotation);
            ![p.x, p.y, p.z, q.x, q.y, q.z, q.w]
                .iter()
                .all(|c| c.is_finite())
        })
        .map(|o| o.id.as_str())
}

/// Whether a `lifted` goal names object `i` (the episode may end holding it up).
fn lifts(spec: &TaskSpec, scene: &SimScene, i: usize) -> bool {
    let id = &scene.objects[i].id;
    spec.goals
        .iter()
        .any(|g| matches!(g, assay_spec::spec::Goal::Lifted { object, .. } if object == id))
}

/// Joint goals and `actuate` steps name moving joints of their articulated objects: checked once
/// the URDFs are read (the spec alone does not know their joints).
fn check_joints(spec: &TaskSpec, scene: &SimScene) -> Result<(), SimError> {
    use assay_spec::spec::{Goal, Primitive};
    let refs = spec
        .goals
        .iter()
        .enumerate()
        .filter_map(|(i, g)| match g {
            Goal::JointPosition { object, joint, .. } => {
                Some((format!("goals[{i}].joint_position.joint"), object, joint))
            }
            _ => None,
        })
        .chain(spec.oracle.iter().enumerate().filter_map(|(i, p)| match p {
            Primitive::Actuate { object, joint, .. } => {
                Some((format!("oracle[{i}].actuate.joint"), object, joint))
            }
            _ => None,
        }));
    for (path, object, joint) in refs {
        let Some(o) = scene.object(object) else {
            continue;
        };
        if scene.joint(o, joint).is_none() {
            let known: Vec<&str> = o.joints.iter().map(|j| j.name.as_str()).collect();
            return Err(SimError::spec(
                path,
                format!(
                    "'{object}' has no moving joint '{joint}' (its moving joints: {})",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
    }
    Ok(())
}

/// Simulates one episode of `spec` with `seed` and `policy`. Deterministic: the same inputs give
/// the same outcome and the same file, byte for byte.
pub fn simulate(spec: &TaskSpec, seed: u64, policy: &str) -> Result<Episode, SimError> {
    simulate_with(spec, seed, policy, SimOptions::default())
}

/// [`simulate`], also keeping what `options` asks for (video and clip states), with its observer
/// drawing what a seeing policy sees. The options never change the episode itself.
pub fn simulate_with(
    spec: &TaskSpec,
    seed: u64,
    policy: &str,
    options: SimOptions<'_>,
) -> Result<Episode, SimError> {
    let SimOptions {
        video_frames,
        clip,
        clip_interface,
        mut observer,
        policy: policy_object,
        frame_size,
    } = options;
    // The task as submitted is what the episode names; this seed's variation of it (recoloured
    // objects) is what it runs and draws.
    let spec_hash = spec.spec_hash();
    let varied = spec.for_seed(seed);
    let spec: &TaskSpec = &varied;
    let (parsed, horizon) = PolicySpec::parse_with_horizon(policy).map_err(SimError::Policy)?;
    let (noise, sense, grasp) = match parsed {
        PolicySpec::Oracle {
            noise,
            sense,
            grasp,
        } => (noise, sense, grasp),
        // A policy object acts instead of the oracle's plan.
        _ => (0.0, Sense::State, 1.0),
    };
    let needs_camera = sense == Sense::Camera || !parsed.is_oracle();
    if needs_camera && observer.is_none() {
        return Err(SimError::Policy(format!(
            "policy '{policy}' sees through a camera: it needs a worker with the render role (--roles sim,render)"
        )));
    }
    if let Some(interface) = clip_interface.as_ref().filter(|_| clip) {
        at_interface::check_task(interface, spec).map_err(SimError::Policy)?;
    }
    let mut learned = learned_policy(policy, &parsed, spec, policy_object, frame_size)?;
    let camera = assay_model::policy::observation_camera();
    let mut run = Rollout::new(spec, seed, noise, grasp, sense, learned.is_some())?;
    let request = Request {
        spec_hash,
        seed,
        policy,
        max_steps: u64::from(
            horizon.map_or(spec.physics.max_steps, |h| h.min(spec.physics.max_steps)),
        ),
        video_frames,
        clip,
        clip_interface,
    };
    run.settle_in();
    let acted = run.act(&request, learned.as_mut(), &mut observer, &camera)?;
    run.release(acted.truncated);
    run.settle_out();
    run.episode(&request, &acted)
}

/// The driver of a policy object for `policy` (`parsed`) on `spec`, its frames `frame_size`
/// pixels (0: [`DEFAULT_FRAME_SIZE`]); `None` for the built-in oracle.
fn learned_policy<'p>(
    policy: &str,
    parsed: &PolicySpec,
    spec: &TaskSpec,
    policy_object: Option<&'p mut dyn Policy>,
    frame_size: u32,
) -> Result<Option<learned::Learned<'p>>, SimError> {
    match (parsed.is_oracle(), policy_object) {
        (true, _) => Ok(None),
        (false, Some(p)) => {
            let size = if frame_size == 0 {
                DEFAULT_FRAME_SIZE
            } else {
                frame_size
            };
            Ok(Some(learned::Learned::new(p, policy, spec, size)?))
        }
        (false, None) => Err(SimError::Policy(format!(
            "policy '{policy}' is not built into the simulator and no policy object was given"
        ))),
    }
}

/// What an episode was asked for: the task as submitted (its hash), the seed, the policy and
/// its step limit, and what to keep besides the episode.
struct Request<'p> {
    spec_hash: String,
    seed: u64,
    policy: &'p str,
    /// Physics steps the policy may act (the policy's horizon, at most `physics.max_steps`).
    max_steps: u64,
    video_frames: usize,
    clip: bool,
    clip_interface: Option<Interface>,
}

/// How the policy's part of an episode went.
struct Acted {
    /// The recorded row the policy started from (the last of the initial settle).
    first_policy_row: usize,
    /// The oracle's plan was cut off at the step limit.
    truncated: bool,
    /// A policy object used up the step limit before its goals held.
    ran_out: bool,
    /// Camera frames the policy looked at.
    observations: u64,
}

/// When one goal last held with nothing in the tool, and when it then stopped holding.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct GoalHeld {
    /// The last physics step at a recorded row where it held with nothing in the tool (`None`:
    /// never).
    pub last: Option<u64>,
    /// The first recorded row after `last` where it no longer held: its step, and the object the
    /// tool carried then (`None`: nothing). `None` where it held to the end.
    pub lost: Option<(u64, Option<String>)>,
}

/// One episode as it runs: this seed's variation of the task, its scene and controller, what is
/// recorded, and the physics step reached.
struct Rollout<'s> {
    spec: &'s TaskSpec,
    scene: SimScene,
    ctl: Controller,
    rec: Recorder,
    /// Goals holding at each recorded row, for the keyframes' ground truth.
    met: Vec<u32>,
    /// Per goal, when it last held with nothing in the tool, and when it then stopped.
    goals_held: Vec<GoalHeld>,
    /// The generator's staged reward (`reward_steps`), checked at each recorded row where
    /// nothing is held (GenSim checks after each action, once the object is let go).
    reward: predicates::StagedReward,
    step: u64,
    dt: f64,
    /// Physics steps of each settle, before the policy acts and after.
    settle: u64,
}

impl<'s> Rollout<'s> {
    /// The scene of `spec` built for `seed`, and the controller at the tool: it runs the
    /// oracle's plan (with `noise` and the chance `grasp` that its grasps close, seeing as
    /// `sense` says) unless a policy object acts (`learned`).
    fn new(
        spec: &'s TaskSpec,
        seed: u64,
        noise: f64,
        grasp: f64,
        sense: Sense,
        learned: bool,
    ) -> Result<Self, SimError> {
        let scene = scene::build_scene(spec, seed)?;
        check_joints(spec, &scene)?;
        let start = scene.gripper_position();
        let tracker = (sense == Sense::Camera).then(|| Tracker::new(scene.objects.len()));
        let mut ctl = Controller::new(spec, start, noise, grasp, seed, tracker);
        if learned {
            // The policy object decides every move: the oracle's plan is not run.
            ctl.clear_plan();
        }
        let dt = f64::from(scene.world.integration_parameters.dt);
        let rec = Recorder::new(scene.objects.len());
        Ok(Rollout {
            spec,
            scene,
            ctl,
            rec,
            met: Vec::new(),
            goals_held: vec![GoalHeld::default(); spec.goals.len()],
            reward: predicates::StagedReward::default(),
            step: 0,
            dt,
            settle: u64::from(spec.physics.settle_steps),
        })
    }

    /// A recorded row (physics step `step`, time `time`, holding `held`) of the scene as it is,
    /// with the goals that hold in it.
    fn record(&mut self, step: u32, time: f64, held: Option<usize>) {
        self.rec
            .record(&self.scene, step, time, self.ctl.command, held);
        let goals = predicates::evaluate(&self.spec.goals, &self.scene);
        self.met
            .push(goals.iter().filter(|p| p.holds).count() as u32);
        for (g, p) in self.goals_held.iter_mut().zip(&goals) {
            if p.holds && held.is_none() {
                g.last = Some(u64::from(step));
                g.lost = None;
            } else if !p.holds && g.last.is_some() && g.lost.is_none() {
                let carried = held.map(|k| self.scene.objects[k].id.clone());
                g.lost = Some((u64::from(step), carried));
            }
        }
        if held.is_none() && !self.spec.reward_steps.is_empty() {
            self.reward.check(&self.spec.reward_steps, &self.scene);
        }
    }

    /// One physics step: the tool goes to `act`'s command and its event follows the step; with
    /// `None` the tool holds its last command (the settles).
    fn advance(&mut self, act: Option<(rapier3d::prelude::Vec3, controller::Event)>) {
        let scene = &mut self.scene;
        // The oracle's plan turns what it holds: the weld follows.
        if let Some(h) = self.ctl.held {
            h.spin(scene);
        }
        let ev = match act {
            Some((cmd, ev)) => {
                let at = scene.drive_arm(cmd);
                scene.world.bodies[scene.gripper].set_next_kinematic_position(at);
                ev
            }
            None => {
                let at = scene.drive_arm(self.ctl.command);
                scene.world.bodies[scene.gripper].set_next_kinematic_position(at);
                controller::Event::None
            }
        };
        scene.hold_joints();
        scene.drive_fingers();
        scene.step();
        self.ctl.apply(ev, scene, self.step);
        self.step += 1;
        if self.step.is_multiple_of(RECORD_STRIDE) {
            let held = self.ctl.held.map(|h| h.object);
            self.record(self.step as u32, self.step as f64 * self.dt, held);
        }
    }

    /// The first row, then the initial settle.
    fn settle_in(&mut self) {
        self.record(0, 0.0, None);
        for _ in 0..self.settle {
            self.advance(None);
        }
    }

    /// A camera frame for an oracle that sees (none for one that reads the sim's state).
    fn look(
        &mut self,
        observer: &mut Option<&mut dyn Observer>,
        camera: &Camera,
    ) -> Result<(), SimError> {
        if let (Some(obs), Some(tracker)) = (observer.as_deref_mut(), self.ctl.tracker.as_mut()) {
            let step = self.step;
            let seen = obs
                .observe(record::live_snapshot(&self.scene, self.spec), step, camera)
                .map_err(|e| SimError::internal(format!("policy camera at step {step}: {e}")))?;
            tracker.update(&seen, step);
        }
        Ok(())
    }

    /// The policy's part, after the initial settle: the oracle's plan through the controller
    /// (looking through `camera` when it sees), or the policy object `learned`.
    fn act(
        &mut self,
        request: &Request<'_>,
        learned: Option<&mut learned::Learned<'_>>,
        observer: &mut Option<&mut dyn Observer>,
        camera: &Camera,
    ) -> Result<Acted, SimError> {
        let first_policy_row = self.rec.rows() - 1;
        self.look(observer, camera)?;
        let (truncated, ran_out, observations) = match learned {
            None => {
                let truncated = self.run_plan(request.max_steps, observer, camera)?;
                let frames = self.ctl.tracker.as_ref().map_or(0, |t| t.frames);
                (truncated, false, frames)
            }
            Some(l) => {
                l.reset(&mut self.scene, self.spec, request.seed, self.step)?;
                let ran_out = self.run_policy(l, observer, request.max_steps)?;
                (false, ran_out, l.frames)
            }
        };
        Ok(Acted {
            first_policy_row,
            truncated,
            ran_out,
            observations,
        })
    }

    /// The oracle's plan, step by step, until it is done; whether `max_steps` cut it off.
    fn run_plan(
        &mut self,
        max_steps: u64,
        observer: &mut Option<&mut dyn Observer>,
        camera: &Camera,
    ) -> Result<bool, SimError> {
        loop {
            if self.ctl.done() {
                return Ok(false);
            }
            if self.step >= self.settle + max_steps {
                return Ok(true);
            }
            let act = self.ctl.step(&self.scene, self.step);
            self.advance(Some(act));
            if self.step.is_multiple_of(OBSERVE_EVERY_STEPS) {
                self.look(observer, camera)?;
            }
        }
    }

    /// Policy object `l` acts until the goals hold with nothing held (checked at its control
    /// steps), or for `max_steps`; whether it ran out of steps (its failure, not a truncated
    /// plan).
    fn run_policy(
        &mut self,
        l: &mut learned::Learned<'_>,
        observer: &mut Option<&mut dyn Observer>,
        max_steps: u64,
    ) -> Result<bool, SimError> {
        let dt32 = self.dt as f32;
        loop {
            let since = self.step - self.settle;
            if self.step >= self.settle + max_steps {
                return Ok(true);
            }
            if since > 0
                && since.is_multiple_of(assay_model::policy::CONTROL_STRIDE_STEPS)
                && self
                    .ctl
                    .held
                    .is_none_or(|h| lifts(self.spec, &self.scene, h.object))
                && predicates::evaluate(&self.spec.goals, &self.scene)
                    .iter()
                    .all(|p| p.holds)
            {
                return Ok(false);
            }
            let obs = observer.as_deref_mut().expect("checked above");
            let act = l.step(
                &mut self.scene,
                self.spec,
                &mut self.ctl,
                obs,
                self.step,
                dt32,
            )?;
            self.advance(Some(act));
        }
    }

    /// A truncated plan may still hold something: let it go before the final settle. What a
    /// `lifted` goal wants held up stays held to the end.
    fn release(&mut self, truncated: bool) {
        if let Some(h) = self.ctl.held
            && (truncated || !lifts(self.spec, &self.scene, h.object))
        {
            self.ctl.held = None;
            if let Some(j) = h.joint {
                self.scene.world.remove_impulse_joint(j);
            }
            if let Some(max) = self.scene.fingers.as_ref().map(|f| f.max_opening) {
                self.scene.set_finger_target(max);
            }
        }
    }

    /// The final settle, and a last row of the final state where the stride left none.
    fn settle_out(&mut self) {
        for _ in 0..self.settle {
            self.advance(None);
        }
        if !self.step.is_multiple_of(RECORD_STRIDE) {
            self.record(self.step as u32, self.step as f64 * self.dt, None);
        }
    }

    /// The outcome of the final state, the episode file, and the states kept besides.
    fn episode(self, request: &Request<'_>, acted: &Acted) -> Result<Episode, SimError> {
        // Numbers a spec may still combine badly (a heavy body on a tiny one, a stiff joint) can
        // blow the physics up: that episode measured nothing, so it is an error of the shard,
        // never a policy's failure.
        if let Some(id) = blown_up(&self.scene) {
            return Err(SimError::spec(
                "scene",
                format!(
                    "the physics state of object '{id}' became non-finite (NaN or infinite) by \
                     step {}: the episode measured nothing and is not scored",
                    self.step
                ),
            ));
        }
        let outcome = self.outcome(request, acted);
        let mut notes: Vec<String> = self
            .ctl
            .notes
            .iter()
            .map(|n| format!("step {}: {}", n.step, n.text))
            .collect();
        if acted.truncated {
            notes.push(format!(
                "plan cut off at physics.max_steps = {}",
                request.max_steps
            ));
        }
        let object_ids: Vec<String> = self.scene.objects.iter().map(|o| o.id.clone()).collect();
        let metadata = metadata(&outcome, &notes, &object_ids, self.dt, acted.observations);
        let (rec, spec, first) = (&self.rec, self.spec, acted.first_policy_row);
        let file = rec.encode(&object_ids, metadata)?;
        let keyframe_rows = evenly_spaced(first, rec.rows() - 1, KEYFRAMES);
        Ok(Episode {
            outcome,
            file,
            notes,
            initial: rec.snapshot(first, spec),
            initial_step: u64::from(rec.step_at(first)),
            keyframes: keyframe_rows
                .iter()
                .map(|&row| (u64::from(rec.step_at(row)), rec.snapshot(row, spec)))
                .collect(),
            keyframe_goals: keyframe_rows.iter().map(|&row| self.met[row]).collect(),
            goals_held: self.goals_held.clone(),
            video: evenly_spaced(first, rec.rows() - 1, request.video_frames)
                .into_iter()
                .map(|row| (u64::from(rec.step_at(row)), rec.snapshot(row, spec)))
                .collect(),
            observations: acted.observations,
            clip: request.clip.then(|| {
                clip_states(
                    rec,
                    spec,
                    first,
                    self.dt,
                    CLIP_STRIDE_STEPS,
                    request.clip_interface.as_ref(),
                )
            }),
        })
    }

    /// The goal predicates on the final state, and what else an episode's outcome says.
    fn outcome(&self, request: &Request<'_>, acted: &Acted) -> EpisodeOutcome {
        let max_steps = request.max_steps;
        let predicates = predicates::evaluate(&self.spec.goals, &self.scene);
        let success = !acted.truncated && predicates.iter().all(|p| p.holds);
        let cutoff = if acted.truncated {
            Some(format!(
                "step limit: the plan was cut off at physics.max_steps = {max_steps}"
            ))
        } else if acted.ran_out {
            Some(format!(
                "step limit: the policy used all physics.max_steps = {max_steps} steps before its \
                 goals held"
            ))
        } else {
            None
        };
        EpisodeOutcome {
            task_id: self.spec.id.clone(),
            seed: request.seed,
            policy: request.policy.to_owned(),
            success,
            label_source: LabelSource::Sim,
            predicates,
            steps: self.step,
            sim_time_s: self.step as f64 * self.dt,
            // Filled in by whoever stores `file` (the worker, in its artifact store).
            artifact: String::new(),
            spec_hash: request.spec_hash.clone(),
            versions: versions(),
            imagery: None,
            cutoff,
            generator_reward: self.generator_reward(),
            scenes: None,
        }
    }

    /// The generator's staged reward at the end, where the task has one: the checks made at the
    /// recorded rows, and one more on the final state.
    fn generator_reward(&self) -> Option<assay_model::episode::GeneratorReward> {
        let steps = &self.spec.reward_steps;
        if steps.is_empty() {
            return None;
        }
        let mut last = self.reward.clone();
        last.check(steps, &self.scene);
        Some(assay_model::episode::GeneratorReward {
            by: if self.spec.source.pipeline.is_empty() {
                "generator".into()
            } else {
                self.spec.source.pipeline.clone()
            },
            value: last.value(),
            max: steps.iter().map(|s| s.max_reward).sum(),
            steps_met: last.met as u32,
            steps: steps.len() as u32,
        })
    }
}

/// The metadata of an episode file: what the outcome says, the notes, the objects (in the order
/// of the file's columns), the time step and the frames the policy looked at.
fn metadata(
    outcome: &EpisodeOutcome,
    notes: &[String],
    object_ids: &[String],
    dt: f64,
    observations: u64,
) -> HashMap<String, String> {
    HashMap::from([
        (
            "assay.episode_format".to_owned(),
            record::EPISODE_FORMAT_VERSION.to_owned(),
        ),
        ("assay.task_id".to_owned(), outcome.task_id.clone()),
        ("assay.seed".to_owned(), outcome.seed.to_string()),
        ("assay.policy".to_owned(), outcome.policy.clone()),
        ("assay.success".to_owned(), outcome.success.to_string()),
        ("assay.label_source".to_owned(), "sim".to_owned()),
        (
            "assay.predicates".to_owned(),
            serde_json::to_string(&outcome.predicates).unwrap_or_default(),
        ),
        (
            "assay.notes".to_owned(),
            serde_json::to_string(notes).unwrap_or_default(),
        ),
        ("assay.spec_hash".to_owned(), outcome.spec_hash.clone()),
        (
            "assay.versions".to_owned(),
            serde_json::to_string(&outcome.versions).unwrap_or_default(),
        ),
        (
            "assay.objects".to_owned(),
            serde_json::to_string(object_ids).unwrap_or_default(),
        ),
        ("assay.dt".to_owned(), dt.to_string()),
        ("assay.record_stride".to_owned(), RECORD_STRIDE.to_string()),
        ("assay.observations".to_owned(), observations.to_string()),
    ])
}

/// A recorded episode's states every `stride_steps` physics steps from its first policy step to
/// its end, as [`ClipStates`] (the scenes, the proprioception and the commanded velocities a
/// dynamics clip holds, which is a clip's when `stride_steps` is [`CLIP_STRIDE_STEPS`]). `spec`
/// is the task as submitted, `file` the episode file the sim role wrote for it with `seed`:
/// nothing is simulated again, the file's rows are drawn as they were recorded.
///
/// Refused: a file recorded for another task, another version of it or another seed, and a
/// stride that is not a whole number of recorded rows ([`RECORD_STRIDE`]).
pub fn recorded_states(
    spec: &TaskSpec,
    seed: u64,
    file: &[u8],
    stride_steps: u64,
) -> Result<ClipStates, SimError> {
    read_recorded(spec, seed, file, stride_steps, None)
}

/// [`recorded_states`] at a policy's `interface` (its cameras sized), one frame per control
/// step ([`CLIP_STRIDE_STEPS`]): the state and actions a policy of that interface would have
/// seen and taken, and where its cameras were. An interface the task cannot fill is refused
/// naming the task and the field.
pub fn recorded_states_at(
    spec: &TaskSpec,
    seed: u64,
    file: &[u8],
    interface: &Interface,
) -> Result<ClipStates, SimError> {
    at_interface::check_task(interface, &spec.for_seed(seed)).map_err(SimError::Policy)?;
    read_recorded(spec, seed, file, CLIP_STRIDE_STEPS, Some(interface))
}

fn read_recorded(
    spec: &TaskSpec,
    seed: u64,
    file: &[u8],
    stride_steps: u64,
    interface: Option<&Interface>,
) -> Result<ClipStates, SimError> {
    if stride_steps == 0 || !stride_steps.is_multiple_of(RECORD_STRIDE) {
        return Err(SimError::Policy(format!(
            "frames every {stride_steps} physics steps: rows are recorded every {RECORD_STRIDE} \
             steps, so the stride must be a positive multiple of {RECORD_STRIDE}"
        )));
    }
    let (rec, meta) = Recorder::decode(file)?;
    let field = |k: &str| meta.get(k).map(String::as_str).unwrap_or("");
    let hash = spec.spec_hash();
    if field("assay.task_id") != spec.id || field("assay.spec_hash") != hash {
        return Err(SimError::internal(format!(
            "the episode file was recorded for task '{}' (spec {}), not for '{}' (spec {hash})",
            field("assay.task_id"),
            field("assay.spec_hash"),
            spec.id
        )));
    }
    if field("assay.seed") != seed.to_string() {
        return Err(SimError::internal(format!(
            "the episode file was recorded with seed {}, not {seed}",
            field("assay.seed")
        )));
    }
    let dt: f64 = field("assay.dt")
        .parse()
        .map_err(|_| SimError::internal("episode file: assay.dt is not a number"))?;
    let varied = spec.for_seed(seed);
    let first = first_policy_row(&rec, &varied);
    Ok(clip_states(
        &rec,
        &varied,
        first,
        dt,
        stride_steps,
        interface,
    ))
}

/// The row a policy started from in `rec` (an episode of `spec` for its seed): the last one of
/// the initial settle.
fn first_policy_row(rec: &Recorder, spec: &TaskSpec) -> usize {
    let settle = spec.physics.settle_steps;
    (0..rec.rows())
        .take_while(|&row| rec.step_at(row) <= settle)
        .last()
        .unwrap_or(0)
}

/// The recorded rows every `stride_steps` physics steps from `first` to the end, as clip states
/// at `interface` (`None`: the original one).
fn clip_states(
    rec: &Recorder,
    spec: &TaskSpec,
    first: usize,
    dt: f64,
    stride_steps: u64,
    interface: Option<&Interface>,
) -> ClipStates {
    let start = rec.step_at(first);
    let rows: Vec<usize> = (first..rec.rows())
        .filter(|&row| u64::from(rec.step_at(row) - start).is_multiple_of(stride_steps))
        .collect();
    let interval = stride_steps as f64 * dt;
    // The original interface's numbers are its state parts (tool position, holding) and space
    // (tool velocity).
    let original = Interface::default();
    let at = interface.unwrap_or(&original);
    let mut proprio = Vec::new();
    let mut actions = Vec::new();
    for (k, &row) in rows.iter().enumerate() {
        let tool = at_interface::recorded_tool(rec, spec, row);
        proprio.extend(at_interface::state_vector(&at.state, &tool));
        let next = rows.get(k + 1).copied();
        let a = at_interface::recorded_action(at.action, rec, row, next.unwrap_or(row), interval);
        // Nothing follows the last frame: its action is zeros.
        match next {
            Some(_) => actions.extend(a),
            None => actions.extend(std::iter::repeat_n(0.0, a.len())),
        }
    }
    let cameras = match interface {
        None => Vec::new(),
        Some(i) => at_interface::policy_cameras(i, spec, DEFAULT_FRAME_SIZE)
            .into_iter()
            .map(|c| ClipCamera {
                frames: rows
                    .iter()
                    .map(|&row| c.placed(rec.ee_at(row), rec.turn_at(row)))
                    .collect(),
                name: c.name,
            })
            .collect(),
    };
    ClipStates {
        interval_s: interval as f32,
        steps: rows
            .iter()
            .map(|&row| u64::from(rec.step_at(row)))
            .collect(),
        scenes: rows.iter().map(|&row| rec.snapshot(row, spec)).collect(),
        proprio,
        actions,
        interface: interface.cloned(),
        cameras,
    }
}

/// `n` indices from `first` to `last` inclusive, evenly spaced (rounded).
fn evenly_spaced(first: usize, last: usize, n: usize) -> Vec<usize> {
    if n <= 1 || last <= first {
        return vec![last; n.min(1)];
    }
    (0..n)
        .map(|k| first + ((last - first) as f64 * k as f64 / (n - 1) as f64).round() as usize)
        .collect()
}

use scene::SimScene;
