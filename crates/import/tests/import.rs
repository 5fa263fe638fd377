//! Importers on the fixtures of `tests/fixtures/import/` (see its README).
//!
//! Golden specs live in `tests/fixtures/import/expected/<pipeline>/<id>.yaml`, with
//! `source.origin` and `source.asset_root` made relative to the fixture root (`gensim/...`) so
//! that they do not depend on where the checkout is. `UPDATE_GOLDEN=1` rewrites them (then read
//! every one by hand before committing).

use std::path::{Path, PathBuf};

use assay_import::{Import, ImportOptions, MappingStatus, Pipeline, spec_to_yaml};
use assay_spec::spec::{self, Format, TaskSpec};

fn fixtures() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fixtures/import"
    ))
}

fn run(pipeline: Pipeline, root: &Path, assets: Option<PathBuf>) -> Import {
    assay_import::import(
        pipeline,
        root,
        &ImportOptions {
            asset_root: assets,
            // Three layouts keep the goldens readable (the default is 23).
            layout_seeds: Some(vec![0, 1, 2]),
            ..ImportOptions::default()
        },
    )
}

fn well_formed(p: Pipeline) -> Import {
    run(p, &fixtures().join(p.name()), None)
}

fn malformed(p: Pipeline) -> Import {
    let f = fixtures();
    let assets = match p {
        Pipeline::Bbsea => f.join("bbsea"),
        _ => f.join(p.name()).join("assets"),
    };
    run(p, &f.join(p.name()).join("malformed"), Some(assets))
}

/// Paths relative to the fixture root.
fn normalise(spec: &TaskSpec) -> TaskSpec {
    let root = fixtures().canonicalize().unwrap();
    let rel = |s: &str| -> String {
        let p = Path::new(s);
        let c = p.canonicalize().unwrap_or(p.to_path_buf());
        c.strip_prefix(&root)
            .map(|r| r.display().to_string())
            .unwrap_or(s.to_owned())
    };
    let mut s = spec.clone();
    s.source.origin = s.source.origin.as_deref().map(rel);
    s.source.asset_root = s.source.asset_root.as_deref().map(rel);
    s
}

fn ids(imp: &Import) -> Vec<&str> {
    imp.tasks.iter().map(|t| t.id.as_str()).collect()
}

fn check_goldens(p: Pipeline) {
    let imp = well_formed(p);
    let dir = fixtures().join("expected").join(p.name());
    for spec in imp.specs() {
        assert!(spec::validate(spec, "").is_empty(), "{}", spec.id);
        assert_eq!(spec.source.pipeline, p.name());
        assert!(Path::new(spec.source.asset_root.as_deref().unwrap()).is_absolute());
        // Round trip through YAML.
        let yaml = spec_to_yaml(spec);
        let back = spec::parse_task(&yaml, Format::Yaml, "").expect("round trip parses");
        assert_eq!(&back, spec);
        // Golden.
        let norm = spec_to_yaml(&normalise(spec));
        let file = dir.join(format!("{}.yaml", spec.id));
        if std::env::var("UPDATE_GOLDEN").is_ok() {
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(&file, &norm).unwrap();
        }
        let expected =
            std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert_eq!(norm, expected, "{} differs from its golden file", spec.id);
    }
}

fn fields(imp: &Import, id: &str, status: MappingStatus) -> Vec<String> {
    let t = imp.tasks.iter().find(|t| t.id == id).unwrap();
    t.mapping
        .iter()
        .filter(|m| m.status == status)
        .map(|m| m.field.clone())
        .collect()
}

