//! `assay bench churn`: a large batch while workers join and leave, every way a worker leaves.
//!
//! The coordinator is a child process (`assay coordinator` on loopback, its own store), so its
//! CPU time and memory are its own, read from `/proc/<pid>` apart from the fake workers' (this
//! process). W fake workers, each on its own connection as a worker process would be, hold one
//! shard at a time and "run" it for `work` (a sleep). Every `every`, one event, leaves and joins
//! in turn so the pool stays near W: a leave is, in rotation,
//!
//! - **kill**: the worker vanishes mid-shard, its connection dropped (what `kill -9` does to a
//!   process: the coordinator sees the session end and re-queues the lease at once);
//! - **graceful**: it hands its lease back (`ReturnLeases`, as SIGTERM does) and closes;
//! - **stall**: it stops answering with its connection open (a frozen host): its lease expires
//!   after the lease TTL, the shard runs elsewhere, and the stalled worker's late result, sent
//!   after three TTLs, must be refused.
//!
//! What it counts: **lost** shards (not done when the batch should be: must be 0), shards run
//! more than once, each re-run explained by what interrupted it (a worker killed mid-shard, or
//! killed with its result sent but not acknowledged — in a buffer when the process died —, a
//! lease handed back, a stalled worker's lease expired, a live worker's lease that expired
//! before its result came) or **unexplained** (must be 0), results accepted twice for one shard
//! (must be 0), late results refused, throughput, and the coordinator's CPU per 1,000 shards.
//! Fake workers heartbeat their shard at the interval the coordinator asks, as workers do.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use assay_proto::v1 as pb;
use pb::coordinator_message::Msg as In;
use pb::worker_message::Msg as Out;
use serde_json::json;
use tokio_stream::wrappers::ReceiverStream;

use super::cpu_s;

/// What the churn benchmark is asked to do.
#[derive(Debug, Clone)]
pub struct Churn {
    /// The `assay` binary, started as the coordinator.
    pub exe: PathBuf,
    pub workers: u32,
    pub shards: u64,
    /// Time between two events (a join or a leave).
    pub every: Duration,
    /// How long each fake episode takes.
    pub work: Duration,
    /// The coordinator's lease TTL: how long a stalled worker's shard waits.
    pub lease_ttl: Duration,
}

/// How a worker leaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Leave {
    Kill,
    Graceful,
    Stall,
}

/// Counts every fake worker adds to.
#[derive(Default)]
struct Tally {
    /// Times each shard was assigned to a worker that read the assignment.
    runs: Mutex<HashMap<u64, u32>>,
    /// Shards whose run a leave interrupted, by how it left.
    interrupted: Mutex<HashMap<u64, u32>>,
    killed: AtomicU64,
    /// Results a killed worker had sent and not seen acknowledged: lost with it or not.
    killed_unacknowledged: AtomicU64,
    handed_back: AtomicU64,
    /// Stalled workers' shards (their leases expire).
    expired: AtomicU64,
    /// Results of live workers refused because their lease had expired.
    refused: AtomicU64,
    /// Every lease a worker read: its shard.
    leases: Mutex<HashMap<u64, u64>>,
    /// Results the coordinator accepted, per shard.
    accepted: Mutex<HashMap<u64, u32>>,
    late_refused: AtomicU64,
    late_accepted: AtomicU64,
    first: std::sync::OnceLock<Instant>,
}

impl Tally {
    fn accepted(&self, lease_id: u64) {
        let shard = self.leases.lock().expect("tally").get(&lease_id).copied();
        let shard = shard.unwrap_or(u64::MAX);
        *self
            .accepted
            .lock()
            .expect("tally")
            .entry(shard)
            .or_default() += 1;
    }

    /// A live worker's result refused: its lease had expired and the shard was queued again.
    fn refused(&self, shard: u64) {
        *self
            .interrupted
            .lock()
            .expect("tally")
            .entry(shard)
            .or_default() += 1;
        self.refused.fetch_add(1, Ordering::Relaxed);
    }

    /// A killed worker's result, sent but not acknowledged: the coordinator may never have
    /// read it (a process killed with its result in a buffer), and then runs the shard again.
    fn unacknowledged(&self, shard: u64) {
        *self
            .interrupted
            .lock()
            .expect("tally")
            .entry(shard)
            .or_default() += 1;
        self.killed_unacknowledged.fetch_add(1, Ordering::Relaxed);
    }

