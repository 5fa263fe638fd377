//! A world model served elsewhere over the `assay.v1.WorldModel` gRPC service
//! (`proto/assay/v1/world_model.proto`): the client behind [`WorldModelService`], for the proxy to
//! imagine policies' episodes in any lab's model (the Python kit serves one in a few lines:
//! `serve_world_model`, `python/assay-policy-kit/README.md`).
//!
//! It shares its connection with the remote policy client ([`crate::remote`]) through
//! [`crate::grpc`]: a health check at connect (a server that is down is
//! [`WorldError::Unavailable`] naming its address), a deadline on every call, sent as
//! `grpc-timeout` and enforced here too (a late answer is `Unavailable` naming the call and the
//! wait), and the cluster's token, when this process has one, presented as a secret derived from
//! it ([`TOKEN_PURPOSE`]). An answer that is not one frame of the episode's size per action, with
//! finite states if any, is [`WorldError::BadAnswer`]; a request the server declared it does not
//! take (frame size, action width) is refused here before it is sent ([`WorldError::Refused`]).
//!
//! The client blocks on the runtime [`Handle`] it is given: call it from plain threads, never from
//! inside that runtime (tokio panics if `block_on` is called on one of its own threads).

use std::time::Duration;

use assay_model::clip::ACTION_DIMS;
use assay_model::interface::Interface;
use assay_model::world::{ImaginedEpisode, WorldError, WorldFrame, WorldModelService, WorldStart};
use assay_proto::auth::Token;
use assay_proto::v1 as pb;
use tokio::runtime::Handle;
use tonic::Code;
use tracing::debug;

use crate::grpc::{Connection, ServiceClient, new_episode_id};
use crate::server::MAX_FRAME_SIDE;

/// What the token a world-model server checks is derived for: calls carry
/// [`Token::for_service`]`("world-model")` of the cluster token, so a world-model server sees
/// neither the cluster token nor a policy server's secret.
pub const TOKEN_PURPOSE: &str = "world-model";

/// Most actions in one `Step`.
pub const MAX_STEP_ACTIONS: usize = 1024;

/// Largest message either side sends or accepts: a `Step` answer is one frame per action.
pub const MAX_MESSAGE_BYTES: usize = 256 * 1024 * 1024;

/// What a world-model server said in `Health`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct WorldModelHealth {
    pub name: String,
    pub description: String,
    /// The frame size the model works at; `None`: any size.
    pub frame_size: Option<(u32, u32)>,
    /// Floats per action the model takes; `None`: any width.
    pub action_dims: Option<u32>,
    /// Episodes the server holds.
    pub live_episodes: u32,
    /// The policy interfaces the model imagines in, as declared; empty: see
    /// [`WorldModelHealth::accepted`].
    pub interfaces: Vec<Interface>,
}

impl WorldModelHealth {
    /// The interfaces a policy may act in inside the model: the declared ones, else the original
    /// interface at the declared frame size (any: the proxy's) when the declared action width is
    /// 0 or 4, else none.
    pub fn accepted(&self) -> Vec<Interface> {
        if !self.interfaces.is_empty() {
            return self.interfaces.clone();
        }
        if self.action_dims.is_some_and(|d| d as usize != ACTION_DIMS) {
            return Vec::new();
        }
        let mut legacy = Interface::default();
        if let Some((w, h)) = self.frame_size {
            legacy.cameras[0].width = w;
            legacy.cameras[0].height = h;
        }
        vec![legacy]
    }
}

impl TryFrom<pb::WorldModelHealthResponse> for WorldModelHealth {
    type Error = String;

    fn try_from(h: pb::WorldModelHealthResponse) -> Result<Self, String> {
        let interfaces = h
            .interfaces
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                crate::wire::interface_from_pb(Some(p))
                    .map_err(|e| format!("Health: interfaces[{i}]: {e}"))
            })
            .collect::<Result<_, _>>()?;
        Ok(Self {
            name: h.name,
            description: h.description,
            frame_size: (h.width != 0 && h.height != 0).then_some((h.width, h.height)),
            action_dims: (h.action_dims != 0).then_some(h.action_dims),
            live_episodes: h.live_episodes,
            interfaces,
        })
    }
}