#[test]
fn gensim_imports_the_library() {
    let imp = well_formed(Pipeline::Gensim);
    assert!(imp.errors.is_empty());
    assert_eq!(
        ids(&imp),
        [
            "connect-blocks-with-rope",
            "place-blocks-in-green-zone",
            "place-red-block-in-green-bowl",
            "stack-blocks-in-color-order"
        ]
    );
    let imported: Vec<&str> = imp.specs().iter().map(|s| s.id.as_str()).collect();
    assert_eq!(
        imported,
        [
            "place-blocks-in-green-zone",
            "place-red-block-in-green-bowl",
            "stack-blocks-in-color-order"
        ]
    );
    let rope = imp
        .tasks
        .iter()
        .find(|t| t.id == "connect-blocks-with-rope")
        .unwrap();
    assert_eq!(rope.errors[0].path, "make_ropes");
    check_goldens(Pipeline::Gensim);
    assert_eq!(
        fields(
            &imp,
            "place-red-block-in-green-bowl",
            MappingStatus::NotMapped
        ),
        ["max_steps", "language_goal"]
    );
    assert_eq!(
        fields(
            &imp,
            "place-red-block-in-green-bowl",
            MappingStatus::Inferred
        ),
        ["add_goal[0].rotations", "oracle", "group"]
    );
    // GenSim's staged reward: mapped, one reward step per add_goal, beside success.
    assert!(
        fields(&imp, "stack-blocks-in-color-order", MappingStatus::Mapped)
            .contains(&"add_goal.step_max_reward".to_string())
    );
}

#[test]
fn robogen_imports_examples() {
    let imp = well_formed(Pipeline::Robogen);
    assert!(imp.errors.is_empty());
    assert_eq!(
        ids(&imp),
        [
            "close-storage-box-lid",
            "open-the-laptops-lid",
            "put-toy-car-into-storage-box"
        ]
    );
    assert_eq!(imp.specs().len(), 3);
    check_goldens(Pipeline::Robogen);
    assert_eq!(
        fields(&imp, "open-the-laptops-lid", MappingStatus::NotMapped),
        [
            "[1].lang",
            "[1].reward_asset_path",
            "[4].spatial_relationships[0]",
            "robot",
            "action_spaces.txt",
            "substeps *.py"
        ]
    );
    assert_eq!(
        fields(&imp, "open-the-laptops-lid", MappingStatus::Inferred),
        [
            "[1].center",
            "goals",
            "oracle",
            "end_effector",
            "arm",
            "group"
        ]
    );
}

#[test]
fn bbsea_imports_logs() {
    let imp = well_formed(Pipeline::Bbsea);
    assert!(imp.errors.is_empty(), "{:?}", imp.errors);
    assert_eq!(
        ids(&imp),
        [
            "push-the-blue-cube-to-the-left-of-the-gray-bin",
            "put-the-red-cube-into-the-gray-bin",
            "stack-green-cube-on-red-cube"
        ]
    );
    let push = &imp.tasks[0];
    assert!(push.spec.is_none());
    assert_eq!(push.errors[0].path, "log.primitive_action_list");
    assert!(push.errors[0].reason.contains("to the left of"));
    let labels = |t: &assay_import::ImportedTask| -> Vec<(String, Option<bool>)> {
        t.episodes.iter().map(|e| (e.id.clone(), e.label)).collect()
    };
    assert_eq!(labels(push), [("1000".to_string(), None)]);
    assert_eq!(
        labels(&imp.tasks[1]),
        [
            ("1000".to_string(), Some(true)),
            ("1001".to_string(), Some(false))
        ]
    );
    assert_eq!(labels(&imp.tasks[2]), [("1000".to_string(), Some(false))]);
    assert!(
        imp.tasks
            .iter()
            .flat_map(|t| &t.episodes)
            .all(|e| e.label_source == "llm")
    );
    check_goldens(Pipeline::Bbsea);
    assert_eq!(
        fields(
            &imp,
            "stack-green-cube-on-red-cube",
            MappingStatus::Inferred
        ),
        ["qpos_ranges", "goals", "oracle", "end_effector", "group"]
    );
    assert_eq!(
        fields(
            &imp,
            "stack-green-cube-on-red-cube",
            MappingStatus::NotMapped
        ),
        [
            "log: task_decomposition_reasoning, scene_graph_list, infer_info",
            "output/trajectory",
            "fixed_objects.drawer",
            "assets[1].qpos_ranges[3..5]",
            "assets[2].qpos_ranges[3..5]",
            "assets[3].qpos_ranges[3..5]"
        ]
    );
}

fn error_of<'a>(imp: &'a Import, id: &str) -> &'a assay_spec::SpecError {
    let t = imp
        .tasks
        .iter()
        .find(|t| t.id == id)
        .unwrap_or_else(|| panic!("no task {id}"));
    assert!(t.spec.is_none(), "{id} should not import");
    &t.errors[0]
}

