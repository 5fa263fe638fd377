//! Fault tolerance across "hosts": the coordinator in the root network namespace, every worker in
//! a namespace of its own, joined by veth pairs (`ip netns`). A 200-episode batch runs while
//! workers are killed with -9 and restarted, while the coordinator is killed with -9 and
//! restarted, while a worker is cut off the network and comes back, and while a worker's link is
//! slow. In every case the batch completes, every episode counts once, and the report's results
//! equal a clean run's.
//!
//! Needs root and iproute2; where namespaces cannot be created the tests say so and pass.

use std::process::Command;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::common::*;
use assay_proto::v1 as pb;
use assay_report::report::Report;

/// 4 tasks × 50 seeds.
const BATCH: &str = "tests/fixtures/small";
const SEEDS: u64 = 50;

/// The scenarios share the two cores: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Namespaces `{prefix}{k}`, each joined to the root namespace by a veth pair: the root side
/// `10.{net}.{k}.1/24`, the namespace side `10.{net}.{k}.2/24`. Removed on drop.
struct Hosts {
    prefix: String,
    net: u8,
    n: usize,
}

impl Hosts {
    fn new(tag: &str, net: u8, n: usize) -> Result<Self, String> {
        let prefix = format!("as{tag}{}", std::process::id() % 1000);
        let hosts = Hosts { prefix, net, n: 0 };
        let mut hosts = hosts;
        for k in 0..n {
            let (ns, host, peer) = hosts.names(k);
            let _ = ip(&["netns", "del", &ns]);
            ip(&["netns", "add", &ns])?;
            hosts.n = k + 1;
            ip(&["link", "add", &host, "type", "veth", "peer", "name", &peer])?;
            ip(&["link", "set", &peer, "netns", &ns])?;
            ip(&["addr", "add", &format!("10.{net}.{k}.1/24"), "dev", &host])?;
            ip(&["link", "set", &host, "up"])?;
            ip(&[
                "netns",
                "exec",
                &ns,
                "ip",
                "addr",
                "add",
                &format!("10.{net}.{k}.2/24"),
                "dev",
                &peer,
            ])?;
            ip(&["netns", "exec", &ns, "ip", "link", "set", &peer, "up"])?;
            ip(&["netns", "exec", &ns, "ip", "link", "set", "lo", "up"])?;
        }
        Ok(hosts)
    }

    /// (namespace, root-side link, namespace-side link) of host `k`.
    fn names(&self, k: usize) -> (String, String, String) {
        (
            format!("{}n{k}", self.prefix),
            format!("{}h{k}", self.prefix),
            format!("{}p{k}", self.prefix),
        )
    }

    /// The coordinator's address as host `k` reaches it.
    fn coordinator(&self, k: usize, port: u16) -> String {
        format!("http://10.{}.{k}.1:{port}", self.net)
    }

    /// `assay worker` on host `k` (sim role, capacity 1).
    fn worker(&self, dir: &std::path::Path, k: usize, port: u16, name: &str) -> Proc {
        let (ns, _, _) = self.names(k);
        let addr = self.coordinator(k, port);
        let bin = bin();
        Proc::spawn_cmd(
            name,
            "ip",
            &[
                "netns",
                "exec",
                &ns,
                bin.to_str().unwrap(),
                "worker",
                "--coordinator",
                &addr,
                "--roles",
                "sim",
                "--capacity",
                "1",
                "--worker-id",
                &format!("host-{k}/worker"),
                "--node-id",
                &format!("host-{k}"),
            ],
            dir,
        )
    }

    fn link(&self, k: usize, up: bool) {
        let (_, host, _) = self.names(k);
        ip(&["link", "set", &host, if up { "up" } else { "down" }]).unwrap();
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for k in 0..self.n {
            let (ns, host, _) = self.names(k);
            let _ = ip(&["link", "del", &host]);
            let _ = ip(&["netns", "del", &ns]);
        }
    }
}

/// The hosts, or `None` (with the reason printed) where namespaces cannot be made.
fn hosts(tag: &str, net: u8, n: usize) -> Option<Hosts> {
    match Hosts::new(tag, net, n) {
        Ok(h) => Some(h),
        Err(e) => {
            eprintln!(
                "SKIPPED: this machine cannot create network namespaces (needs root and iproute2): {e}"
            );
            None
        }
    }
}

