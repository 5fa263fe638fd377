//! The OpenAI-compatible client against the local fixture server: real HTTP over loopback.

use std::sync::Arc;
use std::time::{Duration, Instant};

use assay_openai::{CallError, ChatRequest, Endpoint, EndpointConfig};
use assay_testkit::fixture::{self, Fixture, Received, Reply};
use base64::Engine as _;
use serde_json::json;

/// Small fake PNGs: the client sends bytes as they are, so only the signature is real.
fn png(tag: u8, len: usize) -> Vec<u8> {
    let mut bytes = vec![0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];
    bytes.extend((0..len).map(|i| tag.wrapping_add(i as u8)));
    bytes
}

fn request(images: Vec<Vec<u8>>) -> ChatRequest {
    ChatRequest {
        prompt_version: "scene-alignment@3".to_owned(),
        system: Some("You are a strict judge.".to_owned()),
        text: "Rate the scene from 0 to 10.".to_owned(),
        images,
    }
}

fn config(fx: &Fixture) -> EndpointConfig {
    let mut cfg = EndpointConfig::new(fx.base_url(), "fixture-vlm");
    cfg.timeout_s = 10.0;
    cfg
}

fn endpoint(cfg: EndpointConfig) -> Endpoint {
    Endpoint::new(cfg).expect("endpoint")
}

fn decode_data_url(url: &str) -> Vec<u8> {
    let b64 = url
        .strip_prefix("data:image/png;base64,")
        .unwrap_or_else(|| panic!("not a PNG data URL: {url:.40}"));
    base64::engine::general_purpose::STANDARD
        .decode(b64)
        .expect("base64")
}

#[tokio::test]
async fn request_carries_images_model_parameters_and_prompt_version() {
    let fx = Fixture::start(fixture::constant(Reply::Answer {
        text: "Score: 6".into(),
        tokens_in: 1234,
        tokens_out: 5,
    }))
    .unwrap();
    let mut cfg = config(&fx);
    cfg.temperature = 0.3;
    cfg.max_tokens = 77;
    cfg.image_detail = "low".into();
    let images: Vec<Vec<u8>> = (0..3).map(|i| png(i * 50, 1000 + i as usize)).collect();

    let answer = endpoint(cfg).chat(&request(images.clone())).await.unwrap();
    assert_eq!(answer.text, "Score: 6");
    assert_eq!((answer.tokens_in, answer.tokens_out), (1234, 5));

    let got = fx.received();
    assert_eq!(got.len(), 1);
    let r = &got[0];
    assert_eq!(r.n, 0);
    assert_eq!(
        (r.method.as_str(), r.path.as_str()),
        ("POST", "/v1/chat/completions")
    );
    assert_eq!(r.model, "fixture-vlm");
    assert_eq!(r.prompt_version.as_deref(), Some("scene-alignment@3"));
    assert_eq!(r.header("content-type"), Some("application/json"));
    assert_eq!(r.authorization, None, "no key configured, no Authorization");
    assert_eq!(r.images, 3);
    assert_eq!(r.body["temperature"], json!(0.3));
    assert_eq!(r.body["max_tokens"], json!(77));
    assert_eq!(
        r.body["messages"][0],
        json!({"role": "system", "content": "You are a strict judge."})
    );
    let user = &r.body["messages"][1];
    assert_eq!(user["role"], "user");
    assert_eq!(
        user["content"][0],
        json!({"type": "text", "text": "Rate the scene from 0 to 10."})
    );
    assert_eq!(
        r.text,
        "You are a strict judge.\nRate the scene from 0 to 10."
    );
    for part in user["content"].as_array().unwrap()[1..].iter() {
        assert_eq!(part["image_url"]["detail"], "low");
    }
    let sent: Vec<Vec<u8>> = r.image_urls().iter().map(|u| decode_data_url(u)).collect();
    assert_eq!(sent, images);
}

/// The variable the child test reads; unique to this test.
const KEY_VAR: &str = "ASSAY_JUDGE_TEST_OPENAI_KEY_5C1E";
const KEY: &str = "sk-assay-fixture-0123456789";

/// Runs [`bearer_key_child`] in a child process with the key in its environment: setting a
/// variable in this multi-threaded process would race with every other test reading it.
#[test]
fn bearer_key_comes_from_the_named_env_var() {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "bearer_key_child",
            "--exact",
            "--ignored",
            "--test-threads=1",
        ])
        .env(KEY_VAR, KEY)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "child failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("1 passed"),
        "the child test did not run:\n{stdout}"
    );
}

#[test]
#[ignore = "run by bearer_key_comes_from_the_named_env_var with the key set"]
fn bearer_key_child() {
    assert_eq!(std::env::var(KEY_VAR).as_deref(), Ok(KEY));
    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let mut cfg = config(&fx);
    cfg.api_key_env = Some(KEY_VAR.to_owned());
    let ep = endpoint(cfg);
    // From synchronous code: a runtime of our own, separate from the fixture's.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(ep.chat(&request(vec![png(1, 10)]))).unwrap();
    assert_eq!(
        fx.received()[0].authorization.as_deref(),
        Some(format!("Bearer {KEY}").as_str())
    );
    assert!(!format!("{ep:?}").contains(KEY));
}

