//! The world-model client against the Python kit's server (`serve_world_model`) over real gRPC on
//! loopback, serving `tests/python/world_models/trivial.py`: imagined frames follow the actions,
//! episodes do not share state and are ended when dropped; a dead server and a sleeping one are
//! unavailable, malformed answers are bad answers, requests the server declared it does not take
//! are refused before they are sent, and the cluster token is required and accepted.
//!
//! The Python is `$ASSAY_TEST_PYTHON` (scripts/test's venv), by default
//! `$HOME/.cache/assay/test-venv/bin/python`. Deadlines here are short; the bounds on elapsed time
//! only tell a hang from an answer.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use assay_model::world::{WorldError, WorldFrame, WorldModelService, WorldStart};
use assay_policy::world_model::{self, RemoteWorldModel, TOKEN_PURPOSE};
use assay_proto::auth::Token;
use tokio::runtime::Runtime;

/// Far longer than any deadline here: reaching it means the client hung.
const HANG: Duration = Duration::from_secs(10);
const TIMEOUT: Duration = Duration::from_secs(5);
const TOKEN: &str = "world-model-test-token-0123456789";
const W: u32 = 16;
const H: u32 = 12;

fn runtime() -> Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

fn python() -> String {
    std::env::var("ASSAY_TEST_PYTHON").unwrap_or_else(|_| {
        let home = std::env::var("HOME").unwrap_or_default();
        format!("{home}/.cache/assay/test-venv/bin/python")
    })
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A Python world-model server that is killed with the test.
struct Served {
    child: Child,
    url: String,
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `tests/python/world_models/trivial.py ARGS --port 0`, with the cluster token `token` (and no
/// other): waits for its `listening on URL` line.
fn serve(args: &[&str], token: Option<&str>) -> Served {
    let log = tempfile::NamedTempFile::new().unwrap();
    let mut command = Command::new(python());
    command
        .arg(repo().join("tests/python/world_models/trivial.py"))
        .args(args)
        .args(["--port", "0"])
        .env_remove("ASSAY_CLUSTER_TOKEN")
        .env_remove("ASSAY_CLUSTER_TOKEN_FILE")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log.reopen().unwrap());
    if let Some(t) = token {
        command.env("ASSAY_CLUSTER_TOKEN", t);
    }
    let mut child = command.spawn().unwrap_or_else(|e| {
        panic!(
            "cannot run {} ({e}): set ASSAY_TEST_PYTHON to a Python with \
             tests/python/requirements.txt (scripts/test makes one)",
            python()
        )
    });
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    match first.trim().strip_prefix("listening on ") {
        Some(url) => Served {
            url: url.to_owned(),
            child,
        },
        None => {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "trivial.py {args:?}: {first:?}\n{}\n(set ASSAY_TEST_PYTHON to a Python with \
                 tests/python/requirements.txt; scripts/test makes one)",
                std::fs::read_to_string(log.path()).unwrap_or_default()
            );
        }
    }
}

fn connect(rt: &Runtime, url: &str, timeout: Duration) -> RemoteWorldModel {
    RemoteWorldModel::connect_with(url, timeout, rt.handle().clone(), None)
        .unwrap_or_else(|e| panic!("connect to {url}: {e}"))
}

fn start(width: u32, height: u32) -> WorldStart {
    WorldStart {
        task_id: "pick-red-cube".into(),
        seed: 3,
        instruction: "put the red block in the green zone".into(),
        width,
        height,
        rgb: (0..width * height * 3).map(|i| (i % 200) as u8).collect(),
        state: vec![0.5, 0.0, 0.1, 0.0],
        interface: Default::default(),
        views: Vec::new(),
        objects: Vec::new(),
    }
}

fn rgb(frames: &[WorldFrame]) -> Vec<&[u8]> {
    frames.iter().map(|f| f.rgb.as_slice()).collect()
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len(), "{got:?} vs {want:?}");
    assert!(
        got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-5),
        "{got:?} vs {want:?}"
    );
}

const RIGHT: [[f32; 4]; 3] = [
    [1.0, 0.0, 0.0, 1.0],
    [0.0, 1.0, 0.0, 1.0],
    [0.5, 0.5, 0.2, 0.0],
];
const LEFT: [[f32; 4]; 3] = [[-1.0, 0.0, 0.0, 0.0]; 3];

