//! How an Assay gRPC client opens its connection: an address (`http://host:port`) becomes an
//! [`Endpoint`] set up with the transport options its caller picks ([`ChannelOptions`]), and a
//! connected [`Channel`] becomes a generated client that carries the cluster token and a message
//! size limit ([`client`]).
//!
//! Owns: parsing addresses (a bad one is an [`AddressError`] naming the address and what it is
//! for), connect timeouts, `TCP_NODELAY`, HTTP/2 keep-alives and flow-control windows. Never:
//! retries, per-call deadlines, reading the token from the environment (callers pass it), or
//! deciding what an unreachable server means (each caller names that in its own error type).

use std::time::Duration;

use tonic::transport::{Channel, Endpoint};

use crate::auth::{self, AttachToken, Token};

/// The transport options a caller sets on its connection; every one left `None` is tonic's
/// default. `TCP_NODELAY` is always on (no Nagle delay on any Assay channel).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ChannelOptions {
    /// Longest wait to establish the connection; `None`: no limit.
    pub connect_timeout: Option<Duration>,
    /// HTTP/2 pings on an open connection; `None`: none.
    pub keep_alive: Option<KeepAlive>,
    /// Both HTTP/2 flow-control windows (stream and connection), in bytes; `None`: 64 KiB.
    pub window_bytes: Option<u32>,
}

/// HTTP/2 keep-alive pings: one every `interval`, and the connection is closed when a ping is not
/// answered within `timeout`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeepAlive {
    pub interval: Duration,
    pub timeout: Duration,
}

/// An address that is not a URI. Its message names the address and what it is for ("bad
/// coordinator address 'x'"); the reason is its [`source`](std::error::Error::source).
#[derive(Debug, thiserror::Error)]
#[error("bad {what} address '{address}'")]
pub struct AddressError {
    /// What the address is for: "coordinator", "policy server", …
    pub what: String,
    pub address: String,
    /// Why it is not a URI.
    pub source: tonic::transport::Error,
}

/// Why [`connect`] has no channel: a bad address, or no server answering at it.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error(transparent)]
    Address(#[from] AddressError),
    /// Nothing answered at the address (the reason is the source: refused, timed out, …).
    #[error("no {what} at {address}")]
    Unreachable {
        what: String,
        address: String,
        source: tonic::transport::Error,
    },
}

/// The endpoint of the `what` (e.g. "coordinator") at `address`, set up with `options`; not
/// connected yet.
pub fn endpoint(
    what: &str,
    address: &str,
    options: &ChannelOptions,
) -> Result<Endpoint, AddressError> {
    let mut endpoint = Endpoint::from_shared(address.to_owned())
        .map_err(|source| AddressError {
            what: what.to_owned(),
            address: address.to_owned(),
            source,
        })?
        .tcp_nodelay(true);
    if let Some(timeout) = options.connect_timeout {
        endpoint = endpoint.connect_timeout(timeout);
    }
    if let Some(k) = options.keep_alive {
        endpoint = endpoint
            .http2_keep_alive_interval(k.interval)
            .keep_alive_timeout(k.timeout);
    }
    if let Some(bytes) = options.window_bytes {
        endpoint = endpoint
            .initial_stream_window_size(bytes)
            .initial_connection_window_size(bytes);
    }
    Ok(endpoint)
}

/// A channel to the `what` at `address` ([`endpoint`], connected once; no retry).
pub async fn connect(
    what: &str,
    address: &str,
    options: &ChannelOptions,
) -> Result<Channel, ConnectError> {
    endpoint(what, address, options)?
        .connect()
        .await
        .map_err(|source| ConnectError::Unreachable {
            what: what.to_owned(),
            address: address.to_owned(),
            source,
        })
}

/// A generated client of one of the `assay.v1` services over an [`auth::Channel`].
pub trait Client: Sized {
    /// The client of `channel`, sending and accepting messages of at most `max_message_bytes`.
    fn with_limit(channel: auth::Channel, max_message_bytes: usize) -> Self;
}

