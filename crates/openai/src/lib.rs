//! The OpenAI-compatible chat-completions client of the judge role.
//!
//! OpenAI, Azure-style proxies, vLLM, Ollama, LM Studio and SGLang all speak
//! `POST {base_url}/chat/completions`; one [`Endpoint`] is one such server and model, with its own
//! connection pool, concurrency limit and rate limiter shared by every task that holds a clone.
//!
//! This module owns one HTTP attempt ([`Endpoint::chat`]) and the retry arithmetic
//! ([`backoff_delay`], [`parse_retry_after`]). It never retries by itself and never parses scores:
//! the caller retries, because an answer that cannot be parsed as a score is retried too.
//! It never logs the API key or prompt text.

use std::fmt;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use base64::Engine as _;
use reqwest::header::{ACCEPT, AUTHORIZATION, CONTENT_TYPE, HeaderMap, HeaderValue, RETRY_AFTER};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use tokio::sync::Semaphore;
use tokio::time::Instant;

/// The header every request carries, so that fixtures (and proxies' logs) can tell prompt versions
/// apart. Real servers ignore unknown headers.
pub const PROMPT_VERSION_HEADER: &str = "x-assay-prompt-version";

/// The longest wait a server's `Retry-After` can impose on one retry.
pub const MAX_RETRY_AFTER: Duration = Duration::from_secs(600);

/// How much of an error body a [`CallError::Status`] keeps.
const MAX_ERROR_BODY: usize = 2000;

/// One OpenAI-compatible endpoint: where to send, which model, and how hard to push it.
///
/// Deserialises from the `[judge.endpoint]`-style TOML/JSON tables of the configuration; every field
/// but `base_url` and `model` has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EndpointConfig {
    /// Up to and including the API version, without the trailing `/chat/completions`:
    /// `https://api.openai.com/v1`, `http://127.0.0.1:8000/v1`.
    pub base_url: String,
    /// The model name sent in every request body.
    pub model: String,
    /// The NAME of the environment variable that holds the API key, read once by
    /// [`Endpoint::new`]. `None`: no `Authorization` header (local servers).
    #[serde(default)]
    pub api_key_env: Option<String>,
    /// Sampling temperature. Default 0.7: the judge samples each question several times (five in
    /// the paper) and aggregates, which only means something when the samples can differ.
    #[serde(default = "default_temperature")]
    pub temperature: f64,
    /// Completion token limit per request. Default 256: a score and a short reason.
    #[serde(default = "default_max_tokens")]
    pub max_tokens: u32,
    /// Limit on one whole request (connect, send, wait, read the answer), in seconds. Default 60.
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
    /// Requests in flight at once through this endpoint. Default 4.
    #[serde(default = "default_concurrency")]
    pub concurrency: usize,
    /// Rate limit, applied as a minimum spacing of 60/rpm seconds between request starts.
    /// `None`: unlimited.
    #[serde(default)]
    pub requests_per_minute: Option<f64>,
    /// Extra attempts after the first (the caller's retry loop reads it). Default 4.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// First retry delay in seconds, doubled on every further retry. Default 1.
    #[serde(default = "default_backoff_initial_s")]
    pub backoff_initial_s: f64,
    /// Cap on the exponential retry delay, in seconds. Default 30.
    #[serde(default = "default_backoff_max_s")]
    pub backoff_max_s: f64,
    /// USD per million input (prompt) tokens. Default 0 (local servers).
    #[serde(default)]
    pub price_input_per_mtok: f64,
    /// USD per million output (completion) tokens. Default 0.
    #[serde(default)]
    pub price_output_per_mtok: f64,
    /// The `detail` of every image part: `"auto"`, `"low"` or `"high"`. Default `"auto"`.
    #[serde(default = "default_image_detail")]
    pub image_detail: String,
}

fn default_temperature() -> f64 {
    0.7
}
fn default_max_tokens() -> u32 {
    256
}
fn default_timeout_s() -> f64 {
    60.0
}
fn default_concurrency() -> usize {
    4
}
fn default_retries() -> u32 {
    4
}
fn default_backoff_initial_s() -> f64 {
    1.0
}
fn default_backoff_max_s() -> f64 {
    30.0
}
fn default_image_detail() -> String {
    "auto".to_owned()
}

impl EndpointConfig {
    /// A configuration with every default, for `base_url` and `model`.
    pub fn new(base_url: impl Into<String>, model: impl Into<String>) -> Self {
        Self {
            base_url: base_url.into(),
            model: model.into(),
            api_key_env: None,
            temperature: default_temperature(),
            max_tokens: default_max_tokens(),
            timeout_s: default_timeout_s(),
            concurrency: default_concurrency(),
            requests_per_minute: None,
            retries: default_retries(),
            backoff_initial_s: default_backoff_initial_s(),
            backoff_max_s: default_backoff_max_s(),
            price_input_per_mtok: 0.0,
            price_output_per_mtok: 0.0,
            image_detail: default_image_detail(),
        }
    }

