//! Roles as separate processes (issue 28): sim-only, render-only and judge workers on one
//! machine make the report one all-roles worker makes, the judge reading the pictures over
//! shared memory; a batch that renders waits, and says so, while no worker can render; a render
//! worker killed with -9 mid-batch loses nothing.

use std::sync::Arc;
use std::time::Duration;

use crate::common::*;
use assay_proto::v1 as pb;
use assay_report::report::Report;
use assay_testkit::fixture::{Fixture, Received, Reply, Script};

const TASKS: [&str; 2] = [
    "examples/tasks/stacking/bbsea-stack-green-cube-on-red-cube.yaml",
    "examples/tasks/assembling/bbsea-put-red-cube-into-box-and-close-lid.yaml",
];

/// A worker process with `roles`, named `name` in the cluster.
fn role_worker(dir: &std::path::Path, addr: &str, name: &str, roles: &str, extra: &[&str]) -> Proc {
    let id = format!("test/{name}");
    let mut args = vec![
        "worker",
        "--coordinator",
        addr,
        "--roles",
        roles,
        "--worker-id",
        &id,
        "--node-id",
        "test-node",
        "--image-size",
        "320x240",
    ];
    args.extend_from_slice(extra);
    Proc::spawn(name, &args, dir)
}

async fn submit_rendering(addr: &str, seeds: u64, judges: &[&str]) -> pb::SubmitBatchResponse {
    let mut c = client(addr).await;
    c.submit_batch(pb::SubmitBatchRequest {
        name: "roles".into(),
        tasks: documents(&TASKS),
        policies: vec![pb::PolicyRef {
            name: "oracle".into(),
        }],
        seeds: (0..seeds).collect(),
        judges: judges.iter().map(|j| j.to_string()).collect(),
        judge_repeats: 1,
        render: true,
        ..Default::default()
    })
    .await
    .unwrap()
    .into_inner()
}

/// What must not depend on where each role ran: every episode (its file, outcome and
/// pictures, byte for byte by content address) and every judge's scores.
fn comparable(r: &Report) -> serde_json::Value {
    serde_json::json!({
        "tasks": r.results.tasks,
        "totals": {
            "planned": r.results.totals.episodes_planned,
            "completed": r.results.totals.episodes_completed,
        },
        "quality": r.results.quality.as_ref().map(|q| serde_json::json!({
            "tasks": q.tasks,
            "judges": q.judges.iter().map(|j| (&j.judge, j.episodes_judged, j.usage.calls)).collect::<Vec<_>>(),
        })),
    })
}

/// The last statistics `assay top --json` printed for `worker`.
fn last_stats(top: &Proc, worker: &str) -> serde_json::Value {
    top.log_text()
        .lines()
        .filter(|l| l.starts_with("{\"key\""))
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["key"].as_str().is_some_and(|k| k.ends_with("/stats")))
        .rfind(|v| v["value"]["worker"] == worker)
        .map(|v| v["value"].clone())
        .unwrap_or_else(|| panic!("no stats from {worker}:\n{}", top.log_text()))
}

#[test]
fn sim_render_and_judge_workers_apart_make_the_report_one_worker_with_every_role_makes() {
    // A VLM judge whose scores are a function of the pictures it is shown: equal scores mean
    // equal pictures.
    let script: Script = Arc::new(|r: &Received| {
        let urls = r.body.to_string();
        let digest = urls
            .bytes()
            .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(u64::from(b)));
        let score = if r.prompt_version.as_deref() == Some("scene-alignment/v1") {
            1 + digest % 5
        } else {
            digest % 11
        };
        Reply::text(format!("Looked at {} pictures.\nScore: {score}", r.images))
    });
    let f = Fixture::start(script).unwrap();
    let root = tempfile::tempdir().unwrap();
    let config = root.path().join("assay.toml");
    std::fs::write(
        &config,
        format!(
            "[judges.vlm]\nbackend = \"openai\"\nbase_url = \"{}\"\nmodel = \"test-vlm\"\ntimeout_s = 20\nretries = 0\n",
            f.base_url()
        ),
    )
    .unwrap();
    let config = config.to_str().unwrap();
    let judge_args = ["--config", config, "--capacity", "2"];
    let rt = runtime();

    // One worker with every role.
    let one = root.path().join("one");
    std::fs::create_dir_all(&one).unwrap();
    let (_c1, addr1) = coordinator(&one, "127.0.0.1:0", &[]);
    let _all = role_worker(&one, &addr1, "all", "sim,render,judge", &judge_args);
    let whole = rt.block_on(async {
        let sub = submit_rendering(&addr1, 2, &["offline", "vlm"]).await;
        wait_for(&addr1, &sub.batch_id, Duration::from_secs(240), finished).await;
        report(&addr1, &sub.batch_id).await
    });
    let asked = f.count();
    assert_eq!(asked, 4 * 2, "4 episodes, 2 questions each");

    // Sim, render and judge apart, and `assay top` watching the cluster's telemetry.
    let apart = root.path().join("apart");
    std::fs::create_dir_all(&apart).unwrap();
    let (_c2, addr2) = coordinator(&apart, "127.0.0.1:0", &["--heartbeat-ms", "300"]);
    let endpoint = std::fs::read_to_string(apart.join("coordinator.addr"))
        .unwrap()
        .lines()
        .nth(1)
        .expect("the telemetry endpoint")
        .to_owned();
    let mut top = Proc::spawn("top", &["top", "--telemetry", &endpoint, "--json"], &apart);
    let _sim = role_worker(&apart, &addr2, "sim", "sim", &["--capacity", "2"]);
    let _render = role_worker(&apart, &addr2, "render", "render", &[]);
    let _judge = role_worker(&apart, &addr2, "judge", "judge", &judge_args);
    let split = rt.block_on(async {
        let sub = submit_rendering(&addr2, 2, &["offline", "vlm"]).await;
        wait_for(&addr2, &sub.batch_id, Duration::from_secs(240), finished).await;
        report(&addr2, &sub.batch_id).await
    });
    assert_each_episode_once(&split, 2, 2);
    assert_eq!(
        comparable(&split),
        comparable(&whole),
        "the same seeds, episodes, pictures and scores"
    );
    assert_eq!(
        f.count(),
        2 * asked,
        "the split cluster asked the judge the same questions"
    );
    for t in &split.results.tasks {
        for e in &t.episodes {
            assert!(e.imagery.is_some(), "{} seed {} has pictures", t.id, e.seed);
        }
    }
    // The judge read every picture and caption over shared memory: per episode 4 views and 8
    // keyframes for the VLM, the caption for the offline judge, none from the artifact store.
    std::thread::sleep(Duration::from_millis(2500));
    let judge = last_stats(&top, "test/judge");
    assert_eq!(judge["judged"], 8, "{judge}");
    assert_eq!(judge["frames_from_shared_memory"], 4 * 13, "{judge}");
    assert_eq!(judge["frames_from_store"], 0, "{judge}");
    let render = last_stats(&top, "test/render");
    assert_eq!(render["rendered"], 4, "{render}");
    assert_eq!(render["roles"], serde_json::json!(["render"]));
    let sim = last_stats(&top, "test/sim");
    assert_eq!(sim["episodes_done"], 4, "{sim}");
    top.kill9();
}

