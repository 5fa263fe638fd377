//! GenSim (liruiw/GenSim): the task library `generated_tasks.json` plus one Python task class per
//! entry in `generated_tasks/`. The class's `reset()` runs in a sandboxed Python subprocess
//! against a recording stand-in of the Ravens API (`sandbox`, `gensim-recorder/recorder.py`) on
//! a few seeds; what it recorded becomes a spec (`translate`).

use std::path::Path;

mod layouts;
mod repair;
mod sandbox;
mod translate;

use super::{ImportedTask, Notes, Pipeline, check_asset, hash_parts};
use assay_spec::error::SpecError;
use assay_spec::spec::{
    EndEffector, PhysicsSettings, SPEC_VERSION, Scene, Source, Surface, TaskSpec, Variations,
};

/// The Python that runs GenSim task code: `ASSAY_PYTHON`, else Assay's own environment
/// (`~/.cache/assay/python`, made by `scripts/setup-python`) when it is there, else `python3` on
/// the `PATH`.
pub fn python() -> String {
    sandbox::python()
}

pub use sandbox::Boundary;

/// The OS boundary GenSim task code runs behind here, under the recorder's Python guards (a
/// network namespace, Landlock, seccomp), and why a part does not hold where it cannot.
pub fn boundary() -> &'static Boundary {
    sandbox::boundary()
}

/// GenSim colours missing from Assay's named palette (`utils.COLORS`, 0..1).
pub(crate) const EXTRA_COLORS: &[(&str, [f64; 3])] = &[
    ("indigo", [0.29, 0.0, 0.51]),
    ("violet", [0.56, 0.0, 1.0]),
    ("silver", [0.75, 0.75, 0.75]),
    ("gold", [0.86, 0.65, 0.13]),
    ("grey", [0.5, 0.5, 0.5]),
];

pub(crate) fn import(
    root: &Path,
    asset_root: &Path,
    limits: crate::CodeLimits,
    layout_seeds: &[u64],
) -> (Vec<ImportedTask>, Vec<SpecError>) {
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
    // Each task's code runs in a process of its own: as many at once as there are cores.
    let entries: Vec<(&String, &serde_json::Value)> = lib.iter().collect();
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(entries.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut done: Vec<(usize, ImportedTask)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut out = Vec::new();
                    loop {
                        let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some((key, entry)) = entries.get(k) else {
                            break;
                        };
                        out.push((
                            k,
                            import_one(
                                root,
                                asset_root,
                                &lib_path,
                                key,
                                entry,
                                limits,
                                layout_seeds,
                            ),
                        ));
                    }
                    out
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("an import thread panicked"))
            .collect()
    });
    done.sort_by_key(|(k, _)| *k);
    (done.into_iter().map(|(_, t)| t).collect(), Vec::new())
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
    limits: crate::CodeLimits,
    layout_seeds: &[u64],
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
    let description = entry
        .get("task-description")
        .and_then(|v| v.as_str())
        .unwrap_or("")
        .to_owned();
    notes.mapped("task-name", format!("id '{id}', name '{name}'"));
    notes.mapped("task-description", "description");
    // assets-used: every one must exist under the asset root (GenSim's silent substitutions are
    // not imitated).
    if let Some(list) = entry.get("assets-used").and_then(|v| v.as_array()) {
        for (i, a) in list.iter().enumerate() {
            let a = a.as_str().unwrap_or("");
            // GenSim's add_object reads a template that is not there without '-template'.
            let plain = a.replace("-template", "");
            if let Err(e) = check_asset(asset_root, a)
                .or_else(|e| check_asset(asset_root, &plain).map_err(|_| e))
            {
                notes.error(
                    &format!("assets-used[{i}]"),
                    format!(
                        "URDF {e} (GenSim's env.add_object would silently load a substitute; the importer does not)"
                    ),
                );
            }
        }
        notes.mapped("assets-used", "checked against the asset root");
    }
    drop(code);
    // Seeds 0, 1 and 2 show which targets follow which object; the layouts' seeds follow.
    let mut asked: Vec<u64> = BASE_SEEDS.to_vec();
    for s in layout_seeds {
        if !asked.contains(s) {
            asked.push(*s);
        }
    }
    let spec = match sandbox::record(asset_root, root, &code_path, &asked, limits).and_then(|r| {
        let own = std::fs::read_link("/proc/self/ns/net")
            .ok()
            .map(|p| p.display().to_string());
        let network = match (&r.netns, &sandbox::boundary().network) {
            (Some(ns), Ok(())) if Some(ns) != own.as_ref() => {
                Ok(format!("a network namespace of its own ({ns})"))
            }
            (_, Err(why)) => Err(format!("no network namespace ({why})")),
            _ => Err("no network namespace (its namespace is Assay's)".to_string()),
        };
        let parts = [
            network,
            r.filesystem.clone().map_err(|e| format!("no Landlock ({e})")),
            r.syscalls.clone().map_err(|e| format!("no seccomp ({e})")),
        ];
        let held: Vec<&str> = parts.iter().filter_map(|p| p.as_deref().ok()).collect();
        let missing: Vec<&str> = parts
            .iter()
            .filter_map(|p| p.as_ref().err().map(String::as_str))
            .collect();
        let held = if held.is_empty() {
            "rlimits".to_string()
        } else {
            held.join("; ")
        };
        if missing.is_empty() {
            notes.mapped(
                "sandbox",
                format!("reset() ran behind the OS boundary: {held}; under the Python guards"),
            );
        } else {
            notes.not_mapped(
                "sandbox",
                format!(
                    "reset() ran behind part of the OS boundary: {held}; under the Python guards; {}",
                    missing.join("; ")
                ),
            );
        }
        for m in &r.stubbed {
            notes.not_mapped(
                "import",
                format!(
                    "'{m}' is outside the allow-list and reset() never used it: stubbed (a use refuses the task)"
                ),
            );
        }
        answered(&asked, r.seeds)
    }) {
        Ok(outcomes) => build(
            &Task {
                id: &id,
                name: &name,
                description: &description,
            },
            &outcomes,
            layout_seeds,
            asset_root,
            &mut notes,
        ),
        Err(refused) => {
            notes.error(&refused.field, refused.reason);
            None
        }
    };
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