    /// Checks every field; the error names the field and the reason.
    pub fn validate(&self) -> Result<(), CallError> {
        let bad = |field: &str, why: String| {
            Err(CallError::Config(format!(
                "endpoint {:?}: {field} {why}",
                self.base_url
            )))
        };
        let url = self.base_url.trim();
        if !(url.starts_with("http://") || url.starts_with("https://")) {
            return bad("base_url", "must start with http:// or https://".to_owned());
        }
        if self.model.trim().is_empty() {
            return bad("model", "must not be empty".to_owned());
        }
        if !(self.temperature.is_finite() && self.temperature >= 0.0) {
            return bad(
                "temperature",
                format!("must be finite and >= 0, got {}", self.temperature),
            );
        }
        if self.max_tokens == 0 {
            return bad("max_tokens", "must be at least 1".to_owned());
        }
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            return bad(
                "timeout_s",
                format!("must be finite and > 0, got {}", self.timeout_s),
            );
        }
        if self.concurrency == 0 {
            return bad("concurrency", "must be at least 1".to_owned());
        }
        if let Some(rpm) = self.requests_per_minute
            && !(rpm.is_finite() && rpm > 0.0)
        {
            return bad(
                "requests_per_minute",
                format!("must be finite and > 0, got {rpm}"),
            );
        }
        for (field, v) in [
            ("backoff_initial_s", self.backoff_initial_s),
            ("backoff_max_s", self.backoff_max_s),
            ("price_input_per_mtok", self.price_input_per_mtok),
            ("price_output_per_mtok", self.price_output_per_mtok),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, format!("must be finite and >= 0, got {v}"));
            }
        }
        if !matches!(self.image_detail.as_str(), "auto" | "low" | "high") {
            return bad(
                "image_detail",
                format!(
                    "must be \"auto\", \"low\" or \"high\", got {:?}",
                    self.image_detail
                ),
            );
        }
        Ok(())
    }

    /// The per-request timeout as a [`Duration`].
    pub fn timeout(&self) -> Duration {
        secs(self.timeout_s)
    }
}

/// One question to the model.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ChatRequest {
    /// Sent as the `X-Assay-Prompt-Version` header.
    pub prompt_version: String,
    /// An optional system message.
    pub system: Option<String>,
    /// The user text, sent before the images in one user message.
    pub text: String,
    /// PNG bytes, sent as `data:image/png;base64,…` image parts after the text.
    pub images: Vec<Vec<u8>>,
}

/// The model's answer and what it cost.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChatAnswer {
    /// `choices[0].message.content`, text parts joined.
    pub text: String,
    /// `usage.prompt_tokens`, 0 when the server sends no usage.
    pub tokens_in: u64,
    /// `usage.completion_tokens`, 0 when the server sends no usage.
    pub tokens_out: u64,
}

/// Why one attempt failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CallError {
    /// The whole request took longer than `timeout_s`.
    #[error("request timed out after {0:?}")]
    Timeout(Duration),
    /// The server answered with a non-success status.
    #[error("server answered HTTP {code}{}: {body}", retry_after_note(.retry_after))]
    Status {
        code: u16,
        /// From `Retry-After` (or `retry-after-ms`), when the server sent one.
        retry_after: Option<Duration>,
        /// The start of the response body.
        body: String,
    },
    /// Connecting, sending or reading failed.
    #[error("transport error: {0}")]
    Transport(String),
    /// A success status with a body that is not a chat completion.
    #[error("bad response: {0}")]
    BadResponse(String),
    /// The configuration (or the request) cannot be sent at all.
    #[error("configuration error: {0}")]
    Config(String),
}

fn retry_after_note(retry_after: &Option<Duration>) -> String {
    match retry_after {
        Some(d) => format!(" (retry after {d:?})"),
        None => String::new(),
    }
}

impl CallError {
    /// Whether another attempt may succeed: timeouts, transport errors, and HTTP 408, 409, 429
    /// and 5xx. A malformed success body is not retryable here (a server that answers HTML with
    /// 200 is misconfigured, not busy).
    pub fn retryable(&self) -> bool {
        match self {
            CallError::Timeout(_) | CallError::Transport(_) => true,
            CallError::Status { code, .. } => {
                matches!(code, 408 | 409 | 429) || (500..600).contains(code)
            }
            CallError::BadResponse(_) | CallError::Config(_) => false,
        }
    }

    /// The wait the server asked for, if any.
    pub fn retry_after(&self) -> Option<Duration> {
        match self {
            CallError::Status { retry_after, .. } => *retry_after,
            _ => None,
        }
    }
}

/// One OpenAI-compatible endpoint, ready to call. Cheap to clone: clones share the connection pool,
/// the concurrency limit and the rate limiter.
#[derive(Clone)]
pub struct Endpoint {
    inner: Arc<Inner>,
}

struct Inner {
    cfg: EndpointConfig,
    url: String,
    embeddings_url: String,
    api_key: Option<String>,
    client: reqwest::Client,
    permits: Semaphore,
    limiter: Option<RateLimiter>,
}

impl fmt::Debug for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Endpoint")
            .field("url", &self.inner.url)
            .field("model", &self.inner.cfg.model)
            .field(
                "api_key",
                &self.inner.api_key.as_ref().map(|_| "<redacted>"),
            )
            .finish_non_exhaustive()
    }
}

impl Endpoint {
    /// Validates `cfg`, reads the API key from the variable named by `api_key_env` now (a missing or
    /// empty variable is a [`CallError::Config`] naming it) and builds the HTTP client.
    pub fn new(cfg: EndpointConfig) -> Result<Self, CallError> {
        let api_key = match &cfg.api_key_env {
            None => None,
            Some(var) => match std::env::var(var) {
                Ok(key) if !key.trim().is_empty() => Some(key.trim().to_owned()),
                Ok(_) => {
                    return Err(CallError::Config(format!(
                        "endpoint {:?}: api_key_env names the environment variable {var}, which is empty",
                        cfg.base_url
                    )));
                }
                Err(std::env::VarError::NotPresent) => {
                    return Err(CallError::Config(format!(
                        "endpoint {:?}: api_key_env names the environment variable {var}, which is not set",
                        cfg.base_url
                    )));
                }
                Err(std::env::VarError::NotUnicode(_)) => {
                    return Err(CallError::Config(format!(
                        "endpoint {:?}: the environment variable {var} (api_key_env) is not valid UTF-8",
                        cfg.base_url
                    )));
                }
            },
        };
        Self::with_api_key(cfg, api_key)
    }

