//! Operating a cluster: the coordinator's Prometheus metrics scraped while a batch runs.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use crate::common::*;

const STACKING: &str = "examples/tasks/stacking";

/// `GET path` on `addr` over plain HTTP/1.0: (status line, body).
fn http_get(addr: &str, path: &str) -> (String, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut raw = String::new();
    s.read_to_string(&mut raw).unwrap();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((&raw, ""));
    (
        head.lines().next().unwrap_or_default().to_owned(),
        body.to_owned(),
    )
}

/// The value of the sample `series` (name with labels, exactly as exposed).
fn sample(text: &str, series: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(series)?.strip_prefix(' '))
        .unwrap_or_else(|| panic!("no sample {series} in\n{text}"))
        .trim()
        .parse()
        .unwrap()
}

#[test]
fn metrics_are_scraped_while_a_batch_runs() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(
        dir.path(),
        "127.0.0.1:0",
        &["--metrics-listen", "127.0.0.1:0"],
    );
    let announced = std::fs::read_to_string(dir.path().join("coordinator.addr")).unwrap();
    let metrics = announced.lines().nth(2).unwrap().trim().to_owned();
    assert_ne!(metrics, "off");
    let (status, body) = http_get(&metrics, "/healthz");
    assert!(status.contains("200"), "{status}");
    assert_eq!(body, "ok\n");
    let (_, before) = http_get(&metrics, "/metrics");
    assert_eq!(sample(&before, "assay_queue_depth{role=\"sim\"}"), 0.0);
    assert_eq!(sample(&before, "assay_workers_connected"), 0.0);

    let _w = worker(dir.path(), &addr, 0, 1);
    runtime().block_on(async {
        let sub = submit(&addr, &[STACKING], 3).await;
        let planned = sub.accepted_tasks as f64 * 3.0;
        // Scrape while the batch runs: shards queued behind the one worker, one leased, some
        // done, and the figures adding up at every scrape.
        let deadline = Instant::now() + Duration::from_secs(300);
        let (mut saw_queue, mut saw_lease, mut saw_progress) = (false, false, false);
        loop {
            let (status, text) = http_get(&metrics, "/metrics");
            assert!(status.contains("200"), "{status}");
            let queued = sample(&text, "assay_queue_depth{role=\"sim\"}");
            let leased = sample(&text, "assay_leases_active{role=\"sim\"}");
            let done = sample(&text, "assay_shards{role=\"sim\",state=\"done\"}");
            assert_eq!(queued + leased + done, planned, "{text}");
            assert!(
                leased <= 1.0,
                "one worker of capacity 1 holds {leased} leases"
            );
            assert_eq!(
                sample(&text, "assay_shard_seconds_count{role=\"sim\"}"),
                done
            );
            saw_queue |= queued > 0.0;
            saw_lease |= leased == 1.0
                && sample(&text, "assay_workers_connected") == 1.0
                && sample(&text, "assay_batches{state=\"running\"}") == 1.0;
            saw_progress |= done > 0.0 && done < planned;
            if done == planned {
                break;
            }
            assert!(Instant::now() < deadline, "batch did not finish:\n{text}");
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
        assert!(
            saw_queue && saw_lease && saw_progress,
            "queue {saw_queue}, lease {saw_lease}, progress {saw_progress}"
        );
        wait_for(&addr, &sub.batch_id, Duration::from_secs(30), finished).await;
        let (_, after) = http_get(&metrics, "/metrics");
        assert_eq!(sample(&after, "assay_queue_depth{role=\"sim\"}"), 0.0);
        assert_eq!(sample(&after, "assay_batches{state=\"completed\"}"), 1.0);
        assert_eq!(
            sample(
                &after,
                "assay_shard_seconds_bucket{role=\"sim\",le=\"+Inf\"}"
            ),
            planned
        );
        assert_eq!(
            sample(&after, "assay_shard_failures_total{role=\"sim\"}"),
            0.0
        );
        // Histogram buckets are cumulative and end at the count.
        let buckets: Vec<f64> = after
            .lines()
            .filter(|l| l.starts_with("assay_shard_seconds_bucket{role=\"sim\""))
            .map(|l| l.rsplit(' ').next().unwrap().parse().unwrap())
            .collect();
        assert!(buckets.windows(2).all(|w| w[0] <= w[1]), "{buckets:?}");
    });
}

