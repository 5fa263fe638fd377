//! Policy ranking by the world-model proxy with the real cluster: `assay eval` runs a ladder of
//! oracles and a TorchScript policy, trains each group's world model and frame judge on the
//! training policies' episodes, imagines the ranked ones (the TorchScript policy acting on the
//! imagined frames) and prints r and MMRV; a VLM judge (a local OpenAI-compatible fixture) is
//! asked about every imagined rollout's keyframes and is ranked as a proxy of its own; the
//! report joins real and proxy success per task and policy and the correlation plots are
//! written beside it. Bad ranking settings are refused before anything runs, naming the setting.
#![cfg(feature = "trainer")]

use std::process::Command;
use std::sync::Arc;

use crate::common::torchscript::torchscript;
use crate::common::*;
use assay_report::report::Report;
use assay_testkit::fixture::{Fixture, Received, Reply, Script};
use base64::Engine;

const TASKS: [&str; 2] = [
    "examples/tasks/placement/put-block-in-bowl.yaml",
    "examples/tasks/placement/place-cans-on-coasters.yaml",
];

fn eval(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(bin())
        .arg("eval")
        .args(TASKS)
        .args(["--seeds", "2", "--no-diversity", "--image-size", "160x120"])
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

/// Width and height of the PNG behind a `data:image/png;base64,…` URL.
fn png_size(url: &str) -> (u32, u32) {
    let b64 = url.split_once("base64,").unwrap().1;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(b64)
        .unwrap();
    let be = |k: usize| u32::from_be_bytes(bytes[k..k + 4].try_into().unwrap());
    (be(16), be(20))
}

#[test]
fn eval_ranks_a_ladder_by_the_world_model_proxy() {
    // The VLM: scene alignment 4, completion 8 for real rollouts; for the world model's 64×64
    // imagined rollouts, 9 on the bowl task and 2 on the other.
    let script: Script = Arc::new(|r: &Received| {
        let imagined = r.image_urls().iter().any(|u| png_size(u) == (64, 64));
        let score = match (r.prompt_version.as_deref(), imagined) {
            (Some("scene-alignment/v1"), _) => 4,
            (_, false) => 8,
            (_, true) if r.text.contains("bowl") => 9,
            (_, true) => 2,
        };
        Reply::text(format!("Score: {score}"))
    });
    let vlm = Fixture::start(script).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("assay.toml");
    std::fs::write(
        &config,
        format!(
            "[judges.vlm]\nbackend = \"openai\"\nbase_url = \"{}\"\nmodel = \"test-vlm\"\n",
            vlm.base_url()
        ),
    )
    .unwrap();
    let module = torchscript(dir.path());
    let learned = format!("torchscript:path={},max_steps=480", module.display());
    // The report goes to its own folder: `dir` holds the configuration and the module.
    let out_dir = dir.path().join("out");
    let out = eval(
        &out_dir,
        &[
            "--judge",
            "vlm",
            "--judge-repeats",
            "1",
            "--config",
            config.to_str().unwrap(),
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
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
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
    // Every imagined rollout of a ranked episode was shown to the VLM: 8 frames of 64×64, asked
    // about completion only (a rollout that was never seen has no scene to align).
    let got = vlm.received();
    let imagined: Vec<&Received> = got
        .iter()
        .filter(|r| r.image_urls().iter().all(|u| png_size(u) == (64, 64)))
        .collect();
    assert_eq!(imagined.len(), 12, "one per ranked episode");
    for r in &imagined {
        assert_eq!(r.image_urls().len(), 8);
        assert_eq!(r.prompt_version.as_deref(), Some("completion/v1"));
    }
    for r in &k.rows {
        let j = &r.judged_proxy;
        assert_eq!(j.len(), 1, "{r:?}");
        let expected = if r.task_id == "put-block-in-bowl" {
            (2, 9.0)
        } else {
            (0, 2.0)
        };
        assert_eq!(
            (j[0].success.successes, j[0].mean_completion),
            (expected.0, Some(expected.1))
        );
    }
    assert!(k.judging_errors.is_empty(), "{:?}", k.judging_errors);
    let ranking = k.ranking.expect("statistics");
    assert_eq!(ranking.comparisons[0].policies.len(), 3);
    let judged = &ranking.comparisons[1];
    assert_eq!(judged.proxy, "world-model+vlm");
    // The fixture's verdicts depend on the task only: every policy gets R_S = 0.5, so r is
    // undefined and says why.
    assert!(judged.policies.iter().all(|p| p.proxy == 0.5));
    assert!(judged.pearson.undefined.is_some(), "{:?}", judged.pearson);
    assert!(stdout.contains("world-model+vlm against sim"), "{stdout}");
    assert!(out_dir.join("ranking-vlm.svg").is_file());
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(
        md.contains("| `put-block-in-bowl` | oracle:noise=0.05 |"),
        "{md}"
    );
    let svg = std::fs::read_to_string(out_dir.join("ranking.svg")).unwrap();
    assert!(svg.contains("<svg"));
}

#[test]
fn ranking_settings_that_cannot_work_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = eval(
        dir.path(),
        &["--no-judge", "--rank-train-policies", "oracle:noise=0.2"],
    );
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
            "--no-judge",
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