#[test]
fn gensim_malformed() {
    let imp = malformed(Pipeline::Gensim);
    assert_eq!(imp.tasks.len(), 3);
    let e = error_of(&imp, "place-sphere-in-bowl");
    assert_eq!(
        (e.task.as_deref(), e.path.as_str()),
        (Some("place-sphere-in-bowl"), "assets-used[0]")
    );
    assert!(
        e.reason.contains("sphere/sphere-template.urdf")
            && e.reason.contains("not found under the asset root"),
        "{e}"
    );
    let e = error_of(&imp, "align-block-in-zone");
    assert_eq!(e.path, "add_goal[0].metric");
    assert!(e.reason.contains("unknown metric 'distance'"), "{e}");
    let e = error_of(&imp, "build-block-arch");
    assert_eq!(e.path, "");
    assert!(
        e.reason
            .contains("generated_tasks/build_block_arch.py does not exist"),
        "{e}"
    );
    assert!(e.to_string().contains("<document>"));
}

/// A task name is a name, not a path: `../../secret` never reads `secret.py` beside the library.
#[test]
fn gensim_task_names_that_are_paths_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let lib = dir.path().join("lib");
    std::fs::create_dir_all(lib.join("generated_tasks")).unwrap();
    std::fs::write(dir.path().join("secret.py"), "class Secret: pass\n").unwrap();
    std::fs::write(
        lib.join("generated_tasks.json"),
        r#"{"x": {"task-name": "../../secret", "task-description": "d", "assets-used": []}}"#,
    )
    .unwrap();
    let imp = run(Pipeline::Gensim, &lib, Some(lib.clone()));
    let t = &imp.tasks[0];
    assert!(t.spec.is_none());
    let e = &t.errors[0];
    assert_eq!(e.path, "task-name");
    assert!(e.reason.contains("not a plain task name"), "{e}");
    assert!(!t.source.ends_with("secret.py"), "{:?}", t.source);
}

#[test]
fn robogen_malformed() {
    let imp = malformed(Pipeline::Robogen);
    assert_eq!(imp.tasks.len(), 3);
    let e = error_of(&imp, "place-toy-car-on-laptop");
    assert_eq!(e.path, "[2].center");
    assert!(
        e.reason.contains("\"(0.3, zero, 0.1)\" is not (x, y, z)")
            && e.reason.contains("'zero' is not a number")
            && e.reason.contains("Toy car"),
        "{e}"
    );
    let e = error_of(&imp, "open-kettle-lid");
    assert_eq!(e.path, "[1].path");
    assert!(
        e.reason
            .contains("'kettle.urdf' not found under the asset root"),
        "{e}"
    );
    let e = error_of(&imp, "open-storage-box-lid");
    assert_eq!(e.path, "[1].path");
    assert!(
        e.reason
            .contains("'../../etc/passwd.urdf' leaves the asset root"),
        "{e}"
    );
}

#[test]
fn bbsea_malformed_scene_is_reported_once() {
    let imp = malformed(Pipeline::Bbsea);
    assert!(imp.tasks.is_empty());
    assert_eq!(imp.errors.len(), 1);
    let e = &imp.errors[0];
    assert_eq!(e.path, "assets[1].qpos_ranges");
    assert!(e.origin.ends_with("config/scene/8.yaml"));
    assert!(
        e.reason.contains("scene 8")
            && e.reason.contains("red cube")
            && e.reason.contains("expected 6 [low, high] ranges")
            && e.reason.contains("found 3"),
        "{e}"
    );
}

#[test]
fn a_bbsea_asset_asking_for_too_many_copies_is_an_error_not_an_allocation() {
    // Found by core/tests/fuzz.rs: a huge `number` built that many instances (it ran out of
    // 24 GB). 1000 is over the bound and cheap even without it.
    let tmp = tempfile::tempdir().unwrap();
    copy_dir(&fixtures().join("bbsea"), tmp.path());
    let scene = tmp.path().join("config/scene/7.yaml");
    let text = std::fs::read_to_string(&scene).unwrap();
    std::fs::write(&scene, text.replacen("number: 1", "number: 1000", 1)).unwrap();
    let imp = run(Pipeline::Bbsea, tmp.path(), None);
    let e = imp
        .errors
        .iter()
        .chain(imp.tasks.iter().flat_map(|t| &t.errors))
        .find(|e| e.path == "assets[0].number")
        .unwrap_or_else(|| panic!("no error on assets[0].number: {:?}", imp.errors));
    assert!(
        e.reason.contains("1000 copies") && e.reason.contains("at most 200"),
        "{e}"
    );
}

