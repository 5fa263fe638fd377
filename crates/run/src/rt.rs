//! The runtime a command runs its network work on, and the signals that stop it.

use std::future::Future;

/// Runs `f` to completion on a two-thread runtime, on the calling thread (local clusters start
/// their processes from it: see [`crate::local::die_with_parent`]).
pub fn block_on<F: Future>(f: F) -> F::Output {
    runtime("assay-rt").block_on(f)
}

/// A multi-threaded runtime of two threads named `name`, for commands that talk to the network.
pub fn runtime(name: &str) -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name(name)
        .build()
        .expect("tokio runtime")
}

/// Resolves on SIGTERM or Ctrl-C. The handlers are installed when this is called (inside the
/// runtime), not when the future is first polled: a signal that arrives before the future is
/// polled is still caught instead of killing the process.
pub fn terminated() -> impl Future<Output = ()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate()).expect("SIGTERM handler");
    let mut int = signal(SignalKind::interrupt()).expect("SIGINT handler");
    async move {
        tokio::select! {
            _ = term.recv() => {}
            _ = int.recv() => {}
        }
    }
}
