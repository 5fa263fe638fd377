//! What the clients of the policy and world-model gRPC services ([`crate::remote`],
//! [`crate::world_model`]) share: connecting with a `Health` check within the deadline
//! ([`Connection::connect`]), one deadline-bounded blocking call ([`Connection::call`]), a
//! best-effort `End` ([`Connection::end`]), the mapping of a failed call's status to the
//! client's error ([`from_status`]) and episode ids. What differs between the two clients (the
//! generated client, the error type, the message limit, how errors name the server) is their
//! [`ServiceClient`].
//!
//! Owns: the deadline, the wording of "down", "late" and "failed" errors, the status codes every
//! client treats as retryable. Never: what a request or an answer holds (each client checks its
//! own), the server side ([`crate::server`]), reading the cluster token (each client's `connect`).
//!
//! A [`Connection`] blocks on the runtime [`Handle`] it is given: call it from plain threads, never
//! from inside that runtime (tokio panics if `block_on` is called on one of its own threads).

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use assay_proto::auth::Token;
use assay_proto::channel::{ChannelOptions, Client};
use tokio::runtime::Handle;
use tonic::{Code, Status};

/// Longest a client waits for `End` (sent best-effort when an episode is over).
pub(crate) const END_TIMEOUT: Duration = Duration::from_millis(500);

/// A service's generated client, with what its errors need.
pub(crate) trait ServiceClient: Client + Clone {
    /// How errors name the server: "policy server", "world model server".
    const SERVER: &'static str;
    /// Largest message either side sends or accepts.
    const MAX_MESSAGE_BYTES: usize;
    type Error;
    /// A server that is down, silent or late, or a retryable failure: the call may be tried again.
    fn unavailable(message: String) -> Self::Error;
    /// An address that is not one.
    fn bad_address(message: String) -> Self::Error;
    /// A status the server answered with a code that is not retryable (see [`from_status`]);
    /// `message` names the server, the call, the status's message and its code.
    fn answered(code: Code, message: String) -> Self::Error;
}

/// A client connected to one server, with the deadline of its calls and the runtime it blocks on.
pub(crate) struct Connection<C> {
    url: String,
    timeout: Duration,
    rt: Handle,
    client: C,
}

impl<C: ServiceClient> Connection<C> {
    /// Connects to the server at `url` and asks its `Health` with `health` (given a client, it
    /// sends the request with the deadline as its timeout), both within `timeout`, which is also
    /// the deadline of every later call; every call presents `token` (none: no `authorization`
    /// header). A server that is down or silent is `unavailable`; a bad address `bad_address`; a
    /// `Health` the server refused is mapped by its code. Returns the connection and the answer.
    pub(crate) fn connect<H, F>(
        url: &str,
        timeout: Duration,
        rt: Handle,
        token: Option<Token>,
        health: impl FnOnce(C) -> F,
    ) -> Result<(Self, H), C::Error>
    where
        F: Future<Output = Result<tonic::Response<H>, Status>>,
    {
        let start = Instant::now();
        let options = ChannelOptions {
            connect_timeout: Some(timeout),
            ..ChannelOptions::default()
        };
        let endpoint = assay_proto::channel::endpoint(C::SERVER, url, &options)
            .map_err(|e| C::bad_address(format!("{e}: {}", e.source)))?;
        let down = |reason: String| {
            C::unavailable(format!(
                "{} at {url} is down: {reason} (after {} ms)",
                C::SERVER,
                start.elapsed().as_millis()
            ))
        };
        let silent = || {
            down(format!(
                "no answer to Health within the {} ms deadline",
                timeout.as_millis()
            ))
        };
        let (client, answer) = rt
            .block_on(async {
                tokio::time::timeout(timeout, async {
                    let channel = endpoint
                        .connect()
                        .await
                        .map_err(|e| down(error_chain(&e)))?;
                    let client: C =
                        assay_proto::channel::client(channel, token, C::MAX_MESSAGE_BYTES);
                    let answer = health(client.clone()).await.map_err(|s| {
                        if missed_deadline(&s, start.elapsed(), timeout) {
                            silent()
                        } else if lost(&s) {
                            down(format!("Health: {} ({:?})", s.message(), s.code()))
                        } else {
                            from_status::<C>(&format!("{} at {url} failed Health", C::SERVER), &s)
                        }
                    })?;
                    Ok((client, answer.into_inner()))
                })
                .await
            })
            .map_err(|_| silent())??;
        let connection = Self {
            url: url.to_owned(),
            timeout,
            rt,
            client,
        };
        Ok((connection, answer))
    }

    pub(crate) fn url(&self) -> &str {
        &self.url
    }