fn chunk(actions: &[[f32; 4]]) -> Vec<Vec<f32>> {
    actions.iter().map(|a| a.to_vec()).collect()
}

#[test]
fn imagined_frames_follow_the_actions_and_episodes_are_ended_when_dropped() {
    let rt = runtime();
    let server = serve(&["--variant", "ok"], None);
    let model = connect(&rt, &server.url, TIMEOUT);
    let name = model.name();
    assert!(
        name.contains("trivial-ok") && name.contains(&server.url),
        "{name}"
    );
    assert_eq!(model.info().frame_size, None);
    assert_eq!(model.info().action_dims, None);

    let s = start(W, H);
    let mut right = model.reset(&s).unwrap();
    let frames = right.step(&chunk(&RIGHT)).unwrap();
    assert_eq!(frames.len(), 3);
    for f in &frames {
        assert_eq!(f.rgb.len(), (W * H * 3) as usize);
        assert_ne!(f.rgb, s.rgb, "the square is drawn on the first frame");
    }
    // state + 0.1 · action[:3], holding = action[3] ≥ 0.5
    let states: Vec<&[f32]> = frames.iter().map(|f| f.state.as_deref().unwrap()).collect();
    assert_close(states[0], &[0.6, 0.0, 0.1, 1.0]);
    assert_close(states[1], &[0.6, 0.1, 0.1, 1.0]);
    assert_close(states[2], &[0.65, 0.15, 0.12, 0.0]);
    assert_ne!(frames[0].rgb, frames[1].rgb);

    // Other actions from the same start, in an episode live at the same time: other frames; the
    // same actions again: the same frames.
    let mut left = model.reset(&s).unwrap();
    let other = left.step(&chunk(&LEFT)).unwrap();
    assert_eq!(other.len(), 3);
    assert_ne!(rgb(&other), rgb(&frames));
    let mut again = model.reset(&s).unwrap();
    assert_eq!(again.step(&chunk(&RIGHT)).unwrap(), frames);
    assert_eq!(model.health().unwrap().live_episodes, 3);

    // An episode goes on from where its last chunk left it; an empty chunk asks nothing.
    let next = right.step(&chunk(&[[0.0, 0.0, 0.1, 1.0]])).unwrap();
    assert_eq!(next.len(), 1);
    assert_close(next[0].state.as_deref().unwrap(), &[0.65, 0.15, 0.13, 1.0]);
    assert!(right.step(&[]).unwrap().is_empty());

    drop((right, left, again));
    assert_eq!(model.health().unwrap().live_episodes, 0, "End was sent");
}

#[test]
fn a_model_without_states_answers_frames_alone() {
    let rt = runtime();
    let server = serve(&["--variant", "frames_only"], None);
    let model = connect(&rt, &server.url, TIMEOUT);
    let mut episode = model.reset(&start(W, H)).unwrap();
    let frames = episode.step(&chunk(&RIGHT)).unwrap();
    assert_eq!(frames.len(), 3);
    assert!(frames.iter().all(|f| f.state.is_none()));
}

#[test]
fn a_dead_server_is_unavailable_naming_its_url() {
    let rt = runtime();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let url = format!("http://127.0.0.1:{port}");
    let t0 = Instant::now();
    let err = world_model::connect(&url, 2000, rt.handle())
        .map(|m| m.name())
        .unwrap_err();
    assert!(t0.elapsed() < HANG);
    assert!(
        matches!(&err, WorldError::Unavailable(m) if m.contains(&url) && m.contains("down")),
        "{err}"
    );
}

#[test]
fn a_sleeping_server_is_unavailable_after_the_deadline() {
    let rt = runtime();
    let server = serve(&["--variant", "sleep", "--sleep-s", "30"], None);
    let model = connect(&rt, &server.url, Duration::from_millis(1500));
    let mut episode = model.reset(&start(W, H)).unwrap();
    let t0 = Instant::now();
    let err = episode.step(&chunk(&RIGHT)).unwrap_err();
    let waited = t0.elapsed();
    assert!(
        waited >= Duration::from_millis(1000) && waited < HANG,
        "{waited:?}"
    );
    assert!(
        matches!(&err, WorldError::Unavailable(m)
            if m.contains(&server.url) && m.contains("Step of 3 actions") && m.contains("1500 ms")),
        "{err}"
    );
}