/// The generated client of the `assay.v1.WorldModel` service.
pub(crate) type Client = pb::world_model_client::WorldModelClient<assay_proto::auth::Channel>;

impl ServiceClient for Client {
    const SERVER: &'static str = "world model server";
    const MAX_MESSAGE_BYTES: usize = MAX_MESSAGE_BYTES;
    type Error = WorldError;

    fn unavailable(message: String) -> WorldError {
        WorldError::Unavailable(message)
    }

    fn bad_address(message: String) -> WorldError {
        WorldError::Refused(message)
    }

    fn answered(code: Code, message: String) -> WorldError {
        from_code(code, message)
    }
}

/// A connection to one world-model server; any number of imagined episodes at a time.
pub struct RemoteWorldModel {
    connection: Connection<Client>,
    info: WorldModelHealth,
}

impl std::fmt::Debug for RemoteWorldModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteWorldModel")
            .field("url", &self.connection.url())
            .field("timeout", &self.connection.timeout())
            .field("info", &self.info)
            .finish()
    }
}

/// Connects to the world-model server at `url` (`http://host:port`) and checks its `Health`
/// within `timeout_ms`, which is also the deadline of every later call ([`RemoteWorldModel::connect`]).
/// Blocks on `rt`: do not call it from inside that runtime.
pub fn connect(
    url: &str,
    timeout_ms: u64,
    rt: &Handle,
) -> Result<Box<dyn WorldModelService>, WorldError> {
    Ok(Box::new(RemoteWorldModel::connect(
        url,
        Duration::from_millis(timeout_ms),
        rt.clone(),
    )?))
}

impl RemoteWorldModel {
    /// Connects to the server at `url` and checks its `Health`, both within `timeout`, which is
    /// also the deadline of every later call. A server that is down or silent is `Unavailable`;
    /// one that refuses the call (no or a wrong token, not a world-model server) is `Refused`.
    ///
    /// When this process has the cluster's world-model token, every call carries it: the one
    /// in `ASSAY_WORLD_MODEL_TOKEN[_FILE]`, else the secret derived from the cluster token
    /// for [`TOKEN_PURPOSE`] ([`Token::service_from_env`]), never the token itself.
    pub fn connect(url: &str, timeout: Duration, rt: Handle) -> Result<Self, WorldError> {
        let token = Token::service_from_env(TOKEN_PURPOSE)
            .map_err(|e| WorldError::Refused(format!("world model server at {url}: {e}")))?;
        Self::connect_with(url, timeout, rt, token)
    }

    /// [`RemoteWorldModel::connect`] presenting `token` as it is (none: no `authorization`
    /// header); a cluster's is `Token::for_service(TOKEN_PURPOSE)` of its token.
    pub fn connect_with(
        url: &str,
        timeout: Duration,
        rt: Handle,
        token: Option<Token>,
    ) -> Result<Self, WorldError> {
        let (connection, answer) =
            Connection::<Client>::connect(url, timeout, rt, token, |mut client| async move {
                let mut request = tonic::Request::new(pb::WorldModelHealthRequest {});
                request.set_timeout(timeout);
                client.health(request).await
            })?;
        let info = WorldModelHealth::try_from(answer)
            .map_err(|e| WorldError::BadAnswer(format!("world model server at {url}: {e}")))?;
        debug!(%url, name = %info.name, "world model server connected");
        Ok(Self { connection, info })
    }

    /// What the server said about its model when this client connected.
    pub fn info(&self) -> &WorldModelHealth {
        &self.info
    }

    pub fn url(&self) -> &str {
        self.connection.url()
    }

    /// Asks the server's `Health` again (blocks for at most the deadline).
    pub fn health(&self) -> Result<WorldModelHealth, WorldError> {
        let mut request = tonic::Request::new(pb::WorldModelHealthRequest {});
        request.set_timeout(self.connection.timeout());
        let answer = self.connection.call("Health", |mut client| async move {
            client.health(request).await
        })?;
        WorldModelHealth::try_from(answer).map_err(|e| {
            WorldError::BadAnswer(format!("world model server at {}: {e}", self.url()))
        })
    }