/// Starts `assay coordinator` with `extra` flags and `env`, waits for its address file and
/// returns its three lines (gRPC address, telemetry, metrics); the process is killed after.
fn announced(dir: &std::path::Path, extra: &[&str], env: &[(&str, &str)]) -> Vec<String> {
    let addr_file = dir.join("coordinator.addr");
    let _ = std::fs::remove_file(&addr_file);
    let mut cmd = std::process::Command::new(bin());
    cmd.args(["coordinator", "--listen", "127.0.0.1:0", "--addr-file"])
        .arg(&addr_file)
        .arg("--store")
        .arg(dir.join("jobs.db"))
        .arg("--artifacts")
        .arg(dir.join("artifacts"))
        .args(extra)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let text = loop {
        if let Ok(t) = std::fs::read_to_string(&addr_file)
            && t.lines().count() == 3
        {
            break t;
        }
        assert!(child.try_wait().unwrap().is_none(), "coordinator exited");
        assert!(Instant::now() < deadline, "coordinator did not start");
        std::thread::sleep(Duration::from_millis(20));
    };
    let _ = child.kill();
    let _ = child.wait();
    text.lines().map(str::to_owned).collect()
}

#[test]
fn configuration_layers_the_file_under_the_environment_under_flags() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cluster.toml");
    std::fs::write(
        &file,
        "# a cluster's settings\n[coordinator]\ntelemetry = \"off\"\nmetrics-listen = \"off\"\n\n\
         [judges.offline-copy]\nbackend = \"offline\"\n",
    )
    .unwrap();
    let cfg = file.to_str().unwrap();
    // Default: telemetry on loopback, metrics off.
    let l = announced(dir.path(), &[], &[]);
    assert!(l[1].starts_with("tcp/127.0.0.1:"), "{l:?}");
    assert_eq!(l[2], "off");
    // The file beats the defaults.
    let l = announced(dir.path(), &[], &[("ASSAY_CONFIG", cfg)]);
    assert_eq!((l[1].as_str(), l[2].as_str()), ("off", "off"), "{l:?}");
    // An ASSAY_* variable beats the file.
    let env = [
        ("ASSAY_CONFIG", cfg),
        ("ASSAY_METRICS_LISTEN", "127.0.0.1:0"),
    ];
    let l = announced(dir.path(), &[], &env);
    assert_eq!(l[1], "off");
    assert!(l[2].starts_with("127.0.0.1:"), "{l:?}");
    // A flag beats the variable.
    let l = announced(dir.path(), &["--metrics-listen", "off"], &env);
    assert_eq!(l[2], "off");

    // A mistyped key fails before anything starts, naming the file, the section and the key.
    std::fs::write(&file, "[coordinator]\nmetrics-lsten = \"off\"\n").unwrap();
    let out = std::process::Command::new(bin())
        .args(["coordinator"])
        .env("ASSAY_CONFIG", cfg)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("cluster.toml")
            && err.contains("[coordinator] has no option 'metrics-lsten'")
            && err.contains("metrics-listen"),
        "{err}"
    );
}

fn doctor(args: &[&str], env: &[(&str, &str)]) -> (bool, Vec<serde_json::Value>) {
    let mut cmd = std::process::Command::new(bin());
    cmd.arg("doctor").arg("--json").args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    let checks: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    (out.status.success(), checks)
}

fn verdict<'a>(checks: &'a [serde_json::Value], name: &str) -> &'a serde_json::Value {
    checks
        .iter()
        .find(|c| c["name"].as_str().is_some_and(|n| n.starts_with(name)))
        .unwrap_or_else(|| panic!("no check {name}: {checks:#?}"))
}

