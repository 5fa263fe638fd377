//! A client of a coordinator: its address, the cluster token, the message limits.

use assay_proto::v1 as pb;

/// The default coordinator address, also read from ASSAY_COORDINATOR.
pub const DEFAULT_COORDINATOR: &str = "http://127.0.0.1:7878";

/// The generated client over a channel that carries the cluster token.
pub type Client = pb::coordinator_client::CoordinatorClient<assay_proto::auth::Channel>;

/// A client of the coordinator at `addr`, carrying the cluster token when one is set
/// (`assay_proto::auth`).
pub async fn connect(addr: &str) -> anyhow::Result<Client> {
    let token = assay_proto::auth::Token::from_env().map_err(anyhow::Error::msg)?;
    let options = assay_proto::channel::ChannelOptions {
        connect_timeout: Some(std::time::Duration::from_secs(5)),
        ..Default::default()
    };
    let channel = assay_proto::channel::connect("coordinator", addr, &options).await?;
    Ok(assay_proto::channel::client(
        channel,
        token,
        assay_proto::MAX_MESSAGE_BYTES,
    ))
}
