//! Diversity end to end with the real binary: `assay diversity` on a texts file (local
//! sentence-transformers model and an OpenAI-compatible embeddings endpoint served by the local
//! fixture), and a cluster whose trainer worker is killed in the middle of a world-model fit:
//! the fit resumes from its last checkpoint on another trainer worker.

use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::*;
use assay_proto::v1 as pb;
use assay_report::report::Report;
use assay_testkit::fixture::{EMBEDDINGS_PATH, Fixture, embedding_script};

const TEXTS: &str = r#"
drawer:
  - open the drawer using the handle
  - open the drawer using its handle
  - open the top drawer using the handle
tabletop:
  - stack the red block on the blue block
  - sweep the small cubes into the green zone
  - put the banana inside the bowl
All:
  - open the drawer using the handle
  - open the drawer using its handle
  - open the top drawer using the handle
  - stack the red block on the blue block
  - sweep the small cubes into the green zone
  - put the banana inside the bowl
"#;

fn diversity(args: &[&str]) -> std::process::Output {
    Command::new(bin())
        .arg("diversity")
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap()
}

#[test]
fn diversity_command_reports_each_group_per_model_in_file_order() {
    let dir = tempfile::tempdir().unwrap();
    let texts = dir.path().join("texts.yaml");
    std::fs::write(&texts, TEXTS).unwrap();
    let out = diversity(&[texts.to_str().unwrap(), "--json"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["models"][0]["name"], "minilm");
    assert_eq!(v["models"][0]["dimensions"], 384);
    let rows = v["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["group"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["drawer", "tabletop", "All"],
        "the file's groups, no other"
    );
    let div = |i: usize| rows[i]["div"][0].as_f64().unwrap();
    assert_eq!(rows[2]["n"], 6);
    // Near-paraphrases are less diverse than different tasks; mixing both lies between.
    assert!(div(0) < div(2) && div(2) < div(1), "{rows:?}");

    // The Markdown table, and marginal diversity against a corpus of the drawer tasks only.
    let base = dir.path().join("base.json");
    std::fs::write(
        &base,
        r#"{"tabletop": ["open the drawer using the handle", "open the drawer using its handle"]}"#,
    )
    .unwrap();
    let out = diversity(&[texts.to_str().unwrap(), "--base", base.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.contains("| group | N | minilm ("), "{stdout}");
    assert!(stdout.contains("| drawer | 3 |"), "{stdout}");
    let marginal = stdout
        .lines()
        .find(|l| l.starts_with("| tabletop | minilm | 2 | 3 |"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(
        marginal.trim_end().ends_with('|') && marginal.contains("| +"),
        "new, different tasks add diversity: {marginal}"
    );
}

#[test]
fn diversity_command_names_bad_input_and_too_small_groups() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.yaml");
    std::fs::write(&bad, "g:\n  - fine\n  - [not, a, text]\n").unwrap();
    let out = diversity(&[bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("bad.yaml") && stderr.contains("group \"g\", entry 1"),
        "{stderr}"
    );

    let small = dir.path().join("small.json");
    std::fs::write(&small, r#"{"one": ["a single task"], "two": ["a", "b"]}"#).unwrap();
    let out = diversity(&[small.to_str().unwrap(), "--json"]);
    assert_eq!(out.status.code(), Some(1), "a group without a value fails");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["rows"][0]["div"][0].is_null());
    assert!(
        v["rows"][0]["errors"][0]
            .as_str()
            .unwrap()
            .contains("at least 2 texts"),
        "{v}"
    );
    assert!(
        v["rows"][1]["div"][0].is_number(),
        "the other group goes on"
    );

    let out = diversity(&[small.to_str().unwrap(), "--models", "nosuch"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("\"nosuch\" is not configured"),
        "{stderr}"
    );
}

#[test]
fn diversity_command_uses_an_openai_compatible_embeddings_endpoint() {
    let f = Fixture::start(embedding_script(64)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let texts = dir.path().join("texts.yaml");
    std::fs::write(&texts, TEXTS).unwrap();
    let config = dir.path().join("assay.toml");
    std::fs::write(
        &config,
        format!(
            "[embedders.bow]\nbackend = \"openai\"\nbase_url = \"{}\"\nmodel = \"bag-of-words\"\nretries = 0\n",
            f.base_url()
        ),
    )
    .unwrap();
    let out = diversity(&[
        texts.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--models",
        "bow,minilm",
        "--json",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["models"][0]["model"], "bag-of-words");
    assert_eq!(v["models"][0]["dimensions"], 64);
    assert_eq!(v["models"][1]["name"], "minilm");
    let received = f.received();
    assert!(!received.is_empty());
    assert!(
        received
            .iter()
            .all(|r| r.path == EMBEDDINGS_PATH && r.model == "bag-of-words")
    );
    // Side by side, as the paper's Table 1: each row has one value per model.
    for row in v["rows"].as_array().unwrap() {
        assert_eq!(row["div"].as_array().unwrap().len(), 2, "{row}");
        assert!(
            row["div"][0].is_number() && row["div"][1].is_number(),
            "{row}"
        );
    }
}

fn trainer(dir: &std::path::Path, addr: &str, id: &str) -> Proc {
    Proc::spawn(
        id,
        &[
            "worker",
            "--coordinator",
            addr,
            "--roles",
            "trainer",
            "--worker-id",
            &format!("test/{id}"),
        ],
        dir,
    )
}

#[test]
fn a_world_model_fit_resumes_from_its_checkpoint_after_its_worker_is_killed() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &[]);
    let _sim = Proc::spawn(
        "sim worker",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim,render",
            "--image-size",
            "160x120",
            "--worker-id",
            "test/sim-0",
        ],
        dir.path(),
    );
    let mut first = trainer(dir.path(), &addr, "trainer-a");
    let rt = runtime();
    let batch = rt.block_on(async {
        let mut c = client(&addr).await;
        c.submit_batch(pb::SubmitBatchRequest {
            name: "resume".into(),
            tasks: documents(&[
                "examples/tasks/stacking/bbsea-stack-green-cube-on-red-cube.yaml",
                "examples/tasks/placement/put-block-in-bowl.yaml",
            ]),
            policies: vec![pb::PolicyRef {
                name: "oracle".into(),
            }],
            seeds: vec![0, 1],
            text_models: vec!["minilm".into()],
            dynamics_budgets: vec![4],
            dynamics_json: r#"{"steps": 60, "checkpoint_every": 4}"#.into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner()
    });
    assert!(batch.rejected.is_empty(), "{:?}", batch.rejected);
    // Wait for the fit's first checkpoint, then kill its worker without warning.
    let checkpoints = dir
        .path()
        .join("artifacts/checkpoints")
        .join(&batch.batch_id);
    let deadline = Instant::now() + Duration::from_secs(300);
    let ckpt = loop {
        if let Some(f) = std::fs::read_dir(&checkpoints)
            .ok()
            .and_then(|mut d| d.find_map(|e| e.ok().map(|e| e.path())))
            .filter(|p| p.extension().is_some_and(|e| e == "ckpt"))
        {
            break f;
        }
        assert!(
            Instant::now() < deadline,
            "no checkpoint:\n{}",
            first.log_text()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    first.kill9();
    assert!(ckpt.exists());
    let _second = trainer(dir.path(), &addr, "trainer-b");
    let status = rt.block_on(wait_for(
        &addr,
        &batch.batch_id,
        Duration::from_secs(600),
        finished,
    ));
    assert_eq!(
        status.trainer_total, 3,
        "text, one group per budget: {status:?}"
    );
    assert_eq!(status.trainer_done, 3, "{status:?}");
    let report: Report = rt.block_on(async {
        let mut c = client(&addr).await;
        let r = c
            .get_report(pb::GetReportRequest {
                batch_id: batch.batch_id.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        serde_json::from_str(&r.report_json).unwrap()
    });
    let d = report.results.diversity.expect("a diversity section");
    let text = d.text.expect("text diversity");
    let groups: Vec<&str> = text.rows.iter().map(|r| r.group.as_str()).collect();
    assert_eq!(
        groups,
        ["placement", "stacking", "All"],
        "task order (files sorted)"
    );
    assert!(text.rows.iter().all(|r| r.n >= 1));
    assert_eq!(d.dynamics.len(), 2, "{:?}", d.errors);
    for fit in &d.dynamics {
        assert_eq!(fit.train_episodes, 2, "each group has 2 episodes: {fit:?}");
        assert!(fit.eval_image_mse.is_finite() && fit.eval_image_mse > 0.0);
    }
    let resumed: Vec<u64> = d
        .dynamics
        .iter()
        .filter_map(|f| f.resumed_from_step)
        .collect();
    assert!(
        !resumed.is_empty() && resumed.iter().all(|s| *s > 0 && s % 4 == 0),
        "a fit resumed from a checkpoint: {:?}",
        d.dynamics
            .iter()
            .map(|f| (&f.group, f.resumed_from_step, f.steps))
            .collect::<Vec<_>>()
    );
}
