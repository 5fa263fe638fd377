//! RoboGen (Genesis-Embodied-AI/RoboGen): task YAMLs (a list of one-key-group dicts) with a
//! solution folder of substeps. Goals are inferred from the substeps: lid and door tasks become
//! joint goals on an articulated URDF, "put X into Y" a placement goal.
//!
//! Owns: finding the task YAMLs, reading one with its solution folder, and assembling the spec.
//! The scene's objects are read in `objects`, the goals and the oracle inferred in `goals`.

mod goals;
mod objects;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_yaml_ng::Value;

use super::{ImportedTask, Notes, Pipeline, group_for, hash_parts};
use assay_spec::error::SpecError;
use assay_spec::spec::{
    EndEffector, Goal, Object, PhysicsSettings, Primitive, SPEC_VERSION, Scene, Source, Surface,
    TaskSpec, Variations,
};

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

/// Joint values by object (its name in lowercase), then by joint, as the YAML writes them.
type JointValues = BTreeMap<String, BTreeMap<String, String>>;

fn task_id(name: &str) -> String {
    let n = name.replace('\u{2019}', "'").replace('\'', "");
    super::slug(&n, '-')
}

fn str_of(v: &Value) -> Option<String> {
    match v {
        Value::String(s) => Some(s.clone()),
        Value::Number(n) => Some(n.to_string()),
        Value::Bool(b) => Some(b.to_string()),
        _ => None,
    }
}

/// The first item of `items` that has `key`: its index and the value.
fn field<'v>(items: &'v [Value], key: &str) -> Option<(usize, &'v Value)> {
    items
        .iter()
        .enumerate()
        .find_map(|(i, it)| it.get(key).map(|v| (i, v)))
}

fn import_one(root: &Path, asset_root: &Path, file: &Path) -> Option<ImportedTask> {
    let bytes = std::fs::read(file).ok()?;
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let doc: Value = serde_yaml_ng::from_str(&text).ok()?;
    let items = doc.as_sequence()?.clone();
    let name_raw = field(&items, "task_name").and_then(|(_, v)| str_of(v))?;
    let name = name_raw.replace('\u{2019}', "'");
    let id = task_id(&name_raw);
    let origin = file.display().to_string();
    let notes = Notes::new(&id, &origin);
    let description = field(&items, "task_description")
        .and_then(|(_, v)| str_of(v))
        .unwrap_or_default();
    let solution = Solution::read(
        root,
        file,
        field(&items, "solution_path").and_then(|(_, v)| str_of(v)),
    );
    let mut task = ImportedTask {
        id: id.clone(),
        name: name.clone(),
        source: file.to_path_buf(),
        content_hash: solution.content_hash(&bytes),
        spec: None,
        mapping: Vec::new(),
        errors: Vec::new(),
        episodes: Vec::new(),
    };
    let mut t = TaskYaml {
        asset_root,
        items: &items,
        use_table: true,
        notes,
        objs: Vec::new(),
        goals: Vec::new(),
        oracle: Vec::new(),
        fatal: false,
    };
    t.notes
        .mapped("task_name", format!("id '{id}', name '{name}'"));
    t.notes.mapped("task_description", "description");
    t.surface();
    let joint_values = t.joint_values();
    t.objects(&joint_values);
    t.scene_notes();
    t.overlaps();
    t.infer_goals(&name, &solution);
    t.finish(&mut task, description);
    Some(task)
}

/// A task's solution folder (`solution_path`): the substep lists and the solution code.
struct Solution {
    dir: Option<PathBuf>,
    substeps: Vec<u8>,
    types: Vec<u8>,
    spaces: Vec<u8>,
    /// The `*.py` files, by name.
    py: Vec<(String, Vec<u8>)>,
}

