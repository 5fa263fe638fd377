//! A local OpenAI-compatible chat-completions server that stands in for a hosted VLM in tests.
//!
//! Real HTTP/1.1 over loopback TCP, real JSON in and out: a [`Script`] decides each answer from
//! what arrived, and every request is recorded as a [`Received`]. The server runs on its own named
//! thread with its own tokio runtime, so it works from synchronous tests, from inside other
//! runtimes, and from tests of other crates that point real worker processes at
//! [`Fixture::base_url`]. Dropping the [`Fixture`] stops it and cancels requests still being
//! answered.
//!
//! It is compiled into the crate (not behind `cfg(test)`) for those other crates; it never binds
//! anything but `127.0.0.1`.

use std::future::IntoFuture as _;
use std::io;
use std::net::SocketAddr;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, State};
use axum::http::{HeaderMap, Method, Response, StatusCode, Uri, header};
use serde_json::{Value, json};
use tokio::sync::oneshot;

/// The paths the fixture answers; everything else gets a 404 with a JSON error.
pub const CHAT_PATH: &str = "/v1/chat/completions";
pub const EMBEDDINGS_PATH: &str = "/v1/embeddings";

/// Request bodies up to this size are accepted (eight full-HD PNGs fit).
const MAX_BODY: usize = 256 << 20;

/// What the fixture received.
#[derive(Debug, Clone)]
pub struct Received {
    /// 0-based arrival index, over all paths.
    pub n: usize,
    /// The HTTP method.
    pub method: String,
    /// The request path, e.g. `/v1/chat/completions`.
    pub path: String,
    /// Every header, names lowercase, values lossily decoded.
    pub headers: Vec<(String, String)>,
    /// The parsed JSON body; a body that is not JSON is kept as a string.
    pub body: Value,
    /// `body.model`, empty when absent.
    pub model: String,
    /// The `X-Assay-Prompt-Version` header.
    pub prompt_version: Option<String>,
    /// All text of all messages (system and user, string contents and `"text"` parts), in order,
    /// joined with newlines.
    pub text: String,
    /// The number of `"image_url"` parts over all messages.
    pub images: usize,
    /// The `Authorization` header.
    pub authorization: Option<String>,
}

impl Received {
    /// The value of header `name` (case-insensitive).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    /// The `url` of every `"image_url"` part, in order.
    pub fn image_urls(&self) -> Vec<String> {
        messages(&self.body)
            .flat_map(content_parts)
            .filter(|p| p.get("type").and_then(Value::as_str) == Some("image_url"))
            .filter_map(|p| p.pointer("/image_url/url").and_then(Value::as_str))
            .map(str::to_owned)
            .collect()
    }
}

/// How the fixture answers one request.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// 200 with a real `chat.completion` object (id, object, created, model,
    /// `choices[0].message{role,content}`, `finish_reason`, usage).
    Answer {
        text: String,
        tokens_in: u64,
        tokens_out: u64,
    },
    /// An error status, e.g. 429 with `Retry-After: 1`, or 500. A body that parses as JSON is sent
    /// as `application/json`, anything else as `text/plain`.
    Status {
        code: u16,
        retry_after: Option<String>,
        body: String,
    },
    /// Any status with any JSON body, for shapes `Answer` does not make (content as an array of
    /// parts, no usage, a missing `choices`).
    Json { code: u16, body: Value },
    /// Starts a 200 answer that promises more bytes than it sends, so the connection breaks in the
    /// middle of the body: a transport error for the client.
    Hangup,
    /// Sleeps before answering (to trigger client timeouts).
    Delay { seconds: f64, then: Box<Reply> },
}

impl Reply {
    /// A 200 answer with `text` and no token counts.
    pub fn text(text: impl Into<String>) -> Reply {
        Reply::Answer {
            text: text.into(),
            tokens_in: 0,
            tokens_out: 0,
        }
    }

    /// This reply, after `seconds` of waiting.
    pub fn after(self, seconds: f64) -> Reply {
        Reply::Delay {
            seconds,
            then: Box::new(self),
        }
    }
}

/// Decides the answer to each request.
pub type Script = Arc<dyn Fn(&Received) -> Reply + Send + Sync>;

/// A script that gives the same reply every time.
pub fn constant(reply: Reply) -> Script {
    Arc::new(move |_| reply.clone())
}

