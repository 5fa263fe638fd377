//! RoboGen (Genesis-Embodied-AI/RoboGen): task YAMLs (a list of one-key-group dicts) with a
//! solution folder of substeps. Goals are inferred from the substeps: lid and door tasks become
//! joint goals on an articulated URDF, "put X into Y" a placement goal.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde_yaml_ng::Value;

use super::{ImportedTask, Notes, Pipeline, check_asset, group_for, hash_parts, r3, r6, radius};
use assay_spec::error::SpecError;
use assay_spec::spec::{
    EndEffector, Goal, Object, PhysicsSettings, PlaceTarget, Pose, Primitive, SPEC_VERSION, Scene,
    Shape, Source, Surface, TABLE_CENTER, TABLE_HALF_EXTENTS, TaskSpec, Variations,
};
use assay_spec::urdf::{Geometry, JointKind};

/// Fraction of a joint's range RoboGen's joint values are clamped to.
const JOINT_CLAMP: (f64, f64) = (0.06, 0.7);

pub(crate) fn import(root: &Path, asset_root: &Path) -> (Vec<ImportedTask>, Vec<SpecError>) {
    let mut files = yaml_files(root);
    for sub in ["example_tasks", "data/generated_task_from_description"] {
        if let Ok(rd) = std::fs::read_dir(root.join(sub)) {
            let mut dirs: Vec<PathBuf> = rd
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .collect();
            dirs.sort();
            for d in dirs {
                files.extend(yaml_files(&d));
            }
        }
    }
    let tasks = files
        .iter()
        .filter_map(|f| import_one(root, asset_root, f))
        .collect();
    (tasks, Vec::new())
}

fn yaml_files(dir: &Path) -> Vec<PathBuf> {
    super::sorted_entries(dir, |p| {
        p.is_file() && p.extension().is_some_and(|e| e == "yaml" || e == "yml")
    })
}

struct Obj {
    index: usize,
    id: String,
    name: String,
    object: Object,
    half: [f64; 3],
    urdf: Option<(PathBuf, assay_spec::urdf::Urdf)>,
    /// A URDF's frame with every joint at its default position minus its frame at the initial
    /// joints: an articulated object's frame is the former (see `Shape::Urdf`).
    frame_shift: [f64; 3],
}