    /// Starts an imagined episode ([`WorldModelService::reset`]), as the concrete session type.
    pub fn start(&self, start: &WorldStart) -> Result<RemoteEpisode<'_>, WorldError> {
        let (w, h) = (start.width, start.height);
        if !(1..=MAX_FRAME_SIDE).contains(&w) || !(1..=MAX_FRAME_SIDE).contains(&h) {
            return Err(self.refused(format!(
                "a start frame of {w}×{h} (each side 1 to {MAX_FRAME_SIDE})"
            )));
        }
        let bytes = rgb_bytes(w, h);
        if start.rgb.len() != bytes {
            return Err(self.refused(format!(
                "a start frame of {} bytes for {w}×{h} RGB8 ({bytes})",
                start.rgb.len()
            )));
        }
        if let Some((mw, mh)) = self.info.frame_size
            && (mw, mh) != (w, h)
        {
            return Err(self.refused(format!("{w}×{h} frames: the model works at {mw}×{mh}")));
        }
        if start.views.len() + 1 != start.interface.cameras.len().max(1) {
            return Err(self.refused(format!(
                "{} start frame(s) for an interface of {} camera(s)",
                start.views.len() + 1,
                start.interface.cameras.len()
            )));
        }
        for v in &start.views {
            if !(1..=MAX_FRAME_SIDE).contains(&v.width)
                || !(1..=MAX_FRAME_SIDE).contains(&v.height)
                || v.rgb.len() != rgb_bytes(v.width, v.height)
            {
                return Err(self.refused(format!(
                    "a start frame of camera '{}' of {} bytes at {}×{}",
                    v.name,
                    v.rgb.len(),
                    v.width,
                    v.height
                )));
            }
        }
        let episode_id = new_episode_id();
        let mut request = tonic::Request::new(pb::WorldModelResetRequest {
            episode_id: episode_id.clone(),
            task_id: start.task_id.clone(),
            seed: start.seed,
            instruction: start.instruction.clone(),
            frames: vec![pb::Image {
                name: start
                    .interface
                    .cameras
                    .first()
                    .map_or("image".into(), |c| c.name.clone()),
                width: w,
                height: h,
                rgb: start.rgb.clone(),
                depth: Vec::new(),
            }],
            state: start.state.clone(),
            interface: (start.interface != Interface::default())
                .then(|| crate::wire::interface_to_pb(&start.interface)),
            views: crate::wire::images_to_pb(&start.views),
        });
        request.set_timeout(self.connection.timeout());
        self.connection.call(
            &format!("Reset (task {}, seed {})", start.task_id, start.seed),
            |mut client| async move { client.reset(request).await },
        )?;
        Ok(RemoteEpisode {
            model: self,
            episode_id,
            task_id: start.task_id.clone(),
            seed: start.seed,
            width: w,
            height: h,
            views: start
                .views
                .iter()
                .map(|v| (v.name.clone(), v.width, v.height))
                .collect(),
            steps: 0,
        })
    }

    fn refused(&self, what: String) -> WorldError {
        WorldError::Refused(format!(
            "world model server at {} ({}) does not take {what}",
            self.url(),
            self.info.name
        ))
    }
}

impl WorldModelService for RemoteWorldModel {
    /// The server's declared name and its address.
    fn name(&self) -> String {
        if self.info.name.is_empty() {
            format!("world model at {}", self.url())
        } else {
            format!("{} at {}", self.info.name, self.url())
        }
    }

    fn reset(&self, start: &WorldStart) -> Result<Box<dyn ImaginedEpisode + '_>, WorldError> {
        Ok(Box::new(self.start(start)?))
    }

    /// What the server declared in `Health` ([`WorldModelHealth::accepted`]).
    fn interfaces(&self) -> Vec<Interface> {
        self.info.accepted()
    }
}

