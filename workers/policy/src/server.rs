//! The reference server of the `assay.v1.Policy` service: serves any [`Policy`] to remote
//! clients (`assay policy serve`, and the tests of the client).
//!
//! One policy instance per episode, made by the factory on `Reset` and dropped on `End`; at most
//! [`MAX_LIVE_EPISODES`] live at once (the least recently used is evicted beyond that, since a
//! client that crashes never sends `End`). Policy calls run on tokio's blocking pool — they may be
//! slow CPU or GPU work — never on the executor. Requests are checked against the bounds the proto
//! documents before a policy sees them.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex};

use assay_model::clip::{ACTION_DIMS, PROPRIO_DIMS};
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_proto::v1 as pb;
use tonic::{Request, Response, Status};
use tracing::{debug, info};

use crate::status::to_status;

/// Makes a fresh policy for one episode (called on every `Reset`, on the blocking pool).
pub type PolicyFactory = Arc<dyn Fn() -> Result<Box<dyn Policy>, PolicyError> + Send + Sync>;

/// Live episodes a server holds before it evicts the least recently used.
pub const MAX_LIVE_EPISODES: usize = 1024;
/// Largest frame side (pixels) a request may carry.
pub const MAX_FRAME_SIDE: u32 = 4096;
/// Most actions in one answer.
pub const MAX_CHUNK: usize = 1024;
/// Longest episode id (bytes).
pub const MAX_EPISODE_ID_BYTES: usize = 128;
/// Largest message either side sends or accepts: a frame of [`MAX_FRAME_SIDE`]² RGB and change.
pub const MAX_MESSAGE_BYTES: usize =
    (MAX_FRAME_SIDE as usize * MAX_FRAME_SIDE as usize * 3) + 64 * 1024;

/// What a server says about its policy in `Health`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ServerInfo {
    pub name: String,
    pub version: String,
    /// Frame size the policy expects (0: any).
    pub image_width: u32,
    pub image_height: u32,
    /// Actions per answer (0: it varies).
    pub chunk_size: u32,
    /// What the policy sees and how it acts.
    pub interface: assay_model::policy::Interface,
}

/// Serves `assay.v1.Policy` on `listener` until `shutdown` resolves, then stops accepting, lets the
/// calls in flight finish and returns.
///
/// With a `token` (the cluster's policy token, [`assay_proto::auth::Token::for_service`]`("policy")`),
/// every call must carry it (`authorization: Bearer …`); others get `UNAUTHENTICATED`.
pub async fn serve(
    listener: tokio::net::TcpListener,
    factory: PolicyFactory,
    info: ServerInfo,
    token: Option<assay_proto::auth::Token>,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), tonic::transport::Error> {
    info!(
        addr = ?listener.local_addr().ok(),
        policy = %info.name,
        token = if token.is_some() { "required" } else { "not required" },
        "policy server listening"
    );
    let service = PolicyService {
        factory,
        info,
        episodes: Arc::new(Mutex::new(Episodes::default())),
    };
    // Nagle off on every accepted connection (the builder's `tcp_nodelay` only applies to
    // listeners it binds itself): with it on, one answer in a hundred waits ~40 ms for a delayed ACK.
    let incoming = tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
    tonic::transport::Server::builder()
        .layer(tonic::service::InterceptorLayer::new(
            assay_proto::auth::RequireToken::new(token),
        ))
        .add_service(
            pb::policy_server::PolicyServer::new(service)
                .max_decoding_message_size(MAX_MESSAGE_BYTES)
                .max_encoding_message_size(MAX_MESSAGE_BYTES),
        )
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await
}

type Shared = Arc<Mutex<Box<dyn Policy>>>;

#[derive(Default)]
struct Episodes {
    live: HashMap<String, Episode>,
    /// Increases with every use: the smallest `used` is the least recently used episode.
    clock: u64,
}

struct Episode {
    policy: Shared,
    used: u64,
}

impl Episodes {
    fn tick(&mut self) -> u64 {
        self.clock += 1;
        self.clock
    }

    /// Inserts an episode; returns the policies that it replaced or evicted (to be dropped off the
    /// executor).
    fn insert(&mut self, id: String, policy: Shared) -> Vec<Shared> {
        let used = self.tick();
        let mut gone: Vec<Shared> = self
            .live
            .insert(id, Episode { policy, used })
            .map(|e| e.policy)
            .into_iter()
            .collect();
        while self.live.len() > MAX_LIVE_EPISODES {
            let oldest = self
                .live
                .iter()
                .min_by_key(|(_, e)| e.used)
                .map(|(id, _)| id.clone())
                .expect("non-empty");
            debug!(episode = %oldest, "evicting the least recently used episode");
            gone.extend(self.live.remove(&oldest).map(|e| e.policy));
        }
        gone
    }

