//! A policy served over openpi's websocket protocol (`openpi:url=ws://HOST:PORT`), as openpi's
//! `scripts/serve_policy.py` (π0, π0-FAST, π0.5) and RoboArena servers speak it, called
//! synchronously from a simulator shard thread.
//!
//! The protocol (openpi's `WebsocketPolicyServer` and `openpi_client`): on connect the server
//! sends one binary message, its metadata; then every observation is one binary message and the
//! answer one binary message. Both are msgpack, with numpy arrays packed as maps
//! `{"__ndarray__": true, "data": <bytes>, "dtype": "<f4", "shape": [..]}` (openpi_client's
//! `msgpack_numpy`). A text message is the server's error (its traceback), after which it closes.
//!
//! What Assay sends, by the policy's [`Interface`]: each camera as `observation/<name>` (uint8
//! `[H, W, 3]`), depth as `observation/<name>_depth` (float32 `[H, W]`), the state vector as
//! `observation/state` (float32) and the instruction as `prompt`. What it reads: `actions`, a
//! float array `[K, D]` (or `[D]`: one action). One websocket connection is one episode (the
//! server's per-connection state starts fresh at every reset).
//!
//! Errors: a server that is down, closes, or answers later than `timeout_ms` is
//! [`PolicyError::Unavailable`] (the shard is retried); an error text or an answer that is not a
//! chunk of finite actions is [`PolicyError::BadAnswer`]. With `api_key_env=VAR` the key in that
//! environment variable goes as `Authorization: Api-Key <key>` (openpi_client's header).
//!
//! The policy string comes with a batch, from its submitter, and so do the URL and the variable
//! it names: in a worker only the variables its operator allowed ([`allow_key_vars`]) may be
//! sent, or a submitter could have any secret in a worker's environment sent to a server of
//! their choosing.

use std::io::Cursor;
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use assay_model::policy::{EpisodeContext, Interface, Policy, PolicyError, PolicyObservation};
use rmpv::Value;
use tungstenite::client::IntoClientRequest;
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

use crate::server::MAX_CHUNK;

/// Largest message read from a server (an answer is a few kilobytes; metadata may be larger).
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// The environment variables an `api_key_env` may name in this process, set once by a worker's
/// operator ([`allow_key_vars`]). Unset, the process is no worker (a user's own tool, a test,
/// `assay policy serve`): the policy string is its user's own, and any variable may be named.
static KEY_VARS: OnceLock<Vec<String>> = OnceLock::new();

/// Allows `api_key_env` to name only `vars` in this process (a worker: none given, no variable).
/// Set once, at start: the same list again is harmless, another is an error.
pub fn allow_key_vars(vars: &[String]) -> Result<(), String> {
    let mut vars = vars.to_vec();
    vars.sort();
    vars.dedup();
    if let Some(bad) = vars
        .iter()
        .find(|v| v.is_empty() || v.contains(['=', '\0']))
    {
        return Err(format!("policy key variable {bad:?}: not a variable name"));
    }
    match KEY_VARS.set(vars.clone()) {
        Ok(()) => Ok(()),
        Err(_) if KEY_VARS.get() == Some(&vars) => Ok(()),
        Err(_) => Err("the policy key variables are already set, to others".to_owned()),
    }
}

/// Whether `api_key_env=var` may be used here: any variable outside a worker, the operator's in
/// one.
fn key_var_allowed(var: &str) -> Result<(), String> {
    match KEY_VARS.get() {
        None => Ok(()),
        Some(allowed) if allowed.iter().any(|v| v == var) => Ok(()),
        Some(allowed) if allowed.is_empty() => Err(format!(
            "api_key_env={var}: this worker sends no key from its environment (its operator \
             allows variables with --policy-key-env VAR or ASSAY_POLICY_KEY_ENVS)"
        )),
        Some(allowed) => Err(format!(
            "api_key_env={var}: not one of the variables this worker's operator allows \
             policies to send ({})",
            allowed.join(", ")
        )),
    }
}