/// A coordinator listening on every interface of the root namespace (the workers' "hosts"
/// reach it over their veth), telemetry off, short leases.
fn coordinator_on(dir: &std::path::Path, port: u16) -> (Proc, u16) {
    let listen = format!("0.0.0.0:{port}");
    let (p, addr) = coordinator(
        dir,
        &listen,
        &[
            "--telemetry",
            "off",
            "--heartbeat-ms",
            "300",
            "--lease-ttl-ms",
            "2500",
        ],
    );
    let port = addr.rsplit(':').next().unwrap().parse().unwrap();
    (p, port)
}

async fn submit_batch(port: u16) -> String {
    let sub = submit(&format!("http://127.0.0.1:{port}"), &[BATCH], SEEDS).await;
    assert!(sub.rejected.is_empty(), "{:?}", sub.rejected);
    assert_eq!(u64::from(sub.shards), 4 * SEEDS);
    sub.batch_id
}

async fn done(port: u16, batch: &str) -> u32 {
    let mut c = match pb::coordinator_client::CoordinatorClient::connect(format!(
        "http://127.0.0.1:{port}"
    ))
    .await
    {
        Ok(c) => c,
        Err(_) => return 0,
    };
    c.get_batch(pb::GetBatchRequest {
        batch_id: batch.into(),
    })
    .await
    .map(|s| s.into_inner().shards_done)
    .unwrap_or(0)
}

/// The batch's report once it completed (5 minutes at most).
async fn finished_report(port: u16, batch: &str) -> Report {
    let addr = format!("http://127.0.0.1:{port}");
    wait_for(&addr, batch, Duration::from_secs(300), finished).await;
    report(&addr, batch).await
}

/// The clean run's results, computed once.
fn clean_results() -> serde_json::Value {
    static CLEAN: std::sync::OnceLock<serde_json::Value> = std::sync::OnceLock::new();
    CLEAN
        .get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            let (_c, port) = coordinator_on(dir.path(), 0);
            let addr = format!("http://127.0.0.1:{port}");
            let _w: Vec<Proc> = (0..3).map(|i| worker(dir.path(), &addr, i, 1)).collect();
            runtime().block_on(async {
                let batch = submit_batch(port).await;
                let r = finished_report(port, &batch).await;
                assert_each_episode_once(&r, 4, SEEDS);
                serde_json::to_value(&r.results).unwrap()
            })
        })
        .clone()
}

/// The batch completed, every episode once, and the results are the clean run's.
fn check(r: &Report) {
    assert_each_episode_once(r, 4, SEEDS);
    assert_eq!(
        serde_json::to_value(&r.results).unwrap(),
        clean_results(),
        "the results differ from a clean run's"
    );
}

#[test]
fn workers_killed_with_sigkill_every_few_seconds_lose_nothing() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let clean = clean_results();
    let Some(h) = hosts("k", 211, 3) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (_c, port) = coordinator_on(dir.path(), 0);
    let mut workers: Vec<Proc> = (0..3)
        .map(|k| h.worker(dir.path(), k, port, &format!("worker-{k}")))
        .collect();
    let r = runtime().block_on(async {
        let batch = submit_batch(port).await;
        let mut kills = 0;
        let mut victim = 0usize;
        // Often enough that some kill finds a worker mid-episode: without pictures the batch
        // takes about 3 s.
        while done(port, &batch).await < (4 * SEEDS) as u32 * 9 / 10 {
            tokio::time::sleep(Duration::from_millis(500)).await;
            // kill -9 one worker, start a new process in its place.
            victim = (victim * 7 + 5) % 3;
            workers[victim].kill9();
            kills += 1;
            workers[victim] = h.worker(
                dir.path(),
                victim,
                port,
                &format!("worker-{victim}-{kills}"),
            );
        }
        let r = finished_report(port, &batch).await;
        eprintln!(
            "killed {kills} workers; extra attempts {}",
            r.run.extra_attempts
        );
        assert!(kills >= 2, "the batch finished before two kills");
        r
    });
    assert!(r.run.extra_attempts >= 1, "{:?}", r.run);
    check(&r);
    assert_eq!(serde_json::to_value(&r.results).unwrap(), clean);
}

