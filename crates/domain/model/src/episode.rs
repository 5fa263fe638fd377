//! Episode outcomes as every role and the coordinator exchange them: the predicates an episode
//! met, its imagery and keyframes in the artifact store, the state of a shard, and the task as the
//! planner accepted it.
//!
//! Owns: the records. Never aggregates them (that is `assay-report`).

use std::collections::BTreeMap;

use assay_spec::scene::SceneSnapshot;
use serde::{Deserialize, Serialize};

/// Where a success label came from.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum LabelSource {
    Sim,
    Llm,
    Vlm,
    Human,
}

/// The value of one goal predicate at the end of an episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PredicateValue {
    pub label: String,
    pub holds: bool,
    /// What was measured (`distance 0.012 m`), for people reading a failure.
    pub detail: String,
}

/// What a sim worker reports for one finished episode (everything here is deterministic).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct EpisodeOutcome {
    pub task_id: String,
    pub seed: u64,
    pub policy: String,
    pub success: bool,
    pub label_source: LabelSource,
    pub predicates: Vec<PredicateValue>,
    /// Physics steps simulated, settle included.
    pub steps: u64,
    pub sim_time_s: f64,
    /// Content address of the episode file in the artifact store.
    pub artifact: String,
    pub spec_hash: String,
    /// Versions of the code that produced the episode (`assay-sim`, `rapier3d`, ...).
    pub versions: BTreeMap<String, String>,
    /// Rendered pictures of the episode, when a render role ran with the sim role.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imagery: Option<EpisodeImagery>,
    /// Why the episode stopped before its plan or policy finished: the step limit
    /// (`physics.max_steps`). Such an episode is unsuccessful whatever its predicates say.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutoff: Option<String>,
    /// The generator's own staged reward for the episode (GenSim's), where the task has one
    /// (`reward_steps`): reported beside success, never instead of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator_reward: Option<GeneratorReward>,
    /// An episode waiting for its pictures: the scene states a render worker draws them from
    /// (set by a sim worker without a renderer of its own, taken by the render worker; never
    /// part of a finished episode or a report).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(skip)]
    pub scenes: Option<EpisodeScenes>,
}

/// A generator's own score of an episode, as the generator computes it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GeneratorReward {
    /// Whose reward it is: the task's pipeline (`gensim`).
    pub by: String,
    /// The reward: the completed steps' worth plus the current step's share.
    pub value: f64,
    /// The most it can be: every step's worth.
    pub max: f64,
    /// Steps completed, of how many.
    pub steps_met: u32,
    pub steps: u32,
}

/// What an episode's pictures are drawn from, as plain data: small beside the pictures (poses,
/// joint values and shapes), so it travels from a sim worker to a render worker in the shard's
/// result and assignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeScenes {
    /// The scene after the initial settle, before the policy acts (for the scene views).
    pub initial: SceneSnapshot,
    /// The physics step of `initial`.
    pub initial_step: u64,
    /// States evenly spaced from the first policy step to the end, with their steps.
    pub keyframes: Vec<(u64, SceneSnapshot)>,
    /// Goal predicates holding at each keyframe.
    pub keyframe_goals: Vec<u32>,
    /// Video states (empty: no video).
    #[serde(default)]
    pub video: Vec<(u64, SceneSnapshot)>,
    /// The states of a dynamics clip, when the batch asks for clips.
    #[serde(default)]
    pub clip: Option<ClipScenes>,
}

/// The states a dynamics clip is drawn from ([`crate::clip::Clip`] less its pixels).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClipScenes {
    pub interval_s: f32,
    pub steps: Vec<u64>,
    pub scenes: Vec<SceneSnapshot>,
    /// Per frame, the state vector (the original interface's tool position + holding, or the
    /// state parts of `interface`).
    pub proprio: Vec<f32>,
    /// Per frame, the action to the next frame in the interface's action space.
    pub actions: Vec<f32>,
    /// The policy interface the clip is recorded at (`Interface::to_args`; empty: the
    /// original one, drawn from the task's camera at the batch's clip size).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub interface: String,
    /// The interface's cameras in its order, each placed at every frame (a wrist camera moves
    /// with the tool) and sized; empty for the original interface.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cameras: Vec<ClipCamera>,
}

/// One camera of a clip at a policy interface: its name and where it is at each frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClipCamera {
    pub name: String,
    pub frames: Vec<assay_spec::spec::Camera>,
}

/// Pictures of one episode, as artifact keys.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct EpisodeImagery {
    /// The graphics adapter that drew them (a GPU, or a software rasteriser).
    pub adapter: String,
    /// Views of the initial scene (top, front, two obliques), for scene alignment.
    pub views: Vec<NamedArtifact>,
    /// Frames evenly spaced over the rollout, for task completion.
    pub keyframes: Vec<Keyframe>,
    /// One PNG with the views on the first row and the keyframes below.
    pub contact_sheet: String,
    /// A video of the rollout (MP4, or an animated GIF where ffmpeg is not installed), when the
    /// worker was asked for videos.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<String>,
    /// Content address of the scene caption (JSON `assay_model::caption::SceneCaption`): what
    /// the scene views show, measured from their segments and depth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub caption: Option<String>,
    /// Content address of the episode's dynamics clip (`assay_model::clip::Clip`), when the batch
    /// measures dynamics diversity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clip: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct NamedArtifact {
    pub name: String,
    pub artifact: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Keyframe {
    pub step: u64,
    pub camera: String,
    pub artifact: String,
    /// Goal predicates that held in this state (ground truth, for the offline judge).
    #[serde(default)]
    pub goals_met: u32,
}

/// The state of one shard when the report is built: an episode's (`O` = [`EpisodeOutcome`]) or a
/// judge shard's ([`JudgeRecord`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ShardRecord<O = EpisodeOutcome> {
    pub task_id: String,
    pub seed: u64,
    pub policy: String,
    /// The judge of a judge shard; empty for an episode.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub judge: String,
    pub attempts: u32,
    pub outcome: Option<O>,
    /// Last error, for shards that failed (or were cancelled).
    pub error: Option<String>,
    pub cancelled: bool,
}

/// One judge shard as the job store has it.
pub type JudgeRecord = ShardRecord<crate::quality::JudgeOutcome>;

/// A task as the planner accepted it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TaskInfo {
    pub id: String,
    pub name: String,
    pub group: String,
    pub pipeline: String,
    pub origin: String,
    pub spec_hash: String,
}