pub struct OpenPiPolicy {
    url: String,
    timeout: Duration,
    api_key: Option<String>,
    interface: Interface,
    socket: Option<WebSocket<TcpStream>>,
    /// Whether the open connection has served an episode already.
    used: bool,
    /// The server's metadata (msgpack), as it sent it on connect.
    pub metadata: Value,
    instruction: String,
}

impl std::fmt::Debug for OpenPiPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenPiPolicy")
            .field("url", &self.url)
            .field("timeout", &self.timeout)
            .field("interface", &self.interface)
            .finish()
    }
}

impl OpenPiPolicy {
    /// Connects to the server at `url` (`ws://host:port[/path]`) within `timeout` and reads its
    /// metadata. `api_key_env` names the environment variable holding its API key.
    pub fn new(
        url: &str,
        timeout: Duration,
        api_key_env: Option<&str>,
        interface: Interface,
    ) -> Result<OpenPiPolicy, PolicyError> {
        interface
            .validate()
            .map_err(|e| PolicyError::Load(format!("openpi policy at {url}: {e}")))?;
        if let Some(var) = api_key_env {
            // Before the variable is read: a refused name tells nothing of its value.
            key_var_allowed(var)
                .map_err(|e| PolicyError::Load(format!("openpi policy at {url}: {e}")))?;
        }
        let api_key = match api_key_env {
            Some(var) => Some(std::env::var(var).map_err(|_| {
                PolicyError::Load(format!(
                    "openpi policy at {url}: api_key_env={var}, but {var} is not set on this worker"
                ))
            })?),
            None => None,
        };
        let mut policy = OpenPiPolicy {
            url: url.to_owned(),
            timeout,
            api_key,
            interface,
            socket: None,
            used: false,
            metadata: Value::Nil,
            instruction: String::new(),
        };
        policy.connect()?;
        Ok(policy)
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn down(&self, reason: impl std::fmt::Display) -> PolicyError {
        PolicyError::Unavailable(format!("openpi server at {} is down: {reason}", self.url))
    }

    fn connect(&mut self) -> Result<(), PolicyError> {
        if let Some(mut old) = self.socket.take() {
            let _ = old.close(None);
            let _ = old.flush();
        }
        if self.url.starts_with("wss://") {
            return Err(PolicyError::Load(format!(
                "openpi policy at {}: wss:// (TLS) is not supported; reach the server over ws:// \
                 (an SSH tunnel or a TLS-terminating proxy)",
                self.url
            )));
        }
        let mut request = self
            .url
            .as_str()
            .into_client_request()
            .map_err(|e| PolicyError::Load(format!("bad openpi url '{}': {e}", self.url)))?;
        if let Some(key) = &self.api_key {
            let value = format!("Api-Key {key}").parse().map_err(|_| {
                PolicyError::Load("the openpi API key is not a valid header".into())
            })?;
            request.headers_mut().insert("authorization", value);
        }
        let uri = request.uri();
        let host = uri.host().unwrap_or("").trim_matches(['[', ']']).to_owned();
        let port = uri.port_u16().unwrap_or(80);
        let addr = (host.as_str(), port)
            .to_socket_addrs()
            .map_err(|e| self.down(format!("cannot resolve {host}: {e}")))?
            .next()
            .ok_or_else(|| self.down(format!("{host} has no address")))?;
        let stream = TcpStream::connect_timeout(&addr, self.timeout)
            .map_err(|e| self.down(format!("cannot connect: {e}")))?;
        stream
            .set_nodelay(true)
            .and_then(|_| stream.set_read_timeout(Some(self.timeout)))
            .and_then(|_| stream.set_write_timeout(Some(self.timeout)))
            .map_err(|e| self.down(e))?;
        let config = WebSocketConfig::default()
            .max_message_size(Some(MAX_MESSAGE_BYTES))
            .max_frame_size(Some(MAX_MESSAGE_BYTES));
        let (mut socket, _) =
            tungstenite::client::client_with_config(request, stream, Some(config)).map_err(
                |e| match e {
                    tungstenite::HandshakeError::Failure(tungstenite::Error::Http(r)) => {
                        PolicyError::Load(format!(
                            "openpi server at {} refused the connection: HTTP {}{}",
                            self.url,
                            r.status(),
                            if r.status() == 401 || r.status() == 403 {
                                " (check api_key_env)"
                            } else {
                                ""
                            }
                        ))
                    }
                    other => self.down(format!("websocket handshake: {other}")),
                },
            )?;
        let bytes = self.receive(&mut socket, "its metadata")?;
        let metadata = rmpv::decode::read_value(&mut Cursor::new(&bytes[..])).map_err(|e| {
            PolicyError::BadAnswer(format!(
                "openpi server at {}: its metadata is not msgpack: {e}",
                self.url
            ))
        })?;
        self.metadata = metadata;
        self.socket = Some(socket);
        self.used = false;
        Ok(())
    }

    /// Reads one data message; a text message is the server's error.
    fn receive(
        &self,
        socket: &mut WebSocket<TcpStream>,
        what: &str,
    ) -> Result<Vec<u8>, PolicyError> {
        let start = Instant::now();
        loop {
            match socket.read() {
                Ok(Message::Binary(b)) => return Ok(b.to_vec()),
                Ok(Message::Text(t)) => {
                    return Err(PolicyError::BadAnswer(format!(
                        "openpi server at {} failed instead of sending {what}: {}",
                        self.url,
                        last_lines(t.as_str(), 3)
                    )));
                }
                Ok(Message::Close(frame)) => {
                    return Err(self.down(format!(
                        "it closed the connection instead of sending {what}{}",
                        frame.map_or(String::new(), |f| format!(" ({})", f.reason))
                    )));
                }
                Ok(_) => continue,
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Err(PolicyError::Unavailable(format!(
                        "openpi server at {} did not send {what} within the {} ms deadline \
                         (waited {} ms)",
                        self.url,
                        self.timeout.as_millis(),
                        start.elapsed().as_millis()
                    )));
                }
                Err(e) => return Err(self.down(e)),
            }
        }
    }
}

