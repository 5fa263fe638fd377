//! Frames across nodes: the `assay.v1.Frames` gRPC service. A [`FrameHub`] holds one broadcast
//! channel per stream; `assay frames relay` fills it from the node's frame bus, the hand-off
//! benchmark fills it directly. A slow client lags and is told how many frames it lost; it never
//! slows the publisher.

use std::collections::HashMap;
use std::pin::Pin;
use std::sync::{Arc, Mutex};

use assay_proto::v1 as pb;
use tokio::sync::{broadcast, mpsc};
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};

/// Frames a subscription may fall behind before it loses the oldest (as on the frame bus).
const LAG: usize = 2;
/// HTTP/2 flow-control windows: a few 640×480 RGBA frames, so a frame is not split into many
/// round trips by the 64 KiB default.
pub const WINDOW_BYTES: u32 = 8 * 1024 * 1024;

/// A gRPC server set up for frames (no Nagle delay, windows of [`WINDOW_BYTES`]).
pub fn server_builder() -> tonic::transport::Server {
    tonic::transport::Server::builder()
        .tcp_nodelay(true)
        .initial_stream_window_size(WINDOW_BYTES)
        .initial_connection_window_size(WINDOW_BYTES)
}

#[derive(Default, Clone)]
pub struct FrameHub {
    streams: Arc<Mutex<HashMap<String, broadcast::Sender<pb::Frame>>>>,
}

impl FrameHub {
    /// The sending side of `stream` (made on first use).
    pub fn sender(&self, stream: &str) -> broadcast::Sender<pb::Frame> {
        self.streams
            .lock()
            .expect("frame hub lock")
            .entry(stream.to_owned())
            .or_insert_with(|| broadcast::channel(LAG).0)
            .clone()
    }

    /// The Frames service; with `token` (the cluster token or a worker key: the relay is
    /// worker-side), every subscription must carry it.
    pub fn server(
        self,
        token: Option<assay_proto::auth::Token>,
    ) -> tonic::service::interceptor::InterceptedService<
        pb::frames_server::FramesServer<Self>,
        assay_proto::auth::RequireToken,
    > {
        tonic::service::interceptor::InterceptedService::new(
            pb::frames_server::FramesServer::new(self)
                .max_encoding_message_size(assay_proto::MAX_MESSAGE_BYTES),
            assay_proto::auth::RequireToken::new(token),
        )
    }
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<pb::Frame, Status>> + Send>>;

#[tonic::async_trait]
impl pb::frames_server::Frames for FrameHub {
    type SubscribeStream = FrameStream;

    async fn subscribe(
        &self,
        request: Request<pb::SubscribeFrames>,
    ) -> Result<Response<FrameStream>, Status> {
        let stream = request.into_inner().stream;
        if stream.is_empty() {
            return Err(Status::invalid_argument("stream: must name a frame stream"));
        }
        let mut rx = self.sender(&stream).subscribe();
        let (tx, out) = mpsc::channel(1);
        tokio::spawn(async move {
            let mut dropped = 0u64;
            loop {
                match rx.recv().await {
                    Ok(mut frame) => {
                        frame.dropped = std::mem::take(&mut dropped);
                        if tx.send(Ok(frame)).await.is_err() {
                            return; // the client went away
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(n)) => dropped += n,
                    Err(broadcast::error::RecvError::Closed) => return,
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(out))))
    }
}

/// Connects to a `Frames` service and subscribes to `stream`; resolves once the server has
/// registered the subscription (frames published from then on arrive).
pub async fn subscribe(url: &str, stream: &str) -> anyhow::Result<tonic::Streaming<pb::Frame>> {
    use anyhow::Context;
    let options = assay_proto::channel::ChannelOptions {
        connect_timeout: Some(std::time::Duration::from_secs(5)),
        window_bytes: Some(WINDOW_BYTES),
        ..Default::default()
    };
    let channel = assay_proto::channel::connect("frame relay", url, &options).await?;
    let token = assay_proto::auth::Credential::token_from_env(&[assay_proto::auth::Access::Worker])
        .map_err(anyhow::Error::msg)?;
    let mut client: pb::frames_client::FramesClient<_> =
        assay_proto::channel::client(channel, token, assay_proto::MAX_MESSAGE_BYTES);
    Ok(client
        .subscribe(pb::SubscribeFrames {
            stream: stream.to_owned(),
        })
        .await
        .with_context(|| format!("subscribing to '{stream}' at {url}"))?
        .into_inner())
}