fn task_id(name: &str) -> String {
    let n = name.replace('\u{2019}', "'").replace('\'', "");
    super::slug(&n, '-')
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

fn str_of(v: &Value) -> Option<String> {
    match v {
        Value::String(s) => Some(s.clone()),
        Value::Number(n) => Some(n.to_string()),
        Value::Bool(b) => Some(b.to_string()),
        _ => None,
    }
}

fn import_one(root: &Path, asset_root: &Path, file: &Path) -> Option<ImportedTask> {
    let bytes = std::fs::read(file).ok()?;
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let doc: Value = serde_yaml_ng::from_str(&text).ok()?;
    let items = doc.as_sequence()?.clone();
    let get = |key: &str| -> Option<(usize, &Value)> {
        items
            .iter()
            .enumerate()
            .find_map(|(i, it)| it.get(key).map(|v| (i, v)))
    };
    let name_raw = get("task_name").and_then(|(_, v)| str_of(v))?;
    let name = name_raw.replace('\u{2019}', "'");
    let id = task_id(&name_raw);
    let origin = file.display().to_string();
    let mut notes = Notes::new(&id, &origin);
    let description = get("task_description")
        .and_then(|(_, v)| str_of(v))
        .unwrap_or_default();
    // The solution folder.
    let solution = get("solution_path").and_then(|(_, v)| str_of(v));
    // Relative to the RoboGen root; a batch copied elsewhere keeps the folder next to the YAML.
    let sol_dir = solution.as_ref().map(|s| {
        let d = root.join(s);
        match (d.is_dir(), Path::new(s).file_name(), file.parent()) {
            (false, Some(last), Some(dir)) if dir.join(last).is_dir() => dir.join(last),
            _ => d,
        }
    });
    let read = |n: &str| -> Vec<u8> {
        sol_dir
            .as_ref()
            .and_then(|d| std::fs::read(d.join(n)).ok())
            .unwrap_or_default()
    };
    let (substeps, types, spaces) = (
        read("substeps.txt"),
        read("substep_types.txt"),
        read("action_spaces.txt"),
    );
    let mut py: Vec<(String, Vec<u8>)> = sol_dir
        .as_ref()
        .and_then(|d| std::fs::read_dir(d).ok())
        .map(|rd| {
            rd.flatten()
                .filter(|e| e.path().extension().is_some_and(|x| x == "py"))
                .filter_map(|e| {
                    Some((
                        e.file_name().to_string_lossy().into_owned(),
                        std::fs::read(e.path()).ok()?,
                    ))
                })
                .collect()
        })
        .unwrap_or_default();
    py.sort();
    let mut parts: Vec<(&str, &[u8])> = vec![
        ("yaml", &bytes),
        ("substeps", &substeps),
        ("substep_types", &types),
        ("action_spaces", &spaces),
    ];
    for (n, b) in &py {
        parts.push((n, b));
    }
    let content_hash = hash_parts(&parts);
    let mut task = ImportedTask {
        id: id.clone(),
        name: name.clone(),
        source: file.to_path_buf(),
        content_hash: content_hash.clone(),
        spec: None,
        mapping: Vec::new(),
        errors: Vec::new(),
        episodes: Vec::new(),
    };
    notes.mapped("task_name", format!("id '{id}', name '{name}'"));
    notes.mapped("task_description", "description");
    let use_table = get("use_table")
        .and_then(|(_, v)| v.as_bool())
        .unwrap_or(true);
    let surface = if use_table {
        Surface::Table
    } else {
        Surface::Ground
    };
    notes.mapped(
        "use_table",
        format!("surface {}", if use_table { "table" } else { "ground" }),
    );

    // Joint values.
    let mut joint_values: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for (i, it) in items.iter().enumerate() {
        if let Some(target) = it.get("set_joint_angle_object_name").and_then(str_of) {
            let mut m = BTreeMap::new();
            if let Some(map) = it.as_mapping() {
                for (k, v) in map {
                    let k = str_of(k).unwrap_or_default();
                    if k != "set_joint_angle_object_name" {
                        m.insert(k, str_of(v).unwrap_or_default());
                    }
                }
            }
            notes.mapped(
                &format!("[{i}]"),
                format!(
                    "joint values of '{target}' (fraction of range, clamped to {}-{})",
                    JOINT_CLAMP.0, JOINT_CLAMP.1
                ),
            );
            joint_values.insert(target.to_lowercase(), m);
        }
    }

    // Objects.
    let mut objs: Vec<Obj> = Vec::new();
    let mut fatal = false;
    for (i, it) in items.iter().enumerate() {
        let Some(kind) = it.get("type").and_then(str_of) else {
            continue;
        };
        let oname = it.get("name").and_then(str_of).unwrap_or_default();
        let oid = super::slug(&oname, '_');
        let f = |k: &str| format!("[{i}].{k}");
        let path = it.get("path").and_then(str_of).unwrap_or_default();
        let full = match check_asset(asset_root, &path) {
            Ok(p) => p,
            Err(e) => {
                notes.error(&f("path"), format!("{e} (object '{oname}')"));
                fatal = true;
                continue;
            }
        };
        let center = match it.get("center").and_then(str_of).map(|s| parse_center(&s)) {
            Some(Ok(c)) => c,
            Some(Err(e)) => {
                notes.error(&f("center"), format!("{e} (object '{oname}')"));
                fatal = true;
                continue;
            }
            None => [0.5, 0.5, 0.0],
        };
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
        let (shape, half, urdf, frame_shift) = if kind == "urdf" {
            let text = std::fs::read_to_string(&full).unwrap_or_default();
            let u = match assay_spec::urdf::parse(&text) {
                Ok(u) => u,
                Err(e) => {
                    notes.error(&f("path"), format!("URDF '{path}': {e}"));
                    fatal = true;
                    continue;
                }
            };
            let given = joint_values.get(&oname.to_lowercase());
            let mut joints = BTreeMap::new();
            for j in &u.joints {
                let (JointKind::Revolute | JointKind::Prismatic, Some([lo, hi])) =
                    (j.kind, j.limit)
                else {
                    continue;
                };
                let v = match given.and_then(|g| g.get(&j.name)) {
                    Some(s) if s == "random" => {
                        notes.inferred(&format!("[{i}].joints.{}", j.name), "'random' (drawn when RoboGen builds the scene): spec v1 has no joint variation, fixed at 0.06 of the range");
                        JOINT_CLAMP.0
                    }
                    Some(s) => s.parse::<f64>().unwrap_or(0.0),
                    None => {
                        notes.inferred(
                            &format!("[{i}].joints.{}", j.name),
                            "not named: starts at 0.06 of its range, as RoboGen sets it",
                        );
                        JOINT_CLAMP.0
                    }
                };
                let v = v.clamp(JOINT_CLAMP.0, JOINT_CLAMP.1);
                joints.insert(j.name.clone(), r6(lo + v * (hi - lo)));
            }
            let mut shift = [0.0; 3];
            let a = match assay_spec::urdf::assemble(&full, &joints) {
                Ok(a) => a,
                Err(e) => {
                    notes.error(&f("path"), format!("URDF '{path}': {e}"));
                    fatal = true;
                    continue;
                }
            };
            if let Ok(a0) = assay_spec::urdf::assemble(&full, &BTreeMap::new()) {
                shift = std::array::from_fn(|k| a0.centre[k] - a.centre[k]);
                let d = 2.0 * (a0.half[0].powi(2) + a0.half[1].powi(2) + a0.half[2].powi(2)).sqrt();
                if (d - size).abs() > 0.05 {
                    notes.not_mapped(&f("size"), format!("{size}: RoboGen scales the model to this diagonal; the URDF's own is {d:.3} and spec v1 has no URDF scale"));
                } else {
                    notes.mapped(
                        &f("size"),
                        format!("{size}: the URDF's own diagonal ({d:.3}) matches"),
                    );
                }
            }
            (
                Shape::Urdf {
                    path: path.clone(),
                    joints,
                    articulated: false,
                    fill: BTreeMap::new(),
                },
                a.half.map(r6),
                Some((full.clone(), u)),
                shift,
            )
        } else if kind == "mesh" {
            let text = std::fs::read_to_string(&full).unwrap_or_default();
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
            if lo[0] > hi[0] {
                notes.error(&f("path"), format!("mesh '{path}' has no vertices"));
                fatal = true;
                continue;
            }
            let d0 = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2))
                .sqrt();
            let scale = r6(size / d0);
            notes.mapped(&f("size"), format!("{size} → scale {scale} (RoboGen scales a mesh so its bounding-box diagonal equals size)"));
            notes.not_mapped(
                &f("type"),
                "RoboGen rolls Objaverse meshes by +90°; spec poses have yaw only",
            );
            (
                Shape::Mesh {
                    path: path.clone(),
                    scale,
                    collision: Default::default(),
                },
                std::array::from_fn(|k| r6((hi[k] - lo[k]) / 2.0 * scale)),
                None,
                [0.0; 3],
            )
        } else {
            notes.error(
                &f("type"),
                format!("unknown object type '{kind}' (RoboGen has urdf and mesh)"),
            );
            fatal = true;
            continue;
        };
        let fixed = kind == "urdf" && movable != Some(true);
        notes.mapped(
            &f("type"),
            format!(
                "object '{oid}' ({kind}{})",
                if fixed { ", fixed" } else { "" }
            ),
        );
        // Position.
        let (x, y) = if on_table
            || (use_table && center[2] == 0.0 && center[0] <= 1.0 && center[1] <= 1.0)
        {
            let r = radius(half);
            let Some((x, y)) = table_xy(center, r) else {
                notes.error(
                    &f("size"),
                    format!("object '{oid}' (radius {r} m) does not fit on the table"),
                );
                fatal = true;
                continue;
            };
            notes.inferred(&f("center"), format!("table fractions ({}, {}) → ({:.3}, {:.3}) over Assay's reachable workspace x 0.25-0.75, y -0.5-0.5; z: resting on the table", center[0], center[1], x, y));
            (x, y)
        } else {
            let (x, y) = (center[0] - 1.0, center[1] - 1.0);
            notes.inferred(&f("center"), format!("world ({}, {}, {}) with the robot base at (1, 1) → ({x:.3}, {y:.3}) from Assay's robot base; approximate; z: resting on the {}", center[0], center[1], center[2], if use_table { "table" } else { "ground" }));
            (x, y)
        };
        notes.mapped(&f("on_table"), format!("{on_table}"));
        if movable.is_some() {
            notes.not_mapped(
                &f("movable"),
                "only as fixed (a URDF that is not movable is fixed)",
            );
        }
        for k in ["lang", "reward_asset_path", "uid", "all_uid"] {
            if it.get(k).is_some() {
                let why = match k {
                    "lang" => "a caption of the asset, not part of spec v1",
                    "reward_asset_path" => {
                        "RoboGen loads data/dataset/{reward_asset_path}/mobility.urdf; the importer uses path"
                    }
                    _ => "Objaverse ids RoboGen downloads; the importer uses path",
                };
                notes.not_mapped(&f(k), why);
            }
        }
        objs.push(Obj {
            index: i,
            id: oid.clone(),
            name: oname.clone(),
            object: Object {
                id: oid,
                shape,
                color: Default::default(),
                mass: None,
                is_fixed: fixed,
                pose: Some(Pose {
                    position: [r3(x), r3(y), r6(half[2])],
                    yaw_deg: 0.0,
                }),
                pose_range: None,
            },
            half,
            urdf,
            frame_shift,
        });
    }
    if let Some((i, v)) = get("spatial_relationships") {
        let rels: Vec<String> = v
            .as_sequence()
            .map(|s| s.iter().filter_map(str_of).collect())
            .unwrap_or_default();
        if rels.is_empty() {
            notes.mapped(&format!("[{i}].spatial_relationships"), "none");
        }
        for (k, r) in rels.iter().enumerate() {
            notes.not_mapped(&format!("[{i}].spatial_relationships[{k}]"), format!("'{r}': constrains RoboGen's initial placement only (the positions come from center)"));
        }
    }
    notes.not_mapped(
        "robot",
        "RoboGen picks a robot at random; Assay's arm is fixed",
    );
    // Overlaps at start.
    for a in 0..objs.len() {
        for b in a + 1..objs.len() {
            let (pa, pb) = (
                objs[a].object.pose.unwrap().position,
                objs[b].object.pose.unwrap().position,
            );
            if (pa[0] - pb[0]).abs() < objs[a].half[0] + objs[b].half[0]
                && (pa[1] - pb[1]).abs() < objs[a].half[1] + objs[b].half[1]
            {
                notes.error(
                    &format!("[{}].center", objs[b].index),
                    format!("'{}' starts overlapping '{}'", objs[b].name, objs[a].name),
                );
                fatal = true;
            }
        }
    }

    // Substeps.
    let lines = |b: &[u8]| -> Vec<String> {
        String::from_utf8_lossy(b)
            .lines()
            .map(|l| l.trim().to_owned())
            .filter(|l| !l.is_empty())
            .collect()
    };
    let (steps, kinds) = (lines(&substeps), lines(&types));
    if sol_dir.is_none() || steps.is_empty() {
        notes.error("solution_path", "no substeps: the goal cannot be inferred");
        fatal = true;
    }
    notes.not_mapped(
        "action_spaces.txt",
        "RL action spaces of the reward substeps: Assay's oracle is scripted",
    );
    if !py.is_empty() {
        notes.not_mapped("substeps *.py", "RoboGen's primitive and reward code (success tests): the goal is inferred from the substep text instead");
    }
    let py_text: String = py
        .iter()
        .map(|(_, b)| String::from_utf8_lossy(b).into_owned())
        .collect();

    let mut goals = Vec::new();
    let mut oracle = Vec::new();
    if !fatal {
        let text = format!("{} {}", steps.join(" "), name).to_lowercase();
        let urdf_with_joints: Vec<usize> = objs.iter().enumerate().filter(|(_, o)| matches!(&o.object.shape, Shape::Urdf { joints, .. } if !joints.is_empty())).map(|(k, _)| k).collect();
        let joint_task = (text.contains("open") || text.contains("close"))
            && !text.contains(" into ")
            && !urdf_with_joints.is_empty();
        if joint_task {
            let opening = steps
                .iter()
                .zip(kinds.iter().chain(std::iter::repeat(&String::new())))
                .filter(|(_, k)| *k == "reward")
                .any(|(s, _)| s.to_lowercase().starts_with("open"))
                || (!text.contains("close") && text.contains("open"));
            let k = urdf_with_joints
                .iter()
                .copied()
                .find(|&k| text.contains(&objs[k].name.to_lowercase()))
                .unwrap_or(urdf_with_joints[0]);
            let o = &objs[k];
            let (_, u) = o.urdf.as_ref().expect("urdf");
            let movable: Vec<&assay_spec::urdf::Joint> = u
                .joints
                .iter()
                .filter(|j| {
                    matches!(j.kind, JointKind::Revolute | JointKind::Prismatic)
                        && j.limit.is_some()
                })
                .collect();
            // The joint the solution code names, or the joint of a link it names, or the only one.
            let joint = movable
                .iter()
                .find(|j| py_text.contains(&format!("\"{}\"", j.name)))
                .or_else(|| {
                    movable
                        .iter()
                        .find(|j| py_text.contains(&format!("\"{}\"", u.links[j.child].name)))
                })
                .or(if movable.len() == 1 {
                    movable.first()
                } else {
                    None
                });
            match joint {
                None => {
                    notes.error(
                        "substeps",
                        format!("cannot tell which joint of '{}' the task moves", o.name),
                    );
                    fatal = true;
                }
                Some(j) => {
                    let [lo, hi] = j.limit.expect("limit");
                    let range = hi - lo;
                    let q0 = match &o.object.shape {
                        Shape::Urdf { joints, .. } => joints.get(&j.name).copied().unwrap_or(lo),
                        _ => lo,
                    };
                    let (goal, to) = if opening {
                        (
                            Goal::JointPosition {
                                object: o.id.clone(),
                                joint: j.name.clone(),
                                min: Some(r6(lo + 0.6 * range)),
                                max: None,
                            },
                            r6(lo + 0.85 * range),
                        )
                    } else {
                        (
                            Goal::JointPosition {
                                object: o.id.clone(),
                                joint: j.name.clone(),
                                min: None,
                                max: Some(r6(lo + 0.15 * range)),
                            },
                            r6(lo + 0.02 * range),
                        )
                    };
                    let already = match &goal {
                        Goal::JointPosition { min: Some(m), .. } => q0 >= *m,
                        Goal::JointPosition { max: Some(m), .. } => q0 <= *m,
                        _ => false,
                    };
                    if already {
                        notes.error(
                            "goals",
                            format!(
                                "the initial {} = {q0} already satisfies the inferred goal {}",
                                j.name,
                                goal.label()
                            ),
                        );
                        fatal = true;
                    }
                    notes.inferred(
                        "goals",
                        format!(
                            "'{}' → {} ({} beyond {} of the range)",
                            steps.join("; "),
                            goal.label(),
                            if opening { "opened" } else { "closed" },
                            if opening { "0.6" } else { "0.15" }
                        ),
                    );
                    notes.inferred("oracle", format!("actuate {}.{} to {to} ({} of the range); the grasp substep is part of actuate", o.id, j.name, if opening { "0.85" } else { "0.02" }));
                    goals.push(goal);
                    oracle.push(Primitive::Actuate {
                        object: o.id.clone(),
                        joint: j.name.clone(),
                        to,
                    });
                    if let Shape::Urdf { articulated, .. } = &mut objs[k].object.shape {
                        *articulated = true;
                        // Its frame is now the one at default joint positions (yaw is 0).
                        let shift = objs[k].frame_shift;
                        if let Some(p) = &mut objs[k].object.pose {
                            for (c, d) in p.position.iter_mut().zip(shift) {
                                *c = r6(*c + d);
                            }
                        }
                    }
                }
            }
        } else {
            // "put/place the X into/in/on the Y"
            let mut done = false;
            for (s, kind) in steps.iter().zip(kinds.iter()) {
                let l = s.to_lowercase();
                if kind == "primitive" && (l.starts_with("grasp") || l.starts_with("release")) {
                    continue;
                }
                let rel = [
                    (" into the ", true),
                    (" in the ", true),
                    (" onto the ", false),
                    (" on the ", false),
                ]
                .iter()
                .find_map(|(w, into)| {
                    l.split_once(w)
                        .map(|(a, b)| (a.to_owned(), b.to_owned(), *into))
                });
                let Some((a, b, into)) = rel else { continue };
                let find = |t: &str| objs.iter().position(|o| t.contains(&o.name.to_lowercase()));
                let (Some(oa), Some(ob)) = (find(&a), find(&b)) else {
                    continue;
                };
                let (ida, idb) = (objs[oa].id.clone(), objs[ob].id.clone());
                if into {
                    match interior(&objs[ob]) {
                        Some((pos, place_xy)) => {
                            goals.push(Goal::PoseWithin {
                                object: ida.clone(),
                                position: pos,
                                tolerance: 0.14,
                                yaw_deg: None,
                                yaw_tolerance_deg: None,
                                relative_to: None,
                                planar: false,
                                yaw_symmetry_deg: None,
                            });
                            oracle.push(Primitive::Pick {
                                object: ida.clone(),
                            });
                            oracle.push(Primitive::Place {
                                target: PlaceTarget::At(place_xy),
                            });
                            notes.inferred("goals", format!("'{s}' → pose_within({ida}) at the interior bottom centre of '{idb}' + 0.03 m, tolerance 0.14 (a URDF is no container, so in_container does not apply)"));
                            notes.inferred("oracle", format!("pick {ida} (substep 'grasp'), place at {place_xy:?}: inside '{idb}', 0.06 m from its centre away from the lid; the floor stops the descent ('release' is the place's release)"));
                            done = true;
                        }
                        None => {
                            notes.error(
                                "substeps",
                                format!("'{s}': cannot find the interior of '{}'", objs[ob].name),
                            );
                            fatal = true;
                        }
                    }
                } else {
                    goals.push(Goal::OnTopOf {
                        object: ida.clone(),
                        support: idb.clone(),
                    });
                    oracle.push(Primitive::Pick {
                        object: ida.clone(),
                    });
                    oracle.push(Primitive::Place {
                        target: PlaceTarget::On(idb.clone()),
                    });
                    notes.inferred("goals", format!("'{s}' → on_top_of({ida}, {idb})"));
                    notes.inferred("oracle", format!("pick {ida}, place on {idb}"));
                    done = true;
                }
                break;
            }
            if !done && !fatal {
                notes.error(
                    "substeps",
                    format!(
                        "no goal can be inferred from the substeps '{}'",
                        steps.join("; ")
                    ),
                );
                fatal = true;
            }
        }
    }
    notes.inferred("end_effector", "parallel_gripper, max_opening 0.08 (RoboGen's Franka); the imported objects and lids fit it");
    notes.inferred(
        "arm",
        "panda at Assay's robot base, the origin (RoboGen draws its robot at random; the Franka is one of them)",
    );
    let group = group_for(&name, Pipeline::Robogen, &mut notes);
    if !fatal {
        let mut spec = TaskSpec {
            spec_version: SPEC_VERSION,
            id: id.clone(),
            name: name.clone(),
            description,
            source: Source {
                pipeline: Pipeline::Robogen.name().into(),
                generator: None,
                origin: Some(origin.clone()),
                asset_root: Some(asset_root.display().to_string()),
                content_hash: Some(content_hash),
            },
            group,
            scene: Scene {
                surface,
                objects: objs.iter().map(|o| o.object.clone()).collect(),
                zones: Vec::new(),
                piles: Vec::new(),
            },
            end_effector: EndEffector::ParallelGripper {
                max_opening: 0.08,
                grasp: Default::default(),
            },
            arm: Some(assay_spec::spec::Arm {
                model: "panda".into(),
                base: [0.0; 3],
                base_yaw_deg: 0.0,
            }),
            goals,
            variations: Variations::default(),
            oracle,
            cameras: Vec::new(),
            physics: PhysicsSettings::default(),
        };
        if spec.scene.objects.iter().any(|o| !o.is_fixed) {
            spec.variations.position_jitter = super::JITTER;
        }
        notes.settle(&mut task, Some(spec));
    } else {
        notes.settle(&mut task, None);
    }
    Some(task)
}