/// The last `n` lines of a traceback (its message).
fn last_lines(s: &str, n: usize) -> String {
    let lines: Vec<&str> = s.trim_end().lines().collect();
    lines[lines.len().saturating_sub(n)..].join(" | ")
}

/// A numpy array as openpi_client's msgpack_numpy packs it.
fn ndarray(dtype: &str, shape: &[usize], data: Vec<u8>) -> Value {
    Value::Map(vec![
        (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
        (Value::Binary(b"data".to_vec()), Value::Binary(data)),
        (Value::Binary(b"dtype".to_vec()), Value::from(dtype)),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&d| Value::from(d as u64)).collect()),
        ),
    ])
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The observation as openpi servers take it.
pub fn encode_observation(obs: &PolicyObservation, prompt: &str) -> Vec<u8> {
    let mut map = Vec::with_capacity(obs.images.len() * 2 + 2);
    for im in &obs.images {
        let (h, w) = (im.height as usize, im.width as usize);
        map.push((
            Value::from(format!("observation/{}", im.name)),
            ndarray("|u1", &[h, w, 3], im.rgb.clone()),
        ));
        if !im.depth.is_empty() {
            map.push((
                Value::from(format!("observation/{}_depth", im.name)),
                ndarray("<f4", &[h, w], f32_bytes(&im.depth)),
            ));
        }
    }
    map.push((
        Value::from("observation/state"),
        ndarray("<f4", &[obs.state.len()], f32_bytes(&obs.state)),
    ));
    map.push((Value::from("prompt"), Value::from(prompt)));
    let mut out = Vec::with_capacity(obs.images.iter().map(|i| i.rgb.len()).sum::<usize>() + 256);
    rmpv::encode::write_value(&mut out, &Value::Map(map)).expect("writing to a Vec");
    out
}

fn key_is(k: &Value, name: &str) -> bool {
    match k {
        Value::String(s) => s.as_str() == Some(name),
        Value::Binary(b) => b == name.as_bytes(),
        _ => false,
    }
}