    /// Like [`Endpoint::new`], with the key given directly instead of read from `api_key_env`.
    pub fn with_api_key(cfg: EndpointConfig, api_key: Option<String>) -> Result<Self, CallError> {
        cfg.validate()?;
        if let Some(key) = &api_key
            && HeaderValue::from_str(&format!("Bearer {key}")).is_err()
        {
            return Err(CallError::Config(format!(
                "endpoint {:?}: the API key contains characters that cannot go in a header",
                cfg.base_url
            )));
        }
        let base = cfg.base_url.trim().trim_end_matches('/');
        let url = format!("{base}/chat/completions");
        let embeddings_url = format!("{base}/embeddings");
        let timeout = cfg.timeout();
        let mut builder = reqwest::Client::builder()
            .connect_timeout(timeout.min(Duration::from_secs(10)))
            .user_agent(concat!("assay-judge/", env!("CARGO_PKG_VERSION")));
        // A proxy from the environment must never see requests meant for a local server.
        if is_loopback(&url) {
            builder = builder.no_proxy();
        }
        let client = builder.build().map_err(|e| {
            CallError::Config(format!("cannot build the HTTP client: {}", chain(&e)))
        })?;
        let limiter = cfg
            .requests_per_minute
            .map(|rpm| RateLimiter::new(secs(60.0 / rpm)));
        Ok(Self {
            inner: Arc::new(Inner {
                permits: Semaphore::new(cfg.concurrency),
                cfg,
                url,
                embeddings_url,
                api_key,
                client,
                limiter,
            }),
        })
    }

    /// The configuration this endpoint was built from.
    pub fn config(&self) -> &EndpointConfig {
        &self.inner.cfg
    }

    /// ONE attempt, no retries: waits for a concurrency permit and the rate limiter, sends, applies
    /// `timeout_s` to the whole request (send and read), and parses `choices[0].message.content`
    /// (a string, or an array of parts whose `"text"` parts are joined) and
    /// `usage.prompt_tokens` / `usage.completion_tokens` (absent usage counts 0).
    pub async fn chat(&self, req: &ChatRequest) -> Result<ChatAnswer, CallError> {
        let inner = &*self.inner;
        let version = HeaderValue::from_str(&req.prompt_version).map_err(|_| {
            CallError::Config(format!(
                "prompt version {:?} cannot go in a header",
                req.prompt_version
            ))
        })?;
        let body = serde_json::to_vec(&request_body(&inner.cfg, req))
            .map_err(|e| CallError::Config(format!("cannot encode the request body: {e}")))?;

        let started = Instant::now();
        let bytes = self.post(&inner.url, body, Some(version)).await;
        tracing::debug!(
            model = %inner.cfg.model,
            prompt_version = %req.prompt_version,
            images = req.images.len(),
            ok = bytes.is_ok(),
            elapsed_ms = started.elapsed().as_millis() as u64,
            "chat completion answered"
        );
        parse_answer(&bytes?)
    }

    /// ONE attempt at `POST {base_url}/embeddings` with `input` (an array of strings), under the
    /// same concurrency limit, rate limiter and timeout as [`Endpoint::chat`]. The vectors come
    /// back in input order (by each item's `index`); usage is `usage.prompt_tokens` (0 when absent).
    pub async fn embeddings(&self, input: &[String]) -> Result<EmbeddingAnswer, CallError> {
        let inner = &*self.inner;
        let body = serde_json::to_vec(&json!({
            "model": inner.cfg.model,
            "input": input,
            "encoding_format": "float",
        }))
        .map_err(|e| CallError::Config(format!("cannot encode the request body: {e}")))?;
        let bytes = self.post(&inner.embeddings_url, body, None).await?;
        parse_embeddings(&bytes, input.len())
    }

    /// One POST of a JSON `body` to `url` under the endpoint's concurrency limit, rate limiter,
    /// key and `timeout_s` (send and read); a non-success status becomes [`CallError::Status`]
    /// with the server's `Retry-After`.
    async fn post(
        &self,
        url: &str,
        body: Vec<u8>,
        prompt_version: Option<HeaderValue>,
    ) -> Result<Vec<u8>, CallError> {
        let inner = &*self.inner;
        let _permit = inner
            .permits
            .acquire()
            .await
            .map_err(|_| CallError::Config("the endpoint was closed".to_owned()))?;
        if let Some(limiter) = &inner.limiter {
            limiter.wait().await;
        }
        let mut request = inner
            .client
            .post(url)
            .header(CONTENT_TYPE, "application/json")
            .header(ACCEPT, "application/json")
            .body(body);
        if let Some(version) = prompt_version {
            request = request.header(PROMPT_VERSION_HEADER, version);
        }
        if let Some(key) = &inner.api_key {
            request = request.header(AUTHORIZATION, format!("Bearer {key}"));
        }
        let timeout = inner.cfg.timeout();
        let sent = async {
            let response = request.send().await?;
            let status = response.status();
            let headers = response.headers().clone();
            let bytes = response.bytes().await?;
            Ok::<_, reqwest::Error>((status, headers, bytes))
        };
        let (status, headers, bytes) = match tokio::time::timeout(timeout, sent).await {
            Err(_elapsed) => return Err(CallError::Timeout(timeout)),
            Ok(Err(e)) if e.is_timeout() => return Err(CallError::Timeout(timeout)),
            Ok(Err(e)) => return Err(CallError::Transport(chain(&e))),
            Ok(Ok(parts)) => parts,
        };
        if !status.is_success() {
            return Err(CallError::Status {
                code: status.as_u16(),
                retry_after: retry_after_from(&headers, SystemTime::now()),
                body: truncate(&String::from_utf8_lossy(&bytes), MAX_ERROR_BODY),
            });
        }
        Ok(bytes.to_vec())
    }

