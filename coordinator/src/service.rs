//! The two gRPC services: `Coordinator` for clients and `WorkerSession` for workers.

use std::collections::BTreeSet;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use assay_plan::settings::{BatchSettings, Settings, check, check_groups, check_seeds};
use assay_plan::{TaskDocument, plan_tasks};
use assay_proto::v1 as pb;
use tokio::sync::{Notify, broadcast, mpsc, watch};
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use tracing::{debug, info, warn};

use crate::actor::StoreHandle;
use crate::config::CoordinatorConfig;
use crate::error::CoordError;
use crate::store::{BatchCounts, Changed, NewBatch, Priority, Share, batch_state};

pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// State shared by every request handler.
pub struct Shared {
    pub store: StoreHandle,
    pub config: CoordinatorConfig,
    /// Woken when shards enter the queue.
    pub work: Notify,
    /// Ids of batches whose counts changed.
    pub events: broadcast::Sender<String>,
    pub workers_connected: AtomicU32,
    /// What each connected worker can do.
    pub capabilities: crate::capability::Registry,
    pub shutdown: watch::Receiver<bool>,
}

impl Shared {
    pub fn publish(&self, changed: &Changed) {
        for b in &changed.batches {
            let _ = self.events.send(b.clone());
        }
        if changed.requeued > 0 {
            self.work.notify_waiters();
        }
    }

    fn ttl_ms(&self) -> i64 {
        self.config.lease_ttl.as_millis() as i64
    }
}

/// Judge names are keys of the judge workers' configuration.
fn valid_judge_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

fn counts_to_pb(c: &BatchCounts, workers: u32) -> pb::BatchStatus {
    let state = match c.state.as_str() {
        batch_state::RUNNING => pb::BatchState::Running,
        batch_state::COMPLETED => pb::BatchState::Completed,
        batch_state::CANCELLED => pb::BatchState::Cancelled,
        batch_state::SKIPPED => pb::BatchState::Skipped,
        _ => pb::BatchState::Unspecified,
    };
    pb::BatchStatus {
        batch_id: c.id.clone(),
        name: c.name.clone(),
        state: state as i32,
        shards_total: c.total,
        shards_queued: c.queued,
        shards_running: c.leased,
        shards_done: c.done,
        shards_failed: c.failed,
        shards_cancelled: c.cancelled,
        successes: c.successes,
        invalid_tasks: c.invalid_tasks,
        submitted_at_unix_ms: c.submitted_ms,
        finished_at_unix_ms: c.finished_ms.unwrap_or(0),
        workers_connected: workers,
        judge_total: c.judge_total,
        judge_done: c.judge_done,
        judge_failed: c.judge_failed,
        judge_cost_usd: c.judge_cost_usd,
        trainer_total: c.trainer_total,
        trainer_done: c.trainer_done,
        trainer_failed: c.trainer_failed,
        content_hash: c.content_hash.clone(),
        duplicate_of: c.duplicate_of.clone().unwrap_or_default(),
        waiting: Vec::new(),
        priority: c.share.share.priority.to_string(),
        submitter: c.share.share.submitter.clone(),
        max_workers: c.share.share.max_workers,
        workers_holding: c.share.workers,
        fair_share: c.share.fair_share,
        holds: c.share.holds,
    }
}

/// How a submitted batch asks to share the cluster: a known priority (empty: normal), a
/// submitter name of printable characters.
fn share_of(req: &pb::SubmitBatchRequest) -> Result<Share, Status> {
    let priority = if req.priority.is_empty() {
        Priority::default()
    } else {
        req.priority
            .parse()
            .map_err(|e| Status::invalid_argument(format!("priority: {e}")))?
    };
    let submitter = req.submitter.trim();
    if submitter.len() > 128 || submitter.chars().any(char::is_control) {
        return Err(Status::invalid_argument(
            "submitter: expected at most 128 printable characters",
        ));
    }
    Ok(Share {
        priority,
        submitter: submitter.to_owned(),
        max_workers: req.max_workers,
    })
}