#[test]
fn missing_key_variable_is_a_config_error_naming_it() {
    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let mut cfg = config(&fx);
    cfg.api_key_env = Some("ASSAY_JUDGE_TEST_KEY_NEVER_SET_91D2".to_owned());
    let err = Endpoint::new(cfg).unwrap_err();
    assert!(matches!(err, CallError::Config(_)), "{err:?}");
    assert!(
        err.to_string()
            .contains("ASSAY_JUDGE_TEST_KEY_NEVER_SET_91D2"),
        "{err}"
    );
    assert_eq!(fx.count(), 0);
}

#[tokio::test]
async fn too_many_requests_carries_retry_after() {
    let fx = Fixture::start(fixture::constant(Reply::Status {
        code: 429,
        retry_after: Some("1".into()),
        body: r#"{"error":{"message":"Rate limit reached","type":"requests"}}"#.into(),
    }))
    .unwrap();
    let err = endpoint(config(&fx))
        .chat(&request(vec![]))
        .await
        .unwrap_err();
    match &err {
        CallError::Status {
            code,
            retry_after,
            body,
        } => {
            assert_eq!(*code, 429);
            assert_eq!(*retry_after, Some(Duration::from_secs(1)));
            assert!(body.contains("Rate limit reached"), "{body}");
        }
        other => panic!("expected a 429, got {other:?}"),
    }
    assert!(err.retryable());
    assert_eq!(err.retry_after(), Some(Duration::from_secs(1)));
}

#[tokio::test]
async fn server_errors_retry_and_client_errors_do_not() {
    let fx = Fixture::start(Arc::new(|r: &Received| Reply::Status {
        code: if r.n == 0 { 500 } else { 400 },
        retry_after: None,
        body: "nope".into(),
    }))
    .unwrap();
    let ep = endpoint(config(&fx));

    let err = ep.chat(&request(vec![])).await.unwrap_err();
    assert!(
        matches!(
            err,
            CallError::Status {
                code: 500,
                retry_after: None,
                ..
            }
        ),
        "{err:?}"
    );
    assert!(err.retryable());

    let err = ep.chat(&request(vec![])).await.unwrap_err();
    assert!(
        matches!(err, CallError::Status { code: 400, .. }),
        "{err:?}"
    );
    assert!(!err.retryable());
    assert_eq!(err.retry_after(), None);
}

