//! GenSim's own task library (`../shared/corpora/gensim-library`, read where it lies, never
//! copied, no task name special-cased): `assay import gensim --check-oracle 20` runs the inferred
//! oracle of every imported task on 20 seeds and writes what it did into the mapping report; the
//! table of it is printed here. At least 90 % of the imported tasks must be solved on at least 18
//! of the 20 seeds. `ASSAY_GENSIM_SEEDS=N` runs N seeds instead (the bar scales with it).

use crate::common::*;

#[test]
fn gensim_library_oracles_solve_what_imports() {
    let root = repo().join("../shared/corpora/gensim-library");
    assert!(
        root.join("generated_tasks.json").exists(),
        "the GenSim corpus is not at {}",
        root.display()
    );
    let seeds: u64 = std::env::var("ASSAY_GENSIM_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let out = tempfile::tempdir().unwrap();
    let run = std::process::Command::new(bin())
        .args(["import", "gensim"])
        .arg(&root)
        .args(["--check-oracle", &seeds.to_string(), "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("import-report.json")).unwrap())
            .unwrap();
    let need = (seeds * 9).div_ceil(10);
    let prefix = "checked in the simulator: solves ";
    let (mut imported, mut solved) = (0, 0);
    println!("| group | task | oracle success (of {seeds}) | first failure |");
    println!("|---|---|---:|---|");
    for t in report["tasks"].as_array().unwrap() {
        if t["spec"].is_null() {
            continue;
        }
        imported += 1;
        let note = t["mapping"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["field"] == "oracle (checked)")
            .and_then(|m| m["note"].as_str())
            .unwrap_or_else(|| panic!("{}: no oracle check in its mapping report", t["id"]));
        let rest = note
            .strip_prefix(prefix)
            .unwrap_or_else(|| panic!("{note}"));
        let ok: u64 = rest.split(' ').next().unwrap().parse().unwrap();
        solved += usize::from(ok >= need);
        let first = rest.split_once("; seed ").map_or("", |(_, why)| why);
        let first: String = first.chars().take(300).collect();
        println!(
            "| {} | {} | {ok} | {} |",
            t["spec"]["group"].as_str().unwrap(),
            t["id"].as_str().unwrap(),
            if first.is_empty() {
                String::new()
            } else {
                format!("seed {first}")
            }
        );
    }
    println!("{solved} of {imported} imported tasks solved on at least {need} of {seeds} seeds");
    assert!(imported > 0, "nothing imported");
    assert!(
        solved * 10 >= imported * 9,
        "{solved} of {imported} imported tasks solved by their oracle on at least {need} of {seeds} seeds (wanted 90 %)"
    );
}

/// Every imported task starts at rest: over the settle before a policy acts, no object on the
/// table is shoved aside or turned by another it was drawn into (generated code declares sizes
/// smaller than the assets it loads; the importer moves such objects clear, as GenSim's own
/// sampler keeps clear of what it has drawn).
#[test]
fn gensim_library_tasks_start_at_rest() {
    let root = repo().join("../shared/corpora/gensim-library");
    let imp = assay_import::import(
        assay_import::Pipeline::Gensim,
        &root,
        &assay_import::ImportOptions::default(),
    );
    let mut checked = 0;
    let mut shoved = Vec::new();
    for t in &imp.tasks {
        let Some(spec) = &t.spec else { continue };
        for seed in 0..3 {
            let spec = spec.for_seed(seed);
            let mut scene = assay_sim::scene::build_scene(&spec, seed).unwrap();
            let before: Vec<_> = scene.objects.iter().map(|o| scene.pose(o)).collect();
            for _ in 0..spec.physics.settle_steps {
                let at = scene.drive_arm(scene.gripper_position());
                scene.world.bodies[scene.gripper].set_next_kinematic_position(at);
                scene.hold_joints();
                scene.drive_fingers();
                scene.world.step();
            }
            for (o, b) in scene.objects.iter().zip(&before) {
                let a = scene.pose(o);
                let moved = (a.translation - b.translation).truncate().length();
                let turned = a.rotation.angle_between(b.rotation).to_degrees();
                // A few millimetres are settling (a body the code put in the air drops, a mesh
                // finds its rest on its convex pieces); an object drawn into the footprint of an
                // asset larger than its code declared is shoved 1 to 3 cm.
                if moved > 0.005 || turned > 3.0 {
                    shoved.push(format!(
                        "{} seed {seed}: '{}' moved {:.1} mm, turned {turned:.1}°",
                        t.id,
                        o.id,
                        moved * 1000.0
                    ));
                }
            }
            checked += 1;
        }
    }
    println!("{checked} scenes settled; {} objects shoved", shoved.len());
    assert!(checked > 0);
    assert!(shoved.is_empty(), "{shoved:#?}");
}

/// `assay import gensim` with no `ASSAY_PYTHON` and no `python3` on the `PATH` runs GenSim's
/// task code in the environment `scripts/setup-python` makes under the home folder
/// (`~/.cache/assay/python`; here a home whose environment is the test virtual environment, which
/// has numpy): nothing to set up by hand. Without that environment the same command imports
/// nothing.
#[test]
fn gensim_import_finds_assay_s_own_python_without_settings() {
    let root = repo().join("../shared/corpora/gensim-library");
    let python = std::env::var("ASSAY_TEST_PYTHON")
        .expect("ASSAY_TEST_PYTHON names a Python with numpy (scripts/test sets it up)");
    // The virtual environment itself (a Python finds its environment from where it is run).
    let venv = std::path::Path::new(&python)
        .parent()
        .and_then(std::path::Path::parent)
        .expect("ASSAY_TEST_PYTHON is ENV/bin/python");
    let home = tempfile::tempdir().unwrap();
    let import = |home: &std::path::Path| {
        let run = std::process::Command::new(bin())
            .args(["import", "gensim"])
            .arg(&root)
            .env_remove("ASSAY_PYTHON")
            .env("PATH", "/nonexistent")
            .env("HOME", home)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&run.stdout).into_owned();
        let head = text.lines().next().unwrap_or_default().to_owned();
        let imported: usize = head
            .rsplit_once(", ")
            .and_then(|(_, n)| n.strip_suffix(" imported"))
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no import count in {head:?}\n{text}"));
        (imported, text)
    };
    let (none, _) = import(home.path());
    assert_eq!(
        none, 0,
        "without Assay's Python and no python3, no task code can run"
    );
    std::fs::create_dir_all(home.path().join(".cache/assay")).unwrap();
    std::os::unix::fs::symlink(venv, home.path().join(".cache/assay/python")).unwrap();
    let (imported, text) = import(home.path());
    assert!(imported >= 90, "{imported} imported:\n{text}");
}
