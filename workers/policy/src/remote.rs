//! A policy served elsewhere over the `assay.v1.Policy` gRPC service
//! (`proto/assay/v1/policy.proto`), called synchronously from a simulator shard thread.
//!
//! Every call has a deadline (the spec's `timeout_ms`): it is sent to the server as
//! `grpc-timeout` and enforced here as well, so a server that accepts a connection but never
//! answers fails the episode after the deadline instead of hanging the shard thread. A server that
//! cannot be reached or answers late is [`PolicyError::Unavailable`] (the shard is retried); an
//! answer that is not a chunk of finite 4-float actions is [`PolicyError::BadAnswer`]. The
//! connection, the deadline and the status mapping are shared with the world-model client
//! ([`crate::grpc`]).
//!
//! The client blocks on the runtime [`Handle`] it is given: call it from plain threads, never from
//! inside that runtime (tokio panics if `block_on` is called on one of its own threads).

use std::time::Duration;

use assay_model::clip::{ACTION_DIMS, PROPRIO_DIMS};
use assay_model::policy::{
    Action, EpisodeContext, Interface, Policy, PolicyError, PolicyObservation,
};
use assay_proto::v1 as pb;
use tokio::runtime::Handle;
use tonic::Code;
use tracing::debug;

use crate::grpc::{Connection, ServiceClient, new_episode_id};
use crate::server::{MAX_CHUNK, MAX_MESSAGE_BYTES, ServerInfo};

/// The generated client of the `assay.v1.Policy` service.
pub(crate) type Client = pb::policy_client::PolicyClient<assay_proto::auth::Channel>;

impl ServiceClient for Client {
    const SERVER: &'static str = "policy server";
    const MAX_MESSAGE_BYTES: usize = MAX_MESSAGE_BYTES;
    type Error = PolicyError;

    fn unavailable(message: String) -> PolicyError {
        PolicyError::Unavailable(message)
    }

    fn bad_address(message: String) -> PolicyError {
        PolicyError::Load(message)
    }

    fn answered(code: Code, message: String) -> PolicyError {
        crate::status::from_code(code, message)
    }
}

/// What a policy server said in `Health`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Health {
    pub info: ServerInfo,
    /// Episodes the server holds.
    pub live_episodes: u32,
}

/// A connection to one policy server, for one episode at a time.
pub struct RemotePolicy {
    connection: Connection<Client>,
    info: ServerInfo,
    /// The episode being played, once reset.
    episode: Option<String>,
    /// Its instruction, sent again with every observation.
    instruction: String,
}

impl std::fmt::Debug for RemotePolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemotePolicy")
            .field("url", &self.connection.url())
            .field("timeout", &self.connection.timeout())
            .field("info", &self.info)
            .field("episode", &self.episode)
            .finish()
    }
}

impl RemotePolicy {
    /// Connects to the policy server at `url` (`http://host:port`) and checks its `Health`, both
    /// within `timeout`, which is also the deadline of every later call. A server that is down
    /// or silent is `Unavailable`; one whose action or proprioception dims are not Assay's (4 and
    /// 4) is `Load`. Blocks on `rt`: do not call it from inside that runtime.
    ///
    /// When this process has the cluster's policy token, every call carries it: the one in
    /// `ASSAY_POLICY_TOKEN[_FILE]`, else the one derived from the cluster token
    /// ([`assay_proto::auth::Token::service_from_env`]`("policy")`), never the token itself.
    pub fn connect(url: &str, timeout: Duration, rt: Handle) -> Result<RemotePolicy, PolicyError> {
        let token =
            assay_proto::auth::Token::service_from_env("policy").map_err(PolicyError::Load)?;
        Self::connect_with(url, timeout, rt, token)
    }

    /// [`RemotePolicy::connect`] presenting `token` (none: no `authorization` header).
    pub fn connect_with(
        url: &str,
        timeout: Duration,
        rt: Handle,
        token: Option<assay_proto::auth::Token>,
    ) -> Result<RemotePolicy, PolicyError> {
        let (connection, answer) =
            Connection::<Client>::connect(url, timeout, rt, token, |mut client| async move {
                client.health(health_request(timeout)).await
            })?;
        let health = health_from(url, answer)?;
        debug!(%url, name = %health.info.name, version = %health.info.version, "policy server connected");
        Ok(RemotePolicy {
            connection,
            info: health.info,
            episode: None,
            instruction: String::new(),
        })
    }