/// One imagined episode on a world-model server; dropping it sends `End` (best effort).
pub struct RemoteEpisode<'a> {
    model: &'a RemoteWorldModel,
    episode_id: String,
    task_id: String,
    seed: u64,
    width: u32,
    height: u32,
    /// The cameras after the first: name, width, height.
    views: Vec<(String, u32, u32)>,
    /// Actions stepped so far.
    steps: usize,
}

impl std::fmt::Debug for RemoteEpisode<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteEpisode")
            .field("url", &self.model.url())
            .field("episode_id", &self.episode_id)
            .field("size", &(self.width, self.height))
            .field("steps", &self.steps)
            .finish()
    }
}

impl ImaginedEpisode for RemoteEpisode<'_> {
    /// One `Step` call for the whole chunk: blocks the calling thread for at most the deadline.
    /// Actions of different widths, or of a width the server declared it does not take, are
    /// refused before anything is sent; an empty chunk is answered at once with no frames.
    fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<WorldFrame>, WorldError> {
        let Some(first) = actions.first() else {
            return Ok(Vec::new());
        };
        let model = self.model;
        let dims = first.len();
        if dims == 0 {
            return Err(model.refused("actions of no floats".into()));
        }
        if let Some((i, a)) = actions.iter().enumerate().find(|(_, a)| a.len() != dims) {
            return Err(model.refused(format!(
                "a chunk of actions of different widths (action 0 has {dims} floats, action {i} \
                 has {})",
                a.len()
            )));
        }
        if let Some(d) = model.info.action_dims
            && d as usize != dims
        {
            return Err(model.refused(format!("{dims}-float actions: it takes {d}")));
        }
        if let Some(i) = actions
            .iter()
            .position(|a| a.iter().any(|x| !x.is_finite()))
        {
            return Err(model.refused(format!("a non-finite action (action {i} of the chunk)")));
        }
        let k = actions.len();
        let per_action = rgb_bytes(self.width, self.height)
            + self
                .views
                .iter()
                .map(|(_, w, h)| rgb_bytes(*w, *h))
                .sum::<usize>();
        let answer_bytes = k.saturating_mul(per_action);
        if k > MAX_STEP_ACTIONS || answer_bytes > MAX_MESSAGE_BYTES - 1024 * 1024 {
            return Err(model.refused(format!(
                "a chunk of {k} actions of {}×{} frames (at most {MAX_STEP_ACTIONS} actions and \
                 {} MiB of frames per Step)",
                self.width,
                self.height,
                MAX_MESSAGE_BYTES / (1024 * 1024) - 1
            )));
        }
        let mut request = tonic::Request::new(pb::WorldModelStepRequest {
            episode_id: self.episode_id.clone(),
            actions: actions.iter().flatten().copied().collect(),
            action_dims: dims as u32,
        });
        request.set_timeout(model.connection.timeout());
        let what = format!(
            "Step of {k} actions from imagined step {} (task {}, seed {})",
            self.steps, self.task_id, self.seed
        );
        let answer =
            model.connection.call(
                &what,
                |mut client| async move { client.step(request).await },
            )?;
        let frames =
            frames_from(answer, k, self.width, self.height, &self.views).map_err(|reason| {
                WorldError::BadAnswer(format!(
                    "world model server at {} ({}) answered {what}: {reason}",
                    model.url(),
                    model.info.name
                ))
            })?;
        self.steps += k;
        Ok(frames)
    }
}

impl RemoteEpisode<'_> {
    /// Sends `End` without waiting long ([`Connection::end`]).
    fn end(&mut self) {
        let episode_id = std::mem::take(&mut self.episode_id);
        self.model.connection.end(|mut client, wait| {
            let mut request = tonic::Request::new(pb::WorldModelEndRequest { episode_id });
            request.set_timeout(wait);
            async move { client.end(request).await }
        });
    }
}

impl Drop for RemoteEpisode<'_> {
    /// Frees the server's episode state (best effort, waiting at most
    /// [`crate::grpc::END_TIMEOUT`]).
    fn drop(&mut self) {
        // A runtime that is already shut down panics in its timer: nothing to free then.
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.end()));
    }
}