/// Bounds of some boxes, and each box's bounds.
type BoxesBounds = ([f64; 3], [f64; 3], Vec<([f64; 3], [f64; 3])>);

/// The interior bottom centre of a URDF box (world, + 0.03 m) and a release point 0.06 m from
/// it away from the moving parts (a lid), from the boxes of its visuals.
fn interior(o: &Obj) -> Option<([f64; 3], [f64; 2])> {
    let (_, u) = o.urdf.as_ref()?;
    let Shape::Urdf { joints, .. } = &o.object.shape else {
        return None;
    };
    let parts = u.placed_visuals(joints).ok()?;
    // Links that move: children of non-fixed joints and their descendants.
    let mut moving: BTreeSet<usize> = u
        .joints
        .iter()
        .filter(|j| j.kind != JointKind::Fixed)
        .map(|j| j.child)
        .collect();
    loop {
        let before = moving.len();
        for j in &u.joints {
            if moving.contains(&j.parent) {
                moving.insert(j.child);
            }
        }
        if moving.len() == before {
            break;
        }
    }
    let bbox = |sel: &dyn Fn(usize) -> bool| -> Option<BoxesBounds> {
        let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
        let mut each = Vec::new();
        for p in parts.iter().filter(|p| sel(p.link)) {
            let Geometry::Box { size } = p.geometry else {
                continue;
            };
            let (mut plo, mut phi) = ([f64::MAX; 3], [f64::MIN; 3]);
            for c in 0..8 {
                let s = |b: usize| if c & (1 << b) == 0 { -0.5 } else { 0.5 };
                let q = p
                    .pose
                    .transform_point([s(0) * size[0], s(1) * size[1], s(2) * size[2]]);
                for k in 0..3 {
                    plo[k] = plo[k].min(q[k]);
                    phi[k] = phi[k].max(q[k]);
                }
            }
            for k in 0..3 {
                lo[k] = lo[k].min(plo[k]);
                hi[k] = hi[k].max(phi[k]);
            }
            each.push((plo, phi));
        }
        (lo[0] <= hi[0]).then_some((lo, hi, each))
    };
    let (alo, ahi, _) = bbox(&|_| true)?;
    let (blo, bhi, body) = bbox(&|l| !moving.contains(&l))?;
    let floor = body
        .iter()
        .filter(|(plo, _)| (plo[2] - blo[2]).abs() < 1e-3)
        .map(|(_, phi)| phi[2])
        .fold(f64::MAX, f64::min);
    let centre: [f64; 3] = std::array::from_fn(|k| (alo[k] + ahi[k]) / 2.0);
    let p = o.object.pose?.position;
    let world = |q: [f64; 3]| -> [f64; 3] { std::array::from_fn(|k| r6(p[k] + q[k] - centre[k])) };
    let bc = [(blo[0] + bhi[0]) / 2.0, (blo[1] + bhi[1]) / 2.0];
    let goal = world([bc[0], bc[1], floor + 0.03]);
    let mut dir = [1.0, 0.0];
    if let Some((llo, lhi, _)) = bbox(&|l| moving.contains(&l)) {
        let lc = [
            (llo[0] + lhi[0]) / 2.0 - bc[0],
            (llo[1] + lhi[1]) / 2.0 - bc[1],
        ];
        let n = (lc[0] * lc[0] + lc[1] * lc[1]).sqrt();
        if n > 1e-6 {
            dir = [-lc[0] / n, -lc[1] / n];
        }
    }
    Some((
        goal,
        [r3(goal[0] + 0.06 * dir[0]), r3(goal[1] + 0.06 * dir[1])],
    ))
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