impl Solution {
    /// The folder `solution` names for the task in `file`: relative to the RoboGen root; a batch
    /// copied elsewhere keeps the folder next to the YAML. Files that cannot be read are empty.
    fn read(root: &Path, file: &Path, solution: Option<String>) -> Self {
        let dir = solution.as_ref().map(|s| {
            let d = root.join(s);
            match (d.is_dir(), Path::new(s).file_name(), file.parent()) {
                (false, Some(last), Some(dir)) if dir.join(last).is_dir() => dir.join(last),
                _ => d,
            }
        });
        let read = |n: &str| -> Vec<u8> {
            dir.as_ref()
                .and_then(|d| std::fs::read(d.join(n)).ok())
                .unwrap_or_default()
        };
        let (substeps, types, spaces) = (
            read("substeps.txt"),
            read("substep_types.txt"),
            read("action_spaces.txt"),
        );
        let mut py: Vec<(String, Vec<u8>)> = dir
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
        Solution {
            dir,
            substeps,
            types,
            spaces,
            py,
        }
    }

    /// The hash of the task: its YAML's bytes and its solution's.
    fn content_hash(&self, yaml: &[u8]) -> String {
        let mut parts: Vec<(&str, &[u8])> = vec![
            ("yaml", yaml),
            ("substeps", &self.substeps),
            ("substep_types", &self.types),
            ("action_spaces", &self.spaces),
        ];
        for (n, b) in &self.py {
            parts.push((n, b));
        }
        hash_parts(&parts)
    }
}

/// One task YAML on its way to a spec: its items, what was read from them so far, and whether
/// a problem already rules the spec out (`fatal`; the import goes on to report every problem).
struct TaskYaml<'a> {
    asset_root: &'a Path,
    items: &'a [Value],
    /// `use_table`: the scene stands on the table, else on the ground.
    use_table: bool,
    notes: Notes,
    objs: Vec<Obj>,
    goals: Vec<Goal>,
    oracle: Vec<Primitive>,
    fatal: bool,
}

impl TaskYaml<'_> {
    /// An error at `field` that rules the spec out.
    fn fail(&mut self, field: &str, reason: impl Into<String>) {
        self.notes.error(field, reason);
        self.fatal = true;
    }

    /// `use_table`: the table (the default) or the ground.
    fn surface(&mut self) {
        self.use_table = field(self.items, "use_table")
            .and_then(|(_, v)| v.as_bool())
            .unwrap_or(true);
        self.notes.mapped(
            "use_table",
            format!(
                "surface {}",
                if self.use_table { "table" } else { "ground" }
            ),
        );
    }

    /// The items that set an object's joints (`set_joint_angle_object_name`).
    fn joint_values(&mut self) -> JointValues {
        let mut joint_values = JointValues::new();
        let items = self.items;
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
                self.notes.mapped(
                    &format!("[{i}]"),
                    format!(
                        "joint values of '{target}' (fraction of range, clamped to {}-{})",
                        JOINT_CLAMP.0, JOINT_CLAMP.1
                    ),
                );
                joint_values.insert(target.to_lowercase(), m);
            }
        }
        joint_values
    }

    /// Ends the import of `task`: the notes on what every RoboGen task gets (the tool, the arm),
    /// the group, and the spec unless a problem ruled it out.
    fn finish(self, task: &mut ImportedTask, description: String) {
        let TaskYaml {
            asset_root,
            use_table,
            mut notes,
            objs,
            goals,
            oracle,
            fatal,
            ..
        } = self;
        notes.inferred("end_effector", "parallel_gripper, max_opening 0.08 (RoboGen's Franka); the imported objects and lids fit it");
        notes.inferred(
            "arm",
            "panda at Assay's robot base, the origin (RoboGen draws its robot at random; the Franka is one of them)",
        );
        let group = group_for(&task.name, Pipeline::Robogen, &mut notes);
        if fatal {
            notes.settle(task, None);
            return;
        }
        let mut spec = TaskSpec {
            spec_version: SPEC_VERSION,
            id: task.id.clone(),
            name: task.name.clone(),
            description,
            source: Source {
                pipeline: Pipeline::Robogen.name().into(),
                generator: None,
                origin: Some(task.source.display().to_string()),
                asset_root: Some(asset_root.display().to_string()),
                content_hash: Some(task.content_hash.clone()),
            },
            group,
            scene: Scene {
                surface: if use_table {
                    Surface::Table
                } else {
                    Surface::Ground
                },
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
            layouts: Vec::new(),
            reward_steps: Vec::new(),
        };
        if spec.scene.objects.iter().any(|o| !o.is_fixed) {
            spec.variations.position_jitter = super::JITTER;
        }
        notes.settle(task, Some(spec));
    }
}
