//! Following a batch to its end: the coordinator's status stream, the workers' rates from
//! telemetry, a local cluster kept alive beside it (a process that dies is started again, and a
//! coordinator that comes back is watched again on the same address), and the report once the
//! batch is final.
//!
//! What happens is told to an [`Observer`] (the CLI draws progress bars from it; a test records
//! it): the library prints nothing.
//!
//! Owns: the follow loop and its events. Never decides what a batch is (the caller submitted it)
//! or writes files.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use assay_import::{Import, Pipeline};
use assay_proto::v1 as pb;

use crate::client::Client;
use crate::local::LocalCluster;

/// What a run tells its observer, in the order it happens. More kinds may come: match with a
/// catch-all arm.
#[derive(Debug)]
#[non_exhaustive]
pub enum Event<'a> {
    /// A generator's output was imported (its mapping report written into `folder`).
    Imported {
        pipeline: Pipeline,
        path: &'a Path,
        import: &'a Import,
        folder: &'a Path,
    },
    /// A local cluster is running (`description` says what runs where).
    ClusterStarted { description: &'a str },
    /// The batch was submitted.
    Submitted {
        response: &'a pb::SubmitBatchResponse,
    },
    /// The batch of an earlier run goes on from the job store in `run_dir`.
    Resumed {
        batch_id: &'a str,
        run_dir: &'a Path,
    },
    /// Following starts: the batch will have judging and training work when these are set.
    Following { judging: bool, training: bool },
    /// The batch's status changed; the workers' summed rates from telemetry beside it.
    Status {
        status: &'a pb::BatchStatus,
        steps_per_s: f64,
        frames_per_s: f64,
    },
    /// A local process exited, or runs again.
    Process { line: &'a str },
    /// Following ended (the batch is final, or the cluster gave up).
    Followed,
    /// `assay watch`: watching `dir` every `poll_ms`, the corpus report in `corpus`.
    Watching {
        dir: &'a Path,
        poll_ms: u64,
        corpus: &'a Path,
    },
    /// `assay watch`: a submitted batch's rejected tasks.
    Rejected { errors: &'a [pb::SpecError] },
    /// `assay watch`: one batch folder handled (evaluated, skipped or failed).
    Handled {
        entry: &'a crate::corpus::Entry,
        models: &'a [String],
    },
}

/// Told what a run does; every method has a default that ignores it.
pub trait Observer {
    fn event(&mut self, _event: Event<'_>) {}
}

/// How following ended.
pub struct Followed {
    /// The last status seen (none if the coordinator never answered).
    pub last: Option<pb::BatchStatus>,
    /// The report, fetched once the batch was final or the cluster gave up.
    pub report: pb::GetReportResponse,
    /// Why the local cluster gave up before the batch ended, if it did.
    pub exited: Option<String>,
    /// Every local process event, in order (the report's `run.events`).
    pub events: Vec<String>,
}

/// How long an unreachable coordinator is waited for before the run gives up.
const LOST_FOR: Duration = Duration::from_secs(120);

/// Workers' physics steps and frames per second, by worker, from telemetry.
type Rates = Arc<Mutex<HashMap<String, (f64, f64)>>>;

/// Follows `batch_id` on the coordinator at `addr` until it is final, keeping `cluster` alive,
/// then fetches its report.
pub async fn follow(
    addr: &str,
    mut c: Client,
    batch_id: &str,
    cluster: &mut LocalCluster,
    work: (bool, bool),
    observer: &mut dyn Observer,
) -> anyhow::Result<Followed> {
    observer.event(Event::Following {
        judging: work.0,
        training: work.1,
    });
    let telemetry = Telemetry::join(cluster.telemetry.as_deref()).await;
    let watched = watch_loop(addr, &mut c, batch_id, cluster, &telemetry.rates, observer).await;
    observer.event(Event::Followed);
    telemetry.close().await;
    let (last, exited, events) = watched?;
    let report = c
        .get_report(pb::GetReportRequest {
            batch_id: batch_id.to_owned(),
        })
        .await;
    let report = match (report, &exited) {
        (Ok(r), _) => r.into_inner(),
        (Err(e), Some(why)) => anyhow::bail!(
            "{why}, and no report could be fetched ({e}); run the same command again to go \
             on from the job store"
        ),
        (Err(e), None) => return Err(e.into()),
    };
    Ok(Followed {
        last,
        report,
        exited,
        events,
    })
}

/// The status stream until the batch is final; on a broken stream, the same address again every
/// second for [`LOST_FOR`]. Returns the last status, why the cluster gave up (if it did) and the
/// local processes' events.
async fn watch_loop(
    addr: &str,
    c: &mut Client,
    batch_id: &str,
    cluster: &mut LocalCluster,
    rates: &Rates,
    observer: &mut dyn Observer,
) -> anyhow::Result<(Option<pb::BatchStatus>, Option<String>, Vec<String>)> {
    let request = || pb::GetBatchRequest {
        batch_id: batch_id.to_owned(),
    };
    let mut stream = c.watch_batch(request()).await?.into_inner();
    let (mut last, mut events) = (None, Vec::new());
    // Set while the coordinator is unreachable (it died and is being started again).
    let mut lost: Option<(tonic::Status, Instant)> = None;
    let mut check = tokio::time::interval(Duration::from_secs(1));
    loop {
        let next = if lost.is_none() {
            tokio::select! {
                st = stream.message() => Some(st),
                _ = check.tick() => None,
            }
        } else {
            check.tick().await;
            None
        };
        match cluster.supervise() {
            Ok(lines) => {
                for line in lines {
                    observer.event(Event::Process { line: &line });
                    events.push(line);
                }
            }
            Err(e) => return Ok((last, Some(e.to_string()), events)),
        }
        match next {
            Some(Ok(Some(status))) => {
                let (steps, frames) = summed(rates);
                observer.event(Event::Status {
                    status: &status,
                    steps_per_s: steps,
                    frames_per_s: frames,
                });
                last = Some(status);
            }
            // The coordinator ends the stream after the final status. An end before it is a
            // coordinator that went away (its connection closed between two messages): watch
            // again, as for a broken stream.
            Some(Ok(None)) if final_status(last.as_ref()) => return Ok((last, None, events)),
            Some(Ok(None)) => {
                lost = Some((
                    tonic::Status::unavailable("the status stream ended before the batch did"),
                    Instant::now(),
                ))
            }
            Some(Err(e)) => lost = Some((e, Instant::now())),
            None => {
                let Some((e, since)) = &lost else { continue };
                // Back on the same address: watch the batch again.
                let again = async {
                    let mut c2 = crate::client::connect(addr).await?;
                    let s2 = c2.watch_batch(request()).await?.into_inner();
                    anyhow::Ok((c2, s2))
                };
                match again.await {
                    Ok((c2, s2)) => {
                        (*c, stream) = (c2, s2);
                        lost = None;
                    }
                    Err(_) if since.elapsed() < LOST_FOR => {}
                    Err(e2) => anyhow::bail!(
                        "lost the local coordinator ({}) and could not reach it again \
                         ({e2}); run the same command again to go on from the job store",
                        e.message()
                    ),
                }
            }
        }
    }
}

/// Whether `status` is a batch's last: completed, cancelled or skipped.
fn final_status(status: Option<&pb::BatchStatus>) -> bool {
    status.is_some_and(|s| pb::BatchState::try_from(s.state).is_ok_and(pb::BatchState::is_final))
}

/// The workers' rates summed: (physics steps/s, frames/s).
fn summed(rates: &Rates) -> (f64, f64) {
    rates
        .lock()
        .expect("rates")
        .values()
        .fold((0.0, 0.0), |a, r| (a.0 + r.0, a.1 + r.1))
}

/// Cluster-wide rates from the workers' telemetry, while the batch is followed.
struct Telemetry {
    rates: Rates,
    session: Option<zenoh::Session>,
    listener: Option<tokio::task::JoinHandle<()>>,
}

impl Telemetry {
    /// Joins the telemetry router at `endpoint` (none: no rates) as a client.
    async fn join(endpoint: Option<&str>) -> Self {
        let rates = Rates::default();
        let session = match endpoint {
            Some(endpoint) => {
                // The local cluster's processes inherit this process's credential, if any.
                use assay_proto::auth::{Access, Credential};
                let login = Credential::from_env(&[Access::Submitter, Access::Viewer])
                    .ok()
                    .flatten()
                    .map(|c| c.zenoh_login());
                assay_telemetry::open_client(
                    endpoint,
                    login.as_ref().map(|(u, p)| (*u, p.as_str())),
                )
                .await
                .ok()
            }
            None => None,
        };
        let mut listener = None;
        if let Some(session) = &session
            && let Ok(sub) = assay_telemetry::ClusterSubscriber::new(session, "local").await
        {
            let rates = rates.clone();
            listener = Some(tokio::spawn(async move {
                while let Some((key, v)) = sub.next().await {
                    if key.ends_with("/stats")
                        && let Ok(s) = serde_json::from_value::<assay_telemetry::WorkerStats>(v)
                    {
                        rates
                            .lock()
                            .expect("rates")
                            .insert(s.worker, (s.physics_steps_per_s, s.frames_per_s));
                    }
                }
            }));
        }
        Self {
            rates,
            session,
            listener,
        }
    }

    async fn close(self) {
        if let Some(l) = self.listener {
            l.abort();
        }
        if let Some(s) = self.session {
            assay_telemetry::close(s).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{final_status, pb};

    #[test]
    fn only_a_final_status_ends_the_watch() {
        let at = |state: pb::BatchState| pb::BatchStatus {
            state: state as i32,
            ..Default::default()
        };
        // No status yet, or a running batch: a stream that ends there lost its coordinator.
        assert!(!final_status(None));
        assert!(!final_status(Some(&at(pb::BatchState::Running))));
        assert!(!final_status(Some(&at(pb::BatchState::Unspecified))));
        for state in [
            pb::BatchState::Completed,
            pb::BatchState::Cancelled,
            pb::BatchState::Skipped,
        ] {
            assert!(final_status(Some(&at(state))), "{state:?}");
        }
    }
}
