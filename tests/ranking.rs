//! Policy ranking by the world-model proxy with the real cluster: `assay eval` runs a ladder of
//! oracles and a TorchScript policy, trains each group's world model and frame judge on the
//! training policies' episodes, imagines the ranked ones (the TorchScript policy acting on the
//! imagined frames) and prints r and MMRV; the report joins real and proxy success per
//! task and policy and the correlation plot is written beside it. Bad ranking settings are
//! refused before anything runs, naming the setting.
#![cfg(feature = "trainer")]

mod common;

use std::process::Command;

use assay_core::report::Report;
use common::torchscript::torchscript;
use common::*;

const TASKS: [&str; 2] = [
    "examples/tasks/placement/put-block-in-bowl.yaml",
    "examples/tasks/placement/place-cans-on-coasters.yaml",
];

fn eval(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(bin())
        .arg("eval")
        .args(TASKS)
        .args([
            "--seeds",
            "2",
            "--no-judge",
            "--no-diversity",
            "--image-size",
            "160x120",
        ])
        .args(["--policy", "oracle", "--policy", "oracle:noise=0.05"])
        .args([
            "--policy",
            "oracle:noise=0.01",
            "--policy",
            "oracle:noise=0.03",
        ])
        .args(extra)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .current_dir(repo())
        .output()
        .unwrap()
}

#[test]
fn eval_ranks_a_ladder_by_the_world_model_proxy() {
    let dir = tempfile::tempdir().unwrap();
    let module = torchscript(dir.path());
    let learned = format!("torchscript:path={},max_steps=480", module.display());
    let out = eval(
        dir.path(),
        &[
            "--policy",
            &learned,
            "--rank-train-policies",
            "oracle:noise=0.01,oracle:noise=0.03",
            "--proxy",
            r#"{"judge_steps": 30, "world_model": {"steps": 30}}"#,
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("policy ranking, world-model against sim (3 policies): Pearson r")
            && stdout.contains("MMRV"),
        "{stdout}"
    );
    let report: Report =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let k = report.results.ranking.expect("a ranking section");
    assert_eq!(
        k.ranked_policies,
        ["oracle", "oracle:noise=0.05", learned.as_str()]
    );
    assert_eq!(k.train_policies, ["oracle:noise=0.01", "oracle:noise=0.03"]);
    // 2 tasks × 3 ranked policies, each with real and proxy success over the 2 seeds.
    assert_eq!(k.rows.len(), 6);
    for r in &k.rows {
        assert_eq!(r.real.trials, 2);
        assert_eq!(r.proxy.as_ref().map(|p| p.trials), Some(2), "{r:?}");
    }
    assert_eq!(k.groups.len(), 1);
    let g = &k.groups[0];
    assert_eq!((g.group.as_str(), g.predictions.len()), ("placement", 12));
    // The judge learned from 2 × (real + imagined) last frames of each training episode.
    assert_eq!(g.judge_examples, 2 * 2 * 2 * 2);
    assert!(
        g.predictions
            .iter()
            .all(|p| (0.0..=1.0).contains(&p.p_success))
    );
    let ranking = k.ranking.expect("statistics");
    assert_eq!(ranking.comparisons[0].policies.len(), 3);
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(
        md.contains("| put-block-in-bowl | oracle:noise=0.05 |"),
        "{md}"
    );
    let svg = std::fs::read_to_string(dir.path().join("ranking.svg")).unwrap();
    assert!(svg.contains("<svg"));
}

#[test]
fn ranking_settings_that_cannot_work_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = eval(dir.path(), &["--rank-train-policies", "oracle:noise=0.2"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("ranking settings: training policy")
            && stderr.contains("oracle:noise=0.2")
            && stderr.contains("is not one of the batch's policies"),
        "{stderr}"
    );
    let out = eval(
        dir.path(),
        &[
            "--rank-train-policies",
            "oracle:noise=0.01",
            "--proxy",
            r#"{"threshold": 2}"#,
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("threshold: 2 is outside [0, 1]"),
        "{stderr}"
    );
}