    /// [`Endpoint::embeddings`] with the configured retries and backoff (honouring
    /// `Retry-After`), `batch` texts per request.
    pub async fn embed_all(
        &self,
        texts: &[String],
        batch: usize,
    ) -> Result<EmbeddingAnswer, CallError> {
        let mut all = EmbeddingAnswer {
            vectors: Vec::with_capacity(texts.len()),
            tokens_in: 0,
        };
        for chunk in texts.chunks(batch.max(1)) {
            let mut attempt = 0;
            let answer = loop {
                match self.embeddings(chunk).await {
                    Ok(a) => break a,
                    Err(e) if e.retryable() && attempt < self.inner.cfg.retries => {
                        let unit = SystemTime::now()
                            .duration_since(UNIX_EPOCH)
                            .map(|d| f64::from(d.subsec_nanos()) / 1e9)
                            .unwrap_or(0.5);
                        let wait = backoff_delay(&self.inner.cfg, attempt, e.retry_after(), unit);
                        tracing::debug!(error = %e, ?wait, "embeddings request failed; retrying");
                        tokio::time::sleep(wait).await;
                        attempt += 1;
                    }
                    Err(e) => return Err(e),
                }
            };
            all.vectors.extend(answer.vectors);
            all.tokens_in += answer.tokens_in;
        }
        Ok(all)
    }

    /// What `tokens_in` input and `tokens_out` output tokens cost at the configured prices, in USD.
    pub fn cost_usd(&self, tokens_in: u64, tokens_out: u64) -> f64 {
        let cfg = &self.inner.cfg;
        (tokens_in as f64 * cfg.price_input_per_mtok
            + tokens_out as f64 * cfg.price_output_per_mtok)
            / 1e6
    }
}

/// The answer to an embeddings request.
#[derive(Debug, Clone, PartialEq)]
pub struct EmbeddingAnswer {
    /// One vector per input text, in input order.
    pub vectors: Vec<Vec<f32>>,
    pub tokens_in: u64,
}

/// Parses an OpenAI embeddings response: `data[*].embedding` (arrays of numbers) placed by
/// `data[*].index`, exactly one per input.
fn parse_embeddings(bytes: &[u8], n: usize) -> Result<EmbeddingAnswer, CallError> {
    let bad = |why: String| CallError::BadResponse(why);
    let v: Value = serde_json::from_slice(bytes)
        .map_err(|e| bad(format!("embeddings response is not JSON: {e}")))?;
    let data = v
        .get("data")
        .and_then(Value::as_array)
        .ok_or_else(|| bad("embeddings response has no data array".into()))?;
    if data.len() != n {
        return Err(bad(format!(
            "embeddings response has {} vectors for {n} inputs",
            data.len()
        )));
    }
    let mut vectors = vec![Vec::new(); n];
    for (k, item) in data.iter().enumerate() {
        let index = item
            .get("index")
            .and_then(Value::as_u64)
            .map(|i| i as usize)
            .unwrap_or(k);
        let vector: Vec<f32> = item
            .get("embedding")
            .and_then(Value::as_array)
            .ok_or_else(|| bad(format!("data[{k}] has no embedding array")))?
            .iter()
            .map(|x| x.as_f64().map(|f| f as f32))
            .collect::<Option<_>>()
            .ok_or_else(|| bad(format!("data[{k}].embedding holds a non-number")))?;
        if index >= n || !vectors[index].is_empty() {
            return Err(bad(format!("data[{k}] has index {index} out of place")));
        }
        vectors[index] = vector;
    }
    let tokens_in = v
        .pointer("/usage/prompt_tokens")
        .and_then(Value::as_u64)
        .unwrap_or(0);
    Ok(EmbeddingAnswer { vectors, tokens_in })
}

/// The JSON body of one chat-completions request.
fn request_body(cfg: &EndpointConfig, req: &ChatRequest) -> Value {
    let mut content = Vec::with_capacity(1 + req.images.len());
    content.push(json!({"type": "text", "text": req.text}));
    for png in &req.images {
        let url = format!(
            "data:image/png;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(png)
        );
        content.push(json!({
            "type": "image_url",
            "image_url": {"url": url, "detail": cfg.image_detail},
        }));
    }
    let mut messages = Vec::with_capacity(2);
    if let Some(system) = &req.system {
        messages.push(json!({"role": "system", "content": system}));
    }
    messages.push(json!({"role": "user", "content": content}));
    json!({
        "model": cfg.model,
        "messages": messages,
        "temperature": cfg.temperature,
        "max_tokens": cfg.max_tokens,
    })
}