/// A script that answers `"Score: X"` with X = [`scoring_rule`] of the number of images: 4 for 4
/// images, 7 for 8. Token counts are deterministic too: a quarter of the text's bytes plus 85 per
/// image in, 4 out.
pub fn scoring_script() -> Script {
    Arc::new(|r: &Received| Reply::Answer {
        text: format!("Score: {}", scoring_rule(r.images)),
        tokens_in: (r.text.len() / 4 + 85 * r.images) as u64,
        tokens_out: 4,
    })
}

/// The score [`scoring_script`] gives a request with `images` images: `1 + 3·images/4` (integer
/// division), at most 10. 0 → 1, 1 → 1, 2 → 2, 4 → 4, 6 → 5, 8 → 7, 12 and more → 10.
pub fn scoring_rule(images: usize) -> u32 {
    (1 + images.saturating_mul(3) / 4).min(10) as u32
}

/// A script for `POST /v1/embeddings` that answers a real `list` of `embedding` objects: each
/// input's vector is a bag of its lowercase words, each word hashed (FNV-1a) to one of `dims`
/// coordinates, plus one coordinate every text has, so texts sharing words are more similar and
/// the answer is deterministic.
/// Usage counts one prompt token per word.
pub fn embedding_script(dims: usize) -> Script {
    Arc::new(move |r: &Received| {
        let inputs: Vec<String> = match r.body.get("input") {
            Some(Value::String(s)) => vec![s.clone()],
            Some(Value::Array(a)) => a
                .iter()
                .map(|v| v.as_str().unwrap_or_default().to_owned())
                .collect(),
            _ => Vec::new(),
        };
        let mut words = 0;
        let data: Vec<Value> = inputs
            .iter()
            .enumerate()
            .map(|(i, text)| {
                let dims = dims.max(1);
                let mut v = vec![0f64; dims];
                for word in text
                    .split(|c: char| !c.is_alphanumeric())
                    .filter(|w| !w.is_empty())
                {
                    words += 1;
                    let h = word
                        .to_lowercase()
                        .bytes()
                        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
                            (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
                        });
                    v[(h % dims as u64) as usize] += 1.0;
                }
                // A component every text shares, as real embeddings have: no two texts are
                // orthogonal.
                v[0] += 1.0;
                json!({"object": "embedding", "index": i, "embedding": v})
            })
            .collect();
        Reply::Json {
            code: 200,
            body: json!({
                "object": "list",
                "data": data,
                "model": r.model,
                "usage": {"prompt_tokens": words, "total_tokens": words},
            }),
        }
    })
}

/// A running fixture server. Dropping it shuts the server down.
pub struct Fixture {
    addr: SocketAddr,
    shared: Arc<Shared>,
    shutdown: Option<oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

struct Shared {
    script: Script,
    received: Mutex<Vec<Received>>,
    in_flight: AtomicUsize,
    max_in_flight: AtomicUsize,
}

impl std::fmt::Debug for Fixture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fixture")
            .field("addr", &self.addr)
            .field("count", &self.count())
            .finish_non_exhaustive()
    }
}