pub struct CoordinatorService {
    pub shared: Arc<Shared>,
}

type StatusStream = Pin<Box<dyn Stream<Item = Result<pb::BatchStatus, Status>> + Send>>;
type SessionStream = Pin<Box<dyn Stream<Item = Result<pb::CoordinatorMessage, Status>> + Send>>;

impl CoordinatorService {
    /// Checks a batch's request, plans it into shards and stores it (`SubmitBatch`, and
    /// `SubmitBatchStream` once its stream is read).
    async fn submit(&self, req: pb::SubmitBatchRequest) -> Result<pb::SubmitBatchResponse, Status> {
        if req.tasks.is_empty() {
            return Err(Status::invalid_argument("the batch has no task documents"));
        }
        if req.seeds.is_empty() {
            return Err(Status::invalid_argument("the batch has no seeds"));
        }
        let mut seeds = req.seeds.clone();
        seeds.sort_unstable();
        seeds.dedup();
        let settings = check(&BatchSettings::from(&req)).map_err(CoordError::from)?;
        check_seeds(&settings, &seeds).map_err(CoordError::from)?;
        let roots: Vec<std::path::PathBuf> = req
            .asset_roots
            .iter()
            .map(|r| {
                let p = std::path::PathBuf::from(r);
                p.canonicalize().unwrap_or(p)
            })
            .collect();
        let docs: Vec<TaskDocument> = req.tasks.iter().map(TaskDocument::from).collect();
        let (tasks, invalid) = plan_tasks(&docs, &roots);
        assay_plan::interfaces::check_interfaces(&settings.policies, &tasks)
            .map_err(CoordError::from)?;
        let groups: Vec<&str> = tasks.iter().map(|t| t.info.group.as_str()).collect();
        check_groups(&settings, &groups).map_err(CoordError::from)?;
        let mut judges = req.judges.clone();
        judges.sort();
        judges.dedup();
        if let Some(bad) = judges.iter().find(|j| !valid_judge_name(j)) {
            return Err(Status::invalid_argument(format!(
                "judge name {bad:?}: expected letters, digits, '-', '_' or '.'"
            )));
        }
        if !(req.judge_budget_usd >= 0.0 && req.judge_budget_usd.is_finite()) {
            return Err(Status::invalid_argument(format!(
                "judge budget {}: expected a non-negative number of USD",
                req.judge_budget_usd
            )));
        }
        let share = share_of(&req)?;
        let mut text_models: Vec<String> = Vec::new();
        for m in &req.text_models {
            if !text_models.contains(m) {
                text_models.push(m.clone());
            }
        }
        if let Some(bad) = text_models.iter().find(|m| !valid_judge_name(m)) {
            return Err(Status::invalid_argument(format!(
                "embedding model name {bad:?}: expected letters, digits, '-', '_' or '.'"
            )));
        }
        let text_groups = assay_plan::texts::text_groups(&tasks, &req.text_templates)
            .map_err(CoordError::from)?;
        let Settings {
            policies,
            dynamics,
            ranking,
            generalization,
        } = settings;
        let content_hash = assay_plan::hash::content_hash(&docs, &tasks, &invalid);
        let batch = NewBatch {
            name: if req.name.is_empty() {
                "batch".into()
            } else {
                req.name.clone()
            },
            tasks,
            policies,
            seeds,
            max_attempts: if req.max_attempts == 0 {
                self.shared.config.max_attempts
            } else {
                req.max_attempts
            },
            invalid: invalid.clone(),
            role: pb::Role::Sim.name().into(),
            // Judges look at pictures, and clips are pictures: either makes the batch render.
            render: req.render
                || !judges.is_empty()
                || dynamics.is_some()
                || ranking.is_some()
                || generalization.is_some(),
            judges,
            judge_repeats: req.judge_repeats,
            judge_budget_usd: (req.judge_budget_usd > 0.0).then_some(req.judge_budget_usd),
            content_hash,
            text_models,
            text_groups,
            dynamics,
            ranking,
            generalization,
            share,
        };
        let accepted = batch.tasks.len() as u32;
        let now = now_ms();
        let content_hash = batch.content_hash.clone();
        let skip = req.skip_if_evaluated;
        let (batch_id, shards, duplicate_of) = self
            .shared
            .store
            .call(move |s| {
                if skip && let Some(earlier) = s.evaluated_with(&batch.content_hash)? {
                    let id = s.record_skipped(&batch, &earlier, now)?;
                    return Ok((id, 0, earlier));
                }
                let (id, n) = s.submit(&batch, now)?;
                if n == 0 {
                    s.finish_if_empty(&id, now)?;
                }
                Ok((id, n, String::new()))
            })
            .await?;
        if !duplicate_of.is_empty() {
            info!(batch = %batch_id, %duplicate_of, %content_hash, "batch skipped: the same tasks were evaluated before");
            let _ = self.shared.events.send(batch_id.clone());
            return Ok(pb::SubmitBatchResponse {
                batch_id,
                accepted_tasks: accepted,
                shards: 0,
                rejected: invalid.iter().map(pb::SpecError::from).collect(),
                content_hash,
                duplicate_of,
            });
        }
        info!(batch = %batch_id, accepted, rejected = invalid.len(), shards, "batch submitted");
        for e in &invalid {
            warn!(batch = %batch_id, "{e}");
        }
        self.shared.work.notify_waiters();
        let _ = self.shared.events.send(batch_id.clone());
        Ok(pb::SubmitBatchResponse {
            batch_id,
            accepted_tasks: accepted,
            shards,
            rejected: invalid.iter().map(pb::SpecError::from).collect(),
            content_hash,
            duplicate_of: String::new(),
        })
    }