#[tokio::test]
async fn slow_answer_times_out_promptly() {
    let fx = Fixture::start(fixture::constant(Reply::text("Score: 1").after(30.0))).unwrap();
    let mut cfg = config(&fx);
    cfg.timeout_s = 0.5;
    let ep = endpoint(cfg);

    let started = Instant::now();
    let err = ep.chat(&request(vec![png(0, 10)])).await.unwrap_err();
    let took = started.elapsed();
    assert_eq!(err, CallError::Timeout(Duration::from_millis(500)));
    assert!(err.retryable());
    assert!(took >= Duration::from_millis(500), "{took:?}");
    // Far from the 30 s the server would have taken; generous for a busy machine.
    assert!(took < Duration::from_secs(5), "{took:?}");
    assert_eq!(fx.count(), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrency_limit_caps_requests_in_flight() {
    let fx = Fixture::start(fixture::constant(Reply::text("Score: 5").after(0.3))).unwrap();
    let mut cfg = config(&fx);
    cfg.concurrency = 2;
    let ep = endpoint(cfg);

    let started = Instant::now();
    let calls: Vec<_> = (0..6)
        .map(|_| {
            let ep = ep.clone();
            tokio::spawn(async move { ep.chat(&request(vec![])).await })
        })
        .collect();
    for call in calls {
        assert_eq!(call.await.unwrap().unwrap().text, "Score: 5");
    }
    assert_eq!(fx.count(), 6);
    let most = fx.max_in_flight();
    assert!(
        (1..=2).contains(&most),
        "{most} requests were in flight at once"
    );
    // Six 0.3 s answers two at a time take at least three rounds.
    assert!(
        started.elapsed() >= Duration::from_millis(900),
        "{:?}",
        started.elapsed()
    );
}

#[tokio::test]
async fn rate_limit_spaces_request_starts() {
    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let mut cfg = config(&fx);
    cfg.requests_per_minute = Some(600.0); // one start per 0.1 s
    let ep = endpoint(cfg);

    let started = Instant::now();
    for _ in 0..5 {
        ep.chat(&request(vec![])).await.unwrap();
    }
    assert!(
        started.elapsed() >= Duration::from_millis(400),
        "{:?}",
        started.elapsed()
    );
    assert_eq!(fx.count(), 5);
}

#[tokio::test]
async fn answer_shapes_usage_and_content_parts() {
    let fx = Fixture::start(Arc::new(|r: &Received| match r.n {
        0 => Reply::Answer {
            text: "Score: 9".into(),
            tokens_in: 812,
            tokens_out: 17,
        },
        // No usage at all (some local servers).
        1 => Reply::Json {
            code: 200,
            body: json!({"choices": [{"index": 0, "message": {"role": "assistant", "content": "Score: 2"}}]}),
        },
        // Content as an array of parts.
        _ => Reply::Json {
            code: 200,
            body: json!({
                "choices": [{"message": {"role": "assistant", "content": [
                    {"type": "text", "text": "Score: "},
                    {"type": "text", "text": "8"},
                ]}}],
                "usage": {"prompt_tokens": 40, "completion_tokens": 3},
            }),
        },
    }))
    .unwrap();
    let ep = endpoint(config(&fx));

    let a = ep.chat(&request(vec![])).await.unwrap();
    assert_eq!(
        (a.text.as_str(), a.tokens_in, a.tokens_out),
        ("Score: 9", 812, 17)
    );
    let a = ep.chat(&request(vec![])).await.unwrap();
    assert_eq!(
        (a.text.as_str(), a.tokens_in, a.tokens_out),
        ("Score: 2", 0, 0)
    );
    let a = ep.chat(&request(vec![])).await.unwrap();
    assert_eq!(
        (a.text.as_str(), a.tokens_in, a.tokens_out),
        ("Score: 8", 40, 3)
    );
}

#[tokio::test]
async fn malformed_success_is_a_bad_response() {
    let fx = Fixture::start(fixture::constant(Reply::Json {
        code: 200,
        body: json!({"object": "list", "data": []}),
    }))
    .unwrap();
    let err = endpoint(config(&fx))
        .chat(&request(vec![]))
        .await
        .unwrap_err();
    assert!(matches!(err, CallError::BadResponse(_)), "{err:?}");
    assert!(!err.retryable());
}

#[tokio::test]
async fn broken_connection_is_a_retryable_transport_error() {
    let fx = Fixture::start(fixture::constant(Reply::Hangup)).unwrap();
    let err = endpoint(config(&fx))
        .chat(&request(vec![]))
        .await
        .unwrap_err();
    assert!(matches!(err, CallError::Transport(_)), "{err:?}");
    assert!(err.retryable());
}

#[tokio::test]
async fn wrong_path_gets_a_json_404_and_is_recorded() {
    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let mut cfg = config(&fx);
    cfg.base_url = fx.base_url().replace("/v1", "/v2");
    let err = endpoint(cfg).chat(&request(vec![])).await.unwrap_err();
    match &err {
        CallError::Status {
            code: 404, body, ..
        } => {
            let body: serde_json::Value = serde_json::from_str(body).unwrap();
            assert_eq!(body["error"]["type"], "not_found");
        }
        other => panic!("expected a 404, got {other:?}"),
    }
    assert!(!err.retryable());
    assert_eq!(fx.received()[0].path, "/v2/chat/completions");
}

#[tokio::test]
async fn scoring_script_scores_by_image_count() {
    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let ep = endpoint(config(&fx));
    for (images, score) in [(4, 4), (8, 7), (0, 1)] {
        let req = request((0..images).map(|i| png(i, 16)).collect());
        let a = ep.chat(&req).await.unwrap();
        assert_eq!(a.text, format!("Score: {score}"));
        assert_eq!(a.tokens_out, 4);
        assert!(a.tokens_in >= 85 * images as u64);
    }
}

/// Plain HTTP/1.1 by hand, from synchronous code: the fixture is a real server, and a body that
/// is not JSON is answered 400 and still recorded.
#[test]
fn fixture_speaks_plain_http_and_records_bad_json() {
    use std::io::{Read as _, Write as _};

    let fx = Fixture::start(fixture::scoring_script()).unwrap();
    let mut stream = std::net::TcpStream::connect(fx.addr()).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let body = "{not json";
    write!(
        stream,
        "POST /v1/chat/completions HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut answer = String::new();
    stream.read_to_string(&mut answer).unwrap();
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    assert!(answer.contains("invalid_request_error"), "{answer}");
    let got = fx.received();
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].body, serde_json::Value::String(body.to_owned()));
    assert_eq!(got[0].prompt_version, None);
}

#[tokio::test]
async fn dropping_the_fixture_stops_the_server() {
    let fx = Fixture::start(fixture::constant(Reply::text("Score: 3").after(60.0))).unwrap();
    let mut cfg = config(&fx);
    cfg.timeout_s = 0.3;
    let ep = endpoint(cfg);
    // A delayed answer is still pending when the fixture goes: dropping must not wait for it.
    assert!(matches!(
        ep.chat(&request(vec![])).await,
        Err(CallError::Timeout(_))
    ));
    let started = Instant::now();
    drop(fx);
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "{:?}",
        started.elapsed()
    );
    let err = ep.chat(&request(vec![])).await.unwrap_err();
    assert!(matches!(err, CallError::Transport(_)), "{err:?}");
}
