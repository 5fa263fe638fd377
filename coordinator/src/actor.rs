//! The store actor: one named thread owns the SQLite connection; async code sends it closures
//! through a bounded mailbox and awaits the answer. SQLite never blocks the async executor.
//!
//! **Group commit.** When several calls are waiting, the thread takes up to [`MAX_GROUP`] of them
//! and runs them in one transaction (each in its own savepoint), then answers them all after the
//! one commit. A commit writes each changed page to the write-ahead log once per group instead of
//! once per call, which is most of a lease's or a completion's cost. No answer leaves before its
//! changes are committed, so a caller that was told "accepted" can rely on it across a crash, as
//! with one transaction per call.

use std::path::Path;

use tokio::sync::{mpsc, oneshot};

use crate::error::CoordError;
use crate::store::Store;

/// The most calls one transaction takes.
pub const MAX_GROUP: usize = 256;

/// Sends a call's answer once its group is committed (`None`) or has failed to commit.
type Reply = Box<dyn FnOnce(Option<&str>) + Send>;
type Job = Box<dyn FnOnce(&mut Store) -> Reply + Send>;

/// A cheap, cloneable handle to the store thread.
#[derive(Clone)]
pub struct StoreHandle {
    tx: mpsc::Sender<Job>,
}

impl StoreHandle {
    /// Opens (or creates) the store at `path` and starts its thread. The thread ends when the
    /// last handle is dropped.
    pub fn spawn(path: &Path) -> Result<Self, CoordError> {
        let store = Store::open(path)?;
        Ok(Self::spawn_with(store))
    }

    pub fn spawn_with(mut store: Store) -> Self {
        let (tx, mut rx) = mpsc::channel::<Job>(1024);
        std::thread::Builder::new()
            .name("assay-store".into())
            .spawn(move || {
                let mut jobs = Vec::with_capacity(MAX_GROUP);
                while let Some(job) = rx.blocking_recv() {
                    jobs.push(job);
                    while jobs.len() < MAX_GROUP {
                        match rx.try_recv() {
                            Ok(job) => jobs.push(job),
                            Err(_) => break,
                        }
                    }
                    run_group(&mut store, &mut jobs);
                }
            })
            .expect("spawn store thread");
        Self { tx }
    }

    /// Runs `f` on the store thread and returns its result.
    pub async fn call<T, F>(&self, f: F) -> Result<T, CoordError>
    where
        T: Send + 'static,
        F: FnOnce(&mut Store) -> Result<T, CoordError> + Send + 'static,
    {
        let (reply, rx) = oneshot::channel();
        let job: Job = Box::new(move |s| {
            let result = f(s);
            Box::new(move |commit_error: Option<&str>| {
                let result = match commit_error {
                    Some(e) => Err(CoordError::GroupCommit(e.to_owned())),
                    None => result,
                };
                let _ = reply.send(result);
            })
        });
        self.tx
            .send(job)
            .await
            .map_err(|_| CoordError::StoreStopped)?;
        rx.await.map_err(|_| CoordError::StoreStopped)?
    }
}

/// Runs `jobs` (and empties it): one alone in its own transactions, several in one group.
fn run_group(store: &mut Store, jobs: &mut Vec<Job>) {
    if jobs.len() == 1 {
        let job = jobs.pop().expect("one job");
        job(store)(None);
        return;
    }
    if let Err(e) = store.begin_group() {
        // Not in a group: each call runs and commits on its own.
        tracing::warn!(error = %e, "store: could not open a group transaction");
        for job in jobs.drain(..) {
            job(store)(None);
        }
        return;
    }
    let replies: Vec<Reply> = jobs.drain(..).map(|job| job(store)).collect();
    let error = store.commit_group().err().map(|e| e.to_string());
    for reply in replies {
        reply(error.as_deref());
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn meta(s: &mut Store, key: &str) -> Option<i64> {
        use rusqlite::OptionalExtension;
        s.conn()
            .query_row("SELECT value FROM meta WHERE key = ?1", [key], |r| r.get(0))
            .optional()
            .unwrap()
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn waiting_calls_share_a_commit_and_a_failing_one_changes_nothing() {
        let store = StoreHandle::spawn_with(Store::open_in_memory().unwrap());
        // Hold the store thread, so the calls below wait together and run as one group.
        let (started_tx, started_rx) = std::sync::mpsc::channel();
        let held = store.clone();
        let busy = tokio::spawn(async move {
            held.call(move |_| {
                started_tx.send(()).unwrap();
                std::thread::sleep(Duration::from_millis(300));
                Ok(())
            })
            .await
        });
        tokio::task::spawn_blocking(move || started_rx.recv().unwrap())
            .await
            .unwrap();
        let mut calls = Vec::new();
        for i in 0..40i64 {
            let store = store.clone();
            calls.push(tokio::spawn(async move {
                store
                    .call(move |s| {
                        let grouped = !s.conn().is_autocommit();
                        let sp = s.conn().savepoint()?;
                        sp.execute(
                            "INSERT INTO meta (key, value) VALUES (?1, ?2)",
                            rusqlite::params![format!("k{i}"), i],
                        )?;
                        if i == 7 {
                            // Dropped without commit: its savepoint rolls back.
                            return Err(CoordError::InvalidRequest("call 7 fails".into()));
                        }
                        sp.commit()?;
                        Ok(grouped)
                    })
                    .await
            }));
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        busy.await.unwrap().unwrap();
        let mut grouped = 0;
        for (i, c) in calls.into_iter().enumerate() {
            match c.await.unwrap() {
                Ok(g) => grouped += usize::from(g),
                Err(e) => {
                    assert_eq!(i, 7);
                    assert!(e.to_string().contains("call 7 fails"), "{e}");
                }
            }
        }
        assert!(grouped >= 30, "only {grouped} of 39 calls ran in a group");
        let (k7, k6, k39) = store
            .call(|s| Ok((meta(s, "k7"), meta(s, "k6"), meta(s, "k39"))))
            .await
            .unwrap();
        assert_eq!(k7, None, "the failed call's change was committed");
        assert_eq!((k6, k39), (Some(6), Some(39)));
    }
}
