//! `assay watch`: three batches dropped into a folder one after another, the second a repeat of
//! the first under other file names: two evaluations, one skip, marginal diversity for the third,
//! and the history in the coordinator's job store.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::*;
use assay_proto::v1 as pb;

/// Copies `files` (repository paths) into a staging folder, then renames it into `dir` as
/// `name`: a batch appears whole, as a lab's pipeline would drop it. `prefix` renames the files.
fn drop_batch(dir: &Path, staging: &Path, name: &str, files: &[&str], prefix: &str) {
    let stage = staging.join(name);
    std::fs::create_dir_all(&stage).unwrap();
    for f in files {
        let file = Path::new(f).file_name().unwrap().to_string_lossy();
        std::fs::copy(repo().join(f), stage.join(format!("{prefix}{file}"))).unwrap();
    }
    std::fs::rename(&stage, dir.join(name)).unwrap();
}

/// `assay watch DIR` with one physics-only worker, polling every 200 ms, until `exit_after`
/// batches are handled.
fn spawn_watch(tmp: &Path, dir: &Path, out: &Path, seeds: u32, exit_after: u32) -> Proc {
    let (seeds, exit_after) = (seeds.to_string(), exit_after.to_string());
    Proc::spawn(
        "watch",
        &[
            "watch",
            dir.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--roles",
            "sim",
            "--no-judge",
            "--seeds",
            &seeds,
            "--workers",
            "1",
            "--poll-ms",
            "200",
            "--exit-after",
            &exit_after,
        ],
        tmp,
    )
}

