//! Task spec v1: what a generated tabletop task is, as Assay reads it.
//!
//! The world is z-up, metres, kilograms, seconds; the table top is the plane z = 0. Angles in the
//! spec are degrees. A spec is parsed strictly (unknown fields are errors) and then validated; every
//! problem names the task, the field path and the reason.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::{SpecError, SpecErrors};

mod validate;
pub use validate::validate;

/// The spec format version this build reads and writes.
pub const SPEC_VERSION: u32 = 1;

/// One generated task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TaskSpec {
    /// Format version; must be 1.
    pub spec_version: u32,
    /// Unique id within a batch: lowercase letters, digits, `-` and `_`.
    pub id: String,
    /// The generator's task name (GenSim style: `build-two-block-tower`).
    pub name: String,
    /// The natural-language description an LLM wrote for the task.
    pub description: String,
    /// Where the task came from.
    #[serde(default)]
    pub source: Source,
    /// Task group for per-group metrics (stacking, placement, assembling, piles, clutter, ...).
    pub group: String,
    pub scene: Scene,
    pub end_effector: EndEffector,
    /// The robot arm that carries the end effector. Without one the tool moves on its own (a
    /// free-floating kinematic tool, as in the peer reference scene).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm: Option<Arm>,
    /// Goal predicates; the episode succeeds when all hold at the end.
    pub goals: Vec<Goal>,
    /// Ranges sampled per seed (and, later, held out for generalization).
    #[serde(default)]
    pub variations: Variations,
    /// Scripted solution executed by the primitive controller (the oracle policy).
    #[serde(default)]
    pub oracle: Vec<Primitive>,
    /// Cameras used by the render role (recorded with the spec, unused by physics).
    #[serde(default)]
    pub cameras: Vec<Camera>,
    /// Physics settings; defaults suit tabletop manipulation.
    #[serde(default)]
    pub physics: PhysicsSettings,
    /// The scene, goals and plan of each seed as the generator's own code built them (GenSim's
    /// `reset()` run on that seed): on a seed listed here they replace `scene`, `goals` and
    /// `oracle`, and `variations` moves nothing. With layouts, a seed without one (or whose
    /// layout is an `error`) is an error of its episode, naming the seed and the reason.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub layouts: Vec<Layout>,
    /// The generator's own staged reward, reported beside success (GenSim's: Ravens'
    /// `Task.reward`, one step per `add_goal`): the steps are checked in order whenever
    /// nothing is held, a step whose goals all hold is counted for good, and the episode's
    /// reward is the steps completed plus the share of the current one's goals that hold.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reward_steps: Vec<RewardStep>,
}

/// One step of a generator's staged reward.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RewardStep {
    /// What the step is worth when all its goals hold (GenSim's `step_max_reward`).
    pub max_reward: f64,
    /// Its goals, one per object (a `pile_in_zone` counts the share of the pile over the zone).
    pub goals: Vec<Goal>,
}

/// One seed's initial scene, goals and plan, recorded from the generator's code; or why that
/// seed has none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Layout {
    pub seed: u64,
    /// Why the generator's code built no scene a spec can take on this seed (its `reset()`
    /// raised, or built what the importer refuses): the episode on this seed fails with it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The scene on this seed (absent with an `error`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<Scene>,
    /// The goals on this seed; absent, the spec's own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub goals: Vec<Goal>,
    /// The oracle's plan on this seed; absent, the spec's own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub oracle: Vec<Primitive>,
    /// The generator's staged reward on this seed; absent, the spec's own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reward_steps: Vec<RewardStep>,
}

/// The most layouts a spec may carry.
pub const MAX_LAYOUTS: usize = 1000;

/// Provenance of a task.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// `gensim`, `robogen`, `bbsea`, `assay`, or a lab's own pipeline name.
    #[serde(default)]
    pub pipeline: String,
    /// The generator's model or run (free text).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<String>,
    /// The file or record the task was imported from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The folder asset paths (`mesh.path`, `urdf.path`) are relative to: absolute, or relative
    /// to the folder of `origin`. Default: the folder of `origin`. An asset path must stay inside
    /// it (no absolute paths, no `..` that leaves it, no symbolic link that leads out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub asset_root: Option<String>,
    /// Hex SHA-256 of the source file(s) an importer read (the same source gives the same hash).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub content_hash: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// `table` (a 1.2 × 1.6 m top at z = 0 with edges objects can fall off) or `ground` (infinite).
    #[serde(default)]
    pub surface: Surface,
    pub objects: Vec<Object>,
    /// Flat target regions drawn on the surface (no collision).
    #[serde(default)]
    pub zones: Vec<Zone>,
    /// Piles of many small identical objects (beans, chips, debris), drawn per seed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub piles: Vec<Pile>,
}

/// `count` copies of one small shape, heaped in a region of the table: each seed lays them on a
/// grid over the region, in layers, each copy shifted within its cell and turned. Copy `k` is
/// object `{id}_{k}` (drawn, simulated and recorded like any object); goals and the oracle refer
/// to the pile by `id`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Pile {
    pub id: String,
    pub count: u32,
    pub shape: Shape,
    /// The copies' colour, as an object's `color`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<Color>,
    /// Mass of each copy (kg); default 0.01.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// The region (x, y) the pile is heaped over.
    pub region: Region,
}

/// An axis-aligned rectangle of the table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Region {
    pub min: [f64; 2],
    pub max: [f64; 2],
}

/// The most copies a pile may have.
pub const MAX_PILE: u32 = 200;

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Surface {
    #[default]
    Table,
    Ground,
}

/// Centre (x, y) and half-size (x, y) of the table top, in metres; its top is z = 0.
pub const TABLE_CENTER: [f64; 2] = [0.5, 0.0];
pub const TABLE_HALF_EXTENTS: [f64; 2] = [0.6, 0.8];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Object {
    /// Unique within the task; goals and the oracle refer to it.
    pub id: String,
    pub shape: Shape,
    /// A colour name (`red`) or `[r, g, b]` in 0..1. On a URDF object it is drawn over the
    /// materials of its base link (the root), as PyBullet's `changeVisualShape(body, -1,
    /// rgbaColor)` does for GenSim's `add_object(..., color=...)`; its other links keep theirs.
    /// Absent: gray for a primitive shape, a URDF's own materials.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<Color>,
    /// Mass in kg (dynamic objects only); default 0.1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// Fixed objects (containers bolted to the table, pegs) do not move.
    #[serde(default, rename = "fixed")]
    pub is_fixed: bool,
    /// Exactly one of `pose` and `pose_range`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<Pose>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_range: Option<PoseRange>,
}

