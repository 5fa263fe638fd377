//! Episode recording: Arrow IPC files, one per episode, readable from Python
//! (`pyarrow.ipc.open_file(path).read_all()`). The schema is documented in `docs/episode-format.md`.

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int16Array, RecordBatch, UInt32Array,
};
use arrow_schema::{DataType, Field, Schema};
use assay_spec::scene::{SceneSnapshot, SnapshotBox, SnapshotObject};
use assay_spec::spec::TaskSpec;
use rapier3d::prelude::*;

use crate::SimError;
use crate::scene::SimScene;

pub const EPISODE_FORMAT_VERSION: &str = "1";

/// Whether a recorded roll or pitch (rad) tilts the tool: more than the arm's inverse
/// kinematics leaves of a tool held pointing down.
fn tilted(angle: f32) -> bool {
    angle.abs() > 1e-3
}

/// Per-step rows, column by column.
#[derive(Default)]
pub struct Recorder {
    step: Vec<u32>,
    time: Vec<f64>,
    ee: [Vec<f32>; 3],
    cmd: [Vec<f32>; 3],
    grasped: Vec<i16>,
    contact_pairs: Vec<u32>,
    contact_points: Vec<u32>,
    ee_contact: Vec<bool>,
    /// The tool's turn from pointing down as roll, pitch and yaw (rad; see
    /// [`crate::tabletop::turn_of_rpy`]): 0 unless a policy turns it.
    ee_turn: [Vec<f32>; 3],
    /// Per object: x, y, z, qx, qy, qz, qw.
    objects: Vec<[Vec<f32>; 7]>,
    /// Per object: each moving joint's name and position (articulated objects only).
    joints: Vec<Vec<(String, Vec<f32>)>>,
    /// A friction gripper's pads: the gap between them and their yaw (empty without pads).
    fingers: [Vec<f32>; 2],
    /// The arm's joints: name and position (empty without an arm).
    arm: Vec<(String, Vec<f32>)>,
    /// The arm as drawn in snapshots, read once from its URDF.
    drawn_arm: std::cell::OnceCell<Option<crate::arm::Arm>>,
}

impl Recorder {
    pub fn new(objects: usize) -> Self {
        Self {
            objects: (0..objects).map(|_| Default::default()).collect(),
            joints: vec![Vec::new(); objects],
            ..Default::default()
        }
    }

    pub fn rows(&self) -> usize {
        self.step.len()
    }

    pub fn step_at(&self, row: usize) -> u32 {
        self.step[row]
    }

    /// The tool centre recorded at `row` (`ee`).
    pub fn ee_at(&self, row: usize) -> [f32; 3] {
        [self.ee[0][row], self.ee[1][row], self.ee[2][row]]
    }

    /// The commanded tool centre recorded at `row` (`ee_cmd`): the position target the tool was
    /// sent to for the physics step that ended at this row.
    pub fn cmd_at(&self, row: usize) -> [f32; 3] {
        [self.cmd[0][row], self.cmd[1][row], self.cmd[2][row]]
    }

    /// The held object recorded at `row` (`grasped`), or -1.
    pub fn grasped_at(&self, row: usize) -> i16 {
        self.grasped[row]
    }

    /// The tool's turn from pointing down recorded at `row` (`ee_roll`, `ee_pitch`, `ee_yaw`;
    /// 0 in files without the columns).
    pub fn turn_at(&self, row: usize) -> Rotation {
        crate::tabletop::turn_of_rpy(
            self.ee_turn
                .each_ref()
                .map(|c| c.get(row).copied().unwrap_or(0.0)),
        )
    }

    /// The gap between a friction gripper's pads at `row` (m), or `None` without pads.
    pub fn opening_at(&self, row: usize) -> Option<f32> {
        self.fingers[0].get(row).copied()
    }

    /// The arm's joint positions at `row` (rad; empty without an arm).
    pub fn arm_at(&self, row: usize) -> Vec<f64> {
        self.arm.iter().map(|(_, c)| f64::from(c[row])).collect()
    }

