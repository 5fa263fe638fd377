//! `assay bench coordinator` and `assay bench scaling`: the coordinator at scale. Two measurements, one JSON line:
//!
//! - `store`: the job store alone (the coordinator's single-threaded core): a batch of N shards
//!   planned, then leased in grants of `capacity` and completed one by one, as workers would, in
//!   one thread. Lease+complete throughput, and the store's file size.
//! - `grpc`: a real coordinator (`assay_coordinator::serve`, its gRPC services, store actor and
//!   lease sweeper) in this process, with W fake workers — real `WorkerSession` streams over
//!   loopback that answer every assignment at once with a valid episode outcome. Throughput
//!   from the first assignment to the last acknowledgement, the process's CPU time and its peak
//!   resident memory (coordinator and fake workers together: they share the process).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use assay_coordinator::store::{NewBatch, Store};
use assay_proto::v1 as pb;
use serde_json::json;
use tokio_stream::wrappers::ReceiverStream;

use super::cpu_s;

const SPEC: &str = include_str!("../../../../tests/fixtures/small/small-stack-two-blocks.yaml");

/// A line of /proc/self/status in MiB (`VmHWM`: peak resident, `VmRSS`: resident now).
fn status_mib(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// One valid episode outcome, sent for every shard.
pub(super) fn outcome_json() -> String {
    serde_json::to_string(&assay_model::episode::EpisodeOutcome {
        task_id: "small-stack-two-blocks".into(),
        seed: 0,
        policy: "oracle".into(),
        success: true,
        label_source: assay_model::episode::LabelSource::Sim,
        predicates: Vec::new(),
        steps: 1,
        sim_time_s: 0.01,
        artifact: "episodes/bench.arrow".into(),
        spec_hash: String::new(),
        versions: Default::default(),
        imagery: None,
        cutoff: None,
        generator_reward: None,
        scenes: None,
    })
    .expect("outcome serialises")
}

pub(super) fn docs() -> Vec<assay_plan::TaskDocument> {
    vec![assay_plan::TaskDocument {
        origin: "bench.yaml".into(),
        format: String::new(),
        content: SPEC.into(),
    }]
}

fn bench_batch(tasks: Vec<assay_plan::PlannedTask>, shards: u64) -> NewBatch {
    NewBatch {
        name: "bench".into(),
        tasks,
        policies: vec!["oracle".into()],
        seeds: (0..shards).collect(),
        max_attempts: 3,
        invalid: Vec::new(),
        role: "sim".into(),
        render: false,
        judges: Vec::new(),
        judge_repeats: 0,
        judge_budget_usd: None,
        content_hash: String::new(),
        text_models: Vec::new(),
        text_groups: Vec::new(),
        dynamics: None,
        ranking: None,
        generalization: None,
        share: Default::default(),
    }
}

fn store_bench(
    dir: &std::path::Path,
    shards: u64,
    capacity: u32,
) -> anyhow::Result<serde_json::Value> {
    let path = dir.join("store-bench.db");
    let mut store = Store::open(&path)?;
    let (tasks, invalid) = assay_plan::plan_tasks(&docs(), &[]);
    anyhow::ensure!(invalid.is_empty(), "the bench spec is invalid: {invalid:?}");
    let batch = bench_batch(tasks, shards);
    let t = Instant::now();
    store.submit(&batch, 0)?;
    let plan_s = t.elapsed().as_secs_f64();
    let outcome = outcome_json();
    let roles = vec!["sim".to_owned()];
    let (t, cpu) = (Instant::now(), cpu_s());
    let mut done = 0u64;
    let mut now = 1i64;
    loop {
        let leases = store.lease("bench/worker", &roles, capacity, now, 60_000)?;
        if leases.is_empty() {
            break;
        }
        for l in leases {
            let (ok, _) =
                store.complete("bench/worker", l.lease_id, l.shard_id, &outcome, 0.001, now)?;
            done += u64::from(ok);
        }
        now += 1;
    }
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_s() - cpu;
    anyhow::ensure!(
        done == shards,
        "the store completed {done} of {shards} shards"
    );
    let bytes = std::fs::metadata(&path).map_or(0, |m| m.len())
        + std::fs::metadata(path.with_extension("db-wal")).map_or(0, |m| m.len());
    Ok(json!({
        "shards": shards,
        "grant": capacity,
        "plan_s": plan_s,
        "lease_complete_s": wall,
        "shards_per_s": shards as f64 / wall,
        "cpu_s": cpu,
        "store_mib": bytes as f64 / 1048576.0,
    }))
}

/// The store behind its actor, as the coordinator's sessions use it: `clients` tasks each lease
/// `capacity` shards and complete them, concurrently, through one `StoreHandle`. Calls that wait
/// together are committed together (the actor's group commit), which the one-thread measurement
/// above cannot show.
async fn actor_bench(
    dir: &std::path::Path,
    shards: u64,
    clients: u32,
    capacity: u32,
) -> anyhow::Result<serde_json::Value> {
    let path = dir.join("actor-bench.db");
    let handle = assay_coordinator::actor::StoreHandle::spawn(&path)?;
    let (tasks, _) = assay_plan::plan_tasks(&docs(), &[]);
    let batch = bench_batch(tasks, shards);
    handle.call(move |s| s.submit(&batch, 0)).await?;
    let outcome: Arc<str> = outcome_json().into();
    let (t, cpu) = (Instant::now(), cpu_s());
    let mut joins = Vec::new();
    for i in 0..clients {
        let (handle, outcome) = (handle.clone(), outcome.clone());
        joins.push(tokio::spawn(async move {
            let worker = format!("bench/worker-{i}");
            let roles = vec!["sim".to_owned()];
            let mut done = 0u64;
            loop {
                let (w, r) = (worker.clone(), roles.clone());
                let leases = handle
                    .call(move |s| s.lease(&w, &r, capacity, 1, 60_000))
                    .await?;
                if leases.is_empty() {
                    return anyhow::Ok(done);
                }
                for l in leases {
                    let (w, o) = (worker.clone(), outcome.clone());
                    let (ok, _) = handle
                        .call(move |s| s.complete(&w, l.lease_id, l.shard_id, &o, 0.001, 1))
                        .await?;
                    done += u64::from(ok);
                }
            }
        }));
    }
    let mut done = 0;
    for j in joins {
        done += j.await??;
    }
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_s() - cpu;
    anyhow::ensure!(
        done == shards,
        "the store completed {done} of {shards} shards"
    );
    Ok(json!({
        "shards": shards,
        "clients": clients,
        "grant": capacity,
        "lease_complete_s": wall,
        "shards_per_s": shards as f64 / wall,
        "cpu_s": cpu,
    }))
}

/// What every fake worker of one run shares.
struct Run {
    outcome: Arc<str>,
    /// Results acknowledged as accepted, by all workers.
    acked: AtomicU64,
    /// When the first assignment arrived.
    first: std::sync::OnceLock<Instant>,
    /// Shards in the batch.
    total: u64,
    /// How long each fake episode takes.
    work: Duration,
}

async fn fake_worker(
    channel: tonic::transport::Channel,
    id: String,
    capacity: u32,
    run: Arc<Run>,
) -> anyhow::Result<()> {
    let Run {
        outcome,
        acked,
        first,
        total,
        work,
    } = &*run;
    let (total, work) = (*total, *work);
    let mut client = pb::worker_session_client::WorkerSessionClient::new(channel)
        .max_decoding_message_size(assay_proto::MAX_MESSAGE_BYTES);
    let (tx, rx) = tokio::sync::mpsc::channel::<pb::WorkerMessage>(64);
    use pb::worker_message::Msg as Out;
    tx.send(pb::WorkerMessage {
        msg: Some(Out::Register(pb::Register {
            worker_id: id,
            node_id: "bench".into(),
            roles: vec![pb::Role::Sim as i32],
            capacity,
            ..Default::default()
        })),
    })
    .await?;
    let mut inbound = client.session(ReceiverStream::new(rx)).await?.into_inner();
    use pb::coordinator_message::Msg as In;
    while let Some(m) = inbound.message().await? {
        match m.msg {
            Some(In::Assignment(a)) => {
                first.get_or_init(Instant::now);
                let result = pb::WorkerMessage {
                    msg: Some(Out::Result(pb::ShardResult {
                        lease_id: a.lease_id,
                        shard_id: a.shard_id,
                        outcome_json: outcome.to_string(),
                        wall_time_s: work.as_secs_f64(),
                    })),
                };
                if work.is_zero() {
                    tx.send(result).await?;
                } else {
                    // The episode "runs" for `work`, beside the worker's other slots.
                    let tx = tx.clone();
                    tokio::spawn(async move {
                        tokio::time::sleep(work).await;
                        let _ = tx.send(result).await;
                    });
                }
            }
            Some(In::Ack(ack))
                if ack.accepted && acked.fetch_add(1, Ordering::Relaxed) + 1 >= total =>
            {
                return Ok(());
            }
            _ => {}
        }
        if acked.load(Ordering::Relaxed) >= total {
            return Ok(());
        }
    }
    Ok(())
}

async fn grpc_bench(
    dir: &std::path::Path,
    workers: u32,
    shards: u64,
    capacity: u32,
    work: Duration,
) -> anyhow::Result<serde_json::Value> {
    let mut config =
        assay_coordinator::CoordinatorConfig::new(dir.join("grpc-bench.db"), dir.join("artifacts"));
    config.lease_ttl = Duration::from_secs(120);
    config.heartbeat_interval = Duration::from_secs(30);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let addr = format!("http://{}", listener.local_addr()?);
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(assay_coordinator::serve(
        config,
        listener,
        None,
        async move {
            let _ = stop_rx.await;
        },
    ));
    let rss_idle = status_mib("VmRSS");
    let mut c = crate::client::connect(&addr).await?;
    let t = Instant::now();
    let sub = c
        .submit_batch(pb::SubmitBatchRequest {
            name: "bench".into(),
            tasks: docs().into_iter().map(pb::TaskDocument::from).collect(),
            seeds: (0..shards).collect(),
            ..Default::default()
        })
        .await?
        .into_inner();
    let submit_s = t.elapsed().as_secs_f64();
    anyhow::ensure!(sub.shards as u64 == shards, "planned {} shards", sub.shards);
    let rss_planned = status_mib("VmRSS");
    let run = Arc::new(Run {
        outcome: outcome_json().into(),
        acked: AtomicU64::new(0),
        first: std::sync::OnceLock::new(),
        total: shards,
        work,
    });
    // Workers share a few HTTP/2 connections, as many sessions over each as a node would have.
    let mut channels = Vec::new();
    let options = assay_proto::channel::ChannelOptions::default();
    for _ in 0..workers.clamp(1, 16) {
        channels.push(assay_proto::channel::connect("coordinator", &addr, &options).await?);
    }
    let cpu = cpu_s();
    let mut tasks = Vec::new();
    for i in 0..workers {
        tasks.push(tokio::spawn(fake_worker(
            channels[i as usize % channels.len()].clone(),
            format!("bench/worker-{i}"),
            capacity,
            run.clone(),
        )));
    }
    let deadline = Instant::now() + Duration::from_secs(3600);
    while run.acked.load(Ordering::Relaxed) < shards {
        anyhow::ensure!(
            Instant::now() < deadline,
            "the benchmark did not finish in an hour"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let end = Instant::now();
    let cpu = cpu_s() - cpu;
    let wall = end
        .duration_since(*run.first.get().context("no assignment was made")?)
        .as_secs_f64();
    let st = c
        .get_batch(pb::GetBatchRequest {
            batch_id: sub.batch_id.clone(),
        })
        .await?
        .into_inner();
    let connected = st.workers_connected;
    for t in tasks {
        t.abort();
    }
    let _ = stop_tx.send(());
    let _ = server.await;
    anyhow::ensure!(
        st.shards_done as u64 == shards,
        "the coordinator counted {} of {shards} shards done",
        st.shards_done
    );
    Ok(json!({
        "workers": workers,
        "workers_connected_at_end": connected,
        "capacity_per_worker": capacity,
        "work_ms": work.as_secs_f64() * 1000.0,
        "shards": shards,
        "submit_and_plan_s": submit_s,
        "lease_complete_s": wall,
        "shards_per_s": shards as f64 / wall,
        "process_cpu_s": cpu,
        "rss_idle_mib": rss_idle,
        "rss_after_planning_mib": rss_planned,
        "peak_rss_mib": status_mib("VmHWM"),
    }))
}

/// Both measurements, as one JSON value; each part is also told to `progress` as it finishes.
pub fn run(
    workers: u32,
    shards: u64,
    capacity: u32,
    progress: &mut dyn FnMut(String),
) -> anyhow::Result<serde_json::Value> {
    let dir = std::env::temp_dir().join(format!("assay-bench-coordinator-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = (|| -> anyhow::Result<serde_json::Value> {
        let store = store_bench(&dir, shards, capacity.max(1))?;
        progress(format!("store: {store}"));
        let actor =
            crate::rt::block_on(actor_bench(&dir, shards, workers.max(1), capacity.max(1)))?;
        progress(format!("store actor: {actor}"));
        let grpc = crate::rt::block_on(grpc_bench(
            &dir,
            workers,
            shards,
            capacity.max(1),
            Duration::ZERO,
        ))?;
        progress(format!("grpc: {grpc}"));
        Ok(json!({
            "measure": "coordinator",
            "cpus": std::thread::available_parallelism().map_or(1, |n| n.get()),
            "store": store,
            "store_actor": actor,
            "grpc": grpc,
        }))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// `assay bench scaling`: does throughput follow the number of workers? Fake workers whose
/// episodes take `work` each (a sleep: they use no CPU) join a real coordinator in growing
/// numbers — 1, 4, 16, … up to `max_workers` — each run a batch sized for about two seconds of
/// ideal work. Ideal throughput is workers × capacity / work; the ratio of measured to ideal shows
/// where the coordinator stops keeping up.
pub fn scaling(
    max_workers: u32,
    max_shards: u64,
    capacity: u32,
    work: Duration,
    progress: &mut dyn FnMut(String),
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(!work.is_zero(), "--work-ms must be at least 1");
    let dir = std::env::temp_dir().join(format!("assay-bench-scaling-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let capacity = capacity.max(1);
    let mut counts: Vec<u32> = std::iter::successors(Some(1u32), |w| w.checked_mul(4))
        .take_while(|w| *w < max_workers)
        .collect();
    counts.push(max_workers.max(1));
    let result = (|| -> anyhow::Result<serde_json::Value> {
        let mut runs = Vec::new();
        for (i, &workers) in counts.iter().enumerate() {
            let ideal = f64::from(workers) * f64::from(capacity) / work.as_secs_f64();
            let shards = ((ideal * 2.0) as u64).clamp(200, max_shards.max(200));
            let run_dir = dir.join(format!("run-{i}"));
            std::fs::create_dir_all(&run_dir)?;
            let mut r = crate::rt::block_on(grpc_bench(&run_dir, workers, shards, capacity, work))?;
            let measured = r["shards_per_s"].as_f64().unwrap_or(0.0);
            r["ideal_shards_per_s"] = json!(ideal);
            r["of_ideal"] = json!(measured / ideal);
            progress(format!("scaling: {r}"));
            runs.push(r);
        }
        Ok(json!({
            "measure": "scaling",
            "cpus": std::thread::available_parallelism().map_or(1, |n| n.get()),
            "work_ms": work.as_secs_f64() * 1000.0,
            "capacity_per_worker": capacity,
            "runs": runs,
        }))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}
