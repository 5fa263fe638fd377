//! GenSim (liruiw/GenSim): the task library `generated_tasks.json` plus one Python task class per
//! entry in `generated_tasks/`. The class's `reset` is read by a small line-based evaluator that
//! knows the Ravens task API (`env.add_object`, `self.get_random_pose`, `self.fill_template`,
//! `self.add_goal`, `utils.apply`, `for` loops over literals and `range`), never by running it.

use std::collections::BTreeMap;
use std::path::Path;

mod eval;

use super::{
    ImportedTask, JITTER, Notes, Pipeline, Placer, check_asset, group_for, hash_parts, r6, radius,
};
use assay_spec::error::SpecError;
use assay_spec::spec::{
    Color, EndEffector, Goal, Object, PhysicsSettings, PlaceTarget, Pose, Primitive, SPEC_VERSION,
    Scene, Shape, Source, Surface, TaskSpec, Variations, Zone,
};
use eval::*;

/// GenSim's workspace on the table (x, y), inside Assay's table top as it is.
/// The longest `range(n)` the evaluator unrolls (GenSim tasks place a handful of objects).
const MAX_RANGE: f64 = 1000.0;
const BOUNDS: ([f64; 2], [f64; 2]) = ([0.25, -0.5], [0.75, 0.5]);

/// GenSim colours missing from Assay's named palette (`utils.COLORS`, 0..1).
const EXTRA_COLORS: &[(&str, [f64; 3])] = &[
    ("indigo", [0.29, 0.0, 0.51]),
    ("violet", [0.56, 0.0, 1.0]),
    ("silver", [0.75, 0.75, 0.75]),
    ("gold", [0.86, 0.65, 0.13]),
    ("grey", [0.5, 0.5, 0.5]),
];

pub(crate) fn import(root: &Path, asset_root: &Path) -> (Vec<ImportedTask>, Vec<SpecError>) {
    let lib_path = root.join("generated_tasks.json");
    let origin = lib_path.display().to_string();
    let fail = |reason: String| SpecError {
        task: None,
        origin: origin.clone(),
        path: String::new(),
        reason,
    };
    let text = match std::fs::read_to_string(&lib_path) {
        Ok(t) => t,
        Err(e) => return (Vec::new(), vec![fail(format!("cannot read: {e}"))]),
    };
    let lib: serde_json::Map<String, serde_json::Value> = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            return (
                Vec::new(),
                vec![fail(format!("not a GenSim task library: {e}"))],
            );
        }
    };
    let tasks = lib
        .iter()
        .map(|(key, entry)| import_one(root, asset_root, &lib_path, key, entry))
        .collect();
    (tasks, Vec::new())
}

/// A task name that is safe as a file name: letters, digits, `-`, `_` and `.`, not starting
/// with `.` (so never `..`, a hidden file or a path).
fn is_plain_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

