//! BBSEA (yangsizhe/bbsea): scene configs `config/scene/{id}.yaml` with MJCF assets, and per task
//! a log directory `output/log/{scene}/{description}/` of episodes the LLM labelled itself.
//! Goals come from the LLM's primitive decomposition (`Pick`, `PlaceOn`, `Push`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{
    ImportedEpisode, ImportedTask, JITTER, Notes, Pipeline, Placer, check_asset, group_for,
    hash_parts, r6, radius,
};
use assay_spec::error::SpecError;
use assay_spec::spec::{
    Color, EndEffector, Goal, Object, PhysicsSettings, PlaceTarget, Pose, Primitive, SPEC_VERSION,
    Scene, Shape, Source, Surface, TaskSpec, Variations,
};

/// Copies of one asset a scene may ask for (`number`), as many as a pile may hold.
const MAX_NUMBER: u64 = assay_spec::spec::MAX_PILE as u64;

/// One asset instance of a scene.
#[derive(Clone)]
struct Inst {
    name: String,
    id: String,
    shape: Shape,
    half: [f64; 3],
    color: Color,
    xy: ([f64; 2], [f64; 2]),
    index: usize,
    roll_pitch: bool,
}

struct SceneCfg {
    bytes: Vec<u8>,
    path: PathBuf,
    instances: Vec<Inst>,
    fixed: Vec<String>,
}

pub(crate) fn import(root: &Path, asset_root: &Path) -> (Vec<ImportedTask>, Vec<SpecError>) {
    let mut errors = Vec::new();
    let mut scenes: BTreeMap<String, Result<SceneCfg, String>> = BTreeMap::new();
    let scene_dir = root.join("config/scene");
    let files = super::sorted_entries(&scene_dir, |_| true);
    for f in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "yaml"))
    {
        let sid = f
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("")
            .to_owned();
        match read_scene(f, asset_root) {
            Ok(s) => {
                scenes.insert(sid, Ok(s));
            }
            Err((path, reason)) => {
                let e = SpecError {
                    task: None,
                    origin: f.display().to_string(),
                    path,
                    reason: format!("scene {sid}: {reason}"),
                };
                scenes.insert(sid, Err(e.to_string()));
                errors.push(e);
            }
        }
    }
    let mut tasks = Vec::new();
    let log = root.join("output/log");
    for sdir in super::sorted_entries(&log, Path::is_dir) {
        let sid = sdir
            .file_name()
            .and_then(|s| s.to_str())
            .unwrap_or("")
            .to_owned();
        for t in super::sorted_entries(&sdir, Path::is_dir) {
            tasks.push(import_task(&t, &sid, scenes.get(&sid), asset_root));
        }
    }
    (tasks, errors)
}

fn read_scene(f: &Path, asset_root: &Path) -> Result<SceneCfg, (String, String)> {
    let bytes = std::fs::read(f).map_err(|e| (String::new(), e.to_string()))?;
    let doc: serde_yaml_ng::Value =
        serde_yaml_ng::from_slice(&bytes).map_err(|e| (String::new(), e.to_string()))?;
    let fixed = doc
        .get("fixed_objects")
        .and_then(|v| v.as_sequence())
        .map(|s| {
            s.iter()
                .filter_map(|o| o.get("name").and_then(|n| n.as_str()).map(str::to_owned))
                .collect()
        })
        .unwrap_or_default();
    let mut instances = Vec::new();
    let assets = doc
        .get("assets")
        .and_then(|v| v.as_sequence())
        .cloned()
        .unwrap_or_default();
    for (i, a) in assets.iter().enumerate() {
        let field = |k: &str| format!("assets[{i}].{k}");
        let name = a
            .get("name")
            .and_then(|v| v.as_str())
            .unwrap_or("")
            .to_owned();
        let number = a.get("number").and_then(|v| v.as_u64()).unwrap_or(1);
        // A scene of thousands of copies is a typo, and unbounded it is an allocation of any
        // size (core/tests/fuzz.rs ran out of 24 GB on one).
        if number > MAX_NUMBER {
            return Err((
                field("number"),
                format!("'{name}': {number} copies; at most {MAX_NUMBER} are imported"),
            ));
        }
        let number = number as usize;
        let model = a.get("model_path").and_then(|v| v.as_str()).unwrap_or("");
        let ranges: Vec<Vec<f64>> = a
            .get("qpos_ranges")
            .and_then(|v| v.as_sequence())
            .map(|s| {
                s.iter()
                    .map(|r| {
                        r.as_sequence()
                            .map(|p| p.iter().filter_map(|x| x.as_f64()).collect())
                            .unwrap_or_default()
                    })
                    .collect()
            })
            .unwrap_or_default();
        if ranges.len() != 6 || ranges.iter().any(|r| r.len() != 2) {
            return Err((
                field("qpos_ranges"),
                format!(
                    "'{name}': expected 6 [low, high] ranges (x, y, z, roll, pitch, yaw), found {}",
                    ranges.len()
                ),
            ));
        }
        let full = check_asset(asset_root, model).map_err(|e| (field("model_path"), e))?;
        let (shape, half, color) = mjcf(&full).map_err(|e| (field("model_path"), e))?;
        let roll_pitch = ranges[3] != [0.0, 0.0] || ranges[4] != [0.0, 0.0];
        for k in 0..number {
            let iname = if number > 1 {
                format!("{name} {k}")
            } else {
                name.clone()
            };
            instances.push(Inst {
                id: super::slug(&iname, '_'),
                name: iname,
                shape: shape.clone(),
                half,
                color: color.clone(),
                xy: ([ranges[0][0], ranges[1][0]], [ranges[0][1], ranges[1][1]]),
                index: i,
                roll_pitch,
            });
        }
    }
    Ok(SceneCfg {
        bytes,
        path: f.to_path_buf(),
        instances,
        fixed,
    })
}