/// Parses a chat-completion body.
fn parse_answer(bytes: &[u8]) -> Result<ChatAnswer, CallError> {
    let body: Value = serde_json::from_slice(bytes).map_err(|e| {
        CallError::BadResponse(format!(
            "the body is not JSON ({e}): {}",
            truncate(&String::from_utf8_lossy(bytes), 200)
        ))
    })?;
    if let Some(error) = body.get("error").filter(|e| !e.is_null()) {
        return Err(CallError::BadResponse(format!(
            "the server answered an error with a success status: {}",
            truncate(&error.to_string(), MAX_ERROR_BODY)
        )));
    }
    let message = body
        .pointer("/choices/0/message")
        .ok_or_else(|| CallError::BadResponse("no choices[0].message in the answer".to_owned()))?;
    let text = match message.get("content") {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Array(parts)) => {
            let texts: Vec<&str> = parts
                .iter()
                .filter(|p| p.get("type").and_then(Value::as_str) == Some("text"))
                .filter_map(|p| p.get("text").and_then(Value::as_str))
                .collect();
            if texts.is_empty() {
                return Err(CallError::BadResponse(
                    "choices[0].message.content has no text part".to_owned(),
                ));
            }
            texts.join("")
        }
        _ => {
            let refusal = message
                .get("refusal")
                .and_then(Value::as_str)
                .map(|r| format!(" (refusal: {})", truncate(r, 200)))
                .unwrap_or_default();
            return Err(CallError::BadResponse(format!(
                "choices[0].message.content is neither a string nor an array of parts{refusal}"
            )));
        }
    };
    let usage = |field: &str| {
        body.get("usage")
            .and_then(|u| u.get(field))
            .and_then(Value::as_u64)
            .unwrap_or(0)
    };
    Ok(ChatAnswer {
        text,
        tokens_in: usage("prompt_tokens"),
        tokens_out: usage("completion_tokens"),
    })
}

/// The wait a response asks for: `retry-after-ms` (sent by OpenAI and Azure) first, then
/// `Retry-After`.
fn retry_after_from(headers: &HeaderMap, now: SystemTime) -> Option<Duration> {
    let millis = headers
        .get("retry-after-ms")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|ms| ms.is_finite() && *ms >= 0.0)
        .map(|ms| secs(ms / 1000.0));
    millis.or_else(|| {
        headers
            .get(RETRY_AFTER)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| parse_retry_after(v, now))
    })
}

/// A minimum spacing between request starts, shared by every task using one endpoint.
///
/// Each caller reserves the next free start time under a short lock and then sleeps until it
/// without holding the lock, so waiters queue in arrival order and nobody spins.
struct RateLimiter {
    spacing: Duration,
    next: Mutex<Option<Instant>>,
}

impl RateLimiter {
    fn new(spacing: Duration) -> Self {
        Self {
            spacing,
            next: Mutex::new(None),
        }
    }

    async fn wait(&self) {
        let start = {
            let mut next = self.next.lock().unwrap_or_else(|e| e.into_inner());
            let now = Instant::now();
            let start = next.map_or(now, |n| n.max(now));
            *next = Some(start + self.spacing);
            start
        };
        tokio::time::sleep_until(start).await;
    }
}

/// The delay before retry number `attempt` (0 before the first retry): exponential from
/// `backoff_initial_s`, capped at `backoff_max_s`, with full jitter (`unit`, a uniform number in
/// [0, 1) from the caller, scales it), and at least the server's `retry_after` (itself capped at
/// [`MAX_RETRY_AFTER`]).
pub fn backoff_delay(
    cfg: &EndpointConfig,
    attempt: u32,
    retry_after: Option<Duration>,
    unit: f64,
) -> Duration {
    let initial = finite_non_negative(cfg.backoff_initial_s);
    let cap = finite_non_negative(cfg.backoff_max_s).min(MAX_RETRY_AFTER.as_secs_f64());
    let exponential = (initial * 2f64.powi(attempt.min(64) as i32)).min(cap);
    let unit = if unit.is_finite() {
        unit.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let jittered = secs(exponential * unit);
    match retry_after {
        Some(wait) => jittered.max(wait.min(MAX_RETRY_AFTER)),
        None => jittered,
    }
}

/// Parses a `Retry-After` value, relative to `now`: delta-seconds (`"120"`; a decimal fraction is
/// accepted too), or an HTTP-date in any of the three forms RFC 9110 requires recipients to accept
/// (IMF-fixdate `"Wed, 21 Oct 2015 07:28:00 GMT"`, RFC 850 `"Wednesday, 21-Oct-15 07:28:00 GMT"`,
/// asctime `"Wed Oct 21 07:28:00 2015"`). A date in the past gives zero; anything else, `None`.
pub fn parse_retry_after(value: &str, now: SystemTime) -> Option<Duration> {
    let value = value.trim();
    if value.is_empty() {
        return None;
    }
    if value.bytes().all(|b| b.is_ascii_digit()) {
        return Some(
            value
                .parse::<u64>()
                .map(Duration::from_secs)
                .unwrap_or(Duration::MAX),
        );
    }
    if value.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        let s: f64 = value.parse().ok()?;
        return Duration::try_from_secs_f64(s).ok();
    }
    let at = parse_http_date(value)?;
    let now = now.duration_since(UNIX_EPOCH).ok()?.as_secs_f64();
    Some(secs(at as f64 - now))
}