fn import_one(
    root: &Path,
    asset_root: &Path,
    lib_path: &Path,
    key: &str,
    entry: &serde_json::Value,
) -> ImportedTask {
    let name = entry
        .get("task-name")
        .and_then(|v| v.as_str())
        .unwrap_or(key)
        .to_owned();
    let id = {
        let lower = name.to_lowercase();
        if lower
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '_')
            && !lower.is_empty()
        {
            lower
        } else {
            super::slug(&name, '-')
        }
    };
    // The name becomes a file name: it must be one, not a path out of the library.
    if !is_plain_name(&name) {
        let mut notes = Notes::new(&id, &lib_path.display().to_string());
        notes.error(
            "task-name",
            format!(
                "'{name}' is not a plain task name (it would name a file outside \
                 generated_tasks/): only letters, digits, '-', '_' and '.', not starting with '.'"
            ),
        );
        return ImportedTask {
            id,
            name,
            source: lib_path.to_path_buf(),
            content_hash: hash_parts(&[("entry", entry.to_string().as_bytes())]),
            spec: None,
            mapping: Vec::new(),
            errors: notes.errors,
            episodes: Vec::new(),
        };
    }
    let code_rel = format!("generated_tasks/{}.py", name.replace('-', "_"));
    let code_path = root.join(&code_rel);
    let entry_json = serde_json::to_string(entry).unwrap_or_default();
    let code = std::fs::read(&code_path).ok();
    let content_hash = hash_parts(&[
        ("entry", entry_json.as_bytes()),
        ("code", code.as_deref().unwrap_or(&[])),
    ]);
    let (source, origin) = if code.is_some() {
        (code_path.clone(), code_path.display().to_string())
    } else {
        (lib_path.to_path_buf(), lib_path.display().to_string())
    };
    let mut notes = Notes::new(&id, &origin);
    let mut task = ImportedTask {
        id: id.clone(),
        name: name.clone(),
        source,
        content_hash: content_hash.clone(),
        spec: None,
        mapping: Vec::new(),
        errors: Vec::new(),
        episodes: Vec::new(),
    };
    let Some(code) = code else {
        notes.error(
            "",
            format!(
                "no task code: {code_rel} does not exist (library {})",
                lib_path.display()
            ),
        );
        task.errors = notes.errors;
        return task;
    };
    let code = String::from_utf8_lossy(&code).into_owned();
    let description = entry
        .get("task-description")
        .and_then(|v| v.as_str())
        .unwrap_or("")
        .to_owned();
    notes.mapped("task-name", format!("id '{id}', name '{name}'"));
    notes.mapped("task-description", "description");
    // assets-used: every one must exist under the asset root (GenSim's silent substitutions are
    // not imitated).
    let mut missing = Vec::new();
    if let Some(list) = entry.get("assets-used").and_then(|v| v.as_array()) {
        for (i, a) in list.iter().enumerate() {
            let a = a.as_str().unwrap_or("");
            if let Err(e) = check_asset(asset_root, a) {
                notes.error(
                    &format!("assets-used[{i}]"),
                    format!(
                        "URDF {e} (GenSim's env.add_object would silently load a substitute; the importer does not)"
                    ),
                );
                missing.push(a.to_owned());
            }
        }
        notes.mapped("assets-used", "checked against the asset root");
    }
    let spec = build(
        &id,
        &name,
        &description,
        &code,
        asset_root,
        &missing,
        &mut notes,
    );
    let spec = spec.filter(|_| notes.errors.is_empty()).map(|mut spec| {
        spec.source = Source {
            pipeline: Pipeline::Gensim.name().into(),
            generator: None,
            origin: Some(origin.clone()),
            asset_root: Some(asset_root.display().to_string()),
            content_hash: Some(content_hash),
        };
        spec
    });
    notes.settle(&mut task, spec);
    task
}

// ---------------------------------------------------------------------------------------------
// From the evaluation to a spec.

enum Kind {
    Object(Object),
    Zone(Zone),
}

fn color_of(name: Option<&str>) -> Color {
    match name {
        None => Color::default(),
        Some(n) => match EXTRA_COLORS.iter().find(|(k, _)| *k == n) {
            Some((_, rgb)) => Color::Rgb(*rgb),
            None => Color::Named(n.to_owned()),
        },
    }
}