    /// Feeds the server through `interface` (declared in the policy's spec) instead of the one
    /// its `Health` declared.
    pub fn with_interface(mut self, interface: Interface) -> Result<Self, PolicyError> {
        interface.validate().map_err(|e| {
            PolicyError::Load(format!("policy server at {}: {e}", self.connection.url()))
        })?;
        self.info.interface = interface;
        Ok(self)
    }

    /// What the server said about its policy when this client connected.
    pub fn info(&self) -> &ServerInfo {
        &self.info
    }

    pub fn url(&self) -> &str {
        self.connection.url()
    }

    /// Asks the server's `Health` again (blocks for at most the deadline).
    pub fn health(&self) -> Result<Health, PolicyError> {
        let request = health_request(self.connection.timeout());
        let answer = self.connection.call("Health", |mut client| async move {
            client.health(request).await
        })?;
        health_from(self.url(), answer)
    }

    /// Sends `End` for the current episode, if any, without waiting long
    /// ([`Connection::end`]).
    fn end_episode(&mut self) {
        let Some(episode_id) = self.episode.take() else {
            return;
        };
        self.connection.end(|mut client, wait| {
            let mut request = tonic::Request::new(pb::PolicyEndRequest { episode_id });
            request.set_timeout(wait);
            async move { client.end(request).await }
        });
    }
}

fn health_request(timeout: Duration) -> tonic::Request<pb::PolicyHealthRequest> {
    let mut request = tonic::Request::new(pb::PolicyHealthRequest {});
    request.set_timeout(timeout);
    request
}

/// Checks a `Health` answer: the interface the server declares, and dims that agree with it (a
/// server of the original interface acts with 4 floats and sees 4).
fn health_from(url: &str, h: pb::PolicyHealthResponse) -> Result<Health, PolicyError> {
    let declared = h.interface.is_some();
    let interface = crate::wire::interface_from_pb(h.interface).map_err(|e| {
        PolicyError::Load(format!(
            "policy server at {url} ({} {}) declares a bad interface: {e}",
            h.name, h.version
        ))
    })?;
    // Dims that depend on the task's arm are checked by the simulator.
    let (actions, state) = if declared {
        (
            interface.action.dims(None).ok(),
            interface.state_dims(None).ok(),
        )
    } else {
        (Some(ACTION_DIMS), Some(PROPRIO_DIMS))
    };
    if actions.is_some_and(|d| d != h.action_dims as usize)
        || state.is_some_and(|d| d != h.proprio_dims as usize)
    {
        return Err(PolicyError::Load(format!(
            "policy server at {url} ({} {}) has action_dims {} and proprio_dims {}; its interface \
             ({} actions, state {}) acts with {} and sees {}",
            h.name,
            h.version,
            h.action_dims,
            h.proprio_dims,
            interface.action,
            interface
                .state
                .iter()
                .map(|s| s.name())
                .collect::<Vec<_>>()
                .join("+"),
            actions.map_or("?".into(), |d| d.to_string()),
            state.map_or("?".into(), |d| d.to_string()),
        )));
    }
    Ok(Health {
        info: ServerInfo {
            name: h.name,
            version: h.version,
            image_width: h.image_width,
            image_height: h.image_height,
            chunk_size: h.chunk_size,
            interface,
        },
        live_episodes: h.live_episodes,
    })
}

/// Checks an `Act` answer of the original interface: 1..=MAX_CHUNK actions of [`ACTION_DIMS`]
/// finite floats.
#[cfg(test)]
fn chunk(r: pb::PolicyActResponse) -> Result<Vec<Action>, String> {
    Ok(crate::wire::chunk(r, Some(ACTION_DIMS), MAX_CHUNK)?
        .into_iter()
        .map(|a| a.try_into().expect("chunks of ACTION_DIMS"))
        .collect())
}

impl Policy for RemotePolicy {
    /// The server's frame size when it asked for a square one.
    fn frame_size(&self) -> Option<u32> {
        let info = &self.info;
        (info.image_width != 0 && info.image_width == info.image_height).then_some(info.image_width)
    }

