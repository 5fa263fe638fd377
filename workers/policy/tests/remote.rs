//! The remote policy client against the in-process reference server (port 0): a round trip, a
//! stopped server, a dead port, a silent server, a slow server and bad answers. Deadlines here are
//! short; the bounds on elapsed time only tell a hang from an answer.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_policy::{PolicyFactory, RemotePolicy, ServerInfo, serve};
use assay_proto::v1 as pb;
use tokio::runtime::Runtime;
use tokio::sync::oneshot;

/// Far longer than any deadline here: reaching it means the client hung.
const HANG: Duration = Duration::from_secs(10);

fn runtime() -> Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

/// Answers with what it saw, so the test can check every field crossed the wire: [x, y, z, step],
/// [first red, last blue, width, height], [seed, instruction length, 0, 0].
struct Echo {
    episode: Option<EpisodeContext>,
    delay: Duration,
    answer_nan: bool,
}

impl Policy for Echo {
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.episode = Some(episode.clone());
        Ok(())
    }

    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        std::thread::sleep(self.delay);
        let episode = self.episode.as_ref().expect("reset before act");
        let [x, y, z, _] = obs.proprio;
        let nan = if self.answer_nan { f32::NAN } else { 0.0 };
        Ok(vec![
            [x, y, z, obs.step as f32],
            [
                obs.rgb[0] as f32,
                obs.rgb[obs.rgb.len() - 1] as f32,
                obs.width as f32,
                obs.height as f32,
            ],
            [
                episode.seed as f32,
                episode.instruction.len() as f32,
                0.0,
                nan,
            ],
        ])
    }
}

fn echo(delay: Duration, answer_nan: bool) -> PolicyFactory {
    Arc::new(move || {
        Ok(Box::new(Echo {
            episode: None,
            delay,
            answer_nan,
        }) as Box<dyn Policy>)
    })
}

fn info() -> ServerInfo {
    ServerInfo {
        name: "echo".into(),
        version: "1".into(),
        image_width: 64,
        image_height: 64,
        chunk_size: 3,
        ..ServerInfo::default()
    }
}

struct Server {
    url: String,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
}

impl Server {
    fn start(rt: &Runtime, factory: PolicyFactory) -> Server {
        Self::start_with(rt, factory, None)
    }

    fn start_with(
        rt: &Runtime,
        factory: PolicyFactory,
        token: Option<assay_proto::auth::Token>,
    ) -> Server {
        let listener = rt
            .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let (stop, stopped) = oneshot::channel();
        let task = rt.spawn(serve(listener, factory, info(), token, async {
            let _ = stopped.await;
        }));
        Server {
            url: format!("http://{addr}"),
            stop: Some(stop),
            task,
        }
    }

    fn stop(mut self, rt: &Runtime) {
        let _ = self.stop.take().expect("running").send(());
        rt.block_on(async { tokio::time::timeout(HANG, self.task).await })
            .expect("the server stops")
            .expect("server task")
            .expect("server");
    }
}

fn episode() -> EpisodeContext {
    EpisodeContext {
        task_id: "pick-red-cube".into(),
        seed: 7,
        instruction: "pick up the red cube".into(),
        arm: None,
    }
}

fn observation(step: u32) -> PolicyObservation {
    let mut rgb = vec![128u8; 64 * 64 * 3];
    rgb[0] = 200;
    *rgb.last_mut().unwrap() = 9;
    PolicyObservation::legacy(step, 64, 64, rgb, [0.1, -0.2, 0.3, 1.0])
}

fn unavailable(e: PolicyError) -> String {
    match e {
        PolicyError::Unavailable(m) => m,
        other => panic!("expected Unavailable, got {other:?}"),
    }
}

#[test]
fn round_trip_of_reset_and_act() {
    let rt = runtime();
    let server = Server::start(&rt, echo(Duration::ZERO, false));
    let mut policy =
        RemotePolicy::connect(&server.url, Duration::from_secs(5), rt.handle().clone()).unwrap();
    assert_eq!(policy.info(), &info());
    policy.reset(&episode()).unwrap();
    for step in [0, 3] {
        let chunk = policy.act(&observation(step)).unwrap();
        assert_eq!(
            chunk,
            vec![
                [0.1, -0.2, 0.3, step as f32],
                [200.0, 9.0, 64.0, 64.0],
                [7.0, 20.0, 0.0, 0.0]
            ]
        );
    }
    assert_eq!(policy.health().unwrap().live_episodes, 1);
    // A new episode ends the previous one.
    policy.reset(&episode()).unwrap();
    assert_eq!(policy.health().unwrap().live_episodes, 1);
    // Dropping the client ends its episode on the server.
    drop(policy);
    let other =
        RemotePolicy::connect(&server.url, Duration::from_secs(5), rt.handle().clone()).unwrap();
    assert_eq!(other.health().unwrap().live_episodes, 0);
    // A frame of another size than the server expects is refused before it is sent.
    let mut other = other;
    other.reset(&episode()).unwrap();
    let mut small = observation(0);
    small.width = 32;
    assert!(matches!(other.act(&small), Err(PolicyError::Load(m)) if m.contains("64×64")));
    drop(other);
    server.stop(&rt);
}