/// Seconds since the Unix epoch of an HTTP-date (GMT), in any of its three forms.
fn parse_http_date(value: &str) -> Option<i64> {
    let words: Vec<&str> = value.split_ascii_whitespace().collect();
    let (year, month, day, time) = match words.as_slice() {
        // IMF-fixdate: Sun, 06 Nov 1994 08:49:37 GMT
        [wday, day, month, year, time, "GMT"]
            if wday.strip_suffix(',').is_some_and(is_short_day) =>
        {
            if day.len() != 2 || year.len() != 4 {
                return None;
            }
            (number(year)?, month_number(month)?, number(day)?, *time)
        }
        // RFC 850: Sunday, 06-Nov-94 08:49:37 GMT
        [wday, date, time, "GMT"] if wday.strip_suffix(',').is_some_and(is_long_day) => {
            let mut parts = date.split('-');
            let (day, month, year) = (parts.next()?, parts.next()?, parts.next()?);
            if parts.next().is_some() || day.len() != 2 || year.len() != 2 {
                return None;
            }
            let yy = number(year)?;
            let year = if yy < 70 { 2000 + yy } else { 1900 + yy };
            (year, month_number(month)?, number(day)?, *time)
        }
        // asctime: Sun Nov  6 08:49:37 1994
        [wday, month, day, time, year] if is_short_day(wday) => {
            if day.is_empty() || day.len() > 2 || year.len() != 4 {
                return None;
            }
            (number(year)?, month_number(month)?, number(day)?, *time)
        }
        _ => return None,
    };
    let mut hms = time.split(':');
    let (h, m, s) = (hms.next()?, hms.next()?, hms.next()?);
    if hms.next().is_some() || h.len() != 2 || m.len() != 2 || s.len() != 2 {
        return None;
    }
    let (h, m, s) = (number(h)?, number(m)?, number(s)?);
    if h > 23 || m > 59 || s > 60 || day < 1 || day > days_in_month(year, month) {
        return None;
    }
    Some(days_from_civil(year, month, day) * 86_400 + h * 3600 + m * 60 + s)
}

fn number(s: &str) -> Option<i64> {
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

fn is_short_day(s: &str) -> bool {
    matches!(s, "Mon" | "Tue" | "Wed" | "Thu" | "Fri" | "Sat" | "Sun")
}

fn is_long_day(s: &str) -> bool {
    matches!(
        s,
        "Monday" | "Tuesday" | "Wednesday" | "Thursday" | "Friday" | "Saturday" | "Sunday"
    )
}

fn month_number(s: &str) -> Option<i64> {
    const MONTHS: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    MONTHS.iter().position(|m| *m == s).map(|i| i as i64 + 1)
}

fn days_in_month(year: i64, month: i64) -> i64 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (Howard Hinnant's `days_from_civil`).
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Seconds to a [`Duration`], with negative, NaN and huge values clamped.
fn secs(s: f64) -> Duration {
    if s.is_nan() || s <= 0.0 {
        Duration::ZERO
    } else {
        Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX)
    }
}

fn finite_non_negative(v: f64) -> f64 {
    if v.is_finite() && v > 0.0 { v } else { 0.0 }
}

/// At most `max` bytes of `s`, cut on a character boundary, with an ellipsis when cut.
fn truncate(s: &str, max: usize) -> String {
    if s.len() <= max {
        return s.to_owned();
    }
    let mut end = max;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &s[..end])
}

/// An error and its sources, `: `-separated (reqwest's own message is terse).
fn chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut out = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let text = s.to_string();
        if !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        source = s.source();
    }
    out
}

