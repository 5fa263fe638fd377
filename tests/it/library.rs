//! `assay eval` driven through its library (`assay_run::eval::run`), as a program of a lab's own
//! would drive it: no terminal, an observer that records what it is told. The run's phases are
//! told in order, the outcome says how the batch ended, and the bundle is written.

use assay_run::eval::EvalArgs;
use assay_run::follow::{Event, Observer};
use clap::Parser;

use crate::common::*;

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    eval: EvalArgs,
}

/// What the run told, one word per event.
#[derive(Default)]
struct Recorder {
    told: Vec<String>,
    last_done: u32,
}

impl Observer for Recorder {
    fn event(&mut self, event: Event<'_>) {
        let word = match event {
            Event::ClusterStarted { description } => {
                assert!(description.starts_with("local cluster: "), "{description}");
                "started"
            }
            Event::Submitted { response } => {
                assert_eq!(response.accepted_tasks, 2, "{response:?}");
                "submitted"
            }
            Event::Following { judging, training } => {
                assert!(!judging && !training, "a sim-only batch without diversity");
                "following"
            }
            Event::Status { status, .. } => {
                assert!(
                    status.shards_done >= self.last_done,
                    "progress never goes back"
                );
                self.last_done = status.shards_done;
                "status"
            }
            Event::Followed => "followed",
            other => panic!("not told in a plain run: {other:?}"),
        };
        if self.told.last().map(String::as_str) != Some(word) {
            self.told.push(word.into());
        }
    }
}

#[test]
fn eval_runs_through_its_library_and_tells_an_observer_each_phase() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let tiny = repo().join("tests/fixtures/report/tiny");
    let mut args = Cli::try_parse_from([
        "eval".into(),
        tiny.into_os_string(),
        "--roles".into(),
        "sim".into(),
        "--no-diversity".into(),
        "--seeds".into(),
        "2".into(),
        "--workers".into(),
        "1".into(),
        "--asset-root".into(),
        repo().into_os_string(),
        "--out".into(),
        out.clone().into_os_string(),
    ])
    .unwrap()
    .eval;
    args.cluster.exe = Some(bin());
    let mut recorder = Recorder::default();
    let outcome = assay_run::eval::run(args, None, &mut recorder).unwrap();
    assert_eq!(
        recorder.told,
        ["started", "submitted", "following", "status", "followed"]
    );
    // The tiny batch has an invalid task: the run completes, and only --strict fails it.
    assert!(outcome.succeeded(false));
    assert!(!outcome.succeeded(true));
    assert_eq!(outcome.rejected, 1);
    let last = outcome.last.as_ref().unwrap();
    assert_eq!((last.shards_done, last.shards_total), (4, 4));
    assert_eq!(outcome.report.results.batch_name, "tiny");
    for file in [
        "report.json",
        "report.md",
        "report.html",
        "episodes.parquet",
    ] {
        assert!(out.join(file).is_file(), "{file} written");
    }
    let written: assay_report::report::Report =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(written, outcome.report);
}