/// Collision shape. Boxes and containers are axis-aligned in the object frame; cylinders stand on
/// their axis (z).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    Box {
        half_extents: [f64; 3],
    },
    Sphere {
        radius: f64,
    },
    Cylinder {
        radius: f64,
        half_height: f64,
    },
    /// An open-top box (bowl, bin, tray): inner half-extents and wall thickness.
    Container {
        inner_half_extents: [f64; 3],
        wall: f64,
    },
    /// A Wavefront OBJ file (inside the asset root), collided as its convex hull, or with
    /// `collision: decomposition` as the convex parts of an approximate convex decomposition
    /// (V-HACD) of its triangles, so that a bowl or a mug keeps its hollow.
    Mesh {
        path: String,
        #[serde(default = "one")]
        scale: f64,
        #[serde(default, skip_serializing_if = "MeshCollision::is_hull")]
        collision: MeshCollision,
    },
    /// A URDF file (inside the asset root; its meshes, OBJ or STL, inside the URDF's own
    /// folder), drawn from its visual elements and collided as the compound of its collision
    /// elements (a link's visuals where it has none, meshes as convex hulls). `joints` gives the
    /// initial joint positions (joint name → rad or m; a joint not named sits at 0, or at its
    /// lower limit when 0 is outside its limits). Rigid unless `articulated`: then every
    /// revolute, continuous and prismatic joint moves, within its limits, against its URDF
    /// `<dynamics friction>`, and the object (its root link) follows `fixed` like any other.
    /// The object's frame is the centre of its visual bounding box at the initial joint positions
    /// (an articulated object's: with every joint at its default position, so that where it
    /// stands does not depend on how far it starts open).
    Urdf {
        path: String,
        #[serde(default)]
        joints: BTreeMap<String, f64>,
        #[serde(default, skip_serializing_if = "is_false")]
        articulated: bool,
        /// A template URDF's placeholders and what replaces them (Ravens' `fill_template`:
        /// `DIM0` → `0.04`, `FNAME0` → `03.obj`): each key, `A-Z` and `_` then digits, is
        /// replaced in the file's text by its value, a number or a file name inside the URDF's
        /// folder, before the URDF is read.
        #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
        fill: BTreeMap<String, String>,
    },
}

fn one() -> f64 {
    1.0
}

/// How a mesh collides.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MeshCollision {
    /// Its convex hull (fast; fills hollows).
    #[default]
    Hull,
    /// The convex parts of a V-HACD decomposition of its triangles.
    Decomposition,
}

impl MeshCollision {
    fn is_hull(&self) -> bool {
        *self == MeshCollision::Hull
    }
}

fn is_false(b: &bool) -> bool {
    !*b
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Color {
    Named(String),
    Rgb([f64; 3]),
}

impl Default for Color {
    fn default() -> Self {
        Color::Named("gray".into())
    }
}

/// Named colours, the palette GenSim/Ravens tasks use.
pub const COLORS: &[(&str, [f64; 3])] = &[
    ("red", [0.84, 0.15, 0.16]),
    ("green", [0.17, 0.63, 0.17]),
    ("blue", [0.12, 0.47, 0.71]),
    ("yellow", [0.93, 0.79, 0.13]),
    ("orange", [1.0, 0.5, 0.05]),
    ("purple", [0.58, 0.4, 0.74]),
    ("pink", [0.89, 0.47, 0.76]),
    ("cyan", [0.09, 0.75, 0.81]),
    ("brown", [0.55, 0.34, 0.29]),
    ("white", [0.95, 0.95, 0.95]),
    ("black", [0.1, 0.1, 0.1]),
    ("gray", [0.5, 0.5, 0.5]),
];

impl Color {
    pub fn rgb(&self) -> Option<[f64; 3]> {
        match self {
            Color::Rgb(c) => Some(*c),
            Color::Named(n) => COLORS.iter().find(|(k, _)| k == n).map(|(_, c)| *c),
        }
    }
}

/// Position (m) and rotation about z (degrees).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Pose {
    pub position: [f64; 3],
    #[serde(default)]
    pub yaw_deg: f64,
}

/// A pose drawn uniformly per seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PoseRange {
    pub min: [f64; 3],
    pub max: [f64; 3],
    #[serde(default)]
    pub yaw_deg: [f64; 2],
}

/// A flat axis-aligned target region on the surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Zone {
    pub id: String,
    pub center: [f64; 2],
    pub half_extents: [f64; 2],
    #[serde(default)]
    pub color: Color,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum EndEffector {
    /// A suction cup: grasps the top face of any object it touches.
    Suction,
    /// A parallel-jaw gripper: grasps objects narrower than `max_opening` (m).
    ParallelGripper {
        max_opening: f64,
        /// How a grasp holds: `attach` (default) welds the object to the tool where it was
        /// grasped; `friction` closes two finger pads on it, and only their contact friction
        /// holds it (it can slip, turn, or not come up).
        #[serde(default, skip_serializing_if = "Grasp::is_attach")]
        grasp: Grasp,
    },
}

/// The arms Assay has built in (their URDFs ship with the simulator).
pub const ARM_MODELS: &[&str] = &["ur5", "panda"];

/// A robot arm from URDF, driven by inverse kinematics: the tool goes where the arm can put it,
/// pointing straight down (or turned as a policy acting in `ee_delta` or `ee_pose` turns it);
/// its links collide with the scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Arm {
    /// A built-in arm: `ur5` (GenSim's and Ravens' arm) or `panda` (a Franka Emika Panda,
    /// RoboGen's and RoboMimic's).
    pub model: String,
    /// Where its base stands (m); default the origin, the table's near edge.
    #[serde(default)]
    pub base: [f64; 3],
    /// Its base's rotation about z (degrees).
    #[serde(default)]
    pub base_yaw_deg: f64,
}

/// How a parallel gripper holds what it grasps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Grasp {
    #[default]
    Attach,
    Friction,
}

impl Grasp {
    fn is_attach(&self) -> bool {
        *self == Grasp::Attach
    }
}

/// A goal predicate, evaluated on the final state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Goal {
    /// The object's centre lies over the zone, resting at table height.
    InZone { object: String, zone: String },
    /// The object's centre lies inside a container object's interior.
    InContainer { object: String, container: String },
    /// The object rests on top of `support` (centred within its top face).
    OnTopOf { object: String, support: String },
    /// Objects form a tower in this order, bottom first.
    Stacked { order: Vec<String> },
    /// The object's centre is within `distance` of a point or of another object's centre.
    WithinDistance {
        object: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        target: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        point: Option<[f64; 3]>,
        distance: f64,
    },
    /// The object's position (and optionally yaw) is within tolerance of a target pose.
    PoseWithin {
        object: String,
        /// The target position: in the world, or, with `relative_to`, from that object's centre
        /// (world axes), so that the target moves with it from seed to seed.
        position: [f64; 3],
        tolerance: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        yaw_deg: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        yaw_tolerance_deg: Option<f64>,
        /// The object `position` is measured from.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        relative_to: Option<String>,
        /// Compare x and y only (GenSim's and Ravens' pose match ignores height).
        #[serde(default, skip_serializing_if = "is_false")]
        planar: bool,
        /// The object looks the same turned by this angle (degrees; 90 for a square block):
        /// the yaw error is taken modulo it.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        yaw_symmetry_deg: Option<f64>,
    },
    /// At least one of these goals holds (GenSim's `matches`: an object may go to any of
    /// several targets). They may not hold `any_of` themselves.
    AnyOf { any: Vec<Goal> },
    /// A joint of an articulated URDF object lies within [`min`, `max`] (rad or m; either may be
    /// left out): "opened beyond" is a `min`, "closed" a `max`.
    JointPosition {
        object: String,
        joint: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        min: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        max: Option<f64>,
    },
    /// The object's bottom is at least `height` above the surface (held up or resting on
    /// something).
    Lifted { object: String, height: f64 },
    /// At least `fraction` of a pile's copies lie over the zone (GenSim's sweeping score).
    PileInZone {
        pile: String,
        zone: String,
        fraction: f64,
    },
}