fn rgb_bytes(width: u32, height: u32) -> usize {
    width as usize * height as usize * 3
}

/// Checks a `Step` answer to `k` actions: exactly `k` frames of `width × height` RGB8, `k` frames
/// of each camera of `views` at its size, and either no states or `k` finite states of
/// `state_dims` floats.
fn frames_from(
    answer: pb::WorldModelStepResponse,
    k: usize,
    width: u32,
    height: u32,
    views: &[(String, u32, u32)],
) -> Result<Vec<WorldFrame>, String> {
    let pb::WorldModelStepResponse {
        frames,
        states,
        state_dims,
        views: view_frames,
    } = answer;
    let n = views.len();
    if view_frames.len() != k * n {
        return Err(format!(
            "{} frames of the cameras after the first for {k} actions of {n} such camera(s)",
            view_frames.len()
        ));
    }
    for (i, f) in view_frames.iter().enumerate() {
        let (name, w, h) = &views[i % n];
        if (f.width, f.height) != (*w, *h) || f.rgb.len() != rgb_bytes(*w, *h) {
            return Err(format!(
                "view {i} (camera '{name}', action {}) is {}×{} with {} bytes; the camera is {w}×{h} RGB8",
                i / n,
                f.width,
                f.height,
                f.rgb.len()
            ));
        }
    }
    let mut view_frames = view_frames.into_iter().map(|f| f.rgb);
    if frames.len() != k {
        return Err(format!("{} frames for {k} actions", frames.len()));
    }
    let bytes = rgb_bytes(width, height);
    for (i, f) in frames.iter().enumerate() {
        if (f.width, f.height) != (width, height) {
            return Err(format!(
                "frame {i} is {}×{}; the episode's frames are {width}×{height}",
                f.width, f.height
            ));
        }
        if f.rgb.len() != bytes {
            return Err(format!(
                "frame {i} has {} bytes; a {width}×{height} RGB8 frame has {bytes}",
                f.rgb.len()
            ));
        }
    }
    let states: Vec<Option<Vec<f32>>> = if states.is_empty() {
        vec![None; k]
    } else {
        let d = state_dims as usize;
        if d == 0 {
            return Err(format!(
                "{} floats of states with state_dims 0",
                states.len()
            ));
        }
        if states.len() != k * d {
            return Err(format!(
                "{} floats of states for {k} actions of {d}-float states ({})",
                states.len(),
                k * d
            ));
        }
        if let Some(i) = states.iter().position(|x| !x.is_finite()) {
            return Err(format!(
                "a non-finite state (state {}, float {})",
                i / d,
                i % d
            ));
        }
        states.chunks(d).map(|s| Some(s.to_vec())).collect()
    };
    Ok(frames
        .into_iter()
        .zip(states)
        .map(|(f, state)| WorldFrame {
            rgb: f.rgb,
            views: view_frames.by_ref().take(n).collect(),
            state,
            objects: None,
        })
        .collect())
}