impl Fixture {
    /// Binds `127.0.0.1:0` and serves `POST /v1/chat/completions` on a thread of its own with its
    /// own tokio runtime; any other path or method gets a 404 with a JSON error.
    pub fn start(script: Script) -> io::Result<Fixture> {
        let listener = std::net::TcpListener::bind(("127.0.0.1", 0))?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            script,
            received: Mutex::new(Vec::new()),
            in_flight: AtomicUsize::new(0),
            max_in_flight: AtomicUsize::new(0),
        });
        let app = Router::new()
            .fallback(handle)
            .layer(DefaultBodyLimit::max(MAX_BODY))
            .with_state(Arc::clone(&shared));
        let (shutdown, stop) = oneshot::channel::<()>();
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel::<io::Result<()>>(1);
        let thread = std::thread::Builder::new()
            .name(format!("judge-fixture-{}", addr.port()))
            .spawn(move || {
                let runtime = match tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                {
                    Ok(rt) => rt,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                runtime.block_on(async move {
                    let listener = match tokio::net::TcpListener::from_std(listener) {
                        Ok(l) => l,
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                            return;
                        }
                    };
                    let _ = ready_tx.send(Ok(()));
                    tokio::select! {
                        served = axum::serve(listener, app).into_future() => {
                            if let Err(e) = served {
                                tracing::warn!(error = %e, "judge fixture stopped serving");
                            }
                        }
                        _ = stop => {}
                    }
                });
                // Dropping the runtime here cancels every connection, delayed replies included.
            })?;
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(e);
            }
            Err(_) => {
                let _ = thread.join();
                return Err(io::Error::other(
                    "the judge fixture thread died while starting",
                ));
            }
        }
        tracing::debug!(%addr, "judge fixture listening");
        Ok(Fixture {
            addr,
            shared,
            shutdown: Some(shutdown),
            thread: Some(thread),
        })
    }

    /// `http://127.0.0.1:PORT/v1`, the `base_url` for an endpoint configuration.
    pub fn base_url(&self) -> String {
        format!("http://{}/v1", self.addr)
    }

    /// The address the server listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Every request so far, in arrival order.
    pub fn received(&self) -> Vec<Received> {
        lock(&self.shared.received).clone()
    }

    /// How many requests arrived so far.
    pub fn count(&self) -> usize {
        lock(&self.shared.received).len()
    }

    /// Requests being answered right now (a delayed reply counts until it is sent).
    pub fn in_flight(&self) -> usize {
        self.shared.in_flight.load(Ordering::SeqCst)
    }

    /// The most requests that were ever being answered at once.
    pub fn max_in_flight(&self) -> usize {
        self.shared.max_in_flight.load(Ordering::SeqCst)
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        if let Some(shutdown) = self.shutdown.take() {
            let _ = shutdown.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Counts a request as in flight until dropped (also when the connection is cancelled).
struct InFlight<'a>(&'a Shared);

impl<'a> InFlight<'a> {
    fn enter(shared: &'a Shared) -> Self {
        let now = shared.in_flight.fetch_add(1, Ordering::SeqCst) + 1;
        shared.max_in_flight.fetch_max(now, Ordering::SeqCst);
        InFlight(shared)
    }
}

impl Drop for InFlight<'_> {
    fn drop(&mut self) {
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

async fn handle(
    State(shared): State<Arc<Shared>>,
    method: Method,
    uri: Uri,
    headers: HeaderMap,
    body: Bytes,
) -> Response<Body> {
    let _in_flight = InFlight::enter(&shared);
    let parsed = serde_json::from_slice::<Value>(&body);
    let header_of = |name: header::HeaderName| {
        headers
            .get(name)
            .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
    };
    let mut received = Received {
        n: 0,
        method: method.to_string(),
        path: uri.path().to_owned(),
        headers: headers
            .iter()
            .map(|(k, v)| {
                (
                    k.as_str().to_owned(),
                    String::from_utf8_lossy(v.as_bytes()).into_owned(),
                )
            })
            .collect(),
        body: Value::Null,
        model: String::new(),
        prompt_version: header_of(header::HeaderName::from_static(
            assay_openai::PROMPT_VERSION_HEADER,
        )),
        text: String::new(),
        images: 0,
        authorization: header_of(header::AUTHORIZATION),
    };
    match &parsed {
        Ok(value) => {
            received.model = value
                .get("model")
                .and_then(Value::as_str)
                .unwrap_or_default()
                .to_owned();
            received.text = texts(value).join("\n");
            received.images = messages(value)
                .flat_map(content_parts)
                .filter(|p| p.get("type").and_then(Value::as_str) == Some("image_url"))
                .count();
            received.body = value.clone();
        }
        Err(_) => received.body = Value::String(String::from_utf8_lossy(&body).into_owned()),
    }
    {
        let mut all = lock(&shared.received);
        received.n = all.len();
        all.push(received.clone());
    }

    if method != Method::POST || (received.path != CHAT_PATH && received.path != EMBEDDINGS_PATH) {
        return error(
            StatusCode::NOT_FOUND,
            "not_found",
            &format!(
                "the judge fixture serves only POST {CHAT_PATH} and {EMBEDDINGS_PATH}, not {} {}",
                received.method, received.path
            ),
        );
    }
    if let Err(e) = parsed {
        return error(
            StatusCode::BAD_REQUEST,
            "invalid_request_error",
            &format!("the body is not JSON: {e}"),
        );
    }

    let script = Arc::clone(&shared.script);
    let mut reply = match std::panic::catch_unwind(AssertUnwindSafe(|| script(&received))) {
        Ok(reply) => reply,
        Err(_) => {
            return error(
                StatusCode::INTERNAL_SERVER_ERROR,
                "fixture_script_panicked",
                "the fixture's script panicked",
            );
        }
    };
    loop {
        match reply {
            Reply::Delay { seconds, then } => {
                if seconds.is_finite() && seconds > 0.0 {
                    tokio::time::sleep(Duration::from_secs_f64(seconds.min(86_400.0))).await;
                }
                reply = *then;
            }
            other => return render(other, &received),
        }
    }
}

fn render(reply: Reply, received: &Received) -> Response<Body> {
    let built = match reply {
        Reply::Answer {
            text,
            tokens_in,
            tokens_out,
        } => {
            let created = SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            let body = json!({
                "id": format!("chatcmpl-fixture-{}", received.n),
                "object": "chat.completion",
                "created": created,
                "model": received.model,
                "choices": [{
                    "index": 0,
                    "message": {"role": "assistant", "content": text},
                    "logprobs": null,
                    "finish_reason": "stop",
                }],
                "usage": {
                    "prompt_tokens": tokens_in,
                    "completion_tokens": tokens_out,
                    "total_tokens": tokens_in + tokens_out,
                },
            });
            json_response(200, &body)
        }
        Reply::Json { code, body } => json_response(code, &body),
        Reply::Status {
            code,
            retry_after,
            body,
        } => {
            let content_type = if serde_json::from_str::<Value>(&body).is_ok() {
                "application/json"
            } else {
                "text/plain; charset=utf-8"
            };
            let mut builder = Response::builder()
                .status(code)
                .header(header::CONTENT_TYPE, content_type);
            if let Some(wait) = retry_after {
                builder = builder.header(header::RETRY_AFTER, wait);
            }
            builder.body(Body::from(body))
        }
        Reply::Hangup => Response::builder()
            .status(200)
            .header(header::CONTENT_TYPE, "application/json")
            .header(header::CONTENT_LENGTH, "4096")
            .body(Body::from("{\"choices\":[")),
        Reply::Delay { .. } => unreachable!("delays are taken by the caller"),
    };
    built.unwrap_or_else(|e| {
        error(
            StatusCode::INTERNAL_SERVER_ERROR,
            "fixture_bad_reply",
            &format!("the fixture's script gave a reply that cannot be sent: {e}"),
        )
    })
}

fn json_response(code: u16, body: &Value) -> Result<Response<Body>, axum::http::Error> {
    Response::builder()
        .status(code)
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(body.to_string()))
}

/// An OpenAI-shaped error answer.
fn error(status: StatusCode, kind: &str, message: &str) -> Response<Body> {
    let body = json!({"error": {"message": message, "type": kind, "param": null, "code": null}});
    let mut response = Response::new(Body::from(body.to_string()));
    *response.status_mut() = status;
    response.headers_mut().insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static("application/json"),
    );
    response
}