#[test]
fn malformed_answers_are_bad_answers() {
    let rt = runtime();
    let cases = [
        (
            "wrong_size",
            "frame 0 is 17×12; the episode's frames are 16×12",
        ),
        ("too_few", "2 frames for 3 actions"),
        ("nan_state", "non-finite state (state 0, float 0)"),
        ("raises", "world model exploded"),
    ];
    // Started together: each pays Python's start-up once.
    let servers: Vec<Served> = cases
        .iter()
        .map(|(variant, _)| serve(&["--variant", variant], None))
        .collect();
    for ((variant, want), server) in cases.iter().zip(&servers) {
        let model = connect(&rt, &server.url, TIMEOUT);
        let mut episode = model.reset(&start(W, H)).unwrap();
        let err = episode.step(&chunk(&RIGHT)).unwrap_err();
        assert!(
            matches!(&err, WorldError::BadAnswer(m) if m.contains(want) && m.contains(&server.url)),
            "{variant}: {err}"
        );
    }
}

#[test]
fn requests_the_server_does_not_take_are_refused_before_they_are_sent() {
    let rt = runtime();
    let server = serve(&["--size", "32x24", "--action-dims", "4"], None);
    let model = connect(&rt, &server.url, TIMEOUT);
    assert_eq!(model.info().frame_size, Some((32, 24)));
    assert_eq!(model.info().action_dims, Some(4));
    let refused = |r: Result<(), WorldError>, want: &str| match r {
        Err(WorldError::Refused(m)) => assert!(m.contains(want), "{m}"),
        Err(e) => panic!("expected a refusal with {want:?}: {e}"),
        Ok(_) => panic!("expected a refusal with {want:?}"),
    };
    refused(
        model.reset(&start(W, H)).map(drop),
        "the model works at 32×24",
    );
    let mut bad = start(32, 24);
    bad.rgb.pop();
    refused(model.reset(&bad).map(drop), "2303 bytes");

    let mut episode = model.reset(&start(32, 24)).unwrap();
    refused(
        episode.step(&[vec![0.0; 3]]).map(drop),
        "3-float actions: it takes 4",
    );
    refused(
        episode
            .step(&[vec![0.0; 4], vec![0.0; 4], vec![0.0; 5]])
            .map(drop),
        "action 2 has 5",
    );
    refused(
        episode
            .step(&[vec![0.0; 4], vec![f32::NAN, 0.0, 0.0, 0.0]])
            .map(drop),
        "non-finite action (action 1",
    );
    // Nothing was sent: the episode is where it started.
    let frames = episode.step(&chunk(&RIGHT[..1])).unwrap();
    assert_close(frames[0].state.as_deref().unwrap(), &[0.6, 0.0, 0.1, 1.0]);
}

#[test]
fn the_cluster_token_is_required_and_accepted() {
    let rt = runtime();
    let server = serve(&[], Some(TOKEN));
    let connect_with = |token: Option<Token>| {
        RemoteWorldModel::connect_with(&server.url, TIMEOUT, rt.handle().clone(), token)
    };
    let token = Token::new(TOKEN).unwrap();
    for (what, presented) in [
        ("no token", None),
        ("the policy secret", Some(token.for_service("policy"))),
        ("the cluster token itself", Some(token.clone())),
    ] {
        match connect_with(presented) {
            Err(WorldError::Refused(m)) => assert!(
                m.contains(&server.url)
                    && m.contains("Unauthenticated")
                    && m.contains("ASSAY_CLUSTER_TOKEN"),
                "{what}: {m}"
            ),
            Err(e) => panic!("{what}: expected a refusal, got {e}"),
            Ok(_) => panic!("{what}: accepted"),
        }
    }
    let model = connect_with(Some(token.for_service(TOKEN_PURPOSE))).unwrap();
    let mut episode = model.reset(&start(W, H)).unwrap();
    assert_eq!(episode.step(&chunk(&RIGHT)).unwrap().len(), 3);
}