    async fn status(&self, id: String) -> Result<pb::BatchStatus, Status> {
        let (c, queued) = self
            .shared
            .store
            .call(move |s| Ok((s.counts(&id)?, s.queued_needs(Some(&id))?)))
            .await?;
        let mut status = counts_to_pb(&c, self.shared.workers_connected.load(Ordering::Relaxed));
        status.waiting = crate::capability::waiting(&queued, &self.shared.capabilities.offered());
        Ok(status)
    }
}

#[tonic::async_trait]
impl pb::coordinator_server::Coordinator for CoordinatorService {
    async fn submit_batch(
        &self,
        req: Request<pb::SubmitBatchRequest>,
    ) -> Result<Response<pb::SubmitBatchResponse>, Status> {
        self.submit(req.into_inner()).await.map(Response::new)
    }

    async fn submit_batch_stream(
        &self,
        req: Request<tonic::Streaming<pb::SubmitBatchRequest>>,
    ) -> Result<Response<pb::SubmitBatchResponse>, Status> {
        use prost::Message;
        let mut stream = req.into_inner();
        let mut batch = stream
            .message()
            .await?
            .ok_or_else(|| Status::invalid_argument("the stream carried no request"))?;
        let mut bytes = batch.encoded_len();
        let mut n = 1;
        while let Some(mut more) = stream.message().await? {
            n += 1;
            bytes += more.encoded_len();
            if bytes > assay_proto::MAX_BATCH_BYTES {
                return Err(Status::resource_exhausted(format!(
                    "the batch is larger than {} MiB (message {n} of the stream)",
                    assay_proto::MAX_BATCH_BYTES >> 20
                )));
            }
            let tasks = std::mem::take(&mut more.tasks);
            if more != pb::SubmitBatchRequest::default() {
                return Err(Status::invalid_argument(format!(
                    "message {n} of the stream carries more than task documents (only the first \
                     carries the batch's settings)"
                )));
            }
            batch.tasks.extend(tasks);
        }
        self.submit(batch).await.map(Response::new)
    }

    async fn get_batch(
        &self,
        req: Request<pb::GetBatchRequest>,
    ) -> Result<Response<pb::BatchStatus>, Status> {
        Ok(Response::new(self.status(req.into_inner().batch_id).await?))
    }