/// The seeds `reset()` is always recorded on: seed 0 gives the spec's own scene, and with the
/// others it shows which targets follow which object.
const BASE_SEEDS: [u64; 3] = [0, 1, 2];

/// The recorder's answer, checked against the seeds asked (in order; the first built).
fn answered(
    asked: &[u64],
    outcomes: Vec<sandbox::SeedOutcome>,
) -> Result<Vec<sandbox::SeedOutcome>, sandbox::Refused> {
    let got: Vec<u64> = outcomes.iter().map(sandbox::SeedOutcome::seed).collect();
    if got != asked || !matches!(outcomes.first(), Some(sandbox::SeedOutcome::Built(_))) {
        return Err(sandbox::Refused {
            field: "reset".into(),
            reason: "the recording answered other seeds than those asked".into(),
        });
    }
    Ok(outcomes)
}

/// How far one pose target of `s` stands above another within 10 cm of it (2 cm or more):
/// objects go on others.
fn above(s: &sandbox::SeedRecord) -> Option<f64> {
    let targets: Vec<[f64; 3]> = s
        .goals
        .iter()
        .filter(|g| g.metric == "pose")
        .flat_map(|g| g.targets.iter().map(|t| t.0))
        .collect();
    targets
        .iter()
        .flat_map(|a| targets.iter().map(move |b| (a, b)))
        .filter(|(a, b)| (b[0] - a[0]).hypot(b[1] - a[1]) < 0.1)
        .map(|(a, b)| b[2] - a[2])
        .filter(|dz| *dz >= 0.02)
        .max_by(f64::total_cmp)
}

/// The task's names.
struct Task<'a> {
    id: &'a str,
    name: &'a str,
    description: &'a str,
}