#[test]
fn a_stopped_server_is_unavailable_within_the_deadline() {
    let rt = runtime();
    let server = Server::start(&rt, echo(Duration::ZERO, false));
    let timeout = Duration::from_millis(500);
    let mut policy = RemotePolicy::connect(&server.url, timeout, rt.handle().clone()).unwrap();
    policy.reset(&episode()).unwrap();
    policy.act(&observation(0)).unwrap();
    let url = server.url.clone();
    server.stop(&rt);
    let start = Instant::now();
    let e = policy.act(&observation(1)).unwrap_err();
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    assert!(e.retryable());
    let m = unavailable(e);
    assert!(m.contains(&url) && m.contains("step 1"), "{m}");
}

#[test]
fn a_dead_port_is_unavailable_at_once() {
    let rt = runtime();
    let addr: SocketAddr = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    }; // closed again: nothing listens there
    let url = format!("http://{addr}");
    let start = Instant::now();
    let e = RemotePolicy::connect(&url, Duration::from_secs(5), rt.handle().clone()).unwrap_err();
    assert!(start.elapsed() < HANG);
    let m = unavailable(e);
    assert!(
        m.contains(&format!("policy server at {url} is down")),
        "{m}"
    );
}

#[test]
fn a_silent_server_cannot_hang_the_client() {
    let rt = runtime();
    // Accepts connections and never says a word.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let holder = std::thread::spawn(move || {
        let mut held = vec![];
        for conn in listener.incoming().take(1) {
            held.push(conn);
            std::thread::sleep(Duration::from_secs(2));
        }
    });
    let start = Instant::now();
    let e =
        RemotePolicy::connect(&url, Duration::from_millis(300), rt.handle().clone()).unwrap_err();
    assert!(start.elapsed() < HANG);
    let m = unavailable(e);
    assert!(
        m.contains(&format!("policy server at {url} is down")),
        "{m}"
    );
    holder.join().unwrap();
}

#[test]
fn a_slow_server_misses_the_deadline() {
    let rt = runtime();
    let server = Server::start(&rt, echo(Duration::from_millis(1500), false));
    let timeout = Duration::from_millis(200);
    let mut policy = RemotePolicy::connect(&server.url, timeout, rt.handle().clone()).unwrap();
    policy.reset(&episode()).unwrap();
    let start = Instant::now();
    let m = unavailable(policy.act(&observation(4)).unwrap_err());
    assert!(
        start.elapsed() < Duration::from_millis(1500),
        "waited for the slow answer"
    );
    assert!(m.contains("200 ms deadline") && m.contains("step 4"), "{m}");
    drop(policy);
    server.stop(&rt);
}

#[test]
fn a_policy_that_answers_nan_is_a_bad_answer() {
    let rt = runtime();
    let server = Server::start(&rt, echo(Duration::ZERO, true));
    let mut policy =
        RemotePolicy::connect(&server.url, Duration::from_secs(5), rt.handle().clone()).unwrap();
    policy.reset(&episode()).unwrap();
    let e = policy.act(&observation(0)).unwrap_err();
    assert!(
        matches!(&e, PolicyError::BadAnswer(m) if m.contains("non-finite")),
        "{e:?}"
    );
    assert!(!e.retryable());
    drop(policy);
    server.stop(&rt);
}

/// A server written against the proto directly, answering Act with `floats` floats.
struct RawServer {
    floats: usize,
}

#[tonic::async_trait]
impl pb::policy_server::Policy for RawServer {
    async fn health(
        &self,
        _: tonic::Request<pb::PolicyHealthRequest>,
    ) -> Result<tonic::Response<pb::PolicyHealthResponse>, tonic::Status> {
        Ok(tonic::Response::new(pb::PolicyHealthResponse {
            name: "raw".into(),
            action_dims: 4,
            proprio_dims: 4,
            ..Default::default()
        }))
    }
    async fn reset(
        &self,
        _: tonic::Request<pb::PolicyResetRequest>,
    ) -> Result<tonic::Response<pb::PolicyResetResponse>, tonic::Status> {
        Ok(tonic::Response::new(pb::PolicyResetResponse {}))
    }
    async fn act(
        &self,
        _: tonic::Request<pb::PolicyActRequest>,
    ) -> Result<tonic::Response<pb::PolicyActResponse>, tonic::Status> {
        Ok(tonic::Response::new(pb::PolicyActResponse {
            actions: vec![0.5; self.floats],
            action_dims: 4,
        }))
    }
    async fn end(
        &self,
        _: tonic::Request<pb::PolicyEndRequest>,
    ) -> Result<tonic::Response<pb::PolicyEndResponse>, tonic::Status> {
        Ok(tonic::Response::new(pb::PolicyEndResponse {}))
    }
}

