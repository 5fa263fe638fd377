//! Policies other than the oracle through the real cluster: a TorchScript module on the worker
//! and the same module behind `assay policy serve` (the `assay.v1.Policy` gRPC service) act
//! through the same path and give the same episodes; killing the policy server mid-batch fails
//! its remaining episodes with a clear error and the batch still completes.
#![cfg(feature = "trainer")]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::torchscript::torchscript;
use crate::common::{bin, finish_eval, spawn_eval};

/// A pick-and-place task whose episodes end after 1440 physics steps (60 control steps), so a
/// policy that never finishes costs little (the oracle needs about 1100).
fn task() -> String {
    assay_testkit::tasks::put_block_in_zone_within(1440)
}

/// `assay policy serve` on a free port, its log in `dir`; returns the child and its URL.
fn serve(dir: &Path, policy: &str, delay_ms: u32) -> (Child, String) {
    serve_env(dir, policy, delay_ms, &[])
}

/// [`serve`] with extra environment variables.
fn serve_env(dir: &Path, policy: &str, delay_ms: u32, env: &[(&str, &str)]) -> (Child, String) {
    let log = std::fs::File::create(dir.join("policy-server.log")).unwrap();
    let mut child = Command::new(bin())
        .args([
            "policy",
            "serve",
            "--policy",
            policy,
            "--listen",
            "127.0.0.1:0",
        ])
        .args(["--delay-ms", &delay_ms.to_string()])
        .env("ASSAY_LOG", "debug")
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let url = first
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("first line of the server: {first:?}"))
        .to_owned();
    (child, url)
}

fn eval(dir: &Path, task: &Path, policies: &[&str], seeds: u32) -> Child {
    spawn_eval(dir, &[task.to_path_buf()], policies, seeds, &[])
}

fn task_file(dir: &Path) -> PathBuf {
    let path = dir.join("task.yaml");
    std::fs::write(&path, task()).unwrap();
    path
}

#[test]
fn a_torchscript_policy_and_the_same_module_served_remotely_act_alike() {
    let dir = tempfile::tempdir().unwrap();
    let module = torchscript(dir.path());
    let local = format!("torchscript:path={}", module.display());
    let (mut server, url) = serve(dir.path(), &local, 0);
    let remote = format!("remote:url={url},timeout_ms=5000");
    let task = task_file(dir.path());
    let report = finish_eval(
        eval(dir.path(), &task, &[&local, &remote, "oracle"], 2),
        Duration::from_secs(240),
        dir.path(),
    );
    let _ = server.kill();
    let _ = server.wait();
    let t = &report.results.tasks[0];
    assert!(t.failures.is_empty(), "{:#?}", t.failures);
    let of = |p: &str| -> Vec<_> { t.episodes.iter().filter(|e| e.policy == p).collect() };
    let (l, r) = (of(&local), of(&remote));
    assert_eq!((l.len(), r.len(), of("oracle").len()), (2, 2, 2));
    for (a, b) in l.iter().zip(&r) {
        // One module, one path: the same seed gives the same episode whichever way it is served.
        assert_eq!((a.seed, a.steps, a.success), (b.seed, b.steps, b.success));
        assert_eq!(a.unmet, b.unmet);
        // The controller holds the block but never carries it to the zone: every control step
        // until max_steps is run.
        assert!(!a.success);
        assert!(a.steps >= 1440, "{} steps", a.steps);
    }
    assert!(of("oracle").iter().all(|e| e.success));
}

#[test]
fn killing_the_policy_server_mid_batch_fails_its_episodes_not_the_batch() {
    let dir = tempfile::tempdir().unwrap();
    let module = torchscript(dir.path());
    let (mut server, url) = serve(
        dir.path(),
        &format!("torchscript:path={}", module.display()),
        20,
    );
    let remote = format!("remote:url={url},timeout_ms=1000");
    let task = task_file(dir.path());
    let running = eval(dir.path(), &task, &[&remote, "oracle"], 8);
    // Kill -9 the server once it has finished its first episode.
    let start = Instant::now();
    loop {
        let log = std::fs::read_to_string(dir.path().join("policy-server.log")).unwrap_or_default();
        if log.contains("episode ended") {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no episode ended:\n{log}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    server.kill().unwrap();
    server.wait().unwrap();
    let report = finish_eval(running, Duration::from_secs(240), dir.path());
    assert_eq!(report.run.state, "completed");
    let t = &report.results.tasks[0];
    let done = t.episodes.iter().filter(|e| e.policy == remote).count();
    let failed: Vec<_> = t.failures.iter().filter(|f| f.policy == remote).collect();
    assert!(done >= 1, "the episode before the kill is kept");
    assert!(!failed.is_empty(), "episodes after the kill fail");
    assert_eq!(done + failed.len(), 8);
    for f in &failed {
        assert!(
            f.error.contains("policy unavailable") && f.error.contains(&url),
            "{}",
            f.error
        );
    }
    // The oracle's episodes are untouched.
    assert_eq!(
        t.episodes.iter().filter(|e| e.policy == "oracle").count(),
        8
    );
}

/// `assay policy serve` in a cluster with a token answers only callers with the cluster's policy
/// token: `assay policy check` without the token is refused and told why, with it gets `Health`.
#[test]
fn a_policy_server_of_a_cluster_with_a_token_refuses_callers_without_it() {
    const TOKEN: &str = "policy-test-cluster-token-0123456789";
    let dir = tempfile::tempdir().unwrap();
    let module = torchscript(dir.path());
    let policy = format!("torchscript:path={}", module.display());
    let (mut server, url) = serve_env(dir.path(), &policy, 0, &[("ASSAY_CLUSTER_TOKEN", TOKEN)]);
    let check = |token: Option<&str>| {
        let mut cmd = Command::new(bin());
        cmd.args(["policy", "check", &url])
            .env_remove("ASSAY_CLUSTER_TOKEN");
        if let Some(t) = token {
            cmd.env("ASSAY_CLUSTER_TOKEN", t);
        }
        cmd.output().unwrap()
    };
    let refused = check(None);
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{text}");
    assert!(
        text.contains("Unauthenticated") && text.contains("cluster token"),
        "{text}"
    );
    let wrong = check(Some("another-cluster-token-0123456789"));
    assert!(!wrong.status.success());
    let ok = check(Some(TOKEN));
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let health: serde_json::Value = serde_json::from_slice(&ok.stdout).unwrap();
    assert_eq!(health["name"], policy.as_str());
    let _ = server.kill();
    let _ = server.wait();
    let log = std::fs::read_to_string(dir.path().join("policy-server.log")).unwrap();
    assert!(!log.contains(TOKEN), "the policy server logged the token");
}