    /// The recorded state of `row` as a scene a camera can draw.
    pub fn snapshot(&self, row: usize, spec: &TaskSpec) -> SceneSnapshot {
        let turn = self.turn_at(row);
        snapshot_of(
            spec,
            self.objects.iter().map(|c| {
                (
                    [c[0][row], c[1][row], c[2][row]],
                    [c[3][row], c[4][row], c[5][row], c[6][row]],
                )
            }),
            [self.ee[0][row], self.ee[1][row], self.ee[2][row]],
            turn,
            |i| {
                self.joints[i]
                    .iter()
                    .map(|(name, q)| (name.clone(), f64::from(q[row])))
                    .collect()
            },
            // The pads' turn on the tool is their recorded yaw less the tool's.
            (!self.fingers[0].is_empty()).then(|| {
                let on_tool =
                    self.fingers[1][row] - self.ee_turn[2].get(row).copied().unwrap_or(0.0);
                (
                    self.fingers[0][row],
                    turn * Rotation::from_rotation_z(on_tool),
                )
            }),
            self.drawn_arm
                .get_or_init(|| {
                    let a = spec.arm.as_ref()?;
                    crate::arm::Arm::new(&a.model, a.base, a.base_yaw_deg).ok()
                })
                .as_ref()
                .map_or_else(Vec::new, |arm| arm.boxes_at(&self.arm_at(row))),
        )
    }

    pub fn record(
        &mut self,
        scene: &SimScene,
        step: u32,
        time: f64,
        command: Vec3,
        grasped: Option<usize>,
    ) {
        self.step.push(step);
        self.time.push(time);
        let ee = scene.gripper_position();
        for k in 0..3 {
            self.ee[k].push(ee[k]);
            self.cmd[k].push(command[k]);
        }
        self.grasped.push(grasped.map(|g| g as i16).unwrap_or(-1));
        let (pairs, points, ee_touch) = contact_summary(scene);
        self.contact_pairs.push(pairs);
        self.contact_points.push(points);
        self.ee_contact.push(ee_touch);
        // The yaw as before turns existed while the tool points down (within the inverse
        // kinematics' residual); Euler angles that recompose the turn once it tilts.
        let [roll, pitch, yaw] = crate::tabletop::rpy_of_turn(scene.tool_turn());
        let yaw = if tilted(roll) || tilted(pitch) {
            yaw
        } else {
            scene.tool_yaw()
        };
        for (col, v) in self.ee_turn.iter_mut().zip([roll, pitch, yaw]) {
            col.push(v);
        }
        for (o, cols) in scene.objects.iter().zip(self.objects.iter_mut()) {
            let p = scene.pose(o);
            let t = p.translation;
            let q = p.rotation;
            for (k, v) in [t.x, t.y, t.z, q.x, q.y, q.z, q.w].into_iter().enumerate() {
                cols[k].push(v);
            }
        }
        if let Some(arm) = &scene.arm {
            if self.arm.is_empty() {
                self.arm = arm
                    .joint_names()
                    .into_iter()
                    .map(|n| (n, Vec::new()))
                    .collect();
            }
            for ((_, col), q) in self.arm.iter_mut().zip(&arm.q) {
                col.push(*q as f32);
            }
        }
        if let Some(f) = &scene.fingers {
            self.fingers[0].push(f.opening(&scene.world));
            self.fingers[1].push(f.world_yaw(&scene.world));
        }
        for (o, cols) in scene.objects.iter().zip(self.joints.iter_mut()) {
            if cols.is_empty() {
                cols.extend(o.joints.iter().map(|j| (j.name.clone(), Vec::new())));
            }
            for (j, (_, col)) in o.joints.iter().zip(cols.iter_mut()) {
                col.push(j.position(&scene.world) as f32);
            }
        }
    }