    fn get(&mut self, id: &str) -> Option<Shared> {
        let used = self.tick();
        let e = self.live.get_mut(id)?;
        e.used = used;
        Some(e.policy.clone())
    }
}

struct PolicyService {
    factory: PolicyFactory,
    info: ServerInfo,
    episodes: Arc<Mutex<Episodes>>,
}

impl PolicyService {
    fn episodes(&self) -> std::sync::MutexGuard<'_, Episodes> {
        self.episodes.lock().expect("episode table lock")
    }
}

/// Drops policies on the blocking pool (freeing a model can take a while).
fn drop_off_executor(policies: Vec<Shared>) {
    if !policies.is_empty() {
        tokio::task::spawn_blocking(move || drop(policies));
    }
}

fn check_episode_id(id: &str) -> Result<(), Status> {
    if id.is_empty() || id.len() > MAX_EPISODE_ID_BYTES {
        return Err(Status::invalid_argument(format!(
            "episode_id: must be 1 to {MAX_EPISODE_ID_BYTES} bytes, got {}",
            id.len()
        )));
    }
    Ok(())
}

/// Checks an `Act` request against the documented bounds and the policy's frame size.
fn observation(info: &ServerInfo, r: pb::PolicyActRequest) -> Result<PolicyObservation, Status> {
    let (w, h) = (r.width, r.height);
    if !(1..=MAX_FRAME_SIDE).contains(&w) || !(1..=MAX_FRAME_SIDE).contains(&h) {
        return Err(Status::invalid_argument(format!(
            "width, height: {w}×{h} is outside 1..={MAX_FRAME_SIDE}"
        )));
    }
    if (info.image_width != 0 && w != info.image_width)
        || (info.image_height != 0 && h != info.image_height)
    {
        return Err(Status::invalid_argument(format!(
            "width, height: the policy expects {}×{} frames, got {w}×{h}",
            info.image_width, info.image_height
        )));
    }
    let want = w as usize * h as usize * 3;
    if r.rgb.len() != want {
        return Err(Status::invalid_argument(format!(
            "rgb: {} bytes, a {w}×{h} RGB8 frame has {want}",
            r.rgb.len()
        )));
    }
    let proprio: [f32; PROPRIO_DIMS] = r.proprio.as_slice().try_into().map_err(|_| {
        Status::invalid_argument(format!(
            "proprio: {} floats, expected {PROPRIO_DIMS}",
            r.proprio.len()
        ))
    })?;
    let mut images = Vec::with_capacity(r.images.len());
    for (i, im) in r.images.into_iter().enumerate() {
        let (iw, ih) = (im.width, im.height);
        let pixels = iw as usize * ih as usize;
        if !(1..=MAX_FRAME_SIDE).contains(&iw)
            || !(1..=MAX_FRAME_SIDE).contains(&ih)
            || im.rgb.len() != pixels * 3
            || !(im.depth.is_empty() || im.depth.len() == pixels)
        {
            return Err(Status::invalid_argument(format!(
                "images[{i}] ('{}'): {iw}×{ih} with {} bytes of RGB and {} of depth (each side \
                 1..={MAX_FRAME_SIDE}, 3 bytes and 0 or 1 float a pixel)",
                im.name,
                im.rgb.len(),
                im.depth.len()
            )));
        }
        images.push(assay_model::policy::NamedImage {
            name: im.name,
            width: iw,
            height: ih,
            rgb: im.rgb,
            depth: im.depth,
        });
    }
    let mut obs = PolicyObservation::legacy(r.step, w, h, r.rgb, proprio);
    if !images.is_empty() {
        obs.images = images;
    }
    if !r.state.is_empty() {
        obs.state = r.state;
    }
    Ok(obs)
}

/// Runs a policy call on the blocking pool.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, PolicyError> + Send + 'static,
) -> Result<T, Status> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| Status::internal(format!("the policy panicked: {e}")))?
        .map_err(to_status)
}

#[tonic::async_trait]
impl pb::policy_server::Policy for PolicyService {
    async fn health(
        &self,
        _: Request<pb::PolicyHealthRequest>,
    ) -> Result<Response<pb::PolicyHealthResponse>, Status> {
        let info = &self.info;
        let legacy = info.interface.is_legacy();
        Ok(Response::new(pb::PolicyHealthResponse {
            name: info.name.clone(),
            version: info.version.clone(),
            image_width: info.image_width,
            image_height: info.image_height,
            action_dims: if legacy {
                ACTION_DIMS as u32
            } else {
                info.interface.action.dims(None).unwrap_or(0) as u32
            },
            proprio_dims: if legacy {
                PROPRIO_DIMS as u32
            } else {
                info.interface.state_dims(None).unwrap_or(0) as u32
            },
            chunk_size: info.chunk_size,
            live_episodes: self.episodes().live.len() as u32,
            interface: (!legacy).then(|| crate::wire::interface_to_pb(&info.interface)),
        }))
    }

