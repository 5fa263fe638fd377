//! The frame bus between real processes: frames arrive intact in two subscriber processes, a
//! subscriber killed with -9 neither blocks the publisher nor keeps a new subscriber out, and a
//! relay carries a node's frames to a gRPC subscriber (the path to other nodes), and a worker's
//! render role publishes exactly the pictures it stores.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::*;
use assay_proto::v1 as pb;

fn stream(name: &str) -> String {
    // Streams are node-wide: keep concurrent test runs apart.
    format!("assay-test/{name}/{}", std::process::id())
}

fn subscriber(dir: &Path, name: &str, stream: &str, count: u64) -> Proc {
    subscriber_with(dir, name, stream, count, &[])
}

/// A subscriber process (`assay frames subscribe`) with `extra` flags, once it is connected.
fn subscriber_with(dir: &Path, name: &str, stream: &str, count: u64, extra: &[&str]) -> Proc {
    let ready = dir.join(format!("{name}.ready"));
    let count = count.to_string();
    let mut args = vec![
        "frames",
        "subscribe",
        "--stream",
        stream,
        "--count",
        &count,
        "--timeout-s",
        "60",
        "--ready-file",
        ready.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let p = Proc::spawn(name, &args, dir);
    wait_for_file(&p, &ready, &format!("{name} did not connect"));
    p
}

/// A publisher process sending `count` 320 × 240 test frames, `interval_us` apart.
fn publisher(dir: &Path, name: &str, stream: &str, count: u64, interval_us: u64) -> Proc {
    let (count, interval) = (count.to_string(), interval_us.to_string());
    let args = [
        "frames",
        "publish",
        "--stream",
        stream,
        "--count",
        &count,
        "--width",
        "320",
        "--height",
        "240",
        "--interval-us",
        &interval,
    ];
    Proc::spawn(name, &args, dir)
}

/// Waits for the process and returns the JSON line it printed.
fn report(p: &mut Proc, within: Duration) -> serde_json::Value {
    let deadline = Instant::now() + within;
    loop {
        if let Ok(Some(status)) = p.child.try_wait() {
            let text = p.log_text();
            let line = text
                .lines()
                .rev()
                .find(|l| l.starts_with('{') && !l.contains("\"level\""))
                .unwrap_or_else(|| panic!("{} printed no report:\n{text}", p.name));
            let v: serde_json::Value = serde_json::from_str(line).unwrap();
            assert!(status.success(), "{} failed ({status}): {v}", p.name);
            return v;
        }
        assert!(
            Instant::now() < deadline,
            "{} still running after {within:?}:\n{}",
            p.name,
            p.log_text()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn frames_arrive_intact_in_two_subscriber_processes() {
    let dir = tempfile::tempdir().unwrap();
    let s = stream("two");
    let mut a = subscriber(dir.path(), "sub-a", &s, 60);
    let mut b = subscriber(dir.path(), "sub-b", &s, 60);
    let mut sender = publisher(dir.path(), "pub", &s, 60, 3000);
    let sent = report(&mut sender, Duration::from_secs(60));
    assert_eq!(sent["sent"], 60);
    assert_eq!(
        sent["reached_max"], 2,
        "both subscribers were connected: {sent}"
    );
    for sub in [&mut a, &mut b] {
        let r = report(sub, Duration::from_secs(60));
        // Every frame that arrived is intact and in order (a subscriber that falls behind drops
        // its oldest frames rather than slowing the camera, so under load a few may be missing).
        assert_eq!(r["corrupt"], 0, "{r}");
        assert_eq!(r["out_of_order"], 0, "{r}");
        assert!(r["received"].as_u64().unwrap() >= 30, "{r}");
        assert_eq!(r["last"], 59, "the last frame arrived: {r}");
    }
}

#[test]
fn a_killed_subscriber_neither_blocks_the_publisher_nor_locks_out_a_new_one() {
    let dir = tempfile::tempdir().unwrap();
    let s = stream("kill");
    let mut victim = subscriber(dir.path(), "victim", &s, 1_000_000);
    let mut survivor = subscriber(dir.path(), "survivor", &s, 400);
    let mut sender = publisher(dir.path(), "pub", &s, 400, 2000);
    std::thread::sleep(Duration::from_millis(200));
    // The victim stops reading for good with its queue in shared memory still attached.
    victim.kill9();
    let sent = report(&mut sender, Duration::from_secs(120));
    assert_eq!(sent["sent"], 400, "the publisher sent every frame: {sent}");
    let r = report(&mut survivor, Duration::from_secs(60));
    assert_eq!(r["corrupt"], 0, "{r}");
    assert_eq!(
        r["last"], 399,
        "the survivor kept receiving to the end: {r}"
    );
    // A new subscriber can join the stream the dead one was on (its resources were cleaned up).
    let mut late = subscriber(dir.path(), "late", &s, 5);
    let mut again = publisher(dir.path(), "pub-2", &s, 20, 2000);
    assert_eq!(report(&mut again, Duration::from_secs(60))["sent"], 20);
    let r = report(&mut late, Duration::from_secs(60));
    assert!(r["received"].as_u64().unwrap() >= 5, "{r}");
}

#[test]
fn a_relay_carries_frames_to_a_grpc_subscriber_intact() {
    let dir = tempfile::tempdir().unwrap();
    let s = stream("relay");
    let addr_file = dir.path().join("relay.addr");
    let mut relay = Proc::spawn(
        "relay",
        &[
            "frames",
            "relay",
            "--stream",
            &s,
            "--listen",
            "127.0.0.1:0",
            "--addr-file",
            addr_file.to_str().unwrap(),
        ],
        dir.path(),
    );
    wait_for_file(&relay, &addr_file, "the relay did not start");
    let url = format!("http://{}", std::fs::read_to_string(&addr_file).unwrap());
    let mut remote = subscriber_with(dir.path(), "grpc-sub", &s, 40, &["--grpc", &url]);
    let mut local = subscriber(dir.path(), "bus-sub", &s, 40);
    let mut sender = publisher(dir.path(), "pub", &s, 40, 5000);
    let sent = report(&mut sender, Duration::from_secs(60));
    assert_eq!(sent["reached_max"], 2, "relay and local subscriber: {sent}");
    for sub in [&mut remote, &mut local] {
        let r = report(sub, Duration::from_secs(60));
        assert_eq!(r["corrupt"], 0, "{r}");
        assert_eq!(r["out_of_order"], 0, "{r}");
        assert!(r["received"].as_u64().unwrap() >= 20, "{r}");
        assert_eq!(r["last"], 39, "the last frame arrived: {r}");
    }
    assert!(
        relay.term(Duration::from_secs(10)),
        "the relay stops on SIGTERM"
    );
}

/// A coordinator and a `sim,render` worker (160×120 imagery) running one episode of the small
/// stacking fixture with `policy`, while a subscriber process saves the first `frames` frames of
/// the worker's imagery stream into `saved`. The processes live as long as the returned guards.
struct RenderRun {
    report: assay_report::report::Report,
    sub: Proc,
    saved: std::path::PathBuf,
    // Fields drop in order: the processes stop before their folder is removed.
    _procs: [Proc; 2],
    _dir: tempfile::TempDir,
}

fn render_run(name: &str, policy: &str, frames: u64) -> RenderRun {
    let dir = tempfile::tempdir().unwrap();
    let (coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &[]);
    let worker_id = format!("test-{}/{name}", std::process::id());
    let saved = dir.path().join("from-bus");
    let sub = subscriber_with(
        dir.path(),
        &format!("{name}-sub"),
        &format!("{worker_id}/imagery"),
        frames,
        &["--save", saved.to_str().unwrap()],
    );
    let worker = Proc::spawn(
        "render worker",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim,render",
            "--image-size",
            "160x120",
            "--worker-id",
            &worker_id,
        ],
        dir.path(),
    );
    let report = runtime().block_on(async {
        let mut c = client(&addr).await;
        let b = c
            .submit_batch(pb::SubmitBatchRequest {
                name: "test".into(),
                tasks: documents(&["tests/fixtures/small/small-stack-two-blocks.yaml"]),
                policies: vec![pb::PolicyRef {
                    name: policy.into(),
                }],
                seeds: vec![0],
                // The episode's pictures are wanted (no judge asks for them here).
                render: true,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        wait_for(&addr, &b.batch_id, Duration::from_secs(120), finished).await;
        crate::common::report(&addr, &b.batch_id).await
    });
    RenderRun {
        report,
        sub,
        saved,
        _procs: [coord, worker],
        _dir: dir,
    }
}

#[test]
fn a_render_worker_publishes_on_the_bus_the_pictures_it_stores() {
    // 4 scene views and 8 keyframes per episode.
    let mut run = render_run("render", "oracle", 12);
    let (r, saved) = (&run.report, run.saved.clone());
    let img = r.results.tasks[0].episodes[0].imagery.clone().unwrap();
    let stored: std::collections::BTreeSet<String> = img
        .views
        .iter()
        .map(|v| &v.artifact)
        .chain(img.keyframes.iter().map(|k| &k.artifact))
        .map(|k| {
            k.trim_start_matches("imagery/")
                .trim_end_matches(".png")
                .to_owned()
        })
        .collect();
    let got = report(&mut run.sub, Duration::from_secs(60));
    assert_eq!(
        got["corrupt"], 0,
        "every frame was a whole RGBA image: {got}"
    );
    // Read in place from shared memory and encoded here, each frame is byte for byte a picture
    // the worker put in its artifact store (a subscriber that falls behind may lose some).
    let mut from_bus = std::collections::BTreeSet::new();
    for f in std::fs::read_dir(&saved).unwrap() {
        let bytes = std::fs::read(f.unwrap().path()).unwrap();
        from_bus.insert(assay_spec::hash::sha256_hex(&bytes));
    }
    assert!(
        got["received"].as_u64().unwrap() >= 8,
        "most frames arrived: {got}"
    );
    assert!(
        from_bus.is_subset(&stored) && !from_bus.is_empty(),
        "frames on the bus {from_bus:?} are the stored pictures {stored:?}"
    );
}

#[test]
fn a_seeing_policy_acts_on_frames_its_worker_renders_while_the_episode_runs() {
    let mut run = render_run("seeing", "oracle:sense=camera", 40);
    let (r, saved) = (&run.report, run.saved.clone());
    let ep = &r.results.tasks[0].episodes[0];
    assert!(ep.success, "the seeing oracle stacked the blocks: {ep:?}");
    let got = report(&mut run.sub, Duration::from_secs(60));
    assert_eq!(got["corrupt"], 0, "{got}");
    // The policy's own frames went over the bus as they were rendered: camera 2000, 320 × 240,
    // one every 8 physics steps.
    let mut policy_steps = Vec::new();
    for f in std::fs::read_dir(&saved).unwrap() {
        let name = f.unwrap().file_name().to_string_lossy().into_owned();
        let parts: Vec<&str> = name.trim_end_matches(".png").split('-').collect();
        if parts[1] == "2000" {
            policy_steps.push(parts[2].parse::<u64>().unwrap());
            let png =
                assay_render::image::Rgb::from_png(&std::fs::read(saved.join(&name)).unwrap())
                    .unwrap();
            assert_eq!((png.width, png.height), (320, 240));
        }
    }
    assert!(policy_steps.len() >= 20, "policy frames: {policy_steps:?}");
    assert!(policy_steps.iter().all(|s| s % 8 == 0), "{policy_steps:?}");
}

#[test]
fn a_relay_with_the_cluster_token_refuses_a_subscriber_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let s = stream("relay-token");
    let addr_file = dir.path().join("relay.addr");
    let token = [("ASSAY_CLUSTER_TOKEN", "relay-token-0123456789abcdef")];
    let _relay = Proc::spawn_env(
        "relay",
        &[
            "frames",
            "relay",
            "--stream",
            &s,
            "--listen",
            "127.0.0.1:0",
            "--addr-file",
            addr_file.to_str().unwrap(),
        ],
        dir.path(),
        &token,
    );
    wait_for_file(&_relay, &addr_file, "the relay did not start");
    let url = format!("http://{}", std::fs::read_to_string(&addr_file).unwrap());
    let args = [
        "frames",
        "subscribe",
        "--stream",
        &s,
        "--count",
        "1",
        "--timeout-s",
        "10",
        "--grpc",
        &url,
    ];
    let mut intruder = Proc::spawn("intruder", &args, dir.path());
    let status = intruder.wait_exit(Duration::from_secs(30));
    assert!(!status.success());
    assert!(
        intruder.log_text().contains("requires the cluster token"),
        "{}",
        intruder.log_text()
    );
    // With the token, frames arrive.
    let ready = dir.path().join("member.ready");
    let mut member = Proc::spawn_env(
        "member",
        &[
            "frames",
            "subscribe",
            "--stream",
            &s,
            "--count",
            "5",
            "--timeout-s",
            "60",
            "--grpc",
            &url,
            "--ready-file",
            ready.to_str().unwrap(),
        ],
        dir.path(),
        &token,
    );
    wait_for_file(
        &member,
        &ready,
        "the subscriber with the token did not connect",
    );
    let _sender = publisher(dir.path(), "pub", &s, 40, 5000);
    let r = report(&mut member, Duration::from_secs(60));
    assert!(r["received"].as_u64().unwrap() >= 1, "{r}");
    assert_eq!(r["corrupt"], 0, "{r}");
}