/// The one place where a world-model call's gRPC status becomes a [`WorldError`], as the service
/// documents its codes, for the codes that are not retryable ([`crate::grpc::from_status`] makes
/// the retryable ones and errors of the connection itself `Unavailable`): a request the server
/// will not take (a missing token included) is `Refused`; a model that failed is `BadAnswer`.
/// `message` names the server, the call and the status.
fn from_code(code: Code, message: String) -> WorldError {
    match code {
        Code::Unauthenticated | Code::PermissionDenied => WorldError::Refused(format!(
            "{message}; the server wants the cluster's world-model token: set \
             ASSAY_CLUSTER_TOKEN or ASSAY_CLUSTER_TOKEN_FILE to the cluster's token (or \
             ASSAY_WORLD_MODEL_TOKEN[_FILE] to its world-model token)"
        )),
        Code::Unimplemented => {
            WorldError::Refused(format!("{message}; is it an assay.v1.WorldModel server?"))
        }
        Code::InvalidArgument
        | Code::FailedPrecondition
        | Code::OutOfRange
        | Code::AlreadyExists => WorldError::Refused(message),
        // Ok, Internal, DataLoss (the retryable codes never come here).
        _ => WorldError::BadAnswer(message),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::Status;

    fn from_status(what: &str, s: &Status) -> WorldError {
        crate::grpc::from_status::<Client>(what, s)
    }

    fn frame(w: u32, h: u32) -> pb::Image {
        pb::Image {
            name: String::new(),
            width: w,
            height: h,
            rgb: vec![7; rgb_bytes(w, h)],
            depth: Vec::new(),
        }
    }

    fn answer(
        frames: Vec<pb::Image>,
        states: Vec<f32>,
        state_dims: u32,
    ) -> pb::WorldModelStepResponse {
        pb::WorldModelStepResponse {
            frames,
            states,
            state_dims,
            views: Vec::new(),
        }
    }

    #[test]
    fn checks_answers() {
        let ok = frames_from(answer(vec![frame(4, 2); 2], vec![], 0), 2, 4, 2, &[]).unwrap();
        assert_eq!(ok.len(), 2);
        assert!(ok.iter().all(|f| f.rgb.len() == 24 && f.state.is_none()));
        let with_states = frames_from(
            answer(vec![frame(4, 2); 2], vec![1.0, 2.0, 3.0, 4.0], 2),
            2,
            4,
            2,
            &[],
        )
        .unwrap();
        assert_eq!(with_states[1].state, Some(vec![3.0, 4.0]));
        let bad = |a, k| frames_from(a, k, 4, 2, &[]).unwrap_err();
        assert!(bad(answer(vec![frame(4, 2)], vec![], 0), 2).contains("1 frames for 2 actions"));
        assert!(bad(answer(vec![frame(5, 2)], vec![], 0), 1).contains("5×2"));
        let mut short = frame(4, 2);
        short.rgb.pop();
        assert!(bad(answer(vec![short], vec![], 0), 1).contains("23 bytes"));
        assert!(bad(answer(vec![frame(4, 2)], vec![1.0], 0), 1).contains("state_dims 0"));
        assert!(bad(answer(vec![frame(4, 2); 2], vec![1.0; 3], 2), 2).contains("3 floats"));
        assert!(
            bad(
                answer(vec![frame(4, 2); 2], vec![1.0, 2.0, f32::NAN, 4.0], 2),
                2
            )
            .contains("state 1, float 0")
        );
        // A wrist camera of 3×3 after the first: one frame of it per action, in order.
        let wrist = [("wrist_image".to_string(), 3, 3)];
        let mut two = answer(vec![frame(4, 2); 2], vec![], 0);
        two.views = vec![
            frame(3, 3),
            pb::Image {
                rgb: vec![9; 27],
                ..frame(3, 3)
            },
        ];
        let ok = frames_from(two.clone(), 2, 4, 2, &wrist).unwrap();
        assert_eq!((ok[0].views[0][0], ok[1].views[0][0]), (7, 9));
        let e = frames_from(answer(vec![frame(4, 2); 2], vec![], 0), 2, 4, 2, &wrist).unwrap_err();
        assert!(e.contains("0 frames of the cameras after the first"), "{e}");
        two.views[1] = frame(4, 3);
        let e = frames_from(two, 2, 4, 2, &wrist).unwrap_err();
        assert!(e.contains("camera 'wrist_image', action 1"), "{e}");
    }

    #[test]
    fn status_codes_map_to_world_errors() {
        let e = from_status("Step", &Status::unauthenticated("needs the token"));
        assert!(matches!(&e, WorldError::Refused(m) if m.contains("ASSAY_CLUSTER_TOKEN")));
        assert!(matches!(
            from_status("Step", &Status::not_found("episode")),
            WorldError::Unavailable(_)
        ));
        assert!(matches!(
            from_status("Step", &Status::invalid_argument("size")),
            WorldError::Refused(_)
        ));
        assert!(matches!(
            from_status("Step", &Status::internal("raised")),
            WorldError::BadAnswer(_)
        ));
    }
}