#[test]
fn doctor_checks_the_machine_for_real_and_names_the_fix() {
    // This machine has everything (scripts/test installs it): no check fails.
    let (ok, checks) = doctor(&[], &[]);
    assert!(ok, "{checks:#?}");
    for name in [
        "Vulkan adapter",
        "libtorch",
        "embedding model minilm",
        "zenoh telemetry",
        "shared memory",
    ] {
        assert_ne!(verdict(&checks, name)["verdict"], "fail", "{checks:#?}");
    }
    // GenSim's task code needs numpy: scripts/test's Python has it, a bare one says how to get it.
    assert_eq!(
        verdict(&checks, "Python with numpy")["verdict"],
        "ok",
        "{checks:#?}"
    );
    // GenSim's task code behind the OS boundary: said either way, never a failure.
    let b = verdict(&checks, "OS boundary of GenSim task code");
    match assay_import::gensim::boundary().missing() {
        None => assert_eq!(b["verdict"], "ok", "{b:#}"),
        Some(why) => {
            assert_eq!(b["verdict"], "warn", "{b:#}");
            assert!(b["detail"].as_str().unwrap().contains(&why), "{b:#}");
        }
    }
    let (_, bare) = doctor(&[], &[("ASSAY_PYTHON", "/nonexistent/python3")]);
    let p = verdict(&bare, "Python with numpy");
    assert_eq!(p["verdict"], "warn");
    assert!(p["fix"].as_str().unwrap().contains("ASSAY_PYTHON"), "{p:#}");
    assert!(
        verdict(&checks, "embedding model minilm")["detail"]
            .as_str()
            .unwrap()
            .contains("384 dimensions")
    );

    // Without the model files: the check fails and says how to install them.
    let empty = tempfile::tempdir().unwrap();
    let (ok, checks) = doctor(&[], &[("ASSAY_MODELS", empty.path().to_str().unwrap())]);
    assert!(!ok);
    let m = verdict(&checks, "embedding model minilm");
    assert_eq!(m["verdict"], "fail");
    assert!(
        m["fix"].as_str().unwrap().contains("scripts/setup-models"),
        "{m:#}"
    );

    // Judge endpoints: one server that answers but whose key variable is unset, one that is down.
    let up = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let down = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let down_port = down.local_addr().unwrap().port();
    drop(down);
    let cfg = empty.path().join("judges.toml");
    std::fs::write(
        &cfg,
        format!(
            "[judges.local-vlm]\nbackend = \"openai\"\nbase_url = \"http://{}/v1\"\nmodel = \"m\"\n\
             api_key_env = \"ASSAY_DOCTOR_TEST_KEY_NEVER_SET\"\n\n\
             [judges.gone]\nbackend = \"openai\"\nbase_url = \"http://127.0.0.1:{down_port}/v1\"\nmodel = \"m\"\n",
            up.local_addr().unwrap()
        ),
    )
    .unwrap();
    let (ok, checks) = doctor(&["--config", cfg.to_str().unwrap()], &[]);
    assert!(!ok);
    let keyless = verdict(&checks, "judge local-vlm");
    assert_eq!(keyless["verdict"], "fail");
    assert!(
        keyless["detail"]
            .as_str()
            .unwrap()
            .contains("$ASSAY_DOCTOR_TEST_KEY_NEVER_SET (its API key) is not set"),
        "{keyless:#}"
    );
    let gone = verdict(&checks, "judge gone");
    assert!(
        gone["detail"].as_str().unwrap().contains("nothing answers"),
        "{gone:#}"
    );
    let (ok, checks) = doctor(
        &["--config", cfg.to_str().unwrap()],
        &[("ASSAY_DOCTOR_TEST_KEY_NEVER_SET", "k")],
    );
    assert!(!ok, "the second judge is still down");
    assert_eq!(verdict(&checks, "judge local-vlm")["verdict"], "ok");
}

/// Runs `assay ARGS`, which must succeed, and reads the JSON line it prints.
fn bench_json(args: &[&str]) -> serde_json::Value {
    let out = std::process::Command::new(bin())
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(String::from_utf8(out.stdout).unwrap().trim()).unwrap()
}

#[test]
fn the_coordinator_benchmark_runs_every_shard_once_at_small_scale() {
    let v = bench_json(&["bench", "coordinator", "--workers", "8", "--shards", "300"]);
    for part in ["store", "store_actor", "grpc"] {
        assert_eq!(v[part]["shards"], 300, "{v:#}");
        assert!(v[part]["shards_per_s"].as_f64().unwrap() > 0.0, "{v:#}");
    }
    assert_eq!(v["grpc"]["workers"], 8);
    assert!(v["grpc"]["peak_rss_mib"].as_f64().unwrap() > 0.0);
}

/// `assay bench scaling` runs its sweep of worker counts, each run completing its whole batch
/// (the throughput figures are for the benchmark's reader, not asserted here).
#[test]
fn the_scaling_benchmark_runs_each_worker_count_to_the_end() {
    let v = bench_json(&[
        "bench",
        "scaling",
        "--workers",
        "6",
        "--work-ms",
        "5",
        "--shards",
        "400",
    ]);
    let runs = v["runs"].as_array().unwrap();
    let workers: Vec<u64> = runs
        .iter()
        .map(|r| r["workers"].as_u64().unwrap())
        .collect();
    assert_eq!(workers, [1, 4, 6], "{v:#}");
    for r in runs {
        assert!(r["shards"].as_u64().unwrap() >= 200, "{r:#}");
        assert_eq!(r["work_ms"], 5.0, "{r:#}");
        assert!(r["of_ideal"].as_f64().unwrap() > 0.0, "{r:#}");
    }
}