fn corpus(out: &Path) -> serde_json::Value {
    std::fs::read_to_string(out.join("corpus.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::json!({"batches": []}))
}

fn wait_for_batches(p: &mut Proc, out: &Path, n: usize) -> serde_json::Value {
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let c = corpus(out);
        if c["batches"].as_array().unwrap().len() >= n {
            return c;
        }
        if let Ok(Some(st)) = p.child.try_wait() {
            panic!("assay watch exited ({st}):\n{}", p.log_text());
        }
        assert!(
            Instant::now() < deadline,
            "no batch {n} in time:\n{}",
            p.log_text()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn watch_evaluates_new_batches_skips_repeats_and_reports_marginal_diversity() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, staging, out) = (
        tmp.path().join("incoming"),
        tmp.path().join("staging"),
        tmp.path().join("out"),
    );
    std::fs::create_dir_all(&dir).unwrap();
    let first = [
        "tests/fixtures/small/small-put-block-in-bowl.yaml",
        "tests/fixtures/small/small-stack-two-blocks.yaml",
    ];
    let third = [
        "tests/fixtures/small/small-insert-block-into-fixture.yaml",
        "tests/fixtures/small/small-move-two-small-blocks-into-zone.yaml",
    ];
    let mut watch = spawn_watch(tmp.path(), &dir, &out, 2, 3);
    drop_batch(&dir, &staging, "batch-1", &first, "");
    wait_for_batches(&mut watch, &out, 1);
    // The same tasks under other file names: the content hash is of the specs, not the files.
    drop_batch(&dir, &staging, "batch-2", &first, "copy-of-");
    wait_for_batches(&mut watch, &out, 2);
    drop_batch(&dir, &staging, "batch-3", &third, "");
    let status = watch.wait_exit(Duration::from_secs(300));
    assert!(status.success(), "{}", watch.log_text());

    let c = corpus(&out);
    let b = c["batches"].as_array().unwrap();
    let outcomes: Vec<&str> = b.iter().map(|e| e["outcome"].as_str().unwrap()).collect();
    assert_eq!(outcomes, ["evaluated", "skipped", "evaluated"], "{c:#}");
    assert_eq!(b[1]["duplicate_of"], b[0]["batch_id"]);
    assert_eq!(b[1]["content_hash"], b[0]["content_hash"]);
    assert_ne!(b[2]["content_hash"], b[0]["content_hash"]);
    for e in [&b[0], &b[2]] {
        assert_eq!(
            (e["tasks"].as_u64(), e["episodes"].as_u64()),
            (Some(2), Some(4)),
            "{e:#}"
        );
    }
    assert_eq!(b[1]["episodes"], 0);
    // Marginal diversity: none for the first batch (nothing before it), measured for the third
    // against the first batch's two tasks (the skipped repeat adds nothing to the corpus).
    assert!(b[0]["marginal"]["minilm"].is_null(), "{:#}", b[0]);
    let m = &b[2]["marginal"]["minilm"];
    assert_eq!(
        (m["base_n"].as_u64(), m["new_n"].as_u64()),
        (Some(2), Some(2)),
        "{m:#}"
    );
    let (base, union, marginal) = (
        m["base_div"].as_f64().unwrap(),
        m["union_div"].as_f64().unwrap(),
        m["marginal"].as_f64().unwrap(),
    );
    assert!(
        (marginal - (union - base)).abs() < 1e-9 && marginal.is_finite(),
        "{m:#}"
    );
    assert_eq!(b[2]["corpus_diversity"]["minilm"].as_f64(), Some(union));
    let md = std::fs::read_to_string(out.join("corpus.md")).unwrap();
    assert!(
        md.contains("3 batches seen: 2 evaluated (4 tasks), 1 skipped"),
        "{md}"
    );
    assert!(
        md.contains(&format!(
            "skipped: repeats {}",
            b[0]["batch_id"].as_str().unwrap()
        )),
        "{md}"
    );
    // Each evaluated batch has its reports; the skipped one has none.
    for name in ["batch-1", "batch-3"] {
        for f in ["report.json", "report.md", "report.html"] {
            assert!(
                out.join("batches").join(name).join(f).is_file(),
                "{name}/{f}"
            );
        }
    }
    assert!(!out.join("batches/batch-2").exists());

    // The history is in the job store: a coordinator opened on it lists all three batches.
    let (_coord, addr) = coordinator(&out.join("run"), "127.0.0.1:0", &["--telemetry", "off"]);
    runtime().block_on(async {
        let mut c = client(&addr).await;
        let list = c
            .list_batches(pb::ListBatchesRequest {})
            .await
            .unwrap()
            .into_inner()
            .batches;
        let states: Vec<(String, i32, String)> = list
            .iter()
            .map(|s| (s.name.clone(), s.state, s.duplicate_of.clone()))
            .collect();
        assert_eq!(
            states,
            [
                (
                    "batch-1".into(),
                    pb::BatchState::Completed as i32,
                    String::new()
                ),
                (
                    "batch-2".into(),
                    pb::BatchState::Skipped as i32,
                    list[0].batch_id.clone()
                ),
                (
                    "batch-3".into(),
                    pb::BatchState::Completed as i32,
                    String::new()
                ),
            ]
        );
        assert_eq!(list[1].shards_total, 0);
    });
}

/// A local worker killed while `assay watch` evaluates a batch is started again and the batch is
/// evaluated, as in `assay eval`.
#[test]
fn watch_starts_a_killed_local_worker_again_and_the_batch_is_evaluated() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, staging, out) = (
        tmp.path().join("incoming"),
        tmp.path().join("staging"),
        tmp.path().join("out"),
    );
    std::fs::create_dir_all(&dir).unwrap();
    let mut watch = spawn_watch(tmp.path(), &dir, &out, 8, 1);
    drop_batch(
        &dir,
        &staging,
        "batch-1",
        &[
            "tests/fixtures/small/small-put-block-in-bowl.yaml",
            "tests/fixtures/small/small-stack-two-blocks.yaml",
        ],
        "",
    );
    let deadline = Instant::now() + Duration::from_secs(300);
    let episodes = out.join("artifacts");
    loop {
        let stored = std::fs::read_dir(episodes.join("episodes")).map_or(0, |d| d.count());
        if stored >= 2 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no episode:\n{}",
            watch.log_text()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let workers = children(watch.child.id(), "worker");
    assert!(!workers.is_empty(), "no local worker");
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(workers[0]),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    let status = watch.wait_exit(Duration::from_secs(300));
    let log = watch.log_text();
    assert!(status.success(), "{log}");
    assert!(log.contains("starting it again"), "{log}");
    let c = corpus(&out);
    let b = &c["batches"][0];
    assert_eq!(b["outcome"], "evaluated", "{c:#}");
    assert_eq!(b["episodes"], 16, "{c:#}");
}