    /// The deadline of every call.
    pub(crate) fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Runs one call (`f`, given a client) on the runtime with the deadline, blocking. A late
    /// answer (the client's deadline, or the server's `DEADLINE_EXCEEDED`) is `unavailable`; a
    /// failed one is mapped by [`from_status`]; both errors name the server, the call (`what`),
    /// the deadline and the time waited.
    pub(crate) fn call<T, F>(&self, what: &str, f: impl FnOnce(C) -> F) -> Result<T, C::Error>
    where
        F: Future<Output = Result<tonic::Response<T>, Status>>,
    {
        let start = Instant::now();
        let deadline_ms = self.timeout.as_millis();
        let late = || {
            C::unavailable(format!(
                "{} at {} did not answer {what} within the {deadline_ms} ms deadline (waited {} \
                 ms)",
                C::SERVER,
                self.url,
                start.elapsed().as_millis()
            ))
        };
        let call = f(self.client.clone());
        match self
            .rt
            .block_on(async { tokio::time::timeout(self.timeout, call).await })
        {
            Ok(Ok(answer)) => Ok(answer.into_inner()),
            Ok(Err(status)) if missed_deadline(&status, start.elapsed(), self.timeout) => {
                Err(late())
            }
            Ok(Err(status)) => Err(from_status::<C>(
                &format!(
                    "{} at {} failed {what} after {} ms (deadline {deadline_ms} ms)",
                    C::SERVER,
                    self.url,
                    start.elapsed().as_millis()
                ),
                &status,
            )),
            Err(_) => Err(late()),
        }
    }

    /// Sends a best-effort call (an episode's `End`; `f` is given a client and the wait, to send
    /// as the call's timeout) without waiting long: from a plain thread it waits at most
    /// [`END_TIMEOUT`] (or the deadline when shorter); from inside a runtime it only spawns the
    /// call. Its answer is ignored.
    pub(crate) fn end<F>(&self, f: impl FnOnce(C, Duration) -> F)
    where
        F: Future + Send + 'static,
    {
        let wait = self.timeout.min(END_TIMEOUT);
        let call = f(self.client.clone(), wait);
        let end = async move {
            let _ = tokio::time::timeout(wait, call).await;
        };
        if Handle::try_current().is_ok() {
            self.rt.spawn(end);
        } else {
            self.rt.block_on(end);
        }
    }
}

/// The error a client reports for a failed call: `what` names the server and the call (e.g.
/// "policy server at http://h:1 failed Act at step 3"). Errors of the connection itself (no
/// server, a broken stream) and the retryable codes are `unavailable`; other codes are the
/// service's ([`ServiceClient::answered`]).
pub(crate) fn from_status<C: ServiceClient>(what: &str, s: &Status) -> C::Error {
    // A status made by the client from a transport error carries that error as its source; one
    // answered by a server does not.
    if let Some(source) = std::error::Error::source(s) {
        return C::unavailable(format!("{what}: {}", error_chain(source)));
    }
    let message = format!("{what}: {} ({:?})", s.message(), s.code());
    if retryable(s.code()) {
        C::unavailable(message)
    } else {
        C::answered(s.code(), message)
    }
}

/// Codes after which the same call may succeed later (the server is busy, restarting, or lost
/// the episode).
fn retryable(code: Code) -> bool {
    matches!(
        code,
        Code::Unavailable
            | Code::DeadlineExceeded
            | Code::Cancelled
            | Code::ResourceExhausted
            | Code::Aborted
            | Code::Unknown
            | Code::NotFound
    )
}

/// Whether a failed call says nothing about the service: the connection failed, or the code is
/// retryable.
fn lost(s: &Status) -> bool {
    std::error::Error::source(s).is_some() || retryable(s.code())
}

/// An error with its causes ("transport error: tcp connect error: Connection refused"), each
/// cause once (some errors repeat their source in their own message).
fn error_chain(e: &dyn std::error::Error) -> String {
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
fn missed_deadline(s: &Status, elapsed: Duration, timeout: Duration) -> bool {
    match s.code() {
        Code::DeadlineExceeded => true,
        Code::Cancelled => elapsed >= timeout.mul_f32(0.9),
        _ => false,
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

    /// A `Health` that is never asked here.
    async fn no_health<C>(_: C) -> Result<tonic::Response<()>, Status> {
        Err(Status::internal("not asked"))
    }

    #[test]
    fn a_bad_address_is_named_in_each_clients_error() {
        let rt = tokio::runtime::Runtime::new().unwrap();
        let (url, timeout) = ("http://bad host", Duration::from_secs(1));
        let policy = Connection::<crate::remote::Client>::connect(
            url,
            timeout,
            rt.handle().clone(),
            None,
            no_health,
        );
        assert!(matches!(
            policy.err(),
            Some(assay_model::policy::PolicyError::Load(m))
                if m == "bad policy server address 'http://bad host': invalid URI"
        ));
        let world = Connection::<crate::world_model::Client>::connect(
            url,
            timeout,
            rt.handle().clone(),
            None,
            no_health,
        );
        assert!(matches!(
            world.err(),
            Some(assay_model::world::WorldError::Refused(m))
                if m == "bad world model server address 'http://bad host': invalid URI"
        ));
    }
}