    /// Reads an episode file ([`Recorder::encode`]'s output) back: its rows and its schema
    /// metadata. Every column the file format names is read by name; a file without one of the
    /// required columns, or with a column of another type, is refused naming it.
    pub fn decode(file: &[u8]) -> Result<(Self, HashMap<String, String>), SimError> {
        let bad = |what: String| SimError::internal(format!("episode file: {what}"));
        let reader = arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(file), None)
            .map_err(|e| bad(e.to_string()))?;
        let schema = reader.schema();
        let metadata = schema.metadata().clone();
        let objects: Vec<String> = serde_json::from_str(
            metadata
                .get("assay.objects")
                .ok_or_else(|| bad("no assay.objects in its metadata".into()))?,
        )
        .map_err(|e| bad(format!("assay.objects: {e}")))?;
        let names: Vec<String> = schema.fields().iter().map(|f| f.name().clone()).collect();
        let mut rec = Recorder::new(objects.len());
        for (id, cols) in objects.iter().zip(rec.joints.iter_mut()) {
            let prefix = format!("{id}.joint.");
            cols.extend(
                names
                    .iter()
                    .filter_map(|n| n.strip_prefix(&prefix))
                    .map(|j| (j.to_owned(), Vec::new())),
            );
        }
        rec.arm = names
            .iter()
            .filter_map(|n| n.strip_prefix("arm."))
            .map(|j| (j.to_owned(), Vec::new()))
            .collect();
        let has = |n: &str| names.iter().any(|x| x == n);
        let fingers = has("gripper_opening");
        let turns = ["ee_roll", "ee_pitch", "ee_yaw"].map(has);
        for batch in reader {
            let batch = batch.map_err(|e| bad(e.to_string()))?;
            let f32s = |name: &str, into: &mut Vec<f32>| -> Result<(), SimError> {
                into.extend(column::<Float32Array>(&batch, name, "float32")?.values());
                Ok(())
            };
            rec.step
                .extend(column::<UInt32Array>(&batch, "step", "uint32")?.values());
            rec.time
                .extend(column::<Float64Array>(&batch, "time_s", "float64")?.values());
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                f32s(&format!("ee_{axis}"), &mut rec.ee[k])?;
                f32s(&format!("ee_cmd_{axis}"), &mut rec.cmd[k])?;
            }
            rec.grasped
                .extend(column::<Int16Array>(&batch, "grasped", "int16")?.values());
            rec.contact_pairs
                .extend(column::<UInt32Array>(&batch, "contact_pairs", "uint32")?.values());
            rec.contact_points
                .extend(column::<UInt32Array>(&batch, "contact_points", "uint32")?.values());
            let touch = column::<BooleanArray>(&batch, "ee_in_contact", "bool")?;
            rec.ee_contact
                .extend(touch.iter().map(|b| b.unwrap_or(false)));
            for ((name, col), present) in ["ee_roll", "ee_pitch", "ee_yaw"]
                .into_iter()
                .zip(&mut rec.ee_turn)
                .zip(turns)
            {
                if present {
                    f32s(name, col)?;
                } else {
                    col.extend(std::iter::repeat_n(0.0, batch.num_rows()));
                }
            }
            for (id, cols) in objects.iter().zip(rec.objects.iter_mut()) {
                for (k, c) in ["x", "y", "z", "qx", "qy", "qz", "qw"].iter().enumerate() {
                    f32s(&format!("{id}.{c}"), &mut cols[k])?;
                }
            }
            for (name, col) in &mut rec.arm {
                f32s(&format!("arm.{name}"), col)?;
            }
            if fingers {
                f32s("gripper_opening", &mut rec.fingers[0])?;
                f32s("gripper_yaw", &mut rec.fingers[1])?;
            }
            for (id, joints) in objects.iter().zip(rec.joints.iter_mut()) {
                for (name, col) in joints {
                    f32s(&format!("{id}.joint.{name}"), col)?;
                }
            }
        }
        if rec.step.is_empty() {
            return Err(bad("no rows".into()));
        }
        Ok((rec, metadata.into()))
    }

    /// Encodes the episode as an Arrow IPC file with `metadata` on the schema.
    pub fn encode(
        &self,
        object_ids: &[String],
        metadata: HashMap<String, String>,
    ) -> Result<Vec<u8>, SimError> {
        let mut fields = vec![
            Field::new("step", DataType::UInt32, false),
            Field::new("time_s", DataType::Float64, false),
        ];
        let mut cols: Vec<ArrayRef> = vec![
            Arc::new(UInt32Array::from(self.step.clone())),
            Arc::new(Float64Array::from(self.time.clone())),
        ];
        for (name, data) in [("ee", &self.ee), ("ee_cmd", &self.cmd)] {
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                fields.push(Field::new(
                    format!("{name}_{axis}"),
                    DataType::Float32,
                    false,
                ));
                cols.push(Arc::new(Float32Array::from(data[k].clone())));
            }
        }
        fields.push(Field::new("grasped", DataType::Int16, false));
        cols.push(Arc::new(Int16Array::from(self.grasped.clone())));
        fields.push(Field::new("contact_pairs", DataType::UInt32, false));
        cols.push(Arc::new(UInt32Array::from(self.contact_pairs.clone())));
        fields.push(Field::new("contact_points", DataType::UInt32, false));
        cols.push(Arc::new(UInt32Array::from(self.contact_points.clone())));
        fields.push(Field::new("ee_in_contact", DataType::Boolean, false));
        cols.push(Arc::new(BooleanArray::from(self.ee_contact.clone())));
        // Only episodes whose tool turned carry its yaw, and only those whose tool tilted its
        // roll and pitch: other files stay as they were.
        let turned = self.ee_turn[2].iter().any(|&y| y != 0.0);
        let any_tilt = self.ee_turn[..2].iter().flatten().any(|&a| tilted(a));
        for (k, name) in ["ee_roll", "ee_pitch", "ee_yaw"].into_iter().enumerate() {
            if any_tilt || (k == 2 && turned) {
                fields.push(Field::new(name, DataType::Float32, false));
                cols.push(Arc::new(Float32Array::from(self.ee_turn[k].clone())));
            }
        }
        for (id, data) in object_ids.iter().zip(&self.objects) {
            for (k, c) in ["x", "y", "z", "qx", "qy", "qz", "qw"].iter().enumerate() {
                fields.push(Field::new(format!("{id}.{c}"), DataType::Float32, false));
                cols.push(Arc::new(Float32Array::from(data[k].clone())));
            }
        }
        for (name, data) in &self.arm {
            fields.push(Field::new(format!("arm.{name}"), DataType::Float32, false));
            cols.push(Arc::new(Float32Array::from(data.clone())));
        }
        if !self.fingers[0].is_empty() {
            for (name, data) in [
                ("gripper_opening", &self.fingers[0]),
                ("gripper_yaw", &self.fingers[1]),
            ] {
                fields.push(Field::new(name, DataType::Float32, false));
                cols.push(Arc::new(Float32Array::from(data.clone())));
            }
        }
        for (id, joints) in object_ids.iter().zip(&self.joints) {
            for (name, data) in joints {
                fields.push(Field::new(
                    format!("{id}.joint.{name}"),
                    DataType::Float32,
                    false,
                ));
                cols.push(Arc::new(Float32Array::from(data.clone())));
            }
        }
        let schema = Arc::new(Schema::new(fields).with_metadata(metadata));
        let batch = RecordBatch::try_new(schema.clone(), cols)
            .map_err(|e| SimError::internal(format!("episode table: {e}")))?;
        let mut buf = Vec::new();
        {
            let mut w = arrow_ipc::writer::FileWriter::try_new(&mut buf, &schema)
                .map_err(|e| SimError::internal(format!("episode file: {e}")))?;
            w.write(&batch)
                .map_err(|e| SimError::internal(format!("episode file: {e}")))?;
            w.finish()
                .map_err(|e| SimError::internal(format!("episode file: {e}")))?;
        }
        Ok(buf)
    }
}