impl Goal {
    /// A short stable label (`on_top_of(red_block, blue_block)`), used in reports and episode files.
    pub fn label(&self) -> String {
        match self {
            Goal::InZone { object, zone } => format!("in_zone({object}, {zone})"),
            Goal::InContainer { object, container } => {
                format!("in_container({object}, {container})")
            }
            Goal::OnTopOf { object, support } => format!("on_top_of({object}, {support})"),
            Goal::Stacked { order } => format!("stacked({})", order.join(", ")),
            Goal::WithinDistance {
                object,
                target,
                point,
                distance,
            } => match (target, point) {
                (Some(t), _) => format!("within_distance({object}, {t}, {distance})"),
                (None, Some(p)) => format!("within_distance({object}, {p:?}, {distance})"),
                (None, None) => format!("within_distance({object}, ?, {distance})"),
            },
            Goal::PoseWithin {
                object,
                position,
                relative_to: Some(anchor),
                ..
            } => format!(
                "pose_within({object}, ({}, {}) from {anchor})",
                position[0], position[1]
            ),
            Goal::PoseWithin {
                object,
                position,
                planar: true,
                ..
            } => format!(
                "pose_within({object}, at ({}, {}))",
                position[0], position[1]
            ),
            Goal::PoseWithin { object, .. } => format!("pose_within({object})"),
            Goal::AnyOf { any } => format!(
                "any_of({})",
                any.iter().map(Goal::label).collect::<Vec<_>>().join(" | ")
            ),
            Goal::JointPosition {
                object,
                joint,
                min,
                max,
            } => match (min, max) {
                (Some(lo), Some(hi)) => format!("joint_position({object}.{joint} in [{lo}, {hi}])"),
                (Some(lo), None) => format!("joint_position({object}.{joint} >= {lo})"),
                (None, Some(hi)) => format!("joint_position({object}.{joint} <= {hi})"),
                (None, None) => format!("joint_position({object}.{joint})"),
            },
            Goal::Lifted { object, height } => format!("lifted({object}, {height})"),
            Goal::PileInZone {
                pile,
                zone,
                fraction,
            } => format!("pile_in_zone({pile}, {zone}, {fraction})"),
        }
    }
}

/// Per-seed variation of the initial state. Zero everywhere by default.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Variations {
    /// Uniform jitter (± m, in x and y) added to every non-fixed object's initial position.
    #[serde(default)]
    pub position_jitter: f64,
    /// Uniform jitter (± degrees) added to every non-fixed object's initial yaw.
    #[serde(default)]
    pub yaw_jitter_deg: f64,
    /// The palette `recolor`'s objects draw their colour from, uniformly per seed (rendering,
    /// captions and the policies that see them; physics ignores colour).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub colors: Vec<Color>,
    /// Objects whose colour is drawn from `colors` per seed: those the description does not name
    /// by colour (distractors), so that a new colour is a new variation of the same task.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub recolor: Vec<String>,
    /// Range of the end effector's start position.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ee_start: Option<PoseRange>,
}