    async fn list_batches(
        &self,
        _req: Request<pb::ListBatchesRequest>,
    ) -> Result<Response<pb::ListBatchesResponse>, Status> {
        let ids = self.shared.store.call(|s| s.batch_ids()).await?;
        let mut batches = Vec::new();
        for id in ids {
            batches.push(self.status(id).await?);
        }
        Ok(Response::new(pb::ListBatchesResponse { batches }))
    }

    type WatchBatchStream = StatusStream;

    async fn watch_batch(
        &self,
        req: Request<pb::GetBatchRequest>,
    ) -> Result<Response<Self::WatchBatchStream>, Status> {
        let id = req.into_inner().batch_id;
        let first = self.status(id.clone()).await?;
        let shared = self.shared.clone();
        let (tx, rx) = mpsc::channel(16);
        tokio::spawn(async move {
            let mut events = shared.events.subscribe();
            let mut last = first;
            if tx.send(Ok(last.clone())).await.is_err() {
                return;
            }
            let svc = CoordinatorService {
                shared: shared.clone(),
            };
            let mut read = tokio::time::Instant::now();
            loop {
                if pb::BatchState::try_from(last.state).is_ok_and(pb::BatchState::is_final) {
                    return;
                }
                // A status reads the batch's counts (every shard of it): at most one per
                // `PROGRESS_EVERY`, however many shards complete — one per completion took the
                // store thread from leasing. Changes meanwhile wait in `events`.
                tokio::time::sleep_until(read + crate::PROGRESS_EVERY).await;
                // Wake on a change of this batch, or every second (worker counts, lost events).
                let _ = tokio::time::timeout(Duration::from_secs(1), async {
                    loop {
                        match events.recv().await {
                            Ok(b) if b == id => return,
                            Ok(_) => {}
                            Err(broadcast::error::RecvError::Lagged(_)) => return,
                            Err(broadcast::error::RecvError::Closed) => return,
                        }
                    }
                })
                .await;
                read = tokio::time::Instant::now();
                let next = match svc.status(id.clone()).await {
                    Ok(s) => s,
                    Err(e) => {
                        let _ = tx.send(Err(e)).await;
                        return;
                    }
                };
                if next != last {
                    if tx.send(Ok(next.clone())).await.is_err() {
                        return;
                    }
                    last = next;
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn cancel_batch(
        &self,
        req: Request<pb::GetBatchRequest>,
    ) -> Result<Response<pb::BatchStatus>, Status> {
        let id = req.into_inner().batch_id;
        let now = now_ms();
        let id2 = id.clone();
        let changed = self.shared.store.call(move |s| s.cancel(&id2, now)).await?;
        self.shared.publish(&changed);
        info!(batch = %id, "batch cancelled");
        Ok(Response::new(self.status(id).await?))
    }

    async fn get_report(
        &self,
        req: Request<pb::GetReportRequest>,
    ) -> Result<Response<pb::GetReportResponse>, Status> {
        let id = req.into_inner().batch_id;
        let rows = self.shared.store.call(move |s| s.batch_rows(&id)).await?;
        let final_ = rows.batch.state != batch_state::RUNNING;
        // Assembled off the store's thread and the executor: a ranking's bootstrap takes a while.
        let report_json = tokio::task::spawn_blocking(move || {
            let report = assay_report::assemble::report(&rows, crate::store::REPORT_GENERATOR);
            serde_json::to_string_pretty(&report).map_err(CoordError::from)
        })
        .await
        .map_err(|e| Status::internal(format!("assembling the report: {e}")))??;
        Ok(Response::new(pb::GetReportResponse {
            report_json,
            r#final: final_,
        }))
    }
}

pub struct WorkerSessionService {
    pub shared: Arc<Shared>,
}

#[tonic::async_trait]
impl pb::worker_session_server::WorkerSession for WorkerSessionService {
    type SessionStream = SessionStream;

    async fn session(
        &self,
        req: Request<Streaming<pb::WorkerMessage>>,
    ) -> Result<Response<Self::SessionStream>, Status> {
        let mut inbound = req.into_inner();
        let register = match inbound.message().await? {
            Some(pb::WorkerMessage {
                msg: Some(pb::worker_message::Msg::Register(r)),
            }) => r,
            _ => return Err(Status::invalid_argument("a session starts with Register")),
        };
        if register.worker_id.is_empty() || register.capacity == 0 {
            return Err(Status::invalid_argument(
                "Register needs a worker_id and a capacity of at least 1",
            ));
        }
        let roles: Vec<String> = register
            .roles
            .iter()
            .filter_map(|r| pb::Role::try_from(*r).ok())
            .filter(|r| *r != pb::Role::Unspecified)
            .map(|r| r.name().to_owned())
            .collect();
        // Shards are leased by what they need: a worker offers its roles and what it declares.
        let roles = crate::capability::capabilities(&register.capabilities, &roles);
        let (tx, rx) = mpsc::channel(64);
        let shared = self.shared.clone();
        tokio::spawn(async move {
            let worker = register.worker_id.clone();
            shared.workers_connected.fetch_add(1, Ordering::Relaxed);
            let joined = shared.capabilities.join(roles.clone());
            let result = run_session(&shared, register, roles, inbound, &tx).await;
            if let Err((e, _)) = &result {
                warn!(%worker, error = %e, "session failed");
            }
            shared.capabilities.leave(joined);
            shared.workers_connected.fetch_sub(1, Ordering::Relaxed);
            match result {
                Ok(SessionEnd::Shutdown) => debug!(%worker, "session closed for shutdown"),
                Ok(SessionEnd::Drained(held)) => {
                    // Assignments the worker had not seen when it left go back like the rest.
                    let ids: Vec<u64> = held.into_iter().collect();
                    info!(%worker, leases = ids.len(), reason = "session closed while draining", "leases handed back");
                    let w = worker.clone();
                    match shared.store.call(move |s| s.return_leases(&w, &ids)).await {
                        Ok(changed) => shared.publish(&changed),
                        Err(e) => {
                            warn!(%worker, error = %e, "could not re-queue the leases of a departed worker")
                        }
                    }
                }
                Ok(SessionEnd::Disconnected(held)) | Err((_, held)) => {
                    info!(%worker, leases = held.len(), "worker disconnected");
                    let ids: Vec<u64> = held.into_iter().collect();
                    if !ids.is_empty() {
                        let w = worker.clone();
                        match shared
                            .store
                            .call(move |s| s.expire(now_ms(), Some((&w, &ids))))
                            .await
                        {
                            Ok(changed) => shared.publish(&changed),
                            Err(e) => {
                                warn!(%worker, error = %e, "could not re-queue the leases of a lost worker")
                            }
                        }
                    }
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}

enum SessionEnd {
    Shutdown,
    /// The worker handed its leases back and closed the session: leases still held (assigned
    /// but not yet seen by the worker) are returned too, without counting an attempt.
    Drained(BTreeSet<u64>),
    /// The stream ended; these leases were still held.
    Disconnected(BTreeSet<u64>),
}

type Outbound = mpsc::Sender<Result<pb::CoordinatorMessage, Status>>;

fn msg(m: pb::coordinator_message::Msg) -> Result<pb::CoordinatorMessage, Status> {
    Ok(pb::CoordinatorMessage { msg: Some(m) })
}

/// Sends `leases` to the worker as assignments and adds them to `held`; false when the worker
/// has gone.
async fn assign(
    shared: &Shared,
    tx: &Outbound,
    leases: Vec<crate::store::Lease>,
    held: &mut BTreeSet<u64>,
) -> bool {
    use pb::coordinator_message::Msg as Out;
    if leases.is_empty() {
        return true;
    }
    let mut batches = BTreeSet::new();
    for l in leases {
        held.insert(l.lease_id);
        batches.insert(l.batch_id.clone());
        let a = pb::Assignment {
            lease_id: l.lease_id,
            shard_id: l.shard_id,
            batch_id: l.batch_id,
            role: pb::Role::parse(&l.role).unwrap_or(pb::Role::Unspecified) as i32,
            task_spec_json: l.task_spec_json,
            seed: l.seed,
            policy: Some(pb::PolicyRef { name: l.policy }),
            attempt: l.attempt,
            judge: l
                .judge
                .as_ref()
                .map(|j| j.judge.clone())
                .unwrap_or_default(),
            judge_repeats: l.judge.as_ref().map_or(0, |j| j.repeats),
            budget_left_usd: l.judge.as_ref().and_then(|j| j.budget_left_usd),
            input_json: match (l.judge, l.trainer_job, l.render_input) {
                (Some(j), _, _) => j.episode_json,
                (None, Some(job), _) => job,
                (None, None, Some(episode)) => episode,
                (None, None, None) => String::new(),
            },
            clip_size: l.clip_size,
            clip_interface: l.clip_interface,
            render: l.render,
        };
        if tx.send(msg(Out::Assignment(a))).await.is_err() {
            return false;
        }
    }
    shared.publish(&Changed {
        batches: batches.into_iter().collect(),
        requeued: 0,
    });
    true
}

async fn run_session(
    shared: &Arc<Shared>,
    register: pb::Register,
    roles: Vec<String>,
    mut inbound: Streaming<pb::WorkerMessage>,
    tx: &Outbound,
) -> Result<SessionEnd, (Status, BTreeSet<u64>)> {
    use pb::coordinator_message::Msg as Out;
    use pb::worker_message::Msg as In;

    let worker = register.worker_id.clone();
    let capacity = register.capacity as usize;
    let mut held: BTreeSet<u64> = BTreeSet::new();
    let fail = |e: CoordError, held: &BTreeSet<u64>| (Status::from(e), held.clone());

    let (w, ids) = (worker.clone(), register.held_leases.clone());
    let (kept, returned) = shared
        .store
        .call(move |s| s.reconcile(&w, &ids))
        .await
        .map_err(|e| fail(e, &held))?;
    shared.publish(&returned);
    held.extend(kept.iter().copied());
    info!(%worker, node = %register.node_id, roles = ?roles, capacity, kept = kept.len(), "worker registered");
    let registered = pb::Registered {
        session_id: format!("{worker}@{}", now_ms()),
        heartbeat_interval_ms: shared.config.heartbeat_interval.as_millis() as u32,
        lease_ttl_ms: shared.config.lease_ttl.as_millis() as u32,
        artifact_root: shared.config.artifact_root.display().to_string(),
        kept_leases: kept,
        telemetry_endpoint: shared.config.telemetry.clone().unwrap_or_default(),
        cluster: shared.config.cluster.clone(),
    };
    if tx.send(msg(Out::Registered(registered))).await.is_err() {
        return Ok(SessionEnd::Disconnected(held));
    }
    let mut shutdown = shared.shutdown.clone();
    // A worker that hands leases back is leaving: it gets no new work.
    let mut draining = false;
    // Set when the last lease call found less work than it asked for: the next one waits for a
    // wake-up (work queued, or the periodic retry) rather than asking again at once.
    let mut queue_empty = false;
    let mut retry = tokio::time::interval(Duration::from_millis(500));
    retry.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        // Registered before the lease call, so work queued while it runs still wakes this session.
        let work = shared.work.notified();
        tokio::pin!(work);
        work.as_mut().enable();
        if held.len() < capacity && !draining && !*shutdown.borrow() && !queue_empty {
            let (w, r, n, ttl) = (
                worker.clone(),
                roles.clone(),
                (capacity - held.len()) as u32,
                shared.ttl_ms(),
            );
            let leases = shared
                .store
                .call(move |s| s.lease(&w, &r, n, now_ms(), ttl))
                .await
                .map_err(|e| fail(e, &held))?;
            queue_empty = leases.len() < n as usize;
            if !assign(shared, tx, leases, &mut held).await {
                return Ok(SessionEnd::Disconnected(held));
            }
        }
        tokio::select! {
            m = inbound.message() => {
                let m = match m {
                    Ok(Some(m)) => m,
                    Ok(None) if draining => return Ok(SessionEnd::Drained(held)),
                    Ok(None) => return Ok(SessionEnd::Disconnected(held)),
                    Err(e) => return Err((e, held)),
                };
                match m.msg {
                    Some(In::Heartbeat(hb)) => {
                        let (w, ttl, ids) = (worker.clone(), shared.ttl_ms(), hb.lease_ids.clone());
                        let kept = shared.store.call(move |s| s.heartbeat(&w, &ids, now_ms(), ttl)).await.map_err(|e| fail(e, &held))?;
                        // Leases the store no longer grants to this worker no longer take its capacity.
                        for id in hb.lease_ids.iter().filter(|id| !kept.contains(id)) {
                            held.remove(id);
                        }
                    }
                    Some(In::Result(r)) => {
                        held.remove(&r.lease_id);
                        // The result and the worker's next leases in one store call.
                        let want = if draining || *shutdown.borrow() { 0 } else { capacity - held.len() } as u32;
                        let (w, lease_id, roles, ttl) = (worker.clone(), r.lease_id, roles.clone(), shared.ttl_ms());
                        let ((accepted, changed), leases) = shared
                            .store
                            .call(move |s| {
                                let completed = s.complete(&w, r.lease_id, r.shard_id, &r.outcome_json, r.wall_time_s, now_ms())?;
                                let leases = if want > 0 { s.lease(&w, &roles, want, now_ms(), ttl) } else { Ok(Vec::new()) };
                                Ok((completed, leases))
                            })
                            .await
                            .map_err(|e| fail(e, &held))?;
                        if !accepted {
                            info!(%worker, lease = lease_id, "late result not counted (its lease expired or moved on)");
                        }
                        shared.publish(&changed);
                        if tx.send(msg(Out::Ack(pb::ResultAck { lease_id, accepted }))).await.is_err() {
                            return Ok(SessionEnd::Disconnected(held));
                        }
                        let leases = leases.map_err(|e| fail(e, &held))?;
                        queue_empty = leases.len() < want as usize;
                        if !assign(shared, tx, leases, &mut held).await {
                            return Ok(SessionEnd::Disconnected(held));
                        }
                    }
                    Some(In::Failure(f)) => {
                        held.remove(&f.lease_id);
                        warn!(%worker, shard = f.shard_id, retryable = f.retryable, error = %f.error, "shard failed");
                        let changed = shared.store.call(move |s| s.fail(f.lease_id, f.shard_id, &f.error, f.retryable, now_ms())).await.map_err(|e| fail(e, &held))?;
                        shared.publish(&changed);
                    }
                    Some(In::ReturnLeases(r)) => {
                        draining = true;
                        for id in &r.lease_ids {
                            held.remove(id);
                        }
                        info!(%worker, leases = r.lease_ids.len(), reason = %r.reason, "leases handed back");
                        let w = worker.clone();
                        let changed = shared.store.call(move |s| s.return_leases(&w, &r.lease_ids)).await.map_err(|e| fail(e, &held))?;
                        shared.publish(&changed);
                    }
                    Some(In::Register(_)) | None => {
                        return Err((Status::invalid_argument("unexpected message in session"), held));
                    }
                }
            }
            _ = &mut work => queue_empty = false,
            _ = retry.tick() => queue_empty = false,
            _ = shutdown.changed() => {
                let _ = tx.send(msg(Out::Goodbye(pb::Goodbye { reason: "coordinator shutting down".into() }))).await;
                return Ok(SessionEnd::Shutdown);
            }
        }
        // Work queued while a message was handled (its own lease call included) is not missed.
        let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
        if work.as_mut().poll(&mut cx).is_ready() {
            queue_empty = false;
        }
    }
}