#[allow(clippy::too_many_arguments)]
fn build(
    id: &str,
    name: &str,
    description: &str,
    code: &str,
    asset_root: &Path,
    missing: &[String],
    notes: &mut Notes,
) -> Option<TaskSpec> {
    let lines = logical_lines(code);
    // The class docstring and __init__ attributes.
    let class = lines.iter().position(|(_, t)| t.starts_with("class "));
    if let Some(c) = class
        && lines
            .get(c + 1)
            .is_some_and(|(_, t)| t.starts_with("\"\"\"") || t.starts_with("'''"))
    {
        notes.not_mapped(
            "docstring",
            "the class docstring is a longer variant of task-description, which is the description",
        );
    }
    let mut ev = Eval::default();
    ev.block(method(&lines, "__init__"));
    let attr = |ev: &Eval, k: &str| ev.vars.get(&format!("self.{k}")).cloned();
    if attr(&ev, "max_steps").is_some() {
        notes.not_mapped(
            "max_steps",
            "GenSim counts actions, Assay bounds physics steps (physics.max_steps keeps its default)",
        );
    }
    let lang = match attr(&ev, "lang_template") {
        Some(Val::Str(s)) => s,
        _ => String::new(),
    };
    if attr(&ev, "lang_template").is_some() {
        notes.not_mapped(
            "lang_template",
            "language templates are not part of spec v1 (used only to pick pose tolerances)",
        );
    }
    if attr(&ev, "task_completed_desc").is_some() {
        notes.not_mapped("task_completed_desc", "not part of spec v1");
    }
    let pos_eps = match attr(&ev, "pos_eps") {
        Some(Val::Num(x)) => Some(x),
        _ => None,
    };
    ev.vars.retain(|k, _| !k.starts_with("self."));
    ev.block(method(&lines, "reset"));

    let mut fatal = false;
    for (field, reason, is_fatal) in &ev.unmappable {
        notes.not_mapped(field, reason.clone());
        if *is_fatal {
            notes.error(field, format!("cannot import: {reason}"));
            fatal = true;
        }
    }

    // Objects.
    let mut kinds: Vec<Kind> = Vec::new();
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    let mut placer = Placer::new(id);
    // Zone sizes come from the zone goals' params: pose index → size.
    let mut zone_sizes: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for g in &ev.goals {
        if let Some(Val::Seq(params)) = g.kwargs.get("params") {
            for p in params {
                if let Val::Seq(pair) = p
                    && let (Some(Val::Pose(pi)), Some(Val::Seq(size))) = (pair.first(), pair.get(1))
                {
                    zone_sizes.insert(
                        *pi,
                        size.iter()
                            .map(|x| if let Val::Num(n) = x { *n } else { 0.0 })
                            .collect(),
                    );
                }
            }
        }
    }
    // Fixed objects first so that the movable ones are placed around them.
    let mut order: Vec<usize> = (0..ev.objects.len()).collect();
    order.sort_by_key(|&k| !ev.objects[k].fixed);
    let mut made: BTreeMap<usize, usize> = BTreeMap::new(); // add_object index → kinds index
    let mut positions: BTreeMap<usize, [f64; 3]> = BTreeMap::new(); // pose index → position
    for &k in &order {
        let o = &ev.objects[k];
        let field = format!("add_object[{k}]");
        let (path, template) = match &o.urdf {
            Val::Str(p) => (p.clone(), None),
            Val::Template { path, size } => (path.clone(), Some(size.clone())),
            other => {
                notes.error(&field, format!("cannot read the URDF argument {other:?}"));
                fatal = true;
                continue;
            }
        };
        if let Err(e) = check_asset(asset_root, &path) {
            if !missing.contains(&path) {
                notes.error(&field, format!("URDF {e}"));
            }
            fatal = true;
            continue;
        }
        let stem = Path::new(&path)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("object")
            .trim_end_matches("-template")
            .replace('-', "_");
        let base = match &o.color {
            Some(c) => format!("{}_{stem}", super::slug(c, '_')),
            None => stem.clone(),
        };
        let n = counts.entry(base.clone()).or_insert(0);
        let oid = if *n == 0 {
            base.clone()
        } else {
            format!("{base}_{n}")
        };
        *n += 1;
        let color = color_of(o.color.as_deref());
        let pose_size = o.pose.and_then(|p| ev.poses.get(p)).cloned();
        let (shape, half): (Option<Shape>, [f64; 3]) = match path.as_str() {
            "block/block.urdf" | "stacking/block.urdf" => (
                Some(Shape::Box {
                    half_extents: [0.02; 3],
                }),
                [0.02; 3],
            ),
            "box/box-template.urdf" => {
                let s = template.clone().unwrap_or_default();
                if s.len() != 3 {
                    notes.error(&field, "box template without a (x, y, z) DIM");
                    fatal = true;
                    continue;
                }
                let h = [r6(s[0] / 2.0), r6(s[1] / 2.0), r6(s[2] / 2.0)];
                (Some(Shape::Box { half_extents: h }), h)
            }
            "bowl/bowl.urdf" => (
                Some(Shape::Container {
                    inner_half_extents: [0.05, 0.05, 0.015],
                    wall: 0.01,
                }),
                [0.06, 0.06, 0.02],
            ),
            "zone/zone.urdf" => {
                let size = o
                    .pose
                    .and_then(|p| zone_sizes.get(&p).cloned())
                    .or(pose_size.clone())
                    .unwrap_or(vec![0.12, 0.12, 0.0]);
                (None, [size[0] / 2.0, size[1] / 2.0, 0.0])
            }
            _ => match assay_spec::urdf::assemble(&asset_root.join(&path), &BTreeMap::new()) {
                Ok(a) => (
                    Some(Shape::Urdf {
                        path: path.clone(),
                        joints: BTreeMap::new(),
                        articulated: false,
                    }),
                    a.half.map(r6),
                ),
                Err(e) => {
                    notes.error(&field, format!("URDF '{path}': {e}"));
                    fatal = true;
                    continue;
                }
            },
        };
        let r = radius(half);
        let lo = [BOUNDS.0[0] + r, BOUNDS.0[1] + r];
        let hi = [BOUNDS.1[0] - r, BOUNDS.1[1] - r];
        let Some(xy) = placer.place(lo, hi, r) else {
            notes.error(
                &field,
                "no collision-free position left in GenSim's workspace",
            );
            fatal = true;
            continue;
        };
        let z = r6(half[2]);
        if let Some(p) = o.pose {
            positions.insert(p, [xy[0], xy[1], z]);
        }
        match shape {
            Some(shape) => {
                notes.mapped(&field, format!("object '{oid}' from '{path}'"));
                kinds.push(Kind::Object(Object {
                    id: oid.clone(),
                    shape,
                    color,
                    mass: None,
                    is_fixed: o.fixed,
                    pose: Some(Pose {
                        position: [xy[0], xy[1], z],
                        yaw_deg: 0.0,
                    }),
                    pose_range: None,
                }));
            }
            None => {
                let zid = oid.clone();
                notes.mapped(
                    &field,
                    format!("zone '{zid}' (a flat marker, not an object) from '{path}'"),
                );
                kinds.push(Kind::Zone(Zone {
                    id: zid,
                    center: xy,
                    half_extents: [r6(half[0]), r6(half[1])],
                    color,
                }));
            }
        }
        made.insert(k, kinds.len() - 1);
    }
    if !ev.objects.is_empty() {
        notes.inferred(
            "get_random_pose",
            format!(
                "each random pose became one collision-free draw in GenSim's workspace (x 0.25-0.75, y -0.5-0.5) with position_jitter {JITTER} and yaw 0 (GenSim draws yaw 0-360; independent pose ranges could overlap)"
            ),
        );
    }
    if fatal {
        return None;
    }
    // Restore add_object order in the scene.
    let mut by_call: Vec<(usize, usize)> = made.iter().map(|(&k, &i)| (k, i)).collect();
    by_call.sort();
    let mut objects = Vec::new();
    let mut zones = Vec::new();
    let mut obj_ids: BTreeMap<usize, String> = BTreeMap::new();
    let mut pose_owner: BTreeMap<usize, (String, bool)> = BTreeMap::new(); // pose → (id, is container / zone)
    for (k, i) in by_call {
        match &kinds[i] {
            Kind::Object(o) => {
                obj_ids.insert(k, o.id.clone());
                if let Some(p) = ev.objects[k].pose {
                    pose_owner.insert(
                        p,
                        (o.id.clone(), matches!(o.shape, Shape::Container { .. })),
                    );
                }
                objects.push(o.clone());
            }
            Kind::Zone(z) => {
                if let Some(p) = ev.objects[k].pose {
                    pose_owner.insert(p, (z.id.clone(), false));
                }
                zones.push(z.clone());
            }
        }
    }

    // Goals.
    let mut goals = Vec::new();
    let mut oracle = Vec::new();
    let mut stack: Vec<(f64, String)> = Vec::new();
    let mut stack_base: Option<usize> = None;
    let mut stack_goal_at: Option<usize> = None;
    let obj_list = |v: Option<&Val>| -> Vec<String> {
        match v {
            Some(Val::Seq(items)) => items
                .iter()
                .filter_map(|x| match x {
                    Val::Obj(k) => obj_ids.get(k).cloned(),
                    _ => None,
                })
                .collect(),
            _ => Vec::new(),
        }
    };
    for (gi, g) in ev.goals.iter().enumerate() {
        let field = format!("add_goal[{gi}]");
        let metric = match g.kwargs.get("metric") {
            Some(Val::Str(m)) => m.clone(),
            _ => "pose".into(),
        };
        let objs = obj_list(g.kwargs.get("objs"));
        let targets: Vec<Val> = match g.kwargs.get("targ_poses") {
            Some(Val::Seq(t)) => t
                .iter()
                .map(|x| match x {
                    Val::Seq(pair) => pair.first().cloned().unwrap_or(Val::Other("".into())),
                    other => other.clone(),
                })
                .collect(),
            _ => Vec::new(),
        };
        for k in ["matches", "replace"] {
            if let Some(raw) = g.raw.get(k) {
                notes.not_mapped(
                    &format!("{field}.{k}"),
                    format!("'{raw}': GenSim's any-object-to-any-target assignment; each object gets its own goal"),
                );
            }
        }
        if g.raw.contains_key("step_max_reward") {
            notes.not_mapped(
                &format!("{field}.step_max_reward"),
                "goal order and partial reward: GenSim pops goals in sequence, Assay requires all goals at the end",
            );
        }
        if g.raw.contains_key("language_goal") {
            notes.not_mapped(&format!("{field}.language_goal"), "not part of spec v1");
        }
        if objs.is_empty() {
            notes.error(
                &format!("{field}.objs"),
                "no object of this goal could be mapped",
            );
            return None;
        }
        match metric.as_str() {
            "zone" => {
                let zone = match g.kwargs.get("params") {
                    Some(Val::Seq(p)) => p.first().and_then(|pair| match pair {
                        Val::Seq(pair) => match pair.first() {
                            Some(Val::Pose(pi)) => pose_owner.get(pi).map(|(id, _)| id.clone()),
                            _ => None,
                        },
                        _ => None,
                    }),
                    _ => None,
                };
                let Some(zone) = zone.filter(|z| zones.iter().any(|x| &x.id == z)) else {
                    notes.error(
                        &format!("{field}.params"),
                        "the zone pose is not the pose of a zone object",
                    );
                    return None;
                };
                for o in &objs {
                    goals.push(Goal::InZone {
                        object: o.clone(),
                        zone: zone.clone(),
                    });
                    oracle.push(Primitive::Pick { object: o.clone() });
                    oracle.push(Primitive::Place {
                        target: PlaceTarget::Zone(zone.clone()),
                    });
                }
                notes.mapped(
                    &format!("{field}.metric"),
                    format!("'zone' → in_zone({zone}) for each object"),
                );
                notes.not_mapped(
                    &format!("{field}.params"),
                    "zone partial credit: GenSim counts the fraction of the object's points inside the zone, Assay tests the centre",
                );
            }
            "pose" => {
                for (oi, o) in objs.iter().enumerate() {
                    let t = targets.get(oi).or(targets.first()).cloned();
                    match t {
                        Some(Val::Stack { base, dz }) => {
                            stack.push((dz, o.clone()));
                            stack_base = Some(base);
                            stack_goal_at.get_or_insert(goals.len());
                        }
                        Some(Val::Pose(p)) => match pose_owner.get(&p) {
                            Some((c, true)) => {
                                goals.push(Goal::InContainer {
                                    object: o.clone(),
                                    container: c.clone(),
                                });
                                oracle.push(Primitive::Pick { object: o.clone() });
                                oracle.push(Primitive::Place {
                                    target: PlaceTarget::Into(c.clone()),
                                });
                                notes.mapped(
                                    &format!("{field}.targ_poses"),
                                    format!("the pose of container '{c}' → in_container({o}, {c})"),
                                );
                            }
                            owner => {
                                let position = match owner {
                                    Some(_) => positions.get(&p).copied(),
                                    None => {
                                        let size = ev.poses[p].clone();
                                        let h = [size[0] / 2.0, size[1] / 2.0, size[2] / 2.0];
                                        let r = radius(h);
                                        placer
                                            .place(
                                                [BOUNDS.0[0] + r, BOUNDS.0[1] + r],
                                                [BOUNDS.1[0] - r, BOUNDS.1[1] - r],
                                                r,
                                            )
                                            .map(|xy| [xy[0], xy[1], r6(h[2])])
                                    }
                                };
                                let Some(position) = position else {
                                    notes.error(
                                        &format!("{field}.targ_poses"),
                                        "no free target position",
                                    );
                                    return None;
                                };
                                let tolerance = if lang.contains("bowl") {
                                    0.05
                                } else if lang.contains("rope") {
                                    0.02
                                } else {
                                    pos_eps.unwrap_or(0.01)
                                };
                                let sym = match g.kwargs.get("symmetries") {
                                    Some(Val::Seq(s)) => {
                                        matches!(s.first(), Some(Val::Num(x)) if *x > 0.0)
                                    }
                                    _ => false,
                                };
                                goals.push(Goal::PoseWithin {
                                    object: o.clone(),
                                    position,
                                    tolerance,
                                    yaw_deg: sym.then_some(0.0),
                                    yaw_tolerance_deg: sym.then_some(15.0),
                                });
                                oracle.push(Primitive::Pick { object: o.clone() });
                                oracle.push(Primitive::Place {
                                    target: PlaceTarget::At([position[0], position[1]]),
                                });
                                notes.mapped(
                                    &format!("{field}.targ_poses"),
                                    format!("a pose → pose_within({o}), tolerance {tolerance} m"),
                                );
                            }
                        },
                        _ => {
                            notes.error(
                                &format!("{field}.targ_poses"),
                                "target pose not understood",
                            );
                            return None;
                        }
                    }
                }
                if g.raw.contains_key("rotations") {
                    notes.not_mapped(
                        &format!("{field}.rotations"),
                        "in_container and stacked do not test yaw; pose_within tests it only with a symmetry",
                    );
                }
                if g.raw.contains_key("symmetries") {
                    notes.not_mapped(
                        &format!("{field}.symmetries"),
                        "yaw symmetry: only a pose_within yaw tolerance (15°) keeps it",
                    );
                }
            }
            other => {
                notes.error(
                    &format!("{field}.metric"),
                    format!("unknown metric '{other}' (GenSim has 'pose' and 'zone')"),
                );
                return None;
            }
        }
    }
    if !stack.is_empty() {
        stack.sort_by(|a, b| a.0.total_cmp(&b.0));
        let order: Vec<String> = stack.into_iter().map(|(_, o)| o).collect();
        let at = stack_goal_at.unwrap_or(goals.len());
        goals.insert(
            at,
            Goal::Stacked {
                order: order.clone(),
            },
        );
        let size = stack_base
            .map(|b| ev.poses[b].clone())
            .unwrap_or(vec![0.04; 3]);
        let r = radius([size[0] / 2.0, size[1] / 2.0, 0.0]);
        let Some(spot) = placer.place(
            [BOUNDS.0[0] + r, BOUNDS.0[1] + r],
            [BOUNDS.1[0] - r, BOUNDS.1[1] - r],
            r,
        ) else {
            notes.error("add_goal", "no free spot for the stack");
            return None;
        };
        let mut plan = vec![
            Primitive::Pick {
                object: order[0].clone(),
            },
            Primitive::Place {
                target: PlaceTarget::At(spot),
            },
        ];
        for w in order.windows(2) {
            plan.push(Primitive::Pick {
                object: w[1].clone(),
            });
            plan.push(Primitive::Place {
                target: PlaceTarget::On(w[0].clone()),
            });
        }
        // The stack's plan goes where its first goal was.
        let before = oracle.len().min(2 * at);
        oracle.splice(before..before, plan);
        notes.inferred(
            "add_goal.targ_poses",
            format!(
                "poses stacked over one base pose (utils.apply) → stacked [{}], bottom first",
                order.join(", ")
            ),
        );
        notes.not_mapped(
            "stack base pose",
            "the random base position of the stack: any free spot counts (GenSim's pose match compares x, y only, so its stack goals never test height)",
        );
    }
    notes.inferred(
        "oracle",
        "per goal: pick, then place into the container / in the zone / on the block below (the stack's first block at a free spot)",
    );
    notes.mapped(
        "end_effector",
        "suction (Ravens' default self.ee = Suction)",
    );
    notes.mapped(
        "arm",
        "ur5 at the origin (Ravens' UR5 stands at (0, 0, 0) facing +x; its workspace x 0.25-0.75 m)",
    );
    let group = group_for(name, Pipeline::Gensim, notes);
    Some(TaskSpec {
        spec_version: SPEC_VERSION,
        id: id.into(),
        name: name.into(),
        description: description.into(),
        source: Source::default(),
        group,
        scene: Scene {
            surface: Surface::Table,
            objects,
            zones,
            piles: Vec::new(),
        },
        end_effector: EndEffector::Suction,
        arm: Some(assay_spec::spec::Arm {
            model: "ur5".into(),
            base: [0.0; 3],
            base_yaw_deg: 0.0,
        }),
        goals,
        variations: Variations {
            position_jitter: JITTER,
            ..Variations::default()
        },
        oracle,
        cameras: Vec::new(),
        physics: PhysicsSettings::default(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_and_args() {
        let (pos, kw) = args("block_urdf, block_pose, 'fixed', color=utils.COLORS[color]");
        assert_eq!(pos, ["block_urdf", "block_pose", "'fixed'"]);
        assert_eq!(kw["color"], "utils.COLORS[color]");
        assert_eq!(split_top("(a, b), [c, d]", ','), ["(a, b)", "[c, d]"]);
    }

    #[test]
    fn loops_unroll() {
        let code = "def reset(self, env):\n    objs = []\n    for c in ['red', 'blue']:\n        p = self.get_random_pose(env, (0.04, 0.04, 0.04))\n        o = env.add_object('block/block.urdf', p, color=utils.COLORS[c])\n        objs.append(o)\n";
        let lines = logical_lines(code);
        let mut ev = Eval::default();
        ev.block(method(&lines, "reset"));
        assert_eq!(ev.objects.len(), 2);
        assert_eq!(ev.objects[1].color.as_deref(), Some("blue"));
        assert_eq!(ev.vars["objs"], Val::Seq(vec![Val::Obj(0), Val::Obj(1)]));
    }

    #[test]
    fn huge_ranges_are_not_unrolled() {
        // Found by core/tests/fuzz.rs: a number in a task file replaced by 4294967296 made the
        // evaluator allocate 200 GB and abort.
        let mut ev = Eval::default();
        assert!(matches!(ev.eval("range(4294967296)"), Val::Other(_)));
        assert!(matches!(ev.eval("range(1e308)"), Val::Other(_)));
        assert_eq!(
            ev.eval("range(2)"),
            Val::Seq(vec![Val::Num(0.0), Val::Num(1.0)])
        );
        assert_eq!(ev.eval("range(-3)"), Val::Seq(vec![]));
    }
}
