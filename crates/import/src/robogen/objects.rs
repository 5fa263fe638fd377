//! The scene of a RoboGen task: the items with a `type` (URDF and mesh objects) with their
//! sizes, initial joints and positions on the table or the ground, the notes on the scene's other
//! fields, and the check that no two objects start overlapping. Never infers goals (`goals`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_yaml_ng::Value;

use super::{JOINT_CLAMP, JointValues, Obj, TaskYaml, field, str_of};
use crate::{check_asset, r3, r6, radius};
use assay_spec::spec::{Object, Pose, Shape, TABLE_CENTER, TABLE_HALF_EXTENTS};
use assay_spec::urdf::{JointKind, Urdf};

/// What an object's asset makes of it.
struct Body {
    shape: Shape,
    half: [f64; 3],
    urdf: Option<(PathBuf, Urdf)>,
    frame_shift: [f64; 3],
}

impl TaskYaml<'_> {
    /// The objects: one per item with a `type`, in order.
    pub(super) fn objects(&mut self, joint_values: &JointValues) {
        let items = self.items;
        for (i, it) in items.iter().enumerate() {
            let Some(kind) = it.get("type").and_then(str_of) else {
                continue;
            };
            if let Some(o) = self.object(i, it, &kind, joint_values) {
                self.objs.push(o);
            }
        }
    }

    /// Item `i`, an object of `kind`: its asset, size and position, and the notes on its
    /// fields. `None` when it cannot be imported (the error is noted).
    fn object(
        &mut self,
        i: usize,
        it: &Value,
        kind: &str,
        joint_values: &JointValues,
    ) -> Option<Obj> {
        let oname = it.get("name").and_then(str_of).unwrap_or_default();
        let oid = crate::slug(&oname, '_');
        let f = |k: &str| format!("[{i}].{k}");
        let path = it.get("path").and_then(str_of).unwrap_or_default();
        let full = match check_asset(self.asset_root, &path) {
            Ok(p) => p,
            Err(e) => {
                self.fail(&f("path"), format!("{e} (object '{oname}')"));
                return None;
            }
        };
        let center = self.center(i, it, &oname)?;
        let size = it
            .get("size")
            .and_then(|v| v.as_f64())
            .unwrap_or(0.3)
            .clamp(0.1, 1.2);
        let on_table = it
            .get("on_table")
            .and_then(|v| v.as_bool())
            .unwrap_or(false);
        let movable = it.get("movable").and_then(|v| v.as_bool());
        let body = match kind {
            "urdf" => {
                let given = joint_values.get(&oname.to_lowercase());
                self.urdf_body(i, &path, &full, size, given)?
            }
            "mesh" => self.mesh_body(i, &path, &full, size)?,
            _ => {
                self.fail(
                    &f("type"),
                    format!("unknown object type '{kind}' (RoboGen has urdf and mesh)"),
                );
                return None;
            }
        };
        let fixed = kind == "urdf" && movable != Some(true);
        self.notes.mapped(
            &f("type"),
            format!(
                "object '{oid}' ({kind}{})",
                if fixed { ", fixed" } else { "" }
            ),
        );
        let pose = self.position(i, &oid, center, on_table, body.half)?;
        self.notes.mapped(&f("on_table"), format!("{on_table}"));
        if movable.is_some() {
            self.notes.not_mapped(
                &f("movable"),
                "only as fixed (a URDF that is not movable is fixed)",
            );
        }
        self.asset_fields(i, it);
        Some(Obj {
            index: i,
            id: oid.clone(),
            name: oname.clone(),
            object: Object {
                id: oid,
                shape: body.shape,
                color: Default::default(),
                mass: None,
                is_fixed: fixed,
                pose: Some(pose),
                pose_range: None,
            },
            half: body.half,
            urdf: body.urdf,
            frame_shift: body.frame_shift,
        })
    }

    /// Item `i`'s `center` (RoboGen's default: the middle of the table); `None` when it is not
    /// one (the error is noted).
    fn center(&mut self, i: usize, it: &Value, oname: &str) -> Option<[f64; 3]> {
        match it.get("center").and_then(str_of).map(|s| parse_center(&s)) {
            Some(Ok(c)) => Some(c),
            Some(Err(e)) => {
                self.fail(&format!("[{i}].center"), format!("{e} (object '{oname}')"));
                None
            }
            None => Some([0.5, 0.5, 0.0]),
        }
    }

    /// Item `i`'s URDF (`path`, at `full`) with its joints set as `given`, and how its own size
    /// compares with RoboGen's `size`.
    fn urdf_body(
        &mut self,
        i: usize,
        path: &str,
        full: &Path,
        size: f64,
        given: Option<&BTreeMap<String, String>>,
    ) -> Option<Body> {
        let f = |k: &str| format!("[{i}].{k}");
        let text = std::fs::read_to_string(full).unwrap_or_default();
        let u = match assay_spec::urdf::parse(&text) {
            Ok(u) => u,
            Err(e) => {
                self.fail(&f("path"), format!("URDF '{path}': {e}"));
                return None;
            }
        };
        let joints = self.initial_joints(i, &u, given);
        let mut shift = [0.0; 3];
        let a = match assay_spec::urdf::assemble(full, &joints) {
            Ok(a) => a,
            Err(e) => {
                self.fail(&f("path"), format!("URDF '{path}': {e}"));
                return None;
            }
        };
        if let Ok(a0) = assay_spec::urdf::assemble(full, &BTreeMap::new()) {
            shift = std::array::from_fn(|k| a0.centre[k] - a.centre[k]);
            let d = 2.0 * (a0.half[0].powi(2) + a0.half[1].powi(2) + a0.half[2].powi(2)).sqrt();
            if (d - size).abs() > 0.05 {
                self.notes.not_mapped(&f("size"), format!("{size}: RoboGen scales the model to this diagonal; the URDF's own is {d:.3} and spec v1 has no URDF scale"));
            } else {
                self.notes.mapped(
                    &f("size"),
                    format!("{size}: the URDF's own diagonal ({d:.3}) matches"),
                );
            }
        }
        Some(Body {
            shape: Shape::Urdf {
                path: path.to_owned(),
                joints,
                articulated: false,
                fill: BTreeMap::new(),
            },
            half: a.half.map(r6),
            urdf: Some((full.to_path_buf(), u)),
            frame_shift: shift,
        })
    }

    /// The initial position of each moving joint of item `i`'s URDF `u`: the fraction of its
    /// range `given` names, clamped to [`JOINT_CLAMP`].
    fn initial_joints(
        &mut self,
        i: usize,
        u: &Urdf,
        given: Option<&BTreeMap<String, String>>,
    ) -> BTreeMap<String, f64> {
        let mut joints = BTreeMap::new();
        for j in &u.joints {
            let (JointKind::Revolute | JointKind::Prismatic, Some([lo, hi])) = (j.kind, j.limit)
            else {
                continue;
            };
            let v = match given.and_then(|g| g.get(&j.name)) {
                Some(s) if s == "random" => {
                    self.notes.inferred(&format!("[{i}].joints.{}", j.name), "'random' (drawn when RoboGen builds the scene): spec v1 has no joint variation, fixed at 0.06 of the range");
                    JOINT_CLAMP.0
                }
                Some(s) => s.parse::<f64>().unwrap_or(0.0),
                None => {
                    self.notes.inferred(
                        &format!("[{i}].joints.{}", j.name),
                        "not named: starts at 0.06 of its range, as RoboGen sets it",
                    );
                    JOINT_CLAMP.0
                }
            };
            let v = v.clamp(JOINT_CLAMP.0, JOINT_CLAMP.1);
            joints.insert(j.name.clone(), r6(lo + v * (hi - lo)));
        }
        joints
    }

    /// Item `i`'s OBJ mesh (`path`, at `full`), scaled as RoboGen scales it to `size`.
    fn mesh_body(&mut self, i: usize, path: &str, full: &Path, size: f64) -> Option<Body> {
        let f = |k: &str| format!("[{i}].{k}");
        let text = std::fs::read_to_string(full).unwrap_or_default();
        let (lo, hi) = vertex_bounds(&text);
        if lo[0] > hi[0] {
            self.fail(&f("path"), format!("mesh '{path}' has no vertices"));
            return None;
        }
        let d0 =
            ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let scale = r6(size / d0);
        self.notes.mapped(&f("size"), format!("{size} → scale {scale} (RoboGen scales a mesh so its bounding-box diagonal equals size)"));
        self.notes.not_mapped(
            &f("type"),
            "RoboGen rolls Objaverse meshes by +90°; spec poses have yaw only",
        );
        Some(Body {
            shape: Shape::Mesh {
                path: path.to_owned(),
                scale,
                collision: Default::default(),
            },
            half: std::array::from_fn(|k| r6((hi[k] - lo[k]) / 2.0 * scale)),
            urdf: None,
            frame_shift: [0.0; 3],
        })
    }

    /// Where object `oid` (item `i`, half extents `half`) stands: RoboGen's `center` as table
    /// fractions or as a world position → x and y from Assay's robot base, resting on the
    /// surface. `None` when it does not fit on the table (the error is noted).
    fn position(
        &mut self,
        i: usize,
        oid: &str,
        center: [f64; 3],
        on_table: bool,
        half: [f64; 3],
    ) -> Option<Pose> {
        let f = |k: &str| format!("[{i}].{k}");
        let use_table = self.use_table;
        let (x, y) = if on_table
            || (use_table && center[2] == 0.0 && center[0] <= 1.0 && center[1] <= 1.0)
        {
            let r = radius(half);
            let Some((x, y)) = table_xy(center, r) else {
                self.fail(
                    &f("size"),
                    format!("object '{oid}' (radius {r} m) does not fit on the table"),
                );
                return None;
            };
            self.notes.inferred(&f("center"), format!("table fractions ({}, {}) → ({:.3}, {:.3}) over Assay's reachable workspace x 0.25-0.75, y -0.5-0.5; z: resting on the table", center[0], center[1], x, y));
            (x, y)
        } else {
            let (x, y) = (center[0] - 1.0, center[1] - 1.0);
            self.notes.inferred(&f("center"), format!("world ({}, {}, {}) with the robot base at (1, 1) → ({x:.3}, {y:.3}) from Assay's robot base; approximate; z: resting on the {}", center[0], center[1], center[2], if use_table { "table" } else { "ground" }));
            (x, y)
        };
        Some(Pose {
            position: [r3(x), r3(y), r6(half[2])],
            yaw_deg: 0.0,
        })
    }

    /// Item `i`'s fields about where RoboGen finds the asset, which the importer does not use.
    fn asset_fields(&mut self, i: usize, it: &Value) {
        for k in ["lang", "reward_asset_path", "uid", "all_uid"] {
            if it.get(k).is_some() {
                let why = match k {
                    "lang" => "a caption of the asset, not part of spec v1",
                    "reward_asset_path" => {
                        "RoboGen loads data/dataset/{reward_asset_path}/mobility.urdf; the importer uses path"
                    }
                    _ => "Objaverse ids RoboGen downloads; the importer uses path",
                };
                self.notes.not_mapped(&format!("[{i}].{k}"), why);
            }
        }
    }

    /// The scene's fields besides its objects: `spatial_relationships`, and the robot.
    pub(super) fn scene_notes(&mut self) {
        if let Some((i, v)) = field(self.items, "spatial_relationships") {
            let rels: Vec<String> = v
                .as_sequence()
                .map(|s| s.iter().filter_map(str_of).collect())
                .unwrap_or_default();
            if rels.is_empty() {
                self.notes
                    .mapped(&format!("[{i}].spatial_relationships"), "none");
            }
            for (k, r) in rels.iter().enumerate() {
                self.notes.not_mapped(&format!("[{i}].spatial_relationships[{k}]"), format!("'{r}': constrains RoboGen's initial placement only (the positions come from center)"));
            }
        }
        self.notes.not_mapped(
            "robot",
            "RoboGen picks a robot at random; Assay's arm is fixed",
        );
    }

    /// Objects that start overlapping (their boxes, in x and y): an error on the later one.
    pub(super) fn overlaps(&mut self) {
        for a in 0..self.objs.len() {
            for b in a + 1..self.objs.len() {
                let (oa, ob) = (&self.objs[a], &self.objs[b]);
                let (pa, pb) = (
                    oa.object.pose.unwrap().position,
                    ob.object.pose.unwrap().position,
                );
                if (pa[0] - pb[0]).abs() < oa.half[0] + ob.half[0]
                    && (pa[1] - pb[1]).abs() < oa.half[1] + ob.half[1]
                {
                    let field = format!("[{}].center", ob.index);
                    let reason = format!("'{}' starts overlapping '{}'", ob.name, oa.name);
                    self.fail(&field, reason);
                }
            }
        }
    }
}