/// A body of box geoms: one box → `box`, an open box of five → `container`.
fn mjcf(path: &Path) -> Result<(Shape, [f64; 3], Color), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let doc = roxmltree::Document::parse(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let nums = |s: Option<&str>| -> Vec<f64> {
        s.unwrap_or("")
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect()
    };
    let geoms: Vec<_> = doc
        .descendants()
        .filter(|n| n.has_tag_name("geom"))
        .collect();
    let coll: Vec<_> = geoms
        .iter()
        .filter(|g| g.attribute("class") == Some("collision"))
        .collect();
    let use_: Vec<_> = if coll.is_empty() {
        geoms.iter().collect()
    } else {
        coll
    };
    let mut boxes = Vec::new();
    let mut color = Color::default();
    for g in &use_ {
        if g.attribute("type").unwrap_or("sphere") != "box" {
            return Err(format!("{}: only box geoms are mapped", path.display()));
        }
        let size = nums(g.attribute("size"));
        let mut pos = nums(g.attribute("pos"));
        pos.resize(3, 0.0);
        if size.len() != 3 {
            return Err(format!("{}: a box geom needs 3 half-sizes", path.display()));
        }
        if let Some(rgba) = g.attribute("rgba") {
            let c = nums(Some(rgba));
            if c.len() >= 3 {
                color = Color::Rgb([c[0], c[1], c[2]]);
            }
        }
        boxes.push((pos, size));
    }
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for (p, s) in &boxes {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] - s[k]);
            hi[k] = hi[k].max(p[k] + s[k]);
        }
    }
    let half: [f64; 3] = std::array::from_fn(|k| r6((hi[k] - lo[k]) / 2.0));
    match boxes.len() {
        1 => Ok((
            Shape::Box {
                half_extents: boxes[0].1.clone().try_into().unwrap(),
            },
            half,
            color,
        )),
        5 => {
            let bottom = boxes
                .iter()
                .min_by(|a, b| a.0[2].total_cmp(&b.0[2]))
                .unwrap();
            let wall = r6(2.0 * bottom.1[2]);
            Ok((
                Shape::Container {
                    inner_half_extents: [
                        r6(half[0] - wall),
                        r6(half[1] - wall),
                        r6((2.0 * half[2] - wall) / 2.0),
                    ],
                    wall,
                },
                half,
                color,
            ))
        }
        n => Err(format!(
            "{}: {n} box geoms is neither a box nor an open box of five",
            path.display()
        )),
    }
}