/// Whether `url`'s host is this machine.
fn is_loopback(url: &str) -> bool {
    let rest = url.split_once("://").map_or(url, |(_, rest)| rest);
    let authority = rest.split(['/', '?', '#']).next().unwrap_or("");
    let host = authority.rsplit_once('@').map_or(authority, |(_, h)| h);
    let host = if let Some(bracketed) = host.strip_prefix('[') {
        bracketed.split(']').next().unwrap_or("")
    } else {
        host.split(':').next().unwrap_or("")
    };
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> EndpointConfig {
        EndpointConfig::new("http://127.0.0.1:1/v1", "m")
    }

    #[test]
    fn defaults_fill_a_minimal_table() {
        let parsed: EndpointConfig =
            toml::from_str("base_url = \"http://127.0.0.1:8000/v1\"\nmodel = \"qwen\"\n").unwrap();
        assert_eq!(
            parsed,
            EndpointConfig::new("http://127.0.0.1:8000/v1", "qwen")
        );
        assert_eq!(parsed.temperature, 0.7);
        assert_eq!(parsed.max_tokens, 256);
        assert_eq!(parsed.timeout_s, 60.0);
        assert_eq!(parsed.concurrency, 4);
        assert_eq!(parsed.retries, 4);
        assert_eq!(parsed.image_detail, "auto");
        assert!(parsed.validate().is_ok());
    }

    #[test]
    fn unknown_fields_are_rejected() {
        let err = toml::from_str::<EndpointConfig>(
            "base_url = \"http://x/v1\"\nmodel = \"m\"\ntemprature = 0.1\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("temprature"), "{err}");
    }

    #[test]
    fn validation_names_the_field() {
        let mut c = cfg();
        c.image_detail = "medium".into();
        let err = c.validate().unwrap_err().to_string();
        assert!(err.contains("image_detail"), "{err}");
        let mut c = cfg();
        c.concurrency = 0;
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("concurrency")
        );
        let mut c = cfg();
        c.requests_per_minute = Some(0.0);
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("requests_per_minute")
        );
        let mut c = cfg();
        c.base_url = "127.0.0.1:8000/v1".into();
        assert!(c.validate().unwrap_err().to_string().contains("base_url"));
    }

    #[test]
    fn missing_key_variable_is_named() {
        let mut c = cfg();
        c.api_key_env = Some("ASSAY_JUDGE_UNIT_TEST_KEY_THAT_IS_NEVER_SET_7f3a".into());
        let err = Endpoint::new(c).unwrap_err();
        assert!(matches!(err, CallError::Config(_)));
        assert!(
            err.to_string()
                .contains("ASSAY_JUDGE_UNIT_TEST_KEY_THAT_IS_NEVER_SET_7f3a"),
            "{err}"
        );
    }

    #[test]
    fn debug_redacts_the_key() {
        let e = Endpoint::with_api_key(cfg(), Some("sk-secret".into())).unwrap();
        let shown = format!("{e:?}");
        assert!(!shown.contains("sk-secret"), "{shown}");
        assert!(shown.contains("redacted"), "{shown}");
    }

    #[test]
    fn backoff_grows_and_caps() {
        let c = cfg(); // initial 1 s, max 30 s
        let full = |attempt| backoff_delay(&c, attempt, None, 1.0);
        assert_eq!(full(0), Duration::from_secs(1));
        assert_eq!(full(1), Duration::from_secs(2));
        assert_eq!(full(2), Duration::from_secs(4));
        assert_eq!(full(4), Duration::from_secs(16));
        assert_eq!(full(5), Duration::from_secs(30));
        assert_eq!(full(1000), Duration::from_secs(30));
    }

    #[test]
    fn backoff_jitter_scales_uniformly() {
        let c = cfg();
        assert_eq!(backoff_delay(&c, 2, None, 0.0), Duration::ZERO);
        assert_eq!(backoff_delay(&c, 2, None, 0.5), Duration::from_secs(2));
        assert_eq!(backoff_delay(&c, 2, None, 0.25), Duration::from_secs(1));
        // Out-of-range units are clamped, never panic.
        assert_eq!(backoff_delay(&c, 2, None, -3.0), Duration::ZERO);
        assert_eq!(backoff_delay(&c, 2, None, f64::NAN), Duration::ZERO);
        assert_eq!(backoff_delay(&c, 2, None, 7.0), Duration::from_secs(4));
    }

    #[test]
    fn backoff_honours_retry_after() {
        let c = cfg();
        // The server's wait is a floor over the jittered delay ...
        assert_eq!(
            backoff_delay(&c, 0, Some(Duration::from_secs(5)), 0.1),
            Duration::from_secs(5)
        );
        // ... which does not shorten a longer exponential delay ...
        assert_eq!(
            backoff_delay(&c, 4, Some(Duration::from_secs(5)), 1.0),
            Duration::from_secs(16)
        );
        // ... and is capped.
        assert_eq!(
            backoff_delay(&c, 0, Some(Duration::from_secs(86_400)), 0.0),
            MAX_RETRY_AFTER
        );
    }

    #[test]
    fn backoff_survives_odd_configs() {
        let mut c = cfg();
        c.backoff_initial_s = f64::INFINITY;
        c.backoff_max_s = f64::NAN;
        assert_eq!(backoff_delay(&c, 3, None, 0.9), Duration::ZERO);
        let mut c = cfg();
        c.backoff_max_s = 1e12;
        assert_eq!(backoff_delay(&c, 60, None, 1.0), MAX_RETRY_AFTER);
    }

    #[test]
    fn retry_after_seconds() {
        let now = SystemTime::now();
        assert_eq!(parse_retry_after("1", now), Some(Duration::from_secs(1)));
        assert_eq!(
            parse_retry_after(" 120 ", now),
            Some(Duration::from_secs(120))
        );
        assert_eq!(parse_retry_after("0", now), Some(Duration::ZERO));
        assert_eq!(
            parse_retry_after("1.5", now),
            Some(Duration::from_millis(1500))
        );
        assert_eq!(
            parse_retry_after("99999999999999999999999", now),
            Some(Duration::MAX)
        );
    }

    #[test]
    fn retry_after_dates() {
        // 2015-10-21T07:28:00Z is 1445412480 s after the epoch.
        let at = UNIX_EPOCH + Duration::from_secs(1_445_412_480);
        let before = at - Duration::from_secs(90);
        for form in [
            "Wed, 21 Oct 2015 07:28:00 GMT",
            "Wednesday, 21-Oct-15 07:28:00 GMT",
            "Wed Oct 21 07:28:00 2015",
        ] {
            assert_eq!(
                parse_retry_after(form, before),
                Some(Duration::from_secs(90)),
                "{form}"
            );
        }
        // asctime pads single-digit days with a space.
        let nov6 = UNIX_EPOCH + Duration::from_secs(784_111_777); // 1994-11-06T08:49:37Z
        assert_eq!(
            parse_retry_after("Sun Nov  6 08:49:37 1994", nov6),
            Some(Duration::ZERO)
        );
        assert_eq!(
            parse_retry_after(
                "Sun, 06 Nov 1994 08:49:37 GMT",
                nov6 - Duration::from_secs(1)
            ),
            Some(Duration::from_secs(1))
        );
        // A date in the past means "now".
        assert_eq!(
            parse_retry_after(
                "Wed, 21 Oct 2015 07:28:00 GMT",
                at + Duration::from_secs(10)
            ),
            Some(Duration::ZERO)
        );
        // Leap day.
        let leap = UNIX_EPOCH + Duration::from_secs(951_782_400); // 2000-02-29T00:00:00Z
        assert_eq!(
            parse_retry_after("Tue, 29 Feb 2000 00:00:00 GMT", leap),
            Some(Duration::ZERO)
        );
    }

    #[test]
    fn retry_after_garbage() {
        let now = SystemTime::now();
        for bad in [
            "",
            "   ",
            "-1",
            "soon",
            "1e3",
            "1.2.3",
            "Wed, 21 Oct 2015 07:28:00 UTC",
            "Wed, 21 Oct 2015 07:28 GMT",
            "Wed, 32 Oct 2015 07:28:00 GMT",
            "Wed, 29 Feb 2015 07:28:00 GMT",
            "Wed, 21 Foo 2015 07:28:00 GMT",
            "Xyz, 21 Oct 2015 07:28:00 GMT",
            "Wed, 21 Oct 2015 24:00:00 GMT",
            "Wed, 21 Oct 15 07:28:00 GMT",
            "Wednesday, 21-Oct-2015 07:28:00 GMT",
        ] {
            assert_eq!(parse_retry_after(bad, now), None, "{bad:?}");
        }
    }

    #[test]
    fn cost_uses_both_prices() {
        let mut c = cfg();
        c.price_input_per_mtok = 2.5;
        c.price_output_per_mtok = 10.0;
        let e = Endpoint::with_api_key(c, None).unwrap();
        let cost = e.cost_usd(1_000_000, 500_000);
        assert!((cost - 7.5).abs() < 1e-12, "{cost}");
        assert_eq!(e.cost_usd(0, 0), 0.0);
        let free = Endpoint::with_api_key(cfg(), None).unwrap();
        assert_eq!(free.cost_usd(123_456, 789), 0.0);
    }

    #[test]
    fn retryable_classes() {
        let status = |code| CallError::Status {
            code,
            retry_after: None,
            body: String::new(),
        };
        for code in [408, 409, 429, 500, 502, 503, 504] {
            assert!(status(code).retryable(), "{code}");
        }
        for code in [400, 401, 403, 404, 413, 422] {
            assert!(!status(code).retryable(), "{code}");
        }
        assert!(CallError::Timeout(Duration::from_secs(1)).retryable());
        assert!(CallError::Transport("reset".into()).retryable());
        assert!(!CallError::BadResponse("html".into()).retryable());
        assert!(!CallError::Config("no key".into()).retryable());
    }

    #[test]
    fn body_shape() {
        let mut c = cfg();
        c.image_detail = "low".into();
        let body = request_body(
            &c,
            &ChatRequest {
                prompt_version: "v1".into(),
                system: Some("be strict".into()),
                text: "score it".into(),
                images: vec![vec![1, 2, 3]],
            },
        );
        assert_eq!(body["model"], "m");
        assert_eq!(
            body["messages"][0],
            json!({"role": "system", "content": "be strict"})
        );
        assert_eq!(body["messages"][1]["role"], "user");
        assert_eq!(
            body["messages"][1]["content"][0],
            json!({"type": "text", "text": "score it"})
        );
        assert_eq!(
            body["messages"][1]["content"][1],
            json!({"type": "image_url", "image_url": {"url": "data:image/png;base64,AQID", "detail": "low"}})
        );
        assert_eq!(body["max_tokens"], 256);
    }

    #[test]
    fn answer_parsing() {
        let a = parse_answer(br#"{"choices":[{"message":{"content":[{"type":"text","text":"Score: "},{"type":"image_url"},{"type":"text","text":"3"}]}}]}"#).unwrap();
        assert_eq!(
            a,
            ChatAnswer {
                text: "Score: 3".into(),
                tokens_in: 0,
                tokens_out: 0
            }
        );
        assert!(matches!(
            parse_answer(b"<html>"),
            Err(CallError::BadResponse(_))
        ));
        assert!(matches!(
            parse_answer(br#"{"choices":[]}"#),
            Err(CallError::BadResponse(_))
        ));
        assert!(matches!(
            parse_answer(br#"{"error":{"message":"overloaded"}}"#),
            Err(CallError::BadResponse(m)) if m.contains("overloaded")
        ));
        let refused = parse_answer(br#"{"choices":[{"message":{"content":null,"refusal":"no"}}]}"#)
            .unwrap_err();
        assert!(refused.to_string().contains("refusal"), "{refused}");
    }

    #[test]
    fn loopback_hosts() {
        assert!(is_loopback("http://127.0.0.1:8000/v1/chat/completions"));
        assert!(is_loopback("http://localhost/v1"));
        assert!(is_loopback("http://[::1]:8080/v1"));
        assert!(is_loopback("http://user:pw@127.0.0.2:1/v1"));
        assert!(!is_loopback("https://api.openai.com/v1"));
        assert!(!is_loopback("http://10.0.0.1:8000/v1"));
    }

    #[test]
    fn truncation_respects_characters() {
        assert_eq!(truncate("abc", 5), "abc");
        assert_eq!(truncate("ééé", 3), "é…");
    }

    #[tokio::test]
    async fn rate_limiter_spaces_starts() {
        let limiter = RateLimiter::new(Duration::from_millis(20));
        let t0 = Instant::now();
        for _ in 0..5 {
            limiter.wait().await;
        }
        // The first start is free; the other four wait one spacing each.
        assert!(
            t0.elapsed() >= Duration::from_millis(80),
            "{:?}",
            t0.elapsed()
        );
    }
}
