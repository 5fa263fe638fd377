//! `assay import` and `assay eval --import` on batches in GenSim's, RoboGen's and BBSEA's own
//! formats (the fixtures under tests/fixtures/import, described in its README): the mapping
//! report, the spec files, the errors of malformed tasks, and evaluation of the imported tasks
//! on a local cluster of real processes.

use std::process::Command;

use crate::common::*;
use assay_report::report::Report;
use assay_spec::spec::{Format, parse_task};

fn assay(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(bin())
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn import_writes_valid_specs_and_the_per_task_mapping_report() {
    for (pipeline, ids, refused) in [
        (
            "gensim",
            &[
                "place-blocks-in-green-zone",
                "place-red-block-in-green-bowl",
                "stack-blocks-in-color-order",
            ][..],
            &["connect-blocks-with-rope"][..],
        ),
        (
            "robogen",
            &[
                "close-storage-box-lid",
                "open-the-laptops-lid",
                "put-toy-car-into-storage-box",
            ][..],
            &[][..],
        ),
        (
            "bbsea",
            &[
                "put-the-red-cube-into-the-gray-bin",
                "stack-green-cube-on-red-cube",
            ][..],
            &["push-the-blue-cube-to-the-left-of-the-gray-bin"][..],
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let src = format!("tests/fixtures/import/{pipeline}");
        let (ok, stdout, stderr) = assay(&[
            "import",
            pipeline,
            &src,
            "--out",
            dir.path().to_str().unwrap(),
        ]);
        assert!(ok, "{pipeline}: {stdout}\n{stderr}");
        for id in ids {
            assert!(
                stdout.contains(&format!("\n{id} (")),
                "{pipeline}: {id} in\n{stdout}"
            );
            let file = dir.path().join(format!("{id}.yaml"));
            let text = std::fs::read_to_string(&file).unwrap();
            let spec = parse_task(&text, Format::Yaml, &file.display().to_string())
                .unwrap_or_else(|e| panic!("{pipeline}: {e}"));
            assert_eq!(spec.source.pipeline, pipeline);
            assert_eq!(spec.source.content_hash.as_ref().map(String::len), Some(64));
            assert!(spec.source.origin.is_some());
        }
        // Every inferred or dropped field is listed; nothing is left out silently.
        assert!(stdout.contains("  inferred: "), "{stdout}");
        assert!(stdout.contains("  not mapped: "), "{stdout}");
        for id in refused {
            assert!(
                stdout.contains(&format!("\n{id} (")) && stdout.contains("NOT imported"),
                "{pipeline}: {id} is reported as not imported\n{stdout}"
            );
            assert!(!dir.path().join(format!("{id}.yaml")).exists());
        }
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("import-report.json")).unwrap())
                .unwrap();
        assert_eq!(
            report["tasks"].as_array().unwrap().len(),
            ids.len() + refused.len()
        );
    }
}

/// `assay import … | head`: a reader that goes before the first line is written is not a panic
/// (Rust's `println!` panics on a closed pipe); the import still writes its specs and the
/// mapping report and exits with its own status.
#[test]
fn import_into_a_closed_pipe_still_writes_its_specs() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(bin())
        .args(["import", "gensim", "tests/fixtures/import/gensim", "--out"])
        .arg(dir.path())
        .current_dir(repo())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The read end closes now, long before the import (a Python sandbox per task) prints.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(out.status.success(), "{:?}: {stderr}", out.status);
    assert!(dir.path().join("import-report.json").exists());
    assert!(
        dir.path()
            .join("place-red-block-in-green-bowl.yaml")
            .exists()
    );
}