/// The configuration traps of issue 24: a typo in `./assay.toml` breaks neither `--version` nor
/// another command's run, and a variable set for one command does not change another.
#[test]
fn configuration_and_environment_stay_where_they_belong() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("assay.toml"),
        "[worker]\ncapcity = 2\n[rank]\nresamples = 500\n",
    )
    .unwrap();
    let run = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = std::process::Command::new(bin());
        c.args(args).current_dir(dir.path());
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    let ladder = repo().join("examples/rank/ladder.csv");
    let ladder = ladder.to_str().unwrap();
    assert!(run(&["--version"], &[]).status.success());
    assert!(run(&["worker", "--help"], &[]).status.success());
    // `rank` reads [rank] (resamples 500) and is not stopped by [worker]'s typo...
    let base = run(&["rank", ladder, "--json"], &[]);
    assert!(
        base.status.success(),
        "{}",
        String::from_utf8_lossy(&base.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&base.stdout).unwrap();
    assert_eq!(v["resamples"], 500);
    // ...nor changed by variables meant for other commands.
    let noisy = run(
        &["rank", ladder, "--json"],
        &[
            ("ASSAY_SEED", "7"),
            ("ASSAY_REAL", "world-model"),
            ("ASSAY_RESAMPLES", "1"),
        ],
    );
    assert_eq!(noisy.stdout, base.stdout);
    // `worker` itself refuses its section's typo, naming the file and the key.
    let o = run(&["worker", "--coordinator", "http://127.0.0.1:9"], &[]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("assay.toml") && err.contains("[worker] has no option 'capcity'"),
        "{err}"
    );
    // A value the option refuses names the file and the key.
    std::fs::write(
        dir.path().join("assay.toml"),
        "[rank]\nresamples = \"many\"\n",
    )
    .unwrap();
    let o = run(&["rank", ladder], &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("assay.toml: [rank] resamples = \"many\""),
        "{err}"
    );
}

/// `assay bench churn` at small scale: workers killed, leaving gracefully and stalling while a
/// batch runs; nothing lost, every re-run explained by a leave, no result counted twice, every
/// stalled worker's late result refused.
#[test]
fn the_churn_benchmark_loses_nothing_while_workers_come_and_go() {
    let v = bench_json(&[
        "bench",
        "churn",
        "--workers",
        "20",
        "--shards",
        "1500",
        "--every-ms",
        "20",
        "--lease-ttl-ms",
        "400",
    ]);
    assert_eq!(v["batch_state"], "BATCH_STATE_COMPLETED", "{v:#}");
    assert_eq!(v["lost"], 0, "{v:#}");
    assert_eq!(v["failed"], 0, "{v:#}");
    assert_eq!(v["reruns_unexplained"], 0, "{v:#}");
    assert_eq!(v["results_accepted_twice"], 0, "{v:#}");
    assert_eq!(v["late_results_accepted"], 0, "{v:#}");
    for kind in ["kills", "graceful", "stalls"] {
        assert!(v["events"][kind].as_u64().unwrap() >= 2, "{v:#}");
    }
    // Each kind of leave interrupted a running shard at least once, and each was run again.
    let explained = &v["reruns_explained"];
    assert!(explained["killed"].as_u64().unwrap() >= 1, "{v:#}");
    assert!(explained["expired"].as_u64().unwrap() >= 1, "{v:#}");
    // A killed worker's unacknowledged result may have arrived (then nothing runs again).
    let interrupted =
        |keys: &[&str]| -> u64 { keys.iter().map(|k| explained[k].as_u64().unwrap()).sum() };
    let reruns = v["reruns"].as_u64().unwrap();
    assert!(
        reruns >= interrupted(&["killed", "handed_back", "expired"])
            && reruns
                <= interrupted(&[
                    "killed",
                    "handed_back",
                    "expired",
                    "expired_while_running",
                    "killed_with_result_unacknowledged"
                ]),
        "{v:#}"
    );
    assert!(v["coordinator_cpu_s"].as_f64().unwrap() > 0.0, "{v:#}");
}

/// `assay status` where nothing listens (tonic's real connect error on loopback): the error names
/// the coordinator and the reason, each cause once (hyper's chain says "tcp connect error" twice).
#[test]
fn an_unreachable_coordinator_is_named_with_each_cause_once() {
    // A port nothing listens on: bound, then released.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr = format!("http://127.0.0.1:{port}");
    let out = assay(&["status", "--coordinator", &addr]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!("error: no coordinator at {addr}: ")),
        "{stderr}"
    );
    assert!(stderr.contains("refused"), "{stderr}");
    let error = stderr.lines().find(|l| l.starts_with("error: ")).unwrap();
    let causes: Vec<&str> = error.split(": ").collect();
    assert!(
        causes.windows(2).all(|w| w[0] != w[1]),
        "a cause said twice: {error}"
    );
}