#[test]
fn content_hash_is_stable_and_follows_the_source() {
    let a = well_formed(Pipeline::Robogen);
    let b = well_formed(Pipeline::Robogen);
    let hashes = |i: &Import| {
        i.tasks
            .iter()
            .map(|t| t.content_hash.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(hashes(&a), hashes(&b));
    // A copy with one changed description hashes differently; the others keep their hash.
    let tmp = std::env::temp_dir().join(format!("assay-import-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    copy_dir(&fixtures().join("gensim"), &tmp);
    let lib = tmp.join("generated_tasks.json");
    let text = std::fs::read_to_string(&lib).unwrap();
    std::fs::write(&lib, text.replace("into one tower", "into a single tower")).unwrap();
    let orig = well_formed(Pipeline::Gensim);
    let copy = run(Pipeline::Gensim, &tmp, None);
    for (o, c) in orig.tasks.iter().zip(&copy.tasks) {
        assert_eq!(o.id, c.id);
        assert_eq!(
            o.content_hash == c.content_hash,
            o.id != "stack-blocks-in-color-order",
            "{}",
            o.id
        );
    }
    let spec = copy
        .specs()
        .into_iter()
        .find(|s| s.id == "place-red-block-in-green-bowl")
        .unwrap();
    assert_eq!(
        spec.source.content_hash.as_deref(),
        Some(copy.tasks[2].content_hash.as_str())
    );
    std::fs::remove_dir_all(&tmp).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

#[test]
fn report_names_every_task_and_dropped_field() {
    for p in [Pipeline::Gensim, Pipeline::Robogen, Pipeline::Bbsea] {
        let imp = well_formed(p);
        let report = imp.report();
        for t in &imp.tasks {
            assert!(report.contains(&t.id), "{}", t.id);
            for m in t
                .mapping
                .iter()
                .filter(|m| m.status != MappingStatus::Mapped)
            {
                assert!(
                    report.contains(&format!("{}: {}", m.field, m.note)),
                    "{}: {}",
                    t.id,
                    m.field
                );
            }
            for e in &t.errors {
                assert!(report.contains(&e.to_string()));
            }
        }
        serde_json::to_string(&imp).expect("the report serialises");
    }
}

/// What the recording cannot answer (a helper Ravens does not have, a simulator query) refuses the
/// task with the call named; code that runs, whatever its control flow, imports.
#[test]
fn gensim_code_is_run_and_what_it_asks_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    copy_dir(&fixtures().join("gensim"), tmp.path());
    let code = tmp
        .path()
        .join("generated_tasks/place_red_block_in_green_bowl.py");
    let text = std::fs::read_to_string(&code).unwrap();
    // Control flow a reader of call shapes could not follow: a helper method and a branch.
    let changed = text.replace(
        "        super().reset(env)\n",
        "        super().reset(env)\n        self.lighting = 0.5 if self.mode == 'test' else 1.0\n        n = sum(i for i in range(3))\n",
    );
    assert_ne!(changed, text);
    std::fs::write(&code, &changed).unwrap();
    let imp = run(Pipeline::Gensim, tmp.path(), None);
    let task = imp
        .tasks
        .iter()
        .find(|t| t.id == "place-red-block-in-green-bowl")
        .unwrap();
    assert!(task.spec.is_some(), "{:?}", task.errors);
    // A call the stand-in does not provide.
    let asks = text.replace(
        "        super().reset(env)\n",
        "        super().reset(env)\n        self.spawn_distractors(env, n=3)\n",
    );
    std::fs::write(&code, asks).unwrap();
    let imp = run(Pipeline::Gensim, tmp.path(), None);
    let e = error_of(&imp, "place-red-block-in-green-bowl");
    assert_eq!(e.path, "Task.spawn_distractors");
    assert!(e.reason.contains("not part of the Ravens task API"), "{e}");
}