#[test]
fn a_malformed_batch_names_each_task_field_and_reason_and_keeps_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, stdout, _) = assay(&[
        "import",
        "robogen",
        "tests/fixtures/import/robogen/malformed",
        "--asset-root",
        "tests/fixtures/import/robogen/assets",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    // None of the three can be imported: the command fails, and says why for each.
    assert!(!ok, "{stdout}");
    for needle in [
        "task place-toy-car-on-laptop: [2].center: \"(0.3, zero, 0.1)\"",
        "task open-kettle-lid: [1].path:",
        "kettle.urdf",
        "task open-storage-box-lid: [1].path:",
        "leaves the asset root",
    ] {
        assert!(stdout.contains(needle), "{needle:?} in\n{stdout}");
    }

    // GenSim: one good task beside the malformed ones is still imported.
    let (ok, stdout, _) = assay(&[
        "import",
        "gensim",
        "tests/fixtures/import/gensim/malformed",
        "--asset-root",
        "tests/fixtures/import/gensim/assets",
    ]);
    for needle in [
        "task align-block-in-zone: add_goal[0].metric:",
        "'distance'",
        "task place-sphere-in-bowl: assets-used[0]:",
        "task build-block-arch: <document>:",
    ] {
        assert!(stdout.contains(needle), "{needle:?} in\n{stdout}");
    }
    let imported = stdout.matches("\n  imported\n").count();
    assert_eq!(ok, imported > 0, "{stdout}");
}

/// `assay eval --import`: the imported batch runs on a local cluster (coordinator and two sim
/// workers), the mapping report is in the output and beside the report, and every imported
/// task's oracle (inferred from the generator's plan) succeeds.
#[test]
fn eval_runs_imported_gensim_and_robogen_batches() {
    for (pipeline, tasks) in [("gensim", 3), ("robogen", 3)] {
        let dir = tempfile::tempdir().unwrap();
        let src = format!("tests/fixtures/import/{pipeline}");
        let (ok, stdout, stderr) = assay(&[
            "eval",
            "--import",
            pipeline,
            &src,
            "--seeds",
            "2",
            "--workers",
            "2",
            "--roles",
            "sim",
            "--no-judge",
            "--no-diversity",
            "--quiet",
            "--out",
            dir.path().to_str().unwrap(),
        ]);
        assert!(ok, "{pipeline}: {stdout}\n{stderr}");
        assert!(
            stdout.contains(&format!("import {pipeline} from ")),
            "{stdout}"
        );
        assert!(stdout.contains("  inferred: goals: ") || stdout.contains("  not mapped: "));
        assert!(dir.path().join("import-report.json").exists());
        let r: Report =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
                .unwrap();
        assert_eq!(r.results.tasks.len(), tasks, "{pipeline}");
        // The mapping report is in the report: every task of the tree, imported or not.
        assert_eq!(r.imports.len(), 1);
        assert_eq!(r.imports[0].pipeline, pipeline);
        assert_eq!(
            r.imports[0].tasks.iter().filter(|t| t.imported).count(),
            tasks
        );
        assert!(
            r.imports[0]
                .tasks
                .iter()
                .all(|t| t.imported || !t.errors.is_empty())
        );
        let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
        assert!(md.contains(&format!("## Import ({pipeline})")), "{md}");
        assert_each_episode_once(&r, tasks, 2);
        for t in &r.results.tasks {
            assert_eq!(t.pipeline, pipeline);
            assert_eq!(
                t.success.successes, 2,
                "{pipeline}: {} {:?}",
                t.id, t.failures
            );
            // GenSim's own reward beside success, in report.json, for every GenSim episode.
            for e in &t.episodes {
                match (pipeline, &e.generator_reward) {
                    ("gensim", Some(g)) => {
                        assert_eq!(g.by, "gensim");
                        assert!(g.value >= 0.0 && g.value <= g.max + 1e-9, "{g:?}");
                        // The oracle meets every goal: GenSim counts them all.
                        assert_eq!(g.steps_met, g.steps, "{}: {g:?}", t.id);
                    }
                    ("gensim", None) => panic!("{}: no GenSim reward", t.id),
                    (_, Some(g)) => panic!("{pipeline} has no staged reward: {g:?}"),
                    _ => {}
                }
            }
        }
        if pipeline == "gensim" {
            assert!(md.contains("generator's reward"), "{md}");
        }
    }
}

/// `assay import --check-oracle N` runs every imported task's oracle and says in the mapping
/// report how many seeds it solves; a plan that fails is reported with why, not hidden.
#[test]
fn import_checks_the_oracles_it_infers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("specs");
    let (ok, stdout, stderr) = assay(&[
        "import",
        "gensim",
        "tests/fixtures/import/gensim",
        "--check-oracle",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("import-report.json")).unwrap()).unwrap();
    let mut checked = 0;
    for t in report["tasks"].as_array().unwrap() {
        let lines: Vec<&str> = t["mapping"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|m| m["field"] == "oracle (checked)")
            .map(|m| m["note"].as_str().unwrap())
            .collect();
        if t["spec"].is_null() {
            assert!(lines.is_empty());
            continue;
        }
        assert_eq!(lines.len(), 1, "{t:#}");
        assert!(
            lines[0].starts_with("checked in the simulator: solves ")
                && lines[0].contains(" of 2 seeds"),
            "{}",
            lines[0]
        );
        assert!(stdout.contains(lines[0]), "the printed report has it too");
        checked += 1;
    }
    assert_eq!(checked, 3);
    // A plan that cannot succeed is reported as failing, with the unmet goal.
    let tmp = tempfile::tempdir().unwrap();
    let lib = tmp.path().join("gensim");
    copy_tree(&repo().join("tests/fixtures/import/gensim"), &lib);
    let spec = out.join("place-red-block-in-green-bowl.yaml");
    assert!(spec.exists());
    let code = lib.join("generated_tasks/place_red_block_in_green_bowl.py");
    let text = std::fs::read_to_string(&code).unwrap();
    // The goal asks for the block 3 m away, beyond the table: no plan reaches it.
    let unreachable = text.replace(
        "targ_poses=[bowl_pose]",
        "targ_poses=[((3.0, 0.0, 0.02), (0, 0, 0, 1))]",
    );
    assert_ne!(unreachable, text);
    std::fs::write(&code, unreachable).unwrap();
    let (ok, stdout, stderr) = assay(&[
        "import",
        "gensim",
        lib.to_str().unwrap(),
        "--check-oracle",
        "1",
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stdout.contains("checked in the simulator: solves 0 of 1 seeds; GenSim's reward complete on 0 of 1; fails on seed(s) 0; seed 0: pose_within(red_block"),
        "{stdout}"
    );
}

fn copy_tree(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}