    fn interrupted(&self, shard: u64, how: Leave) {
        *self
            .interrupted
            .lock()
            .expect("tally")
            .entry(shard)
            .or_default() += 1;
        match how {
            Leave::Kill => &self.killed,
            Leave::Graceful => &self.handed_back,
            Leave::Stall => &self.expired,
        }
        .fetch_add(1, Ordering::Relaxed);
    }
}

/// One fake worker: registers, runs one shard at a time, and leaves when told how.
async fn worker(
    addr: String,
    id: String,
    work: Duration,
    stall_for: Duration,
    outcome: Arc<str>,
    tally: Arc<Tally>,
    mut leave: tokio::sync::oneshot::Receiver<Leave>,
) -> anyhow::Result<()> {
    let options = assay_proto::channel::ChannelOptions::default();
    let channel = assay_proto::channel::connect("coordinator", &addr, &options).await?;
    let mut client = pb::worker_session_client::WorkerSessionClient::new(channel)
        .max_decoding_message_size(assay_proto::MAX_MESSAGE_BYTES);
    let (tx, rx) = tokio::sync::mpsc::channel::<pb::WorkerMessage>(16);
    tx.send(pb::WorkerMessage {
        msg: Some(Out::Register(pb::Register {
            worker_id: id,
            node_id: "churn".into(),
            roles: vec![pb::Role::Sim as i32],
            capacity: 1,
            ..Default::default()
        })),
    })
    .await?;
    let mut inbound = client.session(ReceiverStream::new(rx)).await?.into_inner();
    // The shard it runs, and when it is done; its results not yet acknowledged (lease → shard).
    let mut running: Option<(pb::Assignment, tokio::time::Instant)> = None;
    let mut unacknowledged: HashMap<u64, u64> = HashMap::new();
    // Heartbeats for the shard it runs, at the interval the coordinator asks (on registering).
    let mut heartbeat = tokio::time::interval(Duration::from_secs(3600));
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let done_at = running.as_ref().map(|(_, at)| *at);
        tokio::select! {
            how = &mut leave => {
                let how = how.unwrap_or(Leave::Kill);
                if let Some((a, _)) = &running {
                    tally.interrupted(a.shard_id, how);
                }
                match how {
                    Leave::Kill => {
                        for shard in unacknowledged.values() {
                            tally.unacknowledged(*shard);
                        }
                        return Ok(());
                    }
                    Leave::Graceful => {
                        if let Some((a, _)) = &running {
                            tx.send(pb::WorkerMessage {
                                msg: Some(Out::ReturnLeases(pb::ReturnLeases {
                                    lease_ids: vec![a.lease_id],
                                    reason: "leaving (churn)".into(),
                                })),
                            })
                            .await?;
                        }
                        // As a worker stopped with SIGTERM: its results acknowledged before it
                        // goes (what is assigned to it meanwhile it never runs).
                        let wait = tokio::time::timeout(Duration::from_secs(10), async {
                            while !unacknowledged.is_empty() {
                                let Ok(Some(m)) = inbound.message().await else { break };
                                if let Some(In::Ack(ack)) = m.msg {
                                    unacknowledged.remove(&ack.lease_id);
                                    if ack.accepted {
                                        tally.accepted(ack.lease_id);
                                    }
                                }
                            }
                        });
                        let _ = wait.await;
                        for shard in unacknowledged.values() {
                            tally.interrupted(*shard, Leave::Graceful);
                        }
                        return Ok(());
                    }
                    Leave::Stall => {
                        tokio::time::sleep(stall_for).await;
                        let Some((a, _)) = running else { return Ok(()) };
                        tx.send(result(&a, &outcome, work)).await?;
                        // Its answer: the late result's acknowledgement (what was assigned to
                        // it meanwhile it never runs).
                        while let Some(m) = inbound.message().await? {
                            if let Some(In::Ack(ack)) = m.msg && ack.lease_id == a.lease_id {
                                if ack.accepted {
                                    tally.late_accepted.fetch_add(1, Ordering::Relaxed);
                                    tally.accepted(a.lease_id);
                                } else {
                                    tally.late_refused.fetch_add(1, Ordering::Relaxed);
                                }
                                break;
                            }
                        }
                        return Ok(());
                    }
                }
            }
            _ = tokio::time::sleep_until(done_at.unwrap_or_else(tokio::time::Instant::now)), if done_at.is_some() => {
                let (a, _) = running.take().expect("a shard runs");
                unacknowledged.insert(a.lease_id, a.shard_id);
                tx.send(result(&a, &outcome, work)).await?;
            }
            _ = heartbeat.tick() => {
                if let Some((a, _)) = &running {
                    tx.send(pb::WorkerMessage {
                        msg: Some(Out::Heartbeat(pb::Heartbeat {
                            lease_ids: vec![a.lease_id],
                        })),
                    })
                    .await?;
                }
            }
            m = inbound.message() => {
                let Some(m) = m? else { return Ok(()) };
                match m.msg {
                    Some(In::Assignment(a)) => {
                        tally.first.get_or_init(Instant::now);
                        *tally.runs.lock().expect("tally").entry(a.shard_id).or_default() += 1;
                        tally.leases.lock().expect("tally").insert(a.lease_id, a.shard_id);
                        running = Some((a, tokio::time::Instant::now() + work));
                    }
                    Some(In::Registered(r)) => {
                        let every = Duration::from_millis(u64::from(r.heartbeat_interval_ms).max(1));
                        heartbeat = tokio::time::interval(every);
                        heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                    }
                    Some(In::Ack(ack)) => {
                        let shard = unacknowledged.remove(&ack.lease_id);
                        if ack.accepted {
                            tally.accepted(ack.lease_id);
                        } else if let Some(shard) = shard {
                            // Its lease ended before its result came (a slow worker missed its
                            // heartbeats): the shard ran elsewhere too.
                            tally.refused(shard);
                        }
                    }
                    Some(In::Goodbye(_)) => return Ok(()),
                    _ => {}
                }
            }
        }
    }
}