    fn interface(&self) -> Interface {
        let mut i = self.info.interface.clone();
        // The original interface's camera takes the size the server asked for.
        if let Some(c) = i.cameras.first_mut()
            && c.width == 0
        {
            c.width = self.info.image_width;
            c.height = self.info.image_height;
            if c.width == 0 || c.height == 0 {
                (c.width, c.height) = (0, 0);
            }
        }
        i
    }

    /// Ends the previous episode (best effort) and starts a new one under a fresh episode id.
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.end_episode();
        let episode_id = new_episode_id();
        let mut request = tonic::Request::new(pb::PolicyResetRequest {
            episode_id: episode_id.clone(),
            task_id: episode.task_id.clone(),
            seed: episode.seed,
            instruction: episode.instruction.clone(),
        });
        request.set_timeout(self.connection.timeout());
        self.connection.call(
            &format!("Reset (task {}, seed {})", episode.task_id, episode.seed),
            |mut client| async move { client.reset(request).await },
        )?;
        self.episode = Some(episode_id);
        self.instruction = episode.instruction.clone();
        Ok(())
    }

    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        self.act_any(obs)?
            .into_iter()
            .map(|a| {
                a.try_into().map_err(|_| {
                    PolicyError::BadAnswer(format!(
                        "policy server at {}: actions are not {ACTION_DIMS} floats",
                        self.url()
                    ))
                })
            })
            .collect()
    }

    /// One `Act` call: blocks the calling thread for at most the deadline.
    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let Some(episode_id) = self.episode.clone() else {
            return Err(PolicyError::Load(format!(
                "remote policy at {}: act before reset (no episode)",
                self.url()
            )));
        };
        let info = &self.info;
        if (info.image_width != 0 && obs.width != info.image_width)
            || (info.image_height != 0 && obs.height != info.image_height)
        {
            return Err(PolicyError::Load(format!(
                "policy server at {} ({}) expects {}×{} frames, the episode has {}×{}",
                self.url(),
                info.name,
                info.image_width,
                info.image_height,
                obs.width,
                obs.height
            )));
        }
        let mut request = tonic::Request::new(pb::PolicyActRequest {
            episode_id,
            step: obs.step,
            width: obs.width,
            height: obs.height,
            rgb: obs.rgb.clone(),
            proprio: obs.proprio.to_vec(),
            images: crate::wire::images_to_pb(&obs.images),
            state: obs.state.clone(),
            instruction: self.instruction.clone(),
        });
        request.set_timeout(self.connection.timeout());
        let answer = self.connection.call(
            &format!("Act at step {}", obs.step),
            |mut client| async move { client.act(request).await },
        )?;
        let dims = self
            .info
            .interface
            .is_legacy()
            .then_some(ACTION_DIMS)
            .or_else(|| self.info.interface.action.dims(None).ok());
        crate::wire::chunk(answer, dims, MAX_CHUNK).map_err(|reason| {
            PolicyError::BadAnswer(format!(
                "policy server at {} at step {}: {reason}",
                self.url(),
                obs.step
            ))
        })
    }
}

impl Drop for RemotePolicy {
    /// Frees the server's episode state (best effort, waiting at most
    /// [`crate::grpc::END_TIMEOUT`]).
    fn drop(&mut self) {
        // A runtime that is already shut down panics in its timer: nothing to free then.
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.end_episode()));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn answer(actions: Vec<f32>) -> pb::PolicyActResponse {
        pb::PolicyActResponse {
            actions,
            action_dims: 4,
        }
    }

    #[test]
    fn checks_answers() {
        assert_eq!(
            chunk(answer(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0])),
            Ok(vec![[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])
        );
        assert!(chunk(answer(vec![])).is_err());
        assert!(
            chunk(answer(vec![0.0; 3]))
                .unwrap_err()
                .contains("3 floats")
        );
        assert!(
            chunk(answer(vec![0.0, f32::NAN, 0.0, 0.0]))
                .unwrap_err()
                .contains("non-finite")
        );
        assert!(chunk(answer(vec![0.0; 4 * (MAX_CHUNK + 1)])).is_err());
        let mut three = answer(vec![0.0; 3]);
        three.action_dims = 3;
        assert!(chunk(three).unwrap_err().contains("action_dims"));
    }
}