fn build(
    task: &Task<'_>,
    outcomes: &[sandbox::SeedOutcome],
    layout_seeds: &[u64],
    asset_root: &Path,
    notes: &mut Notes,
) -> Option<TaskSpec> {
    let &Task {
        id,
        name,
        description,
    } = task;
    let seeds: Vec<sandbox::SeedRecord> = outcomes
        .iter()
        .filter_map(|o| match o {
            sandbox::SeedOutcome::Built(r) => Some((**r).clone()),
            sandbox::SeedOutcome::Failed { .. } => None,
        })
        .collect();
    let s0 = &seeds[0];
    notes.mapped(
        "reset",
        format!(
            "class {} run in the sandbox on seeds {}: {} objects, {} goals on seed 0",
            s0.class,
            assay_spec::spec::seed_ranges(outcomes.iter().map(sandbox::SeedOutcome::seed)),
            s0.objects.len(),
            s0.goals.len()
        ),
    );
    if s0.max_steps.is_some() {
        notes.not_mapped(
            "max_steps",
            "GenSim counts actions, Assay bounds physics steps (physics.max_steps keeps its default)",
        );
    }
    if !s0.lang_goals.is_empty() {
        notes.not_mapped("language_goal", "not part of spec v1 (the description is)");
    }
    let t = translate::translate(&seeds, asset_root, notes, false)?;
    notes.inferred(
        "oracle",
        "per goal, lowest target first: pick, then place at the target (on what lies under it), into the bowl, or in the zone; a pile is swept",
    );
    if s0.ee == "spatula" {
        notes.not_mapped(
            "ee",
            "GenSim's spatula: Assay's suction tool picks, and sweeps piles, instead",
        );
    } else {
        notes.mapped("ee", "suction (Ravens' default self.ee = Suction)");
    }
    let end_effector = EndEffector::Suction;
    notes.mapped(
        "arm",
        "ur5 at the origin (Ravens' UR5 stands at (0, 0, 0) facing +x; its workspace x 0.25-0.75 m)",
    );
    Some(TaskSpec {
        spec_version: SPEC_VERSION,
        id: id.into(),
        name: name.into(),
        description: description.into(),
        source: Source::default(),
        group: String::new(),
        scene: Scene {
            surface: Surface::Table,
            objects: t.objects,
            zones: t.zones,
            piles: t.piles,
        },
        end_effector,
        arm: Some(assay_spec::spec::Arm {
            model: "ur5".into(),
            base: [0.0; 3],
            base_yaw_deg: 0.0,
        }),
        goals: t.goals,
        variations: Variations {
            position_jitter: t.jitter,
            ..Variations::default()
        },
        oracle: t.oracle,
        cameras: Vec::new(),
        physics: PhysicsSettings::default(),
        layouts: Vec::new(),
        reward_steps: t.reward_steps,
    })
    .map(|mut spec| {
        let (group, why) = crate::groups::group_of(&spec, above(s0));
        notes.inferred(
            "group",
            format!("'{group}': {why} (docs/gensim.md has the rule)"),
        );
        spec.group = group;
        spec.layouts = layouts::lay_out(&spec, outcomes, &seeds, layout_seeds, asset_root, notes);
        spec
    })
}

/// One object a task's `reset()` placed, as the recorder saw it: its asset, the template values
/// it was filled with (as the importer writes them), and GenSim's base pose.
#[derive(Debug, Clone, PartialEq)]
pub struct ResetObject {
    pub urdf: String,
    pub fill: std::collections::BTreeMap<String, String>,
    pub position: [f64; 3],
    /// Quaternion x, y, z, w.
    pub rotation: [f64; 4],
    /// A copy in a pile (`make_piles`).
    pub pile: bool,
}

/// Runs the `reset()` of task `name` of the GenSim library at `library` on each of `seeds`, in
/// the same sandbox and under the same limits as the import, and gives what it placed on each
/// (or why that seed failed): for checking an import against the task's own code.
pub fn reset_objects(
    library: &Path,
    asset_root: &Path,
    name: &str,
    seeds: &[u64],
) -> Result<Vec<Result<Vec<ResetObject>, String>>, String> {
    if !is_plain_name(name) {
        return Err(format!("'{name}' is not a plain task name"));
    }
    let code = library.join(format!("generated_tasks/{}.py", name.replace('-', "_")));
    let recording = sandbox::record(
        asset_root,
        library,
        &code,
        seeds,
        crate::CodeLimits::default(),
    )
    .map_err(|r| format!("{}: {}", r.field, r.reason))?;
    Ok(recording
        .seeds
        .into_iter()
        .map(|o| match o {
            sandbox::SeedOutcome::Failed { refused, .. } => {
                Err(format!("{}: {}", refused.field, refused.reason))
            }
            sandbox::SeedOutcome::Built(r) => Ok(r
                .objects
                .iter()
                .map(|o| ResetObject {
                    urdf: o.urdf.clone(),
                    fill: o
                        .fill
                        .iter()
                        .filter_map(|(k, v)| translate::fill_text(v).map(|t| (k.clone(), t)))
                        .collect(),
                    position: o.pose.0,
                    rotation: o.pose.1,
                    pile: o.pile,
                })
                .collect()),
        })
        .collect())
}