fn result(a: &pb::Assignment, outcome: &str, work: Duration) -> pb::WorkerMessage {
    pb::WorkerMessage {
        msg: Some(Out::Result(pb::ShardResult {
            lease_id: a.lease_id,
            shard_id: a.shard_id,
            outcome_json: outcome.to_owned(),
            wall_time_s: work.as_secs_f64(),
        })),
    }
}

/// The coordinator, a child process on loopback; killed when dropped.
struct Coordinator {
    child: std::process::Child,
    addr: String,
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Coordinator {
    fn start(exe: &Path, dir: &Path, ttl: Duration) -> anyhow::Result<Self> {
        let addr_file = dir.join("coordinator.addr");
        let ttl_ms = ttl.as_millis().max(1);
        let mut cmd = std::process::Command::new(exe);
        cmd.arg("coordinator")
            .args(["--listen", "127.0.0.1:0", "--telemetry", "off"])
            .arg("--store")
            .arg(dir.join("churn.db"))
            .arg("--artifacts")
            .arg(dir.join("artifacts"))
            .arg("--addr-file")
            .arg(&addr_file)
            .args(["--lease-ttl-ms", &ttl_ms.to_string()])
            .args(["--heartbeat-ms", &(ttl_ms / 4).max(1).to_string()])
            .args(["--max-attempts", "1000"])
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(dir.join("coordinator.log"))?);
        // Nothing of this shell's cluster (a token, another store) reaches it: it is the
        // benchmark's own, open on loopback.
        for (key, _) in std::env::vars_os() {
            if key.to_string_lossy().starts_with("ASSAY_") {
                cmd.env_remove(key);
            }
        }
        let child = cmd
            .spawn()
            .with_context(|| format!("starting {} coordinator", exe.display()))?;
        let mut c = Coordinator {
            child,
            addr: String::new(),
        };
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Ok(s) = std::fs::read_to_string(&addr_file)
                && s.ends_with('\n')
            {
                c.addr = format!("http://{}", s.lines().next().unwrap_or_default().trim());
                return Ok(c);
            }
            if let Some(st) = c.child.try_wait()? {
                anyhow::bail!(
                    "the coordinator exited ({st}): {}",
                    std::fs::read_to_string(dir.join("coordinator.log")).unwrap_or_default()
                );
            }
            anyhow::ensure!(Instant::now() < deadline, "the coordinator did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Its CPU time so far (user + system), in seconds.
    fn cpu_s(&self) -> f64 {
        let stat =
            std::fs::read_to_string(format!("/proc/{}/stat", self.child.id())).unwrap_or_default();
        // Fields after the command name (which may hold spaces, inside parentheses).
        let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
        let f: Vec<f64> = rest
            .split_whitespace()
            .map(|x| x.parse().unwrap_or(0.0))
            .collect();
        // USER_HZ: 100 on every Linux the kernel ABI allows (`sysconf(_SC_CLK_TCK)`).
        let tick = 100.0;
        // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
        (f.get(11).copied().unwrap_or(0.0) + f.get(12).copied().unwrap_or(0.0)) / tick
    }

    fn peak_rss_mib(&self) -> f64 {
        std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("VmHWM"))
                    .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
            })
            .map_or(f64::NAN, |kb| kb / 1024.0)
    }
}