#[test]
fn three_floats_are_a_bad_answer() {
    let rt = runtime();
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    rt.spawn(
        tonic::transport::Server::builder()
            .add_service(pb::policy_server::PolicyServer::new(RawServer {
                floats: 3,
            }))
            .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
    );
    let mut policy =
        RemotePolicy::connect(&url, Duration::from_secs(5), rt.handle().clone()).unwrap();
    policy.reset(&episode()).unwrap();
    match policy.act(&observation(2)) {
        Err(PolicyError::BadAnswer(m)) => {
            assert!(m.contains("3 floats") && m.contains("step 2"), "{m}")
        }
        other => panic!("expected BadAnswer, got {other:?}"),
    }
}

#[test]
fn unknown_episodes_are_not_found_and_retryable() {
    let rt = runtime();
    let server = Server::start(&rt, echo(Duration::ZERO, false));
    let channel = rt
        .block_on(assay_proto::channel::connect(
            "policy server",
            &server.url,
            &Default::default(),
        ))
        .unwrap();
    let mut client = pb::policy_client::PolicyClient::new(channel);
    let status = rt
        .block_on(client.act(pb::PolicyActRequest {
            episode_id: "never-reset".into(),
            width: 64,
            height: 64,
            rgb: vec![0; 64 * 64 * 3],
            proprio: vec![0.0; 4],
            ..Default::default()
        }))
        .unwrap_err();
    assert_eq!(status.code(), tonic::Code::NotFound);
    // Ending an unknown episode is fine (it may have been evicted).
    rt.block_on(client.end(pb::PolicyEndRequest {
        episode_id: "never-reset".into(),
    }))
    .unwrap();
    drop(client);
    server.stop(&rt);
}

#[test]
fn a_server_can_relay_a_remote_policy() {
    // The relay's policies are remote clients made on the server's blocking pool, which block on
    // the same runtime: what `assay policy serve --policy remote:url=…` does.
    let rt = runtime();
    let upstream = Server::start(&rt, echo(Duration::ZERO, false));
    let spec = assay_model::policy::PolicySpec::Remote {
        url: upstream.url.clone(),
        timeout_ms: 5000,
        interface: None,
    };
    let factory =
        assay_policy::factory(&spec, std::path::Path::new("."), rt.handle(), None).unwrap();
    let relay = Server::start(&rt, factory);
    let mut policy =
        RemotePolicy::connect(&relay.url, Duration::from_secs(5), rt.handle().clone()).unwrap();
    policy.reset(&episode()).unwrap();
    assert_eq!(
        policy.act(&observation(2)).unwrap()[0],
        [0.1, -0.2, 0.3, 2.0]
    );
    drop(policy);
    relay.stop(&rt);
    upstream.stop(&rt);
}

/// A policy server with the cluster's policy token answers only clients that present it; the
/// refusal is a `Load` error (not retried) that says what is missing.
#[test]
fn a_server_with_a_token_refuses_clients_without_it() {
    use assay_proto::auth::Token;
    let rt = runtime();
    let cluster = Token::new("cluster-token-for-the-policy-test").unwrap();
    let server = Server::start_with(
        &rt,
        echo(Duration::ZERO, false),
        Some(cluster.for_service("policy")),
    );
    let timeout = Duration::from_secs(5);
    for (who, token) in [
        ("no token", None),
        ("the coordinator's token itself", Some(cluster.clone())),
        (
            "another cluster's",
            Some(
                Token::new("another-cluster-token-entirely")
                    .unwrap()
                    .for_service("policy"),
            ),
        ),
    ] {
        match RemotePolicy::connect_with(&server.url, timeout, rt.handle().clone(), token) {
            Err(PolicyError::Load(m)) => {
                assert!(m.contains("Unauthenticated"), "{who}: {m}");
                assert!(m.contains("cluster token"), "{who}: {m}");
            }
            other => panic!("{who}: expected a Load error, got {other:?}"),
        }
    }
    let mut policy = RemotePolicy::connect_with(
        &server.url,
        timeout,
        rt.handle().clone(),
        Some(cluster.for_service("policy")),
    )
    .unwrap();
    policy.reset(&episode()).unwrap();
    assert_eq!(policy.act(&observation(0)).unwrap().len(), 3);
    drop(policy);
    server.stop(&rt);
}
