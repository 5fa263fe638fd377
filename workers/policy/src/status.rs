//! The one place where [`PolicyError`] and gRPC status codes meet (both directions), as the
//! service documents them in `proto/assay/v1/policy.proto`; and what the policy and world-model
//! clients share: a deadline-bounded blocking call ([`block_on_call`]), the test for a missed
//! deadline and episode ids.

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use assay_model::policy::PolicyError;
use tokio::runtime::Handle;
use tonic::{Code, Status};

/// The status a server answers when its policy fails.
pub(crate) fn to_status(e: PolicyError) -> Status {
    match e {
        PolicyError::Unavailable(m) => Status::unavailable(m),
        PolicyError::BadAnswer(m) => Status::internal(m),
        PolicyError::Load(m) => Status::failed_precondition(m),
    }
}

/// The error a client reports for a failed call: `what` names the server and the call (e.g.
/// "policy server at http://h:1 failed Act at step 3"). Errors of the connection itself (no
/// server, a broken stream) and the retryable codes are [`PolicyError::Unavailable`]; a server that
/// cannot build the policy is [`PolicyError::Load`]; a policy that failed is
/// [`PolicyError::BadAnswer`].
pub(crate) fn from_status(what: &str, s: &Status) -> PolicyError {
    // A status made by the client from a transport error carries that error as its source; one
    // answered by a server does not.
    if let Some(source) = std::error::Error::source(s) {
        return PolicyError::Unavailable(format!("{what}: {}", error_chain(source)));
    }
    let message = format!("{what}: {} ({:?})", s.message(), s.code());
    match s.code() {
        Code::Unavailable
        | Code::DeadlineExceeded
        | Code::Cancelled
        | Code::ResourceExhausted
        | Code::Aborted
        | Code::Unknown
        | Code::NotFound => PolicyError::Unavailable(message),
        Code::FailedPrecondition | Code::Unimplemented | Code::Unauthenticated => {
            PolicyError::Load(message)
        }
        _ => PolicyError::BadAnswer(message),
    }
}

/// An error with its causes ("transport error: tcp connect error: Connection refused"), each
/// cause once (some errors repeat their source in their own message).
pub(crate) fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        let text = cause.to_string();
        if !s.ends_with(&text) {
            s.push_str(": ");
            s.push_str(&text);
        }
        source = cause.source();
    }
    s
}

/// Whether a failed call ran out of time: the deadline passed on the server
/// (`DEADLINE_EXCEEDED`) or in tonic's client, which cancels a call at its `grpc-timeout`.
pub(crate) fn missed_deadline(s: &Status, elapsed: Duration, timeout: Duration) -> bool {
    match s.code() {
        Code::DeadlineExceeded => true,
        Code::Cancelled => elapsed >= timeout.mul_f32(0.9),
        _ => false,
    }
}

/// How a deadline-bounded call failed, for the client to name in its own error type.
pub(crate) enum CallError {
    /// No answer within the deadline (the client's, or the server's `DEADLINE_EXCEEDED`).
    Late,
    /// An answer with a failing status.
    Failed(Status),
}

/// Runs one unary call on `rt`, blocking, bounded by `timeout` (the policy and world-model
/// clients' calls: each names the server, the call and the wait in its own error type).
pub(crate) fn block_on_call<T>(
    rt: &Handle,
    timeout: Duration,
    f: impl Future<Output = Result<tonic::Response<T>, Status>>,
) -> Result<T, CallError> {
    let start = Instant::now();
    match rt.block_on(async { tokio::time::timeout(timeout, f).await }) {
        Ok(Ok(answer)) => Ok(answer.into_inner()),
        Ok(Err(status)) if missed_deadline(&status, start.elapsed(), timeout) => {
            Err(CallError::Late)
        }
        Ok(Err(status)) => Err(CallError::Failed(status)),
        Err(_) => Err(CallError::Late),
    }
}

/// A unique episode id: a per-process random prefix and a counter.
pub(crate) fn new_episode_id() -> String {
    use std::hash::{BuildHasher, Hasher};
    static PREFIX: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let prefix = PREFIX.get_or_init(|| {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(std::process::id());
        h.write_u128(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0),
        );
        h.finish()
    });
    format!("{prefix:016x}-{}", NEXT.fetch_add(1, Ordering::Relaxed))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episode_ids_are_unique_and_short() {
        let (a, b) = (new_episode_id(), new_episode_id());
        assert_ne!(a, b);
        assert!(a.len() <= crate::server::MAX_EPISODE_ID_BYTES);
    }

    #[test]
    fn policy_errors_survive_the_wire() {
        for e in [
            PolicyError::Unavailable("busy".into()),
            PolicyError::BadAnswer("nan".into()),
            PolicyError::Load("no model".into()),
        ] {
            let back = from_status("act", &to_status(e.clone()));
            assert_eq!(
                std::mem::discriminant(&back),
                std::mem::discriminant(&e),
                "{e} came back as {back}"
            );
        }
        assert!(from_status("act", &Status::not_found("episode e1")).retryable());
        assert!(!from_status("act", &Status::invalid_argument("frame")).retryable());
    }
}
