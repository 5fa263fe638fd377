//! The judge role in a real local cluster (`assay eval`: coordinator, sim+render worker, judge
//! worker), with the built-in offline judge beside a VLM judge served by a local
//! OpenAI-compatible HTTP fixture: both quality scores for every task, an unusable answer that
//! becomes an item error while the batch completes, and a second run served from the cache.

use std::process::Command;
use std::sync::Arc;

use crate::common::*;
use assay_report::report::Report;
use assay_testkit::fixture::{Fixture, Received, Reply, Script};

const TASKS: [&str; 2] = [
    "examples/tasks/stacking/bbsea-stack-green-cube-on-red-cube.yaml",
    "examples/tasks/assembling/bbsea-put-red-cube-into-box-and-close-lid.yaml",
];

fn eval(out: &std::path::Path, config: &std::path::Path, judges: &str) -> std::process::Output {
    let mut args = vec!["eval"];
    args.extend_from_slice(&TASKS);
    args.extend_from_slice(&[
        "--seeds",
        "1",
        "--workers",
        "1",
        "--image-size",
        "320x240",
        "--quiet",
        "--judge",
        judges,
        "--judge-repeats",
        "2",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    Command::new(bin())
        .args(&args)
        .current_dir(repo())
        .output()
        .unwrap()
}

fn read_report(out: &std::path::Path) -> Report {
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn offline_and_vlm_judges_score_every_task_through_the_cluster() {
    // Scene alignment scores 4; completion of the stacking task is never given in the asked
    // form; the other task's completion scores 8.
    let script: Script = Arc::new(|r: &Received| {
        if r.prompt_version.as_deref() == Some("scene-alignment/v1") {
            Reply::Answer {
                text: "The objects are there.\nScore: 4".into(),
                tokens_in: 1000,
                tokens_out: 10,
            }
        } else if r.text.contains("stack the green cube") {
            Reply::text("The green cube ends up on the red one, well done!")
        } else {
            Reply::text("Score: 8")
        }
    });
    let f = Fixture::start(script).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("assay.toml");
    std::fs::write(
        &config,
        format!(
            r#"
[judges.vlm]
backend = "openai"
base_url = "{}"
model = "test-vlm"
timeout_s = 20
retries = 1
backoff_initial_s = 0.01
price_input_per_mtok = 2.5
price_output_per_mtok = 10.0
"#,
            f.base_url()
        ),
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = eval(&out, &config, "offline,vlm");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("a judge worker (offline, vlm)"), "{stderr}");

    // What the endpoint received: per episode, 2 scene-alignment requests with the 4 views
    // and 2 completion requests with the 8 keyframes; the stacking task's unusable completion
    // answers were each asked again once (retries = 1).
    let got = f.received();
    assert_eq!(got.len(), 2 * 2 + 2 + 2 * 2, "{got:#?}");
    for r in &got {
        match r.prompt_version.as_deref() {
            Some("scene-alignment/v1") => assert_eq!(r.images, 4),
            Some("completion/v1") => assert_eq!(r.images, 8),
            other => panic!("prompt version {other:?}"),
        }
        assert_eq!(r.model, "test-vlm");
    }

    let report = read_report(&out);
    assert_eq!(report.results.totals.episodes_completed, 2);
    let q = report.results.quality.as_ref().expect("a quality section");
    let judges: Vec<&str> = q.judges.iter().map(|j| j.judge.as_str()).collect();
    assert_eq!(judges, ["offline", "vlm"]);
    for j in &q.judges {
        assert_eq!(j.episodes_judged, 2, "{}", j.judge);
        assert_eq!(j.repeats, 2);
    }
    let offline = &q.judges[0];
    assert!(offline.offline && offline.usage.calls == 0);
    let vlm = &q.judges[1];
    assert_eq!(vlm.usage.calls, got.len() as u64);
    // 4 scene-alignment answers of 1000 + 10 tokens at $2.50 / $10 per million.
    assert!((vlm.usage.cost_usd - 4.0 * (1000.0 * 2.5 + 10.0 * 10.0) / 1e6).abs() < 1e-9);
    assert_eq!(vlm.item_errors, 2);
    for t in &q.tasks {
        let both = t.scene_alignment.mean.is_some() && t.completion.mean.is_some();
        match (t.judge.as_str(), t.task_id.as_str()) {
            ("offline", _) => {
                assert!(both, "{t:?}");
                // The oracle completes both tasks: the predicates say so at the last keyframe.
                assert_eq!(t.completion.mean, Some(10.0));
                assert!(t.scene_alignment.mean.unwrap() >= 3.0, "{t:?}");
            }
            ("vlm", "bbsea-stack-green-cube-on-red-cube") => {
                assert_eq!(t.scene_alignment.mean, Some(4.0));
                assert_eq!(t.completion.n, 0);
                assert_eq!(t.errors.len(), 2, "{t:?}");
                assert!(
                    t.errors[0].contains("no line of the form 'Score: X'"),
                    "{t:?}"
                );
                assert!(t.errors[0].contains("well done"), "{t:?}");
            }
            ("vlm", _) => {
                assert_eq!(t.scene_alignment.mean, Some(4.0));
                assert_eq!(t.completion.mean, Some(8.0));
                assert_eq!(t.completion.variance, Some(0.0));
            }
            other => panic!("{other:?}"),
        }
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## Quality"), "{md}");
    assert!(md.contains("built-in offline judge"), "{md}");
    let svg = std::fs::read_to_string(out.join("quality.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    // Every judge shard left its transcript in the artifact store.
    let transcripts = std::fs::read_dir(out.join("artifacts/judge"))
        .unwrap()
        .count();
    assert_eq!(transcripts, 4);

    // The same batch again (a fresh job store over the same artifact store): no new request,
    // the same scores and the same item errors. Without its job store the run starts anew
    // (with it, it would go on from it: nothing left to do).
    std::fs::remove_dir_all(out.join("run")).unwrap();
    let o = eval(&out, &config, "offline,vlm");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(f.count(), got.len(), "the rerun made new requests");
    let again = read_report(&out);
    let q2 = again.results.quality.as_ref().unwrap();
    assert_eq!(q2.tasks, q.tasks);
    assert_eq!(q2.judges[1].usage.calls, 0);
    assert_eq!(q2.judges[1].usage.cached, got.len() as u64);
}

#[test]
fn a_judge_that_is_not_configured_is_refused_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    // `assay eval` with these arguments fails; what it says.
    let refused = |args: &[&str]| {
        let o = Command::new(bin())
            .arg("eval")
            .arg(TASKS[0])
            .args(args)
            .arg("--out")
            .arg(dir.path())
            .current_dir(repo())
            .output()
            .unwrap();
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let stderr = refused(&["--judge", "gpt-4o"]);
    assert!(
        stderr.contains("judge 'gpt-4o' needs a configuration file (--config)"),
        "{stderr}"
    );
    let config = dir.path().join("assay.toml");
    std::fs::write(&config, "[judges.local]\nbackend = \"openai\"\nbase_url = \"http://127.0.0.1:9/v1\"\nmodel = \"m\"\nfoo = 1\n").unwrap();
    let stderr = refused(&["--judge", "local", "--config", config.to_str().unwrap()]);
    assert!(
        stderr.contains("assay.toml") && stderr.contains("foo"),
        "{stderr}"
    );
}