fn field<'v>(map: &'v [(Value, Value)], name: &str) -> Option<&'v Value> {
    map.iter().find(|(k, _)| key_is(k, name)).map(|(_, v)| v)
}

/// Reads `actions` from a server's answer: a float array `[K, D]` or `[D]`, finite.
pub fn decode_actions(bytes: &[u8]) -> Result<Vec<Vec<f32>>, String> {
    let value = rmpv::decode::read_value(&mut Cursor::new(bytes))
        .map_err(|e| format!("the answer is not msgpack: {e}"))?;
    let Value::Map(map) = value else {
        return Err("the answer is not a map".into());
    };
    let actions = field(&map, "actions").ok_or_else(|| {
        let keys: Vec<String> = map.iter().map(|(k, _)| k.to_string()).collect();
        format!(
            "the answer has no 'actions' (its keys: {})",
            keys.join(", ")
        )
    })?;
    let (shape, values) = match actions {
        Value::Map(a) if field(a, "__ndarray__").is_some() => {
            let dtype = field(a, "dtype")
                .and_then(|d| match d {
                    Value::String(s) => s.as_str().map(str::to_owned),
                    Value::Binary(b) => String::from_utf8(b.clone()).ok(),
                    _ => None,
                })
                .ok_or("actions: an ndarray without a dtype")?;
            let shape: Vec<usize> = match field(a, "shape") {
                Some(Value::Array(s)) => s
                    .iter()
                    .map(|d| d.as_u64().map(|d| d as usize))
                    .collect::<Option<_>>()
                    .ok_or("actions: a shape that is not integers")?,
                _ => return Err("actions: an ndarray without a shape".into()),
            };
            let Some(Value::Binary(data)) = field(a, "data") else {
                return Err("actions: an ndarray without data".into());
            };
            let values: Vec<f32> = match dtype.as_str() {
                "<f4" => data
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                    .collect(),
                "<f8" => data
                    .chunks_exact(8)
                    .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
                    .collect(),
                "<f2" => data
                    .chunks_exact(2)
                    .map(|c| half_to_f32(u16::from_le_bytes([c[0], c[1]])))
                    .collect(),
                other => {
                    return Err(format!(
                        "actions: dtype '{other}' (expected float32, float64 or float16)"
                    ));
                }
            };
            (shape, values)
        }
        // A plain list of lists of numbers (a server that packs lists).
        Value::Array(rows) => {
            let as_f = |v: &Value| v.as_f64().map(|x| x as f32);
            if rows.iter().all(|r| matches!(r, Value::Array(_))) {
                let mut values = Vec::new();
                let mut d = None;
                for r in rows {
                    let Value::Array(r) = r else { unreachable!() };
                    if d.is_some_and(|d| d != r.len()) {
                        return Err("actions: rows of different lengths".into());
                    }
                    d = Some(r.len());
                    for x in r {
                        values.push(as_f(x).ok_or("actions: a value that is not a number")?);
                    }
                }
                (vec![rows.len(), d.unwrap_or(0)], values)
            } else {
                let values: Vec<f32> = rows
                    .iter()
                    .map(as_f)
                    .collect::<Option<_>>()
                    .ok_or("actions: a value that is not a number")?;
                (vec![values.len()], values)
            }
        }
        other => return Err(format!("actions is {other}, not an array")),
    };
    let (k, d) = match shape.as_slice() {
        [d] => (1, *d),
        [k, d] => (*k, *d),
        [1, k, d] => (*k, *d),
        _ => {
            return Err(format!(
                "actions has shape {shape:?}, expected [K, D] or [D]"
            ));
        }
    };
    if k == 0 || d == 0 || k * d != values.len() {
        return Err(format!(
            "actions has shape {shape:?} and {} values",
            values.len()
        ));
    }
    if k > MAX_CHUNK {
        return Err(format!("{k} actions in one chunk (at most {MAX_CHUNK})"));
    }
    if let Some(i) = values.iter().position(|x| !x.is_finite()) {
        return Err(format!(
            "action {} has the non-finite value {}",
            i / d,
            values[i]
        ));
    }
    Ok(values.chunks_exact(d).map(<[f32]>::to_vec).collect())
}