    async fn reset(
        &self,
        request: Request<pb::PolicyResetRequest>,
    ) -> Result<Response<pb::PolicyResetResponse>, Status> {
        let r = request.into_inner();
        check_episode_id(&r.episode_id)?;
        let context = EpisodeContext {
            task_id: r.task_id,
            seed: r.seed,
            instruction: r.instruction,
            arm: None,
        };
        let factory = self.factory.clone();
        let policy = blocking(move || {
            let mut policy = factory()?;
            policy.reset(&context)?;
            Ok(policy)
        })
        .await?;
        debug!(episode = %r.episode_id, "episode reset");
        let gone = self
            .episodes()
            .insert(r.episode_id, Arc::new(Mutex::new(policy)));
        drop_off_executor(gone);
        Ok(Response::new(pb::PolicyResetResponse {}))
    }

    async fn act(
        &self,
        request: Request<pb::PolicyActRequest>,
    ) -> Result<Response<pb::PolicyActResponse>, Status> {
        let r = request.into_inner();
        check_episode_id(&r.episode_id)?;
        let Some(policy) = self.episodes().get(&r.episode_id) else {
            return Err(Status::not_found(format!(
                "episode_id: no live episode '{}' (never reset, ended, evicted, or the server restarted)",
                r.episode_id
            )));
        };
        let obs = observation(&self.info, r)?;
        let chunk = blocking(move || {
            let mut policy = policy.lock().map_err(|_| {
                PolicyError::BadAnswer("the policy panicked earlier in this episode".into())
            })?;
            policy.act_any(&obs)
        })
        .await?;
        let dims = chunk.first().map_or(0, Vec::len);
        if dims == 0 || chunk.iter().any(|a| a.len() != dims) {
            return Err(Status::internal(
                "the policy returned actions of different lengths (or empty ones)",
            ));
        }
        if chunk.is_empty() || chunk.len() > MAX_CHUNK {
            return Err(Status::internal(format!(
                "the policy returned {} actions (1..={MAX_CHUNK} allowed)",
                chunk.len()
            )));
        }
        if let Some(bad) = chunk.iter().find(|a| a.iter().any(|x| !x.is_finite())) {
            return Err(Status::internal(format!(
                "the policy returned a non-finite action {bad:?}"
            )));
        }
        Ok(Response::new(pb::PolicyActResponse {
            actions: chunk.into_iter().flatten().collect(),
            action_dims: dims as u32,
        }))
    }

    async fn end(
        &self,
        request: Request<pb::PolicyEndRequest>,
    ) -> Result<Response<pb::PolicyEndResponse>, Status> {
        let id = request.into_inner().episode_id;
        let gone = self.episodes().live.remove(&id).map(|e| e.policy);
        debug!(episode = %id, known = gone.is_some(), "episode ended");
        drop_off_executor(gone.into_iter().collect());
        Ok(Response::new(pb::PolicyEndResponse {}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Nop;
    impl Policy for Nop {
        fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
            Ok(())
        }
        fn act(&mut self, _: &PolicyObservation) -> Result<Vec<[f32; 4]>, PolicyError> {
            Ok(vec![[0.0; 4]])
        }
    }

    #[test]
    fn evicts_the_least_recently_used_episode() {
        let mut episodes = Episodes::default();
        let shared = || -> Shared { Arc::new(Mutex::new(Box::new(Nop))) };
        for i in 0..MAX_LIVE_EPISODES {
            assert!(episodes.insert(format!("e{i}"), shared()).is_empty());
        }
        assert!(episodes.get("e0").is_some()); // e1 is now the least recently used
        assert_eq!(episodes.insert("new".into(), shared()).len(), 1);
        assert!(episodes.get("e1").is_none());
        assert!(episodes.get("e0").is_some());
        assert_eq!(episodes.live.len(), MAX_LIVE_EPISODES);
        // Resetting a live episode replaces its policy.
        assert_eq!(episodes.insert("e0".into(), shared()).len(), 1);
    }

    #[test]
    fn rejects_observations_outside_the_bounds() {
        let info = ServerInfo {
            image_width: 2,
            image_height: 2,
            ..Default::default()
        };
        let request = |w, h, bytes, proprio| pb::PolicyActRequest {
            episode_id: "e".into(),
            step: 0,
            width: w,
            height: h,
            rgb: vec![0; bytes],
            proprio: vec![0.0; proprio],
            ..Default::default()
        };
        assert!(observation(&info, request(2, 2, 12, 4)).is_ok());
        for (r, field) in [
            (request(3, 2, 18, 4), "width"),
            (request(0, 2, 0, 4), "width"),
            (request(2, 2, 11, 4), "rgb"),
            (request(2, 2, 12, 3), "proprio"),
        ] {
            let e = observation(&info, r).unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument);
            assert!(e.message().starts_with(field), "{}", e.message());
        }
    }
}