/// Column `name` of an episode file's `batch` as an array of type `T` (`kind` names it in the
/// error).
fn column<'a, T: 'static>(
    batch: &'a arrow_array::RecordBatch,
    name: &str,
    kind: &str,
) -> Result<&'a T, SimError> {
    batch
        .column_by_name(name)
        .ok_or_else(|| SimError::internal(format!("episode file: no column '{name}'")))?
        .as_any()
        .downcast_ref::<T>()
        .ok_or_else(|| SimError::internal(format!("episode file: column '{name}' is not {kind}")))
}

/// Contact points closer than this count as touching. rapier also keeps speculative contacts a
/// few millimetres apart; MuJoCo and PyBullet count points at zero distance (margin 0), so the
/// summary does too, to keep workloads comparable.
pub const TOUCH_DISTANCE: f32 = 1e-3;

/// Touching collider pairs, touching contact points, and whether the tool touches anything.
pub fn contact_summary(scene: &SimScene) -> (u32, u32, bool) {
    let (mut pairs, mut points, mut ee) = (0u32, 0u32, false);
    for pair in scene.world.narrow_phase.contact_pairs() {
        let touching: u32 = pair
            .manifolds()
            .iter()
            .map(|m| m.points.iter().filter(|p| p.dist <= TOUCH_DISTANCE).count() as u32)
            .sum();
        if touching == 0 {
            continue;
        }
        pairs += 1;
        points += touching;
        // The tool, its pads and the arm that carries it.
        let tool = |c: ColliderHandle| {
            c == scene.gripper_collider
                || scene
                    .fingers
                    .as_ref()
                    .is_some_and(|f| f.colliders.contains(&c))
                || scene.arm.as_ref().is_some_and(|a| a.colliders.contains(&c))
        };
        if tool(pair.collider1) || tool(pair.collider2) {
            ee = true;
        }
    }
    (pairs, points, ee)
}