fn import_task(
    dir: &Path,
    sid: &str,
    scene: Option<&Result<SceneCfg, String>>,
    asset_root: &Path,
) -> ImportedTask {
    let description = dir
        .file_name()
        .and_then(|s| s.to_str())
        .unwrap_or("")
        .to_owned();
    let id = super::slug(&description, '-');
    let origin = dir.display().to_string();
    let mut notes = Notes::new(&id, &origin);
    // Episodes.
    let files = super::sorted_entries(dir, |_| true);
    let mut episodes = Vec::new();
    let mut logs: Vec<(String, Vec<u8>)> = Vec::new();
    for f in &files {
        let fname = f.file_name().and_then(|s| s.to_str()).unwrap_or("");
        if let Some(stem) = fname.strip_suffix(".mp4") {
            let Some((eid, raw)) = stem.rsplit_once('_') else {
                continue;
            };
            let label = match raw {
                "True" => Some(true),
                "False" => Some(false),
                _ => None,
            };
            let log = dir.join(format!("log_{eid}.txt"));
            episodes.push(ImportedEpisode {
                id: eid.into(),
                video: f.clone(),
                log: log.is_file().then_some(log),
                label,
                label_source: "llm".into(),
                raw_label: raw.into(),
            });
        } else if fname.starts_with("log_") && fname.ends_with(".txt") {
            logs.push((fname.to_owned(), std::fs::read(f).unwrap_or_default()));
        }
    }
    let names: String = episodes
        .iter()
        .map(|e| format!("{}_{}\n", e.id, e.raw_label))
        .collect();
    let scene_bytes = match scene {
        Some(Ok(s)) => s.bytes.clone(),
        _ => Vec::new(),
    };
    let mut parts: Vec<(&str, &[u8])> = vec![
        ("description", description.as_bytes()),
        ("scene", &scene_bytes),
        ("episodes", names.as_bytes()),
    ];
    for (n, b) in &logs {
        parts.push((n, b));
    }
    let content_hash = hash_parts(&parts);
    let mut task = ImportedTask {
        id: id.clone(),
        name: description.clone(),
        source: dir.to_path_buf(),
        content_hash: content_hash.clone(),
        spec: None,
        mapping: Vec::new(),
        errors: Vec::new(),
        episodes,
    };
    notes.mapped(
        "description",
        format!("the directory name, verbatim; id '{id}'"),
    );
    notes.mapped(
        "episodes",
        "one per video, labelled by the LLM (not sure → no label)",
    );
    notes.not_mapped(
        "log: task_decomposition_reasoning, scene_graph_list, infer_info",
        "the LLM's reasoning and scene graphs are episode metadata, not part of spec v1",
    );
    notes.not_mapped(
        "output/trajectory",
        "BBSEA's trajectories (.mdb) are replay data, not part of spec v1",
    );
    let sc = match scene {
        Some(Ok(s)) => s,
        Some(Err(e)) => {
            notes.error("scene", format!("scene {sid} cannot be read: {e}"));
            task.mapping = notes.mapping;
            task.errors = notes.errors;
            return task;
        }
        None => {
            notes.error("scene", format!("no scene config config/scene/{sid}.yaml"));
            task.mapping = notes.mapping;
            task.errors = notes.errors;
            return task;
        }
    };
    for f in &sc.fixed {
        notes.not_mapped(&format!("fixed_objects.{f}"), "BBSEA's fixed objects (drawer, cupboard, ...) are hard-coded in environment/bebs_scene.py, not in the scene file");
    }
    // Objects, one collision-free draw each.
    let mut placer = Placer::new(&id);
    let mut objects = Vec::new();
    for inst in &sc.instances {
        let r = radius(inst.half);
        let (lo, hi) = inst.xy;
        let Some(xy) = placer.place([lo[0], lo[1]], [hi[0], hi[1]], r) else {
            notes.error(
                &format!("assets[{}].qpos_ranges", inst.index),
                format!("no collision-free position for '{}'", inst.name),
            );
            task.mapping = notes.mapping;
            task.errors = notes.errors;
            return task;
        };
        if inst.roll_pitch {
            let why = if matches!(inst.shape, Shape::Box { half_extents } if half_extents[0] == half_extents[1] && half_extents[1] == half_extents[2])
            {
                "harmless for a cube"
            } else {
                "the object starts upright"
            };
            notes.not_mapped(
                &format!("assets[{}].qpos_ranges[3..5]", inst.index),
                format!(
                    "'{}': roll and pitch ranges are not representable ({why})",
                    inst.name
                ),
            );
        }
        objects.push(Object {
            id: inst.id.clone(),
            shape: inst.shape.clone(),
            color: Some(inst.color.clone()),
            mass: None,
            is_fixed: false,
            pose: Some(Pose {
                position: [xy[0], xy[1], r6(inst.half[2])],
                yaw_deg: 0.0,
            }),
            pose_range: None,
        });
    }
    notes.inferred("qpos_ranges", format!("each asset: one collision-free draw in its x, y ranges, resting on the table (z range is a drop height), yaw 0, position_jitter {JITTER} (independent pose ranges could overlap; BBSEA drops the objects and lets them settle)"));
    notes.mapped("assets", format!("{} object(s) from {} (number > 1: `name k`); none fixed (BBSEA gives every asset a free joint)", objects.len(), sc.path.display()));
    // Goals from the first log's primitive list.
    let plan = logs
        .first()
        .map(|(_, b)| String::from_utf8_lossy(b).into_owned())
        .and_then(|t| {
            let (_, rest) = t.split_once("primitive_action_list:")?;
            rest.lines()
                .map(str::trim)
                .find(|l| !l.is_empty())
                .map(str::to_owned)
        });
    let Some(plan) = plan else {
        notes.error(
            "log.primitive_action_list",
            "no log with a primitive_action_list: the goal cannot be inferred",
        );
        task.mapping = notes.mapping;
        task.errors = notes.errors;
        return task;
    };
    let by_name = |n: &str| sc.instances.iter().find(|i| i.name == n).cloned();
    let mut goals = Vec::new();
    let mut oracle = Vec::new();
    let mut held: Option<String> = None;
    for call in plan.split(';').map(str::trim).filter(|c| !c.is_empty()) {
        let (f, args) = call.split_once('(').unwrap_or((call, ""));
        let arg0 = args
            .split(',')
            .next()
            .unwrap_or("")
            .trim()
            .trim_end_matches(')')
            .trim_matches(|c| c == '\'' || c == '"');
        let obj = by_name(arg0);
        match (f.trim(), obj) {
            ("Pick", Some(o)) => {
                oracle.push(Primitive::Pick {
                    object: o.id.clone(),
                });
                held = Some(o.id.clone());
            }
            ("PlaceOn", Some(t)) => {
                let Some(h) = held.take() else { continue };
                if matches!(t.shape, Shape::Container { .. }) {
                    goals.push(Goal::InContainer {
                        object: h.clone(),
                        container: t.id.clone(),
                    });
                    oracle.push(Primitive::Place {
                        target: PlaceTarget::Into(t.id.clone()),
                    });
                } else {
                    goals.push(Goal::OnTopOf {
                        object: h.clone(),
                        support: t.id.clone(),
                    });
                    oracle.push(Primitive::Place {
                        target: PlaceTarget::On(t.id.clone()),
                    });
                }
            }
            ("Push", _) => {
                notes.error("log.primitive_action_list", format!("{call}: a push has no goal predicate here (\"{description}\": spec v1 has no \"to the left of\"); not imported"));
            }
            _ => {
                notes.error(
                    "log.primitive_action_list",
                    format!("{call}: unknown primitive or object"),
                );
            }
        }
    }
    if notes.errors.is_empty() && goals.is_empty() {
        notes.error(
            "log.primitive_action_list",
            format!("'{plan}': no goal can be inferred"),
        );
    }
    if !notes.errors.is_empty() {
        task.mapping = notes.mapping;
        task.errors = notes.errors;
        return task;
    }
    notes.inferred("goals", format!("from the LLM's primitives '{plan}': PlaceOn a container → in_container, PlaceOn an object → on_top_of"));
    notes.inferred("oracle", format!("'{plan}' as pick / place"));
    notes.inferred(
        "end_effector",
        "parallel_gripper, max_opening 0.08 (BBSEA's Franka Panda; its objects are 3-5 cm cubes)",
    );
    let group = group_for(&description, Pipeline::Bbsea, &mut notes);
    let spec = TaskSpec {
        spec_version: SPEC_VERSION,
        id: id.clone(),
        name: description.clone(),
        description,
        source: Source {
            pipeline: Pipeline::Bbsea.name().into(),
            generator: None,
            origin: Some(origin.clone()),
            asset_root: Some(asset_root.display().to_string()),
            content_hash: Some(content_hash),
        },
        group,
        scene: Scene {
            surface: Surface::Table,
            objects,
            zones: Vec::new(),
            piles: Vec::new(),
        },
        end_effector: EndEffector::ParallelGripper {
            max_opening: 0.08,
            grasp: Default::default(),
        },
        arm: None,
        goals,
        variations: Variations {
            position_jitter: JITTER,
            ..Variations::default()
        },
        oracle,
        cameras: Vec::new(),
        physics: PhysicsSettings::default(),
        layouts: Vec::new(),
        reward_steps: Vec::new(),
    };
    notes.settle(&mut task, Some(spec));
    task
}