fn messages(body: &Value) -> impl Iterator<Item = &Value> {
    body.get("messages")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
}

/// The parts of a message's content; a string content is not a part.
fn content_parts(message: &Value) -> impl Iterator<Item = &Value> {
    message
        .get("content")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
}

/// Every text of every message, in order.
fn texts(body: &Value) -> Vec<&str> {
    let mut out = Vec::new();
    for message in messages(body) {
        match message.get("content") {
            Some(Value::String(s)) => out.push(s.as_str()),
            Some(Value::Array(parts)) => out.extend(
                parts
                    .iter()
                    .filter(|p| p.get("type").and_then(Value::as_str) == Some("text"))
                    .filter_map(|p| p.get("text").and_then(Value::as_str)),
            ),
            _ => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scoring_rule_matches_its_examples() {
        let got: Vec<u32> = [0, 1, 2, 4, 6, 8, 12, 100, usize::MAX]
            .into_iter()
            .map(scoring_rule)
            .collect();
        assert_eq!(got, vec![1, 1, 2, 4, 5, 7, 10, 10, 10]);
    }

    #[test]
    fn texts_cover_string_and_part_contents() {
        let body = json!({"messages": [
            {"role": "system", "content": "sys"},
            {"role": "user", "content": [
                {"type": "text", "text": "a"},
                {"type": "image_url", "image_url": {"url": "data:,"}},
                {"type": "text", "text": "b"},
            ]},
        ]});
        assert_eq!(texts(&body), vec!["sys", "a", "b"]);
        assert_eq!(messages(&body).flat_map(content_parts).count(), 3);
    }
}