fn parse_center(s: &str) -> Result<[f64; 3], String> {
    let inner = s
        .trim()
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'))
        .ok_or_else(|| format!("\"{s}\" is not (x, y, z)"))?;
    let parts: Vec<&str> = inner.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("\"{s}\" is not (x, y, z): {} values", parts.len()));
    }
    let mut out = [0.0; 3];
    for (k, p) in parts.iter().enumerate() {
        out[k] = p
            .parse::<f64>()
            .map_err(|_| format!("\"{s}\" is not (x, y, z): '{p}' is not a number"))?;
    }
    Ok(out)
}

/// The bounds of an OBJ file's vertices (`lo` above `hi` when it has none).
fn vertex_bounds(text: &str) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for l in text.lines() {
        if let Some(rest) = l.strip_prefix("v ") {
            let v: Vec<f64> = rest
                .split_whitespace()
                .filter_map(|x| x.parse().ok())
                .collect();
            if v.len() >= 3 {
                for k in 0..3 {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
        }
    }
    (lo, hi)
}

/// RoboGen's table fractions `center` → a table position for an object of radius `r`, kept on
/// the table; `None` when the object does not fit on it (a clamp with min > max panics; found
/// by core/tests/fuzz.rs with a `size` of 1e308).
fn table_xy(center: [f64; 3], r: f64) -> Option<(f64, f64)> {
    let lo = [0, 1].map(|k| TABLE_CENTER[k] - TABLE_HALF_EXTENTS[k] + r);
    let hi = [0, 1].map(|k| TABLE_CENTER[k] + TABLE_HALF_EXTENTS[k] - r);
    if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
        return None;
    }
    Some((
        (0.25 + center[0] * 0.5).clamp(lo[0], hi[0]),
        (-0.5 + center[1] * 1.0).clamp(lo[1], hi[1]),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_too_large_for_the_table_are_errors() {
        assert!(table_xy([0.5, 0.5, 0.0], 0.05).is_some());
        assert!(table_xy([0.5, 0.5, 0.0], f64::INFINITY).is_none());
        assert!(table_xy([0.5, 0.5, 0.0], f64::NAN).is_none());
        assert!(table_xy([0.5, 0.5, 0.0], 10.0).is_none());
    }
}
