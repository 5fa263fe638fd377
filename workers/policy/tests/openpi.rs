//! Assay's openpi client against small servers on loopback: one connection per episode with the
//! metadata first, a server's error text is a bad answer, a down or silent server is unavailable
//! (retryable), and the API key goes in openpi's header. (The real `openpi-client` package's
//! msgpack-numpy is checked end to end in `tests/it/real_policies.rs`.)

mod common;

use std::net::TcpListener;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use assay_model::policy::{EpisodeContext, Interface, Policy, PolicyError, PolicyObservation};
use assay_policy::openpi::OpenPiPolicy;
use rmpv::Value;
use tungstenite::Message;

fn context() -> EpisodeContext {
    EpisodeContext {
        task_id: "t".into(),
        seed: 0,
        instruction: "put the red block in the green zone".into(),
        arm: None,
    }
}

fn observation() -> PolicyObservation {
    PolicyObservation::legacy(0, 4, 2, vec![7; 4 * 2 * 3], [0.1, 0.2, 0.3, 0.0])
}

fn packed(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, v).unwrap();
    out
}

fn field<'v>(map: &'v Value, key: &str) -> &'v Value {
    let Value::Map(m) = map else {
        panic!("not a map: {map}")
    };
    &m.iter()
        .find(|(k, _)| k.as_str() == Some(key) || k.as_slice() == Some(key.as_bytes()))
        .unwrap_or_else(|| panic!("no {key} in {map}"))
        .1
}

/// What the server saw: per connection, its Authorization header and the messages.
#[derive(Default)]
struct Seen {
    connections: Vec<(Option<String>, Vec<Value>)>,
}

/// A server that answers `answer(observation)` (None: an error text) on each connection.
fn server(answer: fn(&Value) -> Option<Value>) -> (String, Arc<Mutex<Seen>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("ws://{}", listener.local_addr().unwrap());
    let seen = Arc::new(Mutex::new(Seen::default()));
    let log = seen.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { return };
            let log = log.clone();
            std::thread::spawn(move || {
                let (mut ws, auth) = common::accept_with_auth(stream);
                let index = {
                    let mut s = log.lock().unwrap();
                    s.connections.push((auth, Vec::new()));
                    s.connections.len() - 1
                };
                let metadata = Value::Map(vec![(Value::from("server"), Value::from("test"))]);
                ws.send(Message::Binary(packed(&metadata).into())).unwrap();
                while let Ok(msg) = ws.read() {
                    let Message::Binary(b) = msg else { continue };
                    let obs = rmpv::decode::read_value(&mut &b[..]).unwrap();
                    log.lock().unwrap().connections[index].1.push(obs.clone());
                    match answer(&obs) {
                        Some(a) => ws.send(Message::Binary(packed(&a).into())).unwrap(),
                        None => {
                            let _ = ws.send(Message::Text(
                                "Traceback (most recent call last):\n  ...\nValueError: no".into(),
                            ));
                            let _ = ws.close(None);
                        }
                    }
                }
            });
        }
    });
    (url, seen)
}

fn float_array(values: &[f32], shape: &[u64]) -> Value {
    Value::Map(vec![
        (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
        (
            Value::Binary(b"data".to_vec()),
            Value::Binary(values.iter().flat_map(|x| x.to_le_bytes()).collect()),
        ),
        (Value::Binary(b"dtype".to_vec()), Value::from("<f4")),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&d| Value::from(d)).collect()),
        ),
    ])
}

#[test]
fn each_episode_is_a_connection_that_sends_the_observation_and_reads_the_chunk() {
    let (url, seen) = server(|_| {
        Some(Value::Map(vec![(
            Value::from("actions"),
            float_array(&[0.5, 0.0, -0.5, 1.0, 0.0, 0.0, 0.0, 0.0], &[2, 4]),
        )]))
    });
    // The key comes from a variable of the worker's environment (cargo sets this one for tests).
    let key = std::env::var("CARGO_PKG_NAME").unwrap();
    let mut p = OpenPiPolicy::new(
        &url,
        Duration::from_secs(5),
        Some("CARGO_PKG_NAME"),
        Interface::default(),
    )
    .unwrap();
    assert_eq!(field(&p.metadata, "server").as_str(), Some("test"));
    for _ in 0..2 {
        p.reset(&context()).unwrap();
        let chunk = p.act_any(&observation()).unwrap();
        assert_eq!(chunk, vec![vec![0.5, 0.0, -0.5, 1.0], vec![0.0; 4]]);
    }
    let s = seen.lock().unwrap();
    // The first episode used the connection opened at load, the second a fresh one.
    assert_eq!(s.connections.len(), 2);
    for (auth, messages) in &s.connections {
        assert_eq!(auth.clone(), Some(format!("Api-Key {key}")));
        assert_eq!(messages.len(), 1);
        let obs = &messages[0];
        assert_eq!(
            field(obs, "prompt").as_str(),
            Some("put the red block in the green zone")
        );
        let image = field(obs, "observation/image");
        assert_eq!(field(image, "dtype").as_str(), Some("|u1"));
        assert_eq!(
            field(image, "shape"),
            &Value::Array(vec![
                Value::from(2u64),
                Value::from(4u64),
                Value::from(3u64)
            ])
        );
        let state = field(obs, "observation/state");
        assert_eq!(field(state, "data").as_slice().unwrap().len(), 16);
    }
}

#[test]
fn an_error_text_is_a_bad_answer_and_a_missing_key_variable_a_load_error() {
    let (url, _) = server(|_| None);
    let mut p =
        OpenPiPolicy::new(&url, Duration::from_secs(5), None, Interface::default()).unwrap();
    p.reset(&context()).unwrap();
    let e = p.act_any(&observation()).unwrap_err();
    assert!(matches!(e, PolicyError::BadAnswer(_)), "{e:?}");
    assert!(e.to_string().contains("ValueError: no"), "{e}");
    let e = OpenPiPolicy::new(
        &url,
        Duration::from_secs(5),
        Some("ASSAY_TEST_NO_SUCH_VARIABLE"),
        Interface::default(),
    )
    .unwrap_err();
    assert!(matches!(e, PolicyError::Load(_)) && e.to_string().contains("is not set"));
}

#[test]
fn a_down_or_silent_server_is_unavailable_within_the_deadline() {
    // Nothing listens on a port just freed.
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let e = OpenPiPolicy::new(
        &format!("ws://127.0.0.1:{port}"),
        Duration::from_secs(2),
        None,
        Interface::default(),
    )
    .unwrap_err();
    assert!(e.retryable(), "{e:?}");
    // A server that accepts connections and never says anything.
    let silent = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("ws://{}", silent.local_addr().unwrap());
    let start = Instant::now();
    let e = OpenPiPolicy::new(&url, Duration::from_millis(300), None, Interface::default())
        .unwrap_err();
    assert!(e.retryable(), "{e:?}");
    assert!(
        start.elapsed() < Duration::from_secs(5),
        "{:?}",
        start.elapsed()
    );
    drop(silent);
}
