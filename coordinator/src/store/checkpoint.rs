//! Checkpoints beside the store's thread: a second connection copies the write-ahead log into
//! the database file, so the store's own thread rarely waits for the copy and its `fsync`s.
//!
//! SQLite checkpoints the log from the connection that commits, once it holds
//! [`WAL_AUTOCHECKPOINT`] pages: with one transaction per lease and per completion, every few
//! hundred calls stopped for a copy of the pages and two `fsync`s (a quarter of the store's time
//! in `assay bench coordinator`, one thread). This thread runs a PASSIVE checkpoint every
//! [`INTERVAL`] — it copies what is committed without waiting for the writer or blocking it — so
//! when the store's own checkpoint comes due, almost everything is copied already: its copy is
//! short and the log starts again from its beginning at the next transaction (the log restarts
//! only after a checkpoint that copied all of it, which the writer's own makes sure of).
//!
//! Owns: the checkpointing thread and its connection. Never reads or writes rows.

use std::path::Path;
use std::sync::mpsc;
use std::time::Duration;

use rusqlite::Connection;

use crate::error::CoordError;

/// How often the thread copies the log.
const INTERVAL: Duration = Duration::from_millis(10);

/// Pages of log after which the store's own connection checkpoints (SQLite's default is 1,000).
pub(super) const WAL_AUTOCHECKPOINT: u32 = 8_000;

/// The checkpointing thread; stopped, and its connection closed, when dropped.
pub(super) struct Checkpointer {
    stop: Option<mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Checkpointer {
    /// Starts checkpointing the store file at `path` (already open, in WAL mode).
    pub fn start(path: &Path) -> Result<Self, CoordError> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(Duration::from_secs(5))?;
        let (stop, stopped) = mpsc::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("assay-checkpoint".into())
            .spawn(move || {
                while let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(INTERVAL) {
                    let checked = conn
                        .query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |r| r.get::<_, i64>(0));
                    if let Err(e) = checked {
                        tracing::warn!(error = %e, "store: checkpoint failed");
                    }
                }
            })
            .map_err(CoordError::Checkpointer)?;
        Ok(Self {
            stop: Some(stop),
            thread: Some(thread),
        })
    }
}

impl Drop for Checkpointer {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
