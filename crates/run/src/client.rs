//! A client of a coordinator: its address, its credential (the cluster token or a role key), the
//! message limits.

use assay_proto::v1 as pb;

/// The default coordinator address, also read from ASSAY_COORDINATOR.
pub const DEFAULT_COORDINATOR: &str = "http://127.0.0.1:7878";

/// The generated client over a channel that carries the cluster token.
pub type Client = pb::coordinator_client::CoordinatorClient<assay_proto::auth::Channel>;

/// A client of the coordinator at `addr`, carrying the cluster token when one is set
/// (`assay_proto::auth`).
pub async fn connect(addr: &str) -> anyhow::Result<Client> {
    use assay_proto::auth::{Access, Credential};
    // The cluster token, else a submitter's key, else a viewer's (who reads, and is refused
    // the rest with PERMISSION_DENIED).
    let token = Credential::token_from_env(&[Access::Submitter, Access::Viewer])
        .map_err(anyhow::Error::msg)?;
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
