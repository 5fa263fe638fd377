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

/// Submits a batch: by `SubmitBatch` where its request fits one message, else by
/// `SubmitBatchStream` in messages of [`assay_proto::SUBMIT_CHUNK_BYTES`] (a GenSim library with
/// per-seed layouts outgrows one). Either way the coordinator accepts or refuses it whole.
pub async fn submit(
    c: &mut Client,
    req: pb::SubmitBatchRequest,
) -> Result<pb::SubmitBatchResponse, tonic::Status> {
    use prost::Message;
    if req.encoded_len() <= assay_proto::SUBMIT_CHUNK_BYTES {
        return c.submit_batch(req).await.map(tonic::Response::into_inner);
    }
    let chunks = chunks(req, assay_proto::SUBMIT_CHUNK_BYTES);
    c.submit_batch_stream(tokio_stream::iter(chunks))
        .await
        .map(tonic::Response::into_inner)
}

/// `req` as the messages of a stream: the first its settings and first tasks, each after it
/// only tasks, each at most `limit` bytes where its tasks allow (a single larger task goes
/// alone, and the coordinator's message limit says whether it passes).
fn chunks(mut req: pb::SubmitBatchRequest, limit: usize) -> Vec<pb::SubmitBatchRequest> {
    use prost::Message;
    let tasks = std::mem::take(&mut req.tasks);
    let mut size = req.encoded_len();
    let mut out = vec![req];
    for t in tasks {
        // A repeated field's element: its bytes, their length and the field's tag.
        let grows = t.encoded_len() + 8;
        if !out.last().expect("one message at least").tasks.is_empty() && size + grows > limit {
            out.push(pb::SubmitBatchRequest::default());
            size = 0;
        }
        size += grows;
        out.last_mut().expect("one message at least").tasks.push(t);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    #[test]
    fn a_large_batch_is_cut_into_messages_that_keep_its_tasks_in_order() {
        let doc = |i: usize| pb::TaskDocument {
            origin: format!("t{i}.yaml"),
            format: "yaml".into(),
            content: "x".repeat(1000 + i),
        };
        let req = pb::SubmitBatchRequest {
            name: "big".into(),
            seeds: vec![0, 1],
            tasks: (0..50).map(doc).collect(),
            ..Default::default()
        };
        let parts = chunks(req.clone(), 10_000);
        assert!(parts.len() > 5, "{}", parts.len());
        assert!(parts.iter().all(|p| p.encoded_len() <= 10_000));
        assert_eq!(parts[0].name, "big");
        assert_eq!(parts[0].seeds, [0, 1]);
        for p in &parts[1..] {
            let only = pb::SubmitBatchRequest {
                tasks: p.tasks.clone(),
                ..Default::default()
            };
            assert_eq!(*p, only, "a later message carries tasks only");
        }
        let again: Vec<pb::TaskDocument> = parts.into_iter().flat_map(|p| p.tasks).collect();
        assert_eq!(again, req.tasks);
        // A task larger than a message goes alone.
        let one = pb::SubmitBatchRequest {
            tasks: vec![doc(0), doc(20_000), doc(1)],
            ..Default::default()
        };
        assert_eq!(chunks(one, 10_000).len(), 3);
    }
}
