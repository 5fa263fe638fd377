//! The store actor: one named thread owns the SQLite connection; async code sends it closures
//! through a bounded mailbox and awaits the answer. SQLite never blocks the async executor.

use std::path::Path;

use tokio::sync::{mpsc, oneshot};

use crate::error::CoordError;
use crate::store::Store;

type Job = Box<dyn FnOnce(&mut Store) + Send>;

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
                while let Some(job) = rx.blocking_recv() {
                    job(&mut store);
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
            let _ = reply.send(f(s));
        });
        self.tx
            .send(job)
            .await
            .map_err(|_| CoordError::StoreStopped)?;
        rx.await.map_err(|_| CoordError::StoreStopped)?
    }
}