/// The live state of `scene` as a camera can draw it (what a seeing policy's camera renders).
pub fn live_snapshot(scene: &SimScene, spec: &TaskSpec) -> SceneSnapshot {
    snapshot_of(
        spec,
        scene.objects.iter().map(|o| {
            let p = scene.pose(o);
            (
                p.translation.into(),
                [p.rotation.x, p.rotation.y, p.rotation.z, p.rotation.w],
            )
        }),
        scene.gripper_position().into(),
        scene.tool_turn(),
        |i| scene.joint_positions(&scene.objects[i]),
        scene
            .fingers
            .as_ref()
            .map(|f| (f.opening(&scene.world), f.world_turn(&scene.world))),
        scene
            .arm
            .as_ref()
            .map_or_else(Vec::new, |a| a.boxes_at(&a.q)),
    )
}

/// `spec`'s objects at `poses` (position, quaternion x y z w; in spec order) with the tool at
/// `tool` turned by `turn` (its pads, if any, `opening` apart and turned by their own turn in
/// the world), asset paths resolved.
fn snapshot_of(
    spec: &TaskSpec,
    poses: impl Iterator<Item = ([f32; 3], [f32; 4])>,
    tool: [f32; 3],
    turn: Rotation,
    joints: impl Fn(usize) -> std::collections::BTreeMap<String, f64>,
    fingers: Option<(f32, Rotation)>,
    arm: Vec<SnapshotBox>,
) -> SceneSnapshot {
    let objects = spec
        .scene
        .objects
        .iter()
        .zip(poses)
        .enumerate()
        .map(|(i, (o, (position, rotation)))| SnapshotObject {
            id: o.id.clone(),
            shape: spec.resolved_shape(&o.shape),
            color: o
                .color
                .as_ref()
                .and_then(|c| c.rgb())
                .unwrap_or([0.5; 3])
                .map(|x| x as f32),
            color_given: o.color.is_some(),
            position,
            rotation,
            joints: joints(i),
        })
        .collect();
    SceneSnapshot {
        surface: spec.scene.surface,
        objects,
        tool: Some(tool),
        // A tool that has not turned is drawn as before turns existed (no rotation stored).
        tool_rotation: (turn != Rotation::IDENTITY).then_some([turn.x, turn.y, turn.z, turn.w]),
        fingers: fingers
            .map(|(opening, pads)| {
                crate::scene::Fingers::poses(Vec3::from(tool), opening, pads)
                    .map(|p| SnapshotBox {
                        position: p.translation.into(),
                        rotation: [p.rotation.x, p.rotation.y, p.rotation.z, p.rotation.w],
                        half_extents: crate::scene::FINGER_HALF_EXTENTS,
                    })
                    .to_vec()
            })
            .unwrap_or_default(),
        arm,
    }
}