/// A primitive of the oracle plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Primitive {
    /// Move above the object, descend, grasp, lift.
    Pick { object: String },
    /// Carry the grasped object over the target, lower it, release, retreat.
    Place { target: PlaceTarget },
    /// Turn the grasped object about z, where it is held up, until its yaw is `yaw_deg` (world,
    /// degrees) — modulo `symmetry_deg` where it looks the same turned by that much — the
    /// shorter way round.
    Turn {
        yaw_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        symmetry_deg: Option<f64>,
    },
    /// Sweep the object along the table to `to` (x, y).
    Push { object: String, to: [f64; 2] },
    /// Sweep a pile into a zone: strokes of the tool along the table from behind the pile to the
    /// zone, side by side across the pile's width, twice (the second time over what is still
    /// outside).
    Sweep { pile: String, zone: String },
    /// Grasp the moving link of `joint` of an articulated object from above, at the point of its
    /// top farthest from the joint (a handle, a lid's edge), carry it along the joint's motion to
    /// position `to` (rad or m), release, retreat.
    Actuate {
        object: String,
        joint: String,
        to: f64,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum PlaceTarget {
    /// On top of another object (read at the start of the place).
    On(String),
    /// At the centre of a zone.
    Zone(String),
    /// Inside a container object.
    Into(String),
    /// At a table position (x, y); the object rests on the table.
    At([f64; 2]),
    /// With the object's centre at a point (x, y, z) in the air, over a hook or a peg: the
    /// object is lowered there and let go.
    AtPoint([f64; 3]),
    /// At (x, y), in the world or, with `relative_to`, from that object's centre (world axes),
    /// lowered onto whatever lies under that spot (the table where nothing does): a place
    /// beside, on or across other objects.
    Spot {
        xy: [f64; 2],
        #[serde(default, skip_serializing_if = "Option::is_none")]
        relative_to: Option<String>,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub name: String,
    pub eye: [f64; 3],
    pub target: [f64; 3],
    #[serde(default = "default_fovy")]
    pub fovy_deg: f64,
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
    /// The direction that is up in the image (world frame); none: the world's z (its x when
    /// the camera looks straight up or down).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
}

fn default_fovy() -> f64 {
    56.0
}
fn default_width() -> u32 {
    640
}
fn default_height() -> u32 {
    480
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PhysicsSettings {
    /// Time step in seconds.
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Whether resting bodies may sleep (changes outcomes; recorded per task).
    #[serde(default)]
    pub sleeping: bool,
    /// Steps to settle the scene before the policy acts and after it finishes.
    #[serde(default = "default_settle")]
    pub settle_steps: u32,
    /// Upper bound on policy steps per episode.
    #[serde(default = "default_max_steps")]
    pub max_steps: u32,
}

fn default_dt() -> f64 {
    1.0 / 240.0
}
fn default_settle() -> u32 {
    120
}
fn default_max_steps() -> u32 {
    20_000
}

impl Default for PhysicsSettings {
    fn default() -> Self {
        Self {
            dt: default_dt(),
            sleeping: false,
            settle_steps: default_settle(),
            max_steps: default_max_steps(),
        }
    }
}

/// Accepted input formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Yaml,
    Json,
}

impl Format {
    /// From a file name's extension (`.yaml`, `.yml`, `.json`).
    pub fn from_path(path: &str) -> Option<Format> {
        let lower = path.to_ascii_lowercase();
        if lower.ends_with(".yaml") || lower.ends_with(".yml") {
            Some(Format::Yaml)
        } else if lower.ends_with(".json") {
            Some(Format::Json)
        } else {
            None
        }
    }
}

/// Parses and validates one task document. Errors carry the task id when one could be read, the
/// field path and the reason.
pub fn parse_task(text: &str, format: Format, origin: &str) -> Result<TaskSpec, SpecErrors> {
    // Read the id loosely first so that even a document that fails to parse is named by its task.
    let loose: Option<serde_json::Value> = match format {
        Format::Yaml => serde_yaml_ng::from_str(text).ok(),
        Format::Json => serde_json::from_str(text).ok(),
    };
    let task_id = loose
        .as_ref()
        .and_then(|v| v.get("id"))
        .and_then(|v| v.as_str())
        .map(str::to_owned)
        .or_else(|| id_from_lines(text));
    let fail = |path: String, reason: String| {
        SpecErrors(vec![SpecError {
            task: task_id.clone(),
            origin: origin.to_owned(),
            path,
            reason,
        }])
    };
    let spec: TaskSpec = match format {
        Format::Yaml => {
            // serde_yaml_ng 0.9 reads enums only as `!tags`; task files use the `{variant: value}`
            // maps that JSON and the JSON Schema use, so enums go through singleton maps.
            let mut track = serde_path_to_error::Track::new();
            let de = serde_path_to_error::Deserializer::new(
                serde_yaml_ng::Deserializer::from_str(text),
                &mut track,
            );
            serde_yaml_ng::with::singleton_map_recursive::deserialize(de).map_err(|e| {
                let path = track.path().to_string();
                fail(path.clone(), strip_path(&e.to_string(), &path))
            })?
        }
        Format::Json => {
            let mut de = serde_json::Deserializer::from_str(text);
            serde_path_to_error::deserialize(&mut de).map_err(|e| {
                let path = e.path().to_string();
                fail(path.clone(), strip_path(&e.inner().to_string(), &path))
            })?
        }
    };
    let mut spec = spec;
    // Asset paths are relative to the spec file: a spec read from a file with assets and no
    // origin of its own remembers where it was read.
    let has_assets = spec
        .scene
        .objects
        .iter()
        .any(|o| matches!(o.shape, Shape::Mesh { .. } | Shape::Urdf { .. }));
    if has_assets && spec.source.origin.is_none() && !origin.is_empty() {
        spec.source.origin = Some(origin.to_owned());
    }
    let errors = validate(&spec, origin);
    if errors.is_empty() {
        Ok(spec)
    } else {
        Err(SpecErrors(errors))
    }
}

/// serde_yaml_ng prefixes its messages with the path; the error carries the path on its own.
fn strip_path(message: &str, path: &str) -> String {
    match message.split_once(": ") {
        Some((head, rest)) if !head.is_empty() && path.starts_with(head) => rest.to_owned(),
        _ => message.to_owned(),
    }
}

/// The `id:` of a document too broken to parse, read line by line.
fn id_from_lines(text: &str) -> Option<String> {
    text.lines().find_map(|l| {
        let v = l
            .strip_prefix("id:")
            .or_else(|| l.trim_start().strip_prefix("\"id\":"))?;
        let v = v
            .trim()
            .trim_end_matches(',')
            .trim_matches(|c| c == '"' || c == '\'');
        (!v.is_empty()).then(|| v.to_owned())
    })
}

/// Half extents of a pile copy's upright box.
pub(crate) fn pile_half_extents(shape: &Shape) -> [f64; 3] {
    match shape {
        Shape::Box { half_extents } => *half_extents,
        Shape::Sphere { radius } => [*radius; 3],
        Shape::Cylinder {
            radius,
            half_height,
        } => [*radius, *radius, *half_height],
        _ => [0.01; 3],
    }
}

/// Whether `key` → `value` may fill a template (`Shape::Urdf::fill`, applied by
/// `urdf::fill_template`): a placeholder of capitals and `_` followed by digits, replaced by a
/// finite number or by a file name that stays in the URDF's folder (letters, digits, `_`, `-`,
/// `.` and `/`, no `..`), so that a fill can change sizes and name a mesh but never write markup.
pub fn check_fill(key: &str, value: &str) -> Result<(), String> {
    let letters = key.trim_end_matches(|c: char| c.is_ascii_digit());
    if letters.is_empty()
        || letters.len() == key.len()
        || !letters.starts_with(|c: char| c.is_ascii_uppercase())
        || !letters.chars().all(|c| c.is_ascii_uppercase() || c == '_')
        || key.len() > 32
    {
        return Err(format!(
            "'{key}' is not a template placeholder (capitals and '_', then digits)"
        ));
    }
    match value.parse::<f64>() {
        Ok(x) if x.is_finite() => return Ok(()),
        Ok(_) => return Err(format!("'{value}' is not a finite number")),
        Err(_) => {}
    }
    let plain = !value.is_empty()
        && value.len() <= 256
        && value
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/'))
        && !value.starts_with('/')
        && !value.split('/').any(|part| part == ".." || part.is_empty());
    if plain {
        Ok(())
    } else {
        Err(format!(
            "'{value}' is neither a finite number nor a plain file name inside the URDF's folder"
        ))
    }
}

/// Checks an asset path from its text alone (before touching the file system): not empty, not
/// absolute, and no `..` that climbs above the asset root.
pub fn check_asset_path(file: &str) -> Result<(), String> {
    if file.trim().is_empty() {
        return Err("must not be empty".into());
    }
    let p = std::path::Path::new(file);
    if p.is_absolute() || file.starts_with('/') || file.starts_with('\\') {
        return Err(format!(
            "'{file}' is absolute: asset paths are relative to the asset root"
        ));
    }
    let mut depth = 0i32;
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => depth -= 1,
            std::path::Component::Normal(_) => depth += 1,
            std::path::Component::CurDir => {}
            _ => depth = -1,
        }
        if depth < 0 {
            return Err(format!("'{file}' leaves the asset root"));
        }
    }
    Ok(())
}

/// The JSON Schema of task spec v1 (committed as `schema/task-spec-v1.schema.json`).
pub fn json_schema() -> serde_json::Value {
    serde_json::to_value(schemars::schema_for!(TaskSpec)).expect("schema serialises")
}

impl TaskSpec {
    /// Canonical JSON (struct field order, no whitespace): the form sent to workers and hashed.
    pub fn canonical_json(&self) -> String {
        serde_json::to_string(self).expect("task spec serialises")
    }

    /// SHA-256 of the canonical JSON, hex.
    pub fn spec_hash(&self) -> String {
        crate::hash::sha256_hex(self.canonical_json().as_bytes())
    }

    /// The asset root: `source.asset_root` (relative to the folder of `source.origin`), else
    /// that folder, else the working folder.
    pub fn asset_root(&self) -> std::path::PathBuf {
        let dir = self
            .source
            .origin
            .as_deref()
            .and_then(|o| std::path::Path::new(o).parent())
            .map(std::path::Path::to_path_buf)
            .unwrap_or_default();
        match &self.source.asset_root {
            Some(root) => dir.join(root),
            None => dir,
        }
    }

    /// Where an asset path of the spec points: inside [`TaskSpec::asset_root`].
    pub fn asset_path(&self, path: &str) -> std::path::PathBuf {
        let p = std::path::Path::new(path);
        if p.is_absolute() {
            return p.to_path_buf();
        }
        self.asset_root().join(p)
    }