/// A fake worker in the pool: how to make it leave, and its task.
struct Member {
    leave: tokio::sync::oneshot::Sender<Leave>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
}

/// Runs the benchmark; one JSON value.
pub fn run(c: &Churn, progress: &mut dyn FnMut(String)) -> anyhow::Result<serde_json::Value> {
    let dir = std::env::temp_dir().join(format!("assay-bench-churn-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    // A connection per fake worker on each side: both processes need the file descriptors.
    let limit = std::fs::read_to_string("/proc/self/limits")
        .ok()
        .and_then(|l| {
            l.lines()
                .find(|l| l.starts_with("Max open files"))
                .and_then(|l| l.split_whitespace().nth(3)?.parse::<u64>().ok())
        })
        .unwrap_or(u64::MAX);
    anyhow::ensure!(
        limit >= u64::from(c.workers) * 2 + 256,
        "{} fake workers need {} open files; the limit is {limit} (raise it with `ulimit -n`)",
        c.workers,
        u64::from(c.workers) * 2 + 256
    );
    let result = (|| {
        let coordinator = Coordinator::start(&c.exe, &dir, c.lease_ttl)?;
        crate::rt::block_on(drive(c, &coordinator, progress))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

async fn drive(
    c: &Churn,
    coordinator: &Coordinator,
    progress: &mut dyn FnMut(String),
) -> anyhow::Result<serde_json::Value> {
    let addr = coordinator.addr.clone();
    let mut client = crate::client::connect(&addr).await?;
    let t = Instant::now();
    let sub = client
        .submit_batch(pb::SubmitBatchRequest {
            name: "churn".into(),
            tasks: super::coordinator::docs()
                .into_iter()
                .map(pb::TaskDocument::from)
                .collect(),
            seeds: (0..c.shards).collect(),
            ..Default::default()
        })
        .await?
        .into_inner();
    let submit_s = t.elapsed().as_secs_f64();
    anyhow::ensure!(
        sub.shards as u64 == c.shards,
        "planned {} shards",
        sub.shards
    );
    let tally = Arc::new(Tally::default());
    let outcome: Arc<str> = super::coordinator::outcome_json().into();
    let stall_for = c.lease_ttl * 3;
    let mut next_id = 0u64;
    let mut join = |pool: &mut Vec<Member>| {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let task = tokio::spawn(worker(
            addr.clone(),
            format!("churn/worker-{next_id}"),
            c.work,
            stall_for,
            outcome.clone(),
            tally.clone(),
            rx,
        ));
        next_id += 1;
        pool.push(Member { leave: tx, task });
    };
    let mut pool = Vec::new();
    for _ in 0..c.workers {
        join(&mut pool);
    }
    let (cpu0, own0) = (coordinator.cpu_s(), cpu_s());
    let mut left: Vec<tokio::task::JoinHandle<anyhow::Result<()>>> = Vec::new();
    let (mut joins, mut leaves) = (0u64, [0u64; 3]);
    let kinds = [Leave::Kill, Leave::Graceful, Leave::Stall];
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    let mut ticker = tokio::time::interval(c.every);
    ticker.tick().await;
    let deadline = Instant::now() + Duration::from_secs(600);
    let mut event = 0u64;
    let status = loop {
        ticker.tick().await;
        let st = client
            .get_batch(pb::GetBatchRequest {
                batch_id: sub.batch_id.clone(),
            })
            .await?
            .into_inner();
        if st.state != pb::BatchState::Running as i32 || Instant::now() > deadline {
            break st;
        }
        if event.is_multiple_of(2) && !pool.is_empty() {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let m = pool.swap_remove((rng % pool.len() as u64) as usize);
            let k = (event / 2 % 3) as usize;
            let _ = m.leave.send(kinds[k]);
            leaves[k] += 1;
            left.push(m.task);
        } else {
            join(&mut pool);
            joins += 1;
        }
        event += 1;
        if event.is_multiple_of(50) {
            progress(format!(
                "churn: {} of {} done, {} workers, {joins} joins, {} leaves",
                st.shards_done,
                c.shards,
                pool.len(),
                leaves.iter().sum::<u64>()
            ));
        }
    };
    let end = Instant::now();
    let (coordinator_cpu, own_cpu) = (coordinator.cpu_s() - cpu0, cpu_s() - own0);
    // The stalled workers send their late results, then the rest are let go.
    let late_deadline = Instant::now() + stall_for + Duration::from_secs(30);
    for t in left {
        let wait = late_deadline.saturating_duration_since(Instant::now());
        let _ = tokio::time::timeout(wait, t).await;
    }
    for m in pool {
        m.task.abort();
    }
    let wall = end
        .duration_since(*tally.first.get().context("no assignment was made")?)
        .as_secs_f64();
    let runs = tally.runs.lock().expect("tally").clone();
    let interrupted = tally.interrupted.lock().expect("tally").clone();
    let accepted = tally.accepted.lock().expect("tally").clone();
    let reruns: u64 = runs.values().map(|&n| u64::from(n.saturating_sub(1))).sum();
    let unexplained: u64 = runs
        .iter()
        .map(|(s, &n)| {
            let explained = interrupted.get(s).copied().unwrap_or(0);
            u64::from(n.saturating_sub(1).saturating_sub(explained))
        })
        .sum();
    let accepted_twice: u64 = accepted
        .values()
        .map(|&n| u64::from(n.saturating_sub(1)))
        .sum();
    let lost = c.shards.saturating_sub(u64::from(status.shards_done));
    Ok(json!({
        "measure": "churn",
        "cpus": std::thread::available_parallelism().map_or(1, |n| n.get()),
        "workers": c.workers,
        "shards": c.shards,
        "event_every_ms": c.every.as_secs_f64() * 1000.0,
        "work_ms": c.work.as_secs_f64() * 1000.0,
        "lease_ttl_ms": c.lease_ttl.as_secs_f64() * 1000.0,
        "submit_and_plan_s": submit_s,
        "events": {"joins": joins, "kills": leaves[0], "graceful": leaves[1], "stalls": leaves[2]},
        "batch_state": pb::BatchState::try_from(status.state)
            .map_or("unknown", |s| s.as_str_name()),
        "lost": lost,
        "failed": status.shards_failed,
        "runs": runs.values().map(|&n| u64::from(n)).sum::<u64>(),
        "reruns": reruns,
        "reruns_explained": {
            "killed": tally.killed.load(Ordering::Relaxed),
            "killed_with_result_unacknowledged": tally.killed_unacknowledged.load(Ordering::Relaxed),
            "handed_back": tally.handed_back.load(Ordering::Relaxed),
            "expired": tally.expired.load(Ordering::Relaxed),
            "expired_while_running": tally.refused.load(Ordering::Relaxed),
        },
        "reruns_unexplained": unexplained,
        "results_accepted_twice": accepted_twice,
        "late_results_refused": tally.late_refused.load(Ordering::Relaxed),
        "late_results_accepted": tally.late_accepted.load(Ordering::Relaxed),
        "wall_s": wall,
        "shards_per_s": f64::from(status.shards_done) / wall,
        "coordinator_cpu_s": coordinator_cpu,
        "coordinator_cpu_ms_per_1000_shards": coordinator_cpu * 1000.0 / c.shards as f64 * 1000.0,
        "coordinator_peak_rss_mib": coordinator.peak_rss_mib(),
        "fake_workers_cpu_s": own_cpu,
    }))
}