macro_rules! clients {
    ($($client:ty),* $(,)?) => {$(
        impl Client for $client {
            fn with_limit(channel: auth::Channel, max_message_bytes: usize) -> Self {
                Self::new(channel)
                    .max_decoding_message_size(max_message_bytes)
                    .max_encoding_message_size(max_message_bytes)
            }
        }
    )*};
}

clients!(
    crate::v1::coordinator_client::CoordinatorClient<auth::Channel>,
    crate::v1::worker_session_client::WorkerSessionClient<auth::Channel>,
    crate::v1::frames_client::FramesClient<auth::Channel>,
    crate::v1::policy_client::PolicyClient<auth::Channel>,
    crate::v1::world_model_client::WorldModelClient<auth::Channel>,
);

/// A client `C` of `channel` that presents `token` with every call (none: no `authorization`
/// header) and sends and accepts messages of at most `max_message_bytes` (usually
/// [`crate::MAX_MESSAGE_BYTES`]).
pub fn client<C: Client>(channel: Channel, token: Option<Token>, max_message_bytes: usize) -> C {
    C::with_limit(
        tonic::service::interceptor::InterceptedService::new(channel, AttachToken::new(token)),
        max_message_bytes,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::v1 as pb;

    /// An error with its causes, as `anyhow`'s `{:#}` prints it.
    fn chain(e: &dyn std::error::Error) -> String {
        let mut s = e.to_string();
        let mut source = e.source();
        while let Some(cause) = source {
            s.push_str(&format!(": {cause}"));
            source = cause.source();
        }
        s
    }

    #[test]
    fn options_are_set_and_bad_addresses_named() {
        let options = ChannelOptions {
            connect_timeout: Some(Duration::from_secs(2)),
            keep_alive: Some(KeepAlive {
                interval: Duration::from_secs(5),
                timeout: Duration::from_secs(10),
            }),
            window_bytes: Some(1 << 20),
        };
        let e = endpoint("coordinator", "http://127.0.0.1:7878", &options).unwrap();
        assert_eq!(e.get_connect_timeout(), Some(Duration::from_secs(2)));
        assert!(e.get_tcp_nodelay());
        let plain = endpoint("coordinator", "http://h:1", &ChannelOptions::default()).unwrap();
        assert_eq!(plain.get_connect_timeout(), None);
        assert!(plain.get_tcp_nodelay());

        let err = endpoint("policy server", "http://bad host", &options).unwrap_err();
        assert_eq!(
            err.to_string(),
            "bad policy server address 'http://bad host'"
        );
        assert_eq!(
            chain(&err),
            "bad policy server address 'http://bad host': invalid URI: invalid uri character"
        );
    }

    #[test]
    fn an_unreachable_server_is_named() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        // A port nothing listens on: bind one, then free it.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let addr = format!("http://127.0.0.1:{port}");
        let options = ChannelOptions {
            connect_timeout: Some(Duration::from_secs(5)),
            ..ChannelOptions::default()
        };
        let err = rt
            .block_on(connect("frame relay", &addr, &options))
            .unwrap_err();
        assert!(matches!(err, ConnectError::Unreachable { .. }), "{err:?}");
        assert!(
            chain(&err).starts_with(&format!("no frame relay at {addr}: transport error")),
            "{}",
            chain(&err)
        );
        let err = rt
            .block_on(connect("coordinator", "not a uri", &options))
            .unwrap_err();
        assert!(
            chain(&err).starts_with("bad coordinator address 'not a uri': invalid URI"),
            "{}",
            chain(&err)
        );
        // Any service's client comes out of one channel.
        let _runtime = rt.enter();
        let channel = endpoint("coordinator", &addr, &options)
            .unwrap()
            .connect_lazy();
        let _: pb::coordinator_client::CoordinatorClient<auth::Channel> =
            client(channel.clone(), None, crate::MAX_MESSAGE_BYTES);
        let _: pb::frames_client::FramesClient<auth::Channel> = client(
            channel,
            Some(Token::new("0123456789abcdef-token").unwrap()),
            1024,
        );
    }
}