    /// [`TaskSpec::asset_path`], checked on the file system: the file exists and, symbolic
    /// links followed, lies inside the asset root.
    pub fn resolve_asset(&self, path: &str) -> Result<std::path::PathBuf, String> {
        check_asset_path(path)?;
        let root = self.asset_root();
        let full = self.asset_path(path);
        let canonical = full.canonicalize().map_err(|e| {
            format!(
                "asset '{path}' not found under the asset root {}: {e}",
                root.display()
            )
        })?;
        let root_c = root
            .canonicalize()
            .map_err(|e| format!("asset root {}: {e}", root.display()))?;
        if !canonical.starts_with(&root_c) {
            return Err(format!(
                "'{path}' leads out of the asset root {} (to {})",
                root.display(),
                canonical.display()
            ));
        }
        crate::assets::check_allowed(&canonical)?;
        Ok(canonical)
    }

    /// Whether the task reads asset files (a mesh or URDF object).
    pub fn uses_asset_files(&self) -> bool {
        self.scene
            .objects
            .iter()
            .any(|o| matches!(o.shape, Shape::Mesh { .. } | Shape::Urdf { .. }))
    }

    /// Refuses a task that reads asset files from outside every one of `roots` (canonical
    /// folders the operator allowed): its asset root, however `source.asset_root` and
    /// `source.origin` make it, must lie inside one. What the spec's text says cannot widen
    /// the operator's boundary. The error names the field that set the root.
    pub fn check_asset_roots(&self, roots: &[std::path::PathBuf]) -> Result<(), (String, String)> {
        if roots.is_empty() || !self.uses_asset_files() {
            return Ok(());
        }
        let root = std::path::absolute(self.asset_root()).unwrap_or_else(|_| self.asset_root());
        let resolved = root
            .canonicalize()
            .unwrap_or_else(|_| crate::assets::lexical(&root));
        if roots.iter().any(|r| resolved.starts_with(r)) {
            return Ok(());
        }
        let field = if self.source.asset_root.is_some() {
            "source.asset_root"
        } else {
            "source.origin"
        };
        Err((
            field.to_owned(),
            format!(
                "the asset root {} is outside the folders the operator allowed ({}): a task \
                 cannot widen them; pass --asset-root to allow a folder",
                resolved.display(),
                roots
                    .iter()
                    .map(|r| r.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ))
    }

    /// `shape` with its file path made to point where [`TaskSpec::asset_path`] says, so that a
    /// renderer in another working folder finds it.
    pub fn resolved_shape(&self, shape: &Shape) -> Shape {
        match shape {
            Shape::Mesh {
                path,
                scale,
                collision,
            } => Shape::Mesh {
                path: self.asset_path(path).display().to_string(),
                scale: *scale,
                collision: *collision,
            },
            Shape::Urdf {
                path,
                joints,
                articulated,
                fill,
            } => Shape::Urdf {
                path: self.asset_path(path).display().to_string(),
                joints: joints.clone(),
                articulated: *articulated,
                fill: fill.clone(),
            },
            other => other.clone(),
        }
    }

    /// The spec as episode `seed` sees it: every object named in `variations.recolor` takes a
    /// colour drawn from `variations.colors`. The draw has a stream of its own, so a palette
    /// never moves the poses a seed draws. Borrowed when nothing is recoloured.
    pub fn for_seed(&self, seed: u64) -> std::borrow::Cow<'_, TaskSpec> {
        // A seed the generator's code laid out: its scene, goals and plan, nothing jittered.
        if let Some(laid) = self.with_layout(seed) {
            return match laid.for_seed(seed) {
                std::borrow::Cow::Owned(s) => std::borrow::Cow::Owned(s),
                std::borrow::Cow::Borrowed(_) => std::borrow::Cow::Owned(laid),
            };
        }
        let recolour = !self.variations.recolor.is_empty() && !self.variations.colors.is_empty();
        if !recolour && self.scene.piles.is_empty() {
            return std::borrow::Cow::Borrowed(self);
        }
        let mut spec = self.clone();
        if recolour {
            let mut rng = crate::rng::Rng::new(seed, &format!("{}/colors", self.id));
            let palette = &self.variations.colors;
            for o in &mut spec.scene.objects {
                if self.variations.recolor.contains(&o.id) {
                    o.color =
                        Some(palette[(rng.next_u64() % palette.len() as u64) as usize].clone());
                }
            }
        }
        // Piles become their copies, laid out for this seed (their own random stream).
        let mut rng = crate::rng::Rng::new(seed, &format!("{}/piles", self.id));
        for pile in &self.scene.piles {
            // Already laid out (a spec that went through here before).
            if self.object(&format!("{}_0", pile.id)).is_some() {
                continue;
            }
            let half = pile_half_extents(&pile.shape);
            let cell = 2.0 * half[0].max(half[1]) + 0.004;
            let [x0, y0] = pile.region.min;
            let [x1, y1] = pile.region.max;
            let cols = (((x1 - x0) / cell).floor() as u32).max(1);
            let rows = (((y1 - y0) / cell).floor() as u32).max(1);
            let slack = (cell - 2.0 * half[0].max(half[1])) / 2.0;
            for k in 0..pile.count {
                // Saturating: a region of 1e308 m has u32::MAX columns and rows (found by
                // core/tests/fuzz.rs); a pile of at most MAX_PILE copies fits one layer then.
                let per_layer = cols.saturating_mul(rows);
                let (layer, at) = (k / per_layer, k % per_layer);
                let (cx, cy) = (at % cols, at / cols);
                let x = x0 + cell * (f64::from(cx) + 0.5) + rng.uniform(-slack, slack);
                let y = y0 + cell * (f64::from(cy) + 0.5) + rng.uniform(-slack, slack);
                let z = half[2] + f64::from(layer) * (2.0 * half[2] + 0.002);
                spec.scene.objects.push(Object {
                    id: format!("{}_{k}", pile.id),
                    shape: pile.shape.clone(),
                    color: pile.color.clone(),
                    mass: Some(pile.mass.unwrap_or(0.01)),
                    is_fixed: false,
                    pose: Some(Pose {
                        position: [x, y, z],
                        yaw_deg: rng.uniform(0.0, 90.0),
                    }),
                    pose_range: None,
                });
            }
        }
        std::borrow::Cow::Owned(spec)
    }

    /// The layout of `seed`, if the spec has one without an error.
    pub fn layout(&self, seed: u64) -> Option<&Layout> {
        self.layouts
            .iter()
            .find(|l| l.seed == seed && l.error.is_none() && l.scene.is_some())
    }

    /// The spec on `seed` with its layout in place (no layouts left, no position or yaw
    /// jitter); `None` where the spec has no layout for `seed`.
    pub fn with_layout(&self, seed: u64) -> Option<TaskSpec> {
        let l = self.layout(seed)?;
        let mut spec = TaskSpec {
            layouts: Vec::new(),
            scene: l.scene.clone()?,
            // Left out where they are the spec's own.
            goals: if l.goals.is_empty() {
                self.goals.clone()
            } else {
                l.goals.clone()
            },
            oracle: if l.oracle.is_empty() {
                self.oracle.clone()
            } else {
                l.oracle.clone()
            },
            reward_steps: if l.reward_steps.is_empty() {
                self.reward_steps.clone()
            } else {
                l.reward_steps.clone()
            },
            ..self.clone_without_layouts()
        };
        spec.variations.position_jitter = 0.0;
        spec.variations.yaw_jitter_deg = 0.0;
        Some(spec)
    }

    /// A copy without the layouts (they may be large).
    fn clone_without_layouts(&self) -> TaskSpec {
        let layouts = Vec::new();
        let TaskSpec {
            spec_version,
            id,
            name,
            description,
            source,
            group,
            scene,
            end_effector,
            arm,
            goals,
            variations,
            oracle,
            cameras,
            physics,
            layouts: _,
            reward_steps,
        } = self;
        TaskSpec {
            spec_version: *spec_version,
            id: id.clone(),
            name: name.clone(),
            description: description.clone(),
            source: source.clone(),
            group: group.clone(),
            scene: scene.clone(),
            end_effector: end_effector.clone(),
            arm: arm.clone(),
            goals: goals.clone(),
            variations: variations.clone(),
            oracle: oracle.clone(),
            cameras: cameras.clone(),
            physics: physics.clone(),
            layouts,
            reward_steps: reward_steps.clone(),
        }
    }

    /// Why an episode on `seed` cannot run: the spec has layouts, and none for `seed`, or the
    /// one it has is an error. `None` when it can.
    pub fn seed_unavailable(&self, seed: u64) -> Option<String> {
        if self.layouts.is_empty() || self.layout(seed).is_some() {
            return None;
        }
        if let Some(e) = self
            .layouts
            .iter()
            .find(|l| l.seed == seed)
            .and_then(|l| l.error.as_ref())
        {
            return Some(format!("seed {seed}: {e}"));
        }
        Some(format!(
            "seed {seed} has no layout: the task's layouts were recorded from its code on seeds {} only (import it again with those seeds)",
            seed_ranges(self.layouts.iter().map(|l| l.seed))
        ))
    }

    /// The ids of pile `id`'s copies (objects of a spec from [`TaskSpec::for_seed`]).
    pub fn pile_copies(&self, id: &str) -> Vec<String> {
        self.scene
            .piles
            .iter()
            .filter(|p| p.id == id)
            .flat_map(|p| (0..p.count).map(move |k| format!("{}_{k}", p.id)))
            .collect()
    }

    pub fn object(&self, id: &str) -> Option<&Object> {
        self.scene.objects.iter().find(|o| o.id == id)
    }

    pub fn zone(&self, id: &str) -> Option<&Zone> {
        self.scene.zones.iter().find(|z| z.id == id)
    }
}

/// Seeds as ranges: `0–19, 1000000–1000002`.
pub fn seed_ranges(seeds: impl IntoIterator<Item = u64>) -> String {
    let mut seeds: Vec<u64> = seeds.into_iter().collect();
    seeds.sort_unstable();
    seeds.dedup();
    let mut parts: Vec<String> = Vec::new();
    let mut k = 0;
    while k < seeds.len() {
        let start = seeds[k];
        let mut end = start;
        while k + 1 < seeds.len() && seeds[k + 1] == end + 1 {
            k += 1;
            end = seeds[k];
        }
        parts.push(if end == start {
            start.to_string()
        } else {
            format!("{start}–{end}")
        });
        k += 1;
    }
    parts.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = assay_testkit::tasks::PUT_BLOCK_IN_ZONE;

    fn errors(text: &str) -> Vec<SpecError> {
        parse_task(text, Format::Yaml, "t.yaml").unwrap_err().0
    }

    #[test]
    fn a_minimal_task_parses_and_round_trips_through_json() {
        let spec = parse_task(MINIMAL, Format::Yaml, "t.yaml").unwrap();
        let again = parse_task(&spec.canonical_json(), Format::Json, "t.json").unwrap();
        assert_eq!(spec, again);
        assert_eq!(spec.spec_hash(), again.spec_hash());
    }

    /// A spec laid out per seed: a laid-out seed runs its own scene, goals and plan with no
    /// jitter; a seed whose layout is an error, or that has none, cannot run and says why; a
    /// layout validates as the spec does, its errors under `layouts[i]`.
    #[test]
    fn a_seed_laid_out_runs_its_own_scene_and_others_say_why_they_cannot_run() {
        let mut spec = parse_task(MINIMAL, Format::Yaml, "t.yaml").unwrap();
        spec.variations.position_jitter = 0.01;
        let mut scene = spec.scene.clone();
        scene.objects[0].pose.as_mut().unwrap().position = [0.4, 0.2, 0.02];
        spec.layouts = vec![
            Layout {
                seed: 3,
                error: None,
                scene: Some(scene.clone()),
                goals: spec.goals.clone(),
                oracle: spec.oracle.clone(),
                reward_steps: Vec::new(),
            },
            Layout {
                seed: 4,
                error: Some("the task's reset() on this seed: reset: raised ValueError".into()),
                scene: None,
                goals: Vec::new(),
                oracle: Vec::new(),
                reward_steps: Vec::new(),
            },
        ];
        assert!(validate(&spec, "t.yaml").is_empty());
        // Goals, plan and reward left out of a layout are the spec's own.
        let mut bare = spec.clone();
        bare.layouts[0].goals.clear();
        bare.layouts[0].oracle.clear();
        assert_eq!(bare.for_seed(3).goals, spec.goals);
        assert_eq!(bare.for_seed(3).oracle, spec.oracle);
        assert!(validate(&bare, "t.yaml").is_empty());
        let laid = spec.for_seed(3);
        assert_eq!(laid.scene, scene);
        assert_eq!(laid.variations.position_jitter, 0.0);
        assert!(laid.layouts.is_empty());
        assert_eq!(laid.seed_unavailable(3), None);
        assert_eq!(spec.seed_unavailable(3), None);
        let failed = spec.seed_unavailable(4).unwrap();
        assert!(
            failed.starts_with("seed 4: ") && failed.contains("ValueError"),
            "{failed}"
        );
        let missing = spec.seed_unavailable(7).unwrap();
        assert!(
            missing.contains("seed 7 has no layout") && missing.contains("seeds 3–4"),
            "{missing}"
        );
        // Not laid out at all: every seed runs.
        assert_eq!(
            parse_task(MINIMAL, Format::Yaml, "t.yaml")
                .unwrap()
                .seed_unavailable(7),
            None
        );
        // The layouts are part of what is hashed.
        let mut other = spec.clone();
        other.layouts[0].scene.as_mut().unwrap().objects[0]
            .pose
            .as_mut()
            .unwrap()
            .position[0] = 0.41;
        assert_ne!(other.spec_hash(), spec.spec_hash());

        let mut bad = spec.clone();
        bad.layouts[0].goals = vec![Goal::InZone {
            object: "ghost".into(),
            zone: "goal".into(),
        }];
        bad.layouts[1].scene = Some(scene);
        bad.layouts.push(bad.layouts[0].clone());
        let es = validate(&bad, "t.yaml");
        for path in [
            "layouts[0].goals[0].in_zone.object",
            "layouts[1]",
            "layouts[2].seed",
        ] {
            assert!(es.iter().any(|e| e.path == path), "{path}: {es:?}");
        }
        assert_eq!(
            seed_ranges([0, 1, 2, 5, 1_000_000, 1_000_001]),
            "0–2, 5, 1000000–1000001"
        );
    }

    /// Finite but absurd numbers that used to validate and give plausible wrong statistics.
    #[test]
    fn absurd_but_finite_numbers_are_refused_with_the_field_and_the_bound() {
        let obj = "scene.objects[0]";
        for (from, to, path, bound) in [
            (
                "position: [0.5, 0.1, 0.02]",
                "position: [1e308, 0.1, 0.02]",
                format!("{obj}.pose.position[0]"),
                "within ±10 m of the origin, got 1e308",
            ),
            (
                "[0.02, 0.02, 0.02]",
                "[1e308, 0.02, 0.02]",
                format!("{obj}.shape.box.half_extents[0]"),
                "between 0.001 and 5 m",
            ),
            (
                "[0.02, 0.02, 0.02]",
                "[1e-308, 0.02, 0.02]",
                format!("{obj}.shape.box.half_extents[0]"),
                "between 0.001 and 5 m, got 1e-308",
            ),
            (
                "color: red,",
                "color: red, mass: 1e9,",
                format!("{obj}.mass"),
                "between 0.001 and 1000 kg",
            ),
            (
                "goals:\n",
                "variations: {position_jitter: 3}\ngoals:\n",
                "variations.position_jitter".to_owned(),
                "between 0 and 0.5 m",
            ),
        ] {
            let errors = errors(&MINIMAL.replacen(from, to, 1));
            assert!(
                errors
                    .iter()
                    .any(|e| e.path == path && e.reason.contains(bound)),
                "{path}: {errors:?}"
            );
        }
    }

    #[test]
    fn problems_name_the_task_the_field_and_the_reason() {
        let e = &errors(&MINIMAL.replace("[0.02, 0.02, 0.02]", "[0.02, -0.02, 0.02]"))[0];
        assert_eq!(
            (e.task.as_deref(), e.path.as_str()),
            (
                Some("put-block-in-zone"),
                "scene.objects[0].shape.box.half_extents[1]"
            )
        );
        assert!(e.reason.contains("between 0.001 and 5 m, got -0.02"), "{e}");

        let e = &errors(&MINIMAL.replace("color: red,", "colour: red,"))[0];
        assert!(
            e.path.ends_with("colour") && e.reason.contains("unknown field"),
            "{e:?}"
        );

        let e = &errors(&MINIMAL.replace("[0.5, 0.1, 0.02]", "[.nan, 0.1, 0.02]"))[0];
        assert_eq!(e.path, "scene.objects[0].pose.position[0]");

        let es = errors(&MINIMAL.replace("zone: goal}\noracle", "zone: nowhere}\noracle"));
        assert!(
            es.iter()
                .any(|e| e.path == "goals[0].in_zone.zone" && e.reason.contains("nowhere")),
            "{es:?}"
        );

        let es = errors(&MINIMAL.replace("  - place: {target: {zone: goal}}\n", ""));
        assert!(
            es.iter()
                .any(|e| e.path == "oracle" && e.reason.contains("holding")),
            "{es:?}"
        );

        // A document too broken to parse is still named by its id.
        let e = &errors("id: broken-task\nscene: [unclosed\n")[0];
        assert_eq!(e.task.as_deref(), Some("broken-task"));
    }

    /// MINIMAL with a blue distractor that draws its colour per seed.
    fn recoloured(variations: &str) -> String {
        MINIMAL.replace(
            "  zones:",
            "    - {id: distractor, shape: {sphere: {radius: 0.02}}, color: blue, pose: {position: [0.4, 0.2, 0.02]}}\n  zones:",
        ) + variations
    }

    #[test]
    fn recoloured_objects_draw_from_the_palette_per_seed_and_nothing_else_changes() {
        let spec = parse_task(
            &recoloured("variations: {colors: [orange, purple, cyan], recolor: [distractor]}\n"),
            Format::Yaml,
            "t.yaml",
        )
        .unwrap();
        let colors: Vec<Color> = (0..40)
            .map(|seed| {
                let s = spec.for_seed(seed);
                // The block the description names keeps its colour; only the distractor varies.
                assert_eq!(s.scene.objects[0], spec.scene.objects[0]);
                let mut rest = s.clone().into_owned();
                rest.scene.objects[1].color = spec.scene.objects[1].color.clone();
                assert_eq!(rest, spec);
                s.scene.objects[1].color.clone().expect("a drawn colour")
            })
            .collect();
        for c in ["orange", "purple", "cyan"] {
            assert!(colors.contains(&Color::Named(c.into())), "{c} never drawn");
        }
        assert!(!colors.contains(&Color::Named("blue".into())));
        // The same seed, the same colours.
        assert_eq!(spec.for_seed(7), spec.for_seed(7));
        // Without a palette the spec is lent as it is.
        let plain = parse_task(MINIMAL, Format::Yaml, "t.yaml").unwrap();
        assert!(matches!(plain.for_seed(3), std::borrow::Cow::Borrowed(_)));
    }

    #[test]
    fn a_palette_without_objects_or_objects_without_a_palette_are_errors() {
        let es = errors(&recoloured("variations: {colors: [orange]}\n"));
        assert!(
            es.iter()
                .any(|e| e.path == "variations.colors" && e.reason.contains("recolor")),
            "{es:?}"
        );
        let es = errors(&recoloured("variations: {recolor: [distractor]}\n"));
        assert!(es.iter().any(|e| e.path == "variations.recolor"), "{es:?}");
        let es = errors(&recoloured(
            "variations: {colors: [orange, mauve], recolor: [distractor, ghost]}\n",
        ));
        assert!(
            es.iter()
                .any(|e| e.path == "variations.colors[1]" && e.reason.contains("mauve")),
            "{es:?}"
        );
        assert!(
            es.iter()
                .any(|e| e.path == "variations.recolor[1]" && e.reason.contains("ghost")),
            "{es:?}"
        );
    }

    #[test]
    fn asset_paths_that_leave_the_asset_root_are_errors_from_their_text() {
        let with = |path: &str| {
            MINIMAL.replace(
                "  zones:",
                &format!("    - {{id: thing, shape: {{mesh: {{path: \"{path}\"}}}}, pose: {{position: [0.4, 0.2, 0.02]}}}}\n  zones:"),
            )
        };
        for (path, reason) in [
            ("/etc/thing.obj", "is absolute"),
            ("../thing.obj", "leaves the asset root"),
            ("meshes/../../thing.obj", "leaves the asset root"),
            ("", "must not be empty"),
        ] {
            let es = errors(&with(path));
            assert!(
                es.iter()
                    .any(|e| e.path == "scene.objects[1].shape.mesh.path"
                        && e.reason.contains(reason)),
                "{path}: {es:?}"
            );
        }
        // Inside the root, `..` that does not climb out is fine; the file is checked by the sim.
        let spec = parse_task(&with("meshes/../thing.obj"), Format::Yaml, "dir/t.yaml").unwrap();
        assert_eq!(spec.source.origin.as_deref(), Some("dir/t.yaml"));
        assert_eq!(
            spec.asset_path("thing.obj"),
            std::path::Path::new("dir/thing.obj")
        );
        let err = spec.resolve_asset("meshes/../thing.obj").unwrap_err();
        assert!(err.contains("not found under the asset root dir"), "{err}");
    }

    #[test]
    fn joint_goals_and_actuate_need_an_articulated_urdf_and_lifted_may_end_holding() {
        let text = MINIMAL
            .replace(
                "  zones:",
                "    - {id: box, fixed: true, shape: {urdf: {path: box.urdf}}, pose: {position: [0.4, 0.2, 0.1]}}\n  zones:",
            )
            .replace(
                "  - in_zone: {object: red_block, zone: goal}",
                "  - joint_position: {object: box, joint: lid, min: 1.0, max: 0.5}\n  - joint_position: {object: red_block, joint: lid}",
            )
            .replace(
                "  - pick: {object: red_block}\n  - place: {target: {zone: goal}}",
                "  - actuate: {object: box, joint: lid, to: 1.2}\n  - pick: {object: red_block}",
            );
        let es = errors(&text);
        let has = |path: &str, reason: &str| {
            assert!(
                es.iter()
                    .any(|e| e.path == path && e.reason.contains(reason)),
                "{path}: {reason} in {es:?}"
            )
        };
        has("goals[0].joint_position.object", "not an articulated URDF");
        has("goals[0].joint_position", "min 1 exceeds max 0.5");
        has("goals[1].joint_position", "give min, max or both");
        has("oracle[0].actuate.object", "not an articulated URDF");
        has("oracle", "ends holding an object");
        // Articulated, consistent, and the plan ends holding what a lifted goal names.
        let ok = text
            .replace(
                "urdf: {path: box.urdf}",
                "urdf: {path: box.urdf, articulated: true}",
            )
            .replace("min: 1.0, max: 0.5", "min: 1.0")
            .replace(
                "  - joint_position: {object: red_block, joint: lid}",
                "  - lifted: {object: red_block, height: 0.1}",
            );
        let spec = parse_task(&ok, Format::Yaml, "t.yaml").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(spec.goals[0].label(), "joint_position(box.lid >= 1)");
        assert_eq!(spec.goals[1].label(), "lifted(red_block, 0.1)");
    }

    #[test]
    fn a_pile_in_a_huge_region_is_laid_out_without_overflow() {
        // Found by core/tests/fuzz.rs: u32::MAX columns times u32::MAX rows overflowed.
        let text = MINIMAL.replace(
            "  zones:",
            "  piles:\n    - {id: bean, count: 30, shape: {box: {half_extents: [0.006, 0.006, 0.006]}}, color: brown, region: {min: [-1e308, -1e308], max: [1e308, 1e308]}}\n  zones:",
        );
        // Validation refuses the region, naming the field and the bound...
        let e = parse_task(&text, Format::Yaml, "t.yaml").unwrap_err();
        assert!(
            e.0.iter()
                .any(|e| e.path == "scene.piles[0].region.min[0]"
                    && e.reason.contains("within ±10 m")),
            "{e}"
        );
        // ...and the layout itself still does not overflow on one.
        let small = text
            .replace("-1e308, -1e308", "0.3, -0.05")
            .replace("1e308, 1e308", "0.4, 0.05");
        let mut spec = parse_task(&small, Format::Yaml, "t.yaml").unwrap_or_else(|e| panic!("{e}"));
        let pile = spec.scene.piles.first_mut().expect("a pile");
        pile.region.min = [-1e308, -1e308];
        pile.region.max = [1e308, 1e308];
        assert_eq!(spec.for_seed(1).scene.objects.len(), 31);
    }

    #[test]
    fn a_pile_is_laid_out_per_seed_as_copies_that_do_not_overlap() {
        let text = MINIMAL.replace(
            "  zones:",
            "  piles:\n    - {id: bean, count: 30, shape: {box: {half_extents: [0.006, 0.006, 0.006]}}, color: brown, region: {min: [0.3, -0.05], max: [0.4, 0.05]}}\n  zones:",
        ).replace(
            "  - in_zone: {object: red_block, zone: goal}",
            "  - in_zone: {object: red_block, zone: goal}\n  - pile_in_zone: {pile: bean, zone: goal, fraction: 0.8}",
        );
        let spec = parse_task(&text, Format::Yaml, "t.yaml").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            spec.scene.objects.len(),
            1,
            "the submitted spec keeps the pile as one entry"
        );
        let a = spec.for_seed(1);
        assert_eq!(a.scene.objects.len(), 31);
        assert_eq!(a.pile_copies("bean").len(), 30);
        assert!(a.object("bean_29").is_some() && a.object("bean_30").is_none());
        // Inside the region, resting on the table or on the layer below, never overlapping.
        let at: Vec<[f64; 3]> = a.scene.objects[1..]
            .iter()
            .map(|o| o.pose.unwrap().position)
            .collect();
        for (i, p) in at.iter().enumerate() {
            assert!(
                (0.3..=0.4).contains(&p[0]) && (-0.05..=0.05).contains(&p[1]),
                "{p:?}"
            );
            assert!((p[2] - 0.006).abs() < 1e-9 || p[2] > 0.012, "{p:?}");
            for q in &at[i + 1..] {
                let apart = (p[0] - q[0])
                    .abs()
                    .max((p[1] - q[1]).abs())
                    .max((p[2] - q[2]).abs());
                assert!(apart >= 0.0119, "{p:?} and {q:?} overlap");
            }
        }
        // The same seed lays it out the same way; another seed differently; laying it out again
        // adds nothing.
        assert_eq!(spec.for_seed(1).scene.objects, a.scene.objects);
        assert_ne!(spec.for_seed(2).scene.objects, a.scene.objects);
        assert_eq!(a.for_seed(1).scene.objects.len(), 31);

        for (bad, path, reason) in [
            ("count: 30", "scene.piles[0].count", "must lie in 1..=200"),
            (
                "fraction: 0.8",
                "goals[1].pile_in_zone.fraction",
                "must lie in (0, 1]",
            ),
        ] {
            let broken = text.replace(
                bad,
                if bad.starts_with("count") {
                    "count: 0"
                } else {
                    "fraction: 1.5"
                },
            );
            let es = errors(&broken);
            assert!(
                es.iter()
                    .any(|e| e.path == path && e.reason.contains(reason)),
                "{path}: {es:?}"
            );
        }
        let es = errors(&text.replace("pile: bean", "pile: rice"));
        assert!(
            es.iter()
                .any(|e| e.path == "goals[1].pile_in_zone.pile" && e.reason.contains("rice")),
            "{es:?}"
        );
    }

    #[test]
    fn the_committed_json_schema_is_current() {
        let committed = include_str!("../../../../../schema/task-spec-v1.schema.json");
        let committed: serde_json::Value = serde_json::from_str(committed).unwrap();
        assert_eq!(
            committed,
            json_schema(),
            "regenerate with: assay schema > schema/task-spec-v1.schema.json"
        );
    }
}