#[test]
fn a_coordinator_killed_and_restarted_carries_on() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    clean_results();
    let Some(h) = hosts("c", 212, 2) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (mut c, port) = coordinator_on(dir.path(), 0);
    let _workers: Vec<Proc> = (0..2)
        .map(|k| h.worker(dir.path(), k, port, &format!("worker-{k}")))
        .collect();
    let r = runtime().block_on(async {
        let batch = submit_batch(port).await;
        let deadline = Instant::now() + Duration::from_secs(120);
        while done(port, &batch).await < 40 {
            assert!(Instant::now() < deadline);
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        c.kill9();
        tokio::time::sleep(Duration::from_secs(2)).await;
        // The same store, the same port: the workers reconnect with the leases they hold.
        let (c2, _) = coordinator_on(dir.path(), port);
        let r = finished_report(port, &batch).await;
        drop(c2);
        r
    });
    check(&r);
}

#[test]
fn a_worker_cut_off_the_network_loses_its_leases_and_its_late_results_do_not_count() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    clean_results();
    let Some(h) = hosts("p", 213, 2) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (_c, port) = coordinator_on(dir.path(), 0);
    let cut = h.worker(dir.path(), 0, port, "cut-worker");
    let _other = h.worker(dir.path(), 1, port, "other-worker");
    let r = runtime().block_on(async {
        let batch = submit_batch(port).await;
        let deadline = Instant::now() + Duration::from_secs(120);
        while done(port, &batch).await < 30 {
            assert!(Instant::now() < deadline);
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        // Cut host 0 off for longer than a lease lives: its lease expires and the shard runs on
        // host 1; when it comes back, the result it finished meanwhile is not counted.
        h.link(0, false);
        tokio::time::sleep(Duration::from_secs(8)).await;
        h.link(0, true);
        finished_report(port, &batch).await
    });
    assert!(
        r.run.extra_attempts >= 1,
        "no shard was run again: {:?}",
        r.run
    );
    check(&r);
    // Back on the network, what the worker finished for a lease that had moved on was refused:
    // the coordinator says so when the late result arrives, or the worker is told at its
    // reconnection which of its leases no longer count.
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(coordinator_log(dir.path()).contains("late result not counted")
        || cut.log_text().contains("no longer grants these leases"))
    {
        assert!(
            Instant::now() < deadline,
            "no late result was refused:\n{}",
            cut.log_text()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn coordinator_log(dir: &std::path::Path) -> String {
    std::fs::read_to_string(dir.join("coordinator.log")).unwrap_or_default()
}

#[test]
fn a_slow_worker_has_its_shards_run_elsewhere() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    clean_results();
    let Some(h) = hosts("s", 214, 2) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (_c, port) = coordinator_on(dir.path(), 0);
    let slow = h.worker(dir.path(), 0, port, "slow-worker");
    let _fast = h.worker(dir.path(), 1, port, "fast-worker");
    let pid = nix::unistd::Pid::from_raw(slow.child.id() as i32);
    let r = runtime().block_on(async {
        let batch = submit_batch(port).await;
        // A straggler: the worker on host 0 stalls for 4 s at a time (SIGSTOP, as an overloaded
        // node would), longer than a lease lives (2.5 s): its heartbeats stop, its lease
        // expires and the shard runs on host 1; when it wakes, its result for that lease is
        // refused.
        let mut stalls = 0;
        while done(port, &batch).await < (4 * SEEDS) as u32 * 9 / 10 {
            tokio::time::sleep(Duration::from_millis(700)).await;
            let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGSTOP);
            tokio::time::sleep(Duration::from_secs(4)).await;
            let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGCONT);
            stalls += 1;
        }
        eprintln!("the slow worker stalled {stalls} times");
        finished_report(port, &batch).await
    });
    assert!(
        r.run.extra_attempts >= 1,
        "no straggler was re-leased: {:?}",
        r.run
    );
    check(&r);
}