#[test]
fn a_rendering_batch_waits_for_a_render_worker_and_one_killed_mid_batch_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (_c, addr) = coordinator(
        dir.path(),
        "127.0.0.1:0",
        &["--heartbeat-ms", "200", "--lease-ttl-ms", "2000"],
    );
    let _sim = role_worker(dir.path(), &addr, "sim", "sim", &["--capacity", "2"]);
    let rt = runtime();
    let seeds = 3;
    let sub = rt.block_on(submit_rendering(&addr, seeds, &["offline"]));
    let total = 2 * seeds as u32;
    // Every episode is simulated, then waits: no connected worker can render. (Until the sim
    // worker has registered, the shards wait for it instead.)
    let waiting = rt.block_on(wait_for(
        &addr,
        &sub.batch_id,
        Duration::from_secs(120),
        |s| s.shards_queued == total && s.waiting.iter().any(|w| w.contains("need render")),
    ));
    assert_eq!(
        waiting.shards_done, 0,
        "no episode is done without its pictures"
    );
    assert_eq!(
        waiting.waiting,
        vec![format!(
            "{total} shards need render: no connected worker offers it (start a worker with --roles render)"
        )]
    );
    let status = std::process::Command::new(bin())
        .args(["status", &sub.batch_id, "--coordinator", &addr])
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&status.stdout);
    assert!(
        printed.contains("waiting: 6 shards need render"),
        "{printed}"
    );
    // A render worker starts: it takes the work, and is killed with -9 once it has drawn one
    // episode (it holds the next by then: results and new leases go in one exchange).
    let mut first = role_worker(dir.path(), &addr, "render-a", "render", &[]);
    rt.block_on(wait_for(
        &addr,
        &sub.batch_id,
        Duration::from_secs(120),
        |s| s.shards_done >= 1,
    ));
    first.kill9();
    let after_kill = rt.block_on(wait_for(
        &addr,
        &sub.batch_id,
        Duration::from_secs(30),
        |s| s.shards_running == 0,
    ));
    assert!(
        after_kill.shards_done < total,
        "killed mid-batch: {after_kill:?}"
    );
    assert!(
        after_kill.waiting.iter().any(|w| w.contains("need render")),
        "waiting again once the render worker is gone: {after_kill:?}"
    );
    // The episodes the killed worker drew are judged from the artifact store's copies (its
    // memory is gone), the others over shared memory: no gap either way.
    let _judge = role_worker(dir.path(), &addr, "judge", "judge", &[]);
    let _second = role_worker(dir.path(), &addr, "render-b", "render", &[]);
    let done = rt.block_on(wait_for(
        &addr,
        &sub.batch_id,
        Duration::from_secs(240),
        finished,
    ));
    assert!(done.waiting.is_empty());
    let r = rt.block_on(report(&addr, &sub.batch_id));
    assert_each_episode_once(&r, 2, seeds);
    assert!(
        r.run.extra_attempts >= 1,
        "the killed worker's render shard ran again"
    );
    for t in &r.results.tasks {
        for e in &t.episodes {
            let img = e.imagery.as_ref().expect("every episode has its pictures");
            assert_eq!((img.views.len(), img.keyframes.len()), (4, 8));
            for k in img.keyframes.iter().map(|k| &k.artifact) {
                assert!(dir.path().join("artifacts").join(k).is_file(), "{k}");
            }
        }
    }
    // Episodes are the simulator's (the render workers drew them); judging is the judge's.
    assert_eq!(r.run.workers, vec!["test/judge", "test/sim"]);
    let q = r.results.quality.as_ref().expect("judged");
    assert_eq!(q.judges[0].episodes_judged, u64::from(total));
    assert!(q.tasks.iter().all(|t| t.errors.is_empty()), "{:?}", q.tasks);
}