/// IEEE half to single precision.
fn half_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exp = u32::from((h >> 10) & 0x1f);
    let frac = u32::from(h & 0x3ff);
    let bits = match (exp, frac) {
        (0, 0) => sign,
        (0, f) => {
            // Subnormal: normalise.
            let shift = f.leading_zeros() - 21;
            sign | ((113 - shift) << 23) | (((f << shift) & 0x3ff) << 13)
        }
        (31, f) => sign | 0x7f80_0000 | (f << 13),
        (e, f) => sign | ((e + 112) << 23) | (f << 13),
    };
    f32::from_bits(bits)
}

impl Policy for OpenPiPolicy {
    /// A fresh connection for every episode after the first (openpi servers keep their state per
    /// connection).
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        if self.socket.is_none() || self.used {
            self.connect()?;
        }
        self.used = true;
        self.instruction = episode.instruction.clone();
        Ok(())
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let message = encode_observation(obs, &self.instruction);
        let mut socket = self.socket.take().ok_or_else(|| {
            PolicyError::Load(format!("openpi policy at {}: act before reset", self.url))
        })?;
        if let Err(e) = socket.send(Message::Binary(message.into())) {
            return Err(self.down(format!("sending the observation at step {}: {e}", obs.step)));
        }
        let bytes = self.receive(&mut socket, &format!("actions at step {}", obs.step))?;
        self.socket = Some(socket);
        decode_actions(&bytes).map_err(|reason| {
            PolicyError::BadAnswer(format!(
                "openpi server at {} at step {}: {reason}",
                self.url, obs.step
            ))
        })
    }

    fn interface(&self) -> Interface {
        self.interface.clone()
    }
}

impl Drop for OpenPiPolicy {
    fn drop(&mut self) {
        if let Some(mut s) = self.socket.take() {
            let _ = s.close(None);
            let _ = s.flush();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn answer(actions: Value) -> Vec<u8> {
        let mut out = Vec::new();
        rmpv::encode::write_value(
            &mut out,
            &Value::Map(vec![(Value::from("actions"), actions)]),
        )
        .unwrap();
        out
    }

    #[test]
    fn reads_openpi_answers_and_refuses_malformed_ones() {
        let two = ndarray("<f4", &[2, 3], f32_bytes(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
        assert_eq!(
            decode_actions(&answer(two)),
            Ok(vec![vec![1.0, 2.0, 3.0], vec![4.0, 5.0, 6.0]])
        );
        let f8: Vec<u8> = [0.5f64, -0.25]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(
            decode_actions(&answer(ndarray("<f8", &[2], f8))),
            Ok(vec![vec![0.5, -0.25]])
        );
        // 1.0 and -2.0 in half precision.
        assert_eq!(
            decode_actions(&answer(ndarray("<f2", &[2], vec![0x00, 0x3c, 0x00, 0xc0]))),
            Ok(vec![vec![1.0, -2.0]])
        );
        let nan = ndarray("<f4", &[1, 2], f32_bytes(&[0.0, f32::NAN]));
        assert!(
            decode_actions(&answer(nan))
                .unwrap_err()
                .contains("non-finite")
        );
        let short = ndarray("<f4", &[2, 3], f32_bytes(&[0.0; 5]));
        assert!(decode_actions(&answer(short)).is_err());
        let ints = ndarray("<i8", &[1], vec![0; 8]);
        assert!(decode_actions(&answer(ints)).unwrap_err().contains("dtype"));
        assert!(decode_actions(b"\xc1").is_err());
        let mut other = Vec::new();
        rmpv::encode::write_value(
            &mut other,
            &Value::Map(vec![(Value::from("action"), Value::from(1))]),
        )
        .unwrap();
        assert!(decode_actions(&other).unwrap_err().contains("no 'actions'"));
    }
}
