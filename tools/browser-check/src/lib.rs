//! Opens a self-contained HTML report (a local file) in headless Chromium and checks that it
//! renders without errors and without reaching outside the machine.
//!
//! Speaks the Chrome DevTools Protocol directly over one websocket (flattened sessions): no
//! tokio, no browser-automation crate. A check fails on
//! - a console error (`console.error`, a failed `console.assert`, or a browser-side error entry
//!   such as "Failed to load resource"),
//! - an uncaught exception,
//! - a failed request (`Network.loadingFailed`, or an HTTP status of 400 or more),
//! - any request to a non-local URL: everything but `file:` and `data:` (plus `blob:` and
//!   `about:`, which never leave the browser),
//! - an `<img>` that finished loading with no pixels (`complete && naturalWidth == 0`),
//! - a page whose load did not settle within [`Options::timeout`].
//!
//! Console warnings are collected in [`PageCheck::warnings`] and do not fail the check.
//!
//! Favicons: with Chromium 156 `--headless=new`, a page under `file://` without
//! `<link rel="icon">` makes no favicon request: no `Network.requestWillBeSent` for
//! `favicon.ico` (the test `no_favicon_request_without_icon_link` pins it), and under strace no
//! process of the browser even looks for `favicon.ico` next to the page. Chromium only guesses
//! `/favicon.ico` for http(s) pages, and a favicon it does fetch comes from the browser process,
//! outside the page's network domain. `<link rel="icon" href="data:,">` stays the safe choice
//! for reports served over http.
//!
//! Chromium is found through `ASSAY_CHROMIUM`, else `chromium`, `chromium-browser` or
//! `google-chrome` on `PATH` (Debian: `apt-get install chromium`).

use std::collections::{HashMap, VecDeque};
use std::fs;
use std::io::{self, ErrorKind};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine as _;
use serde_json::{Value, json};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

/// How long Chromium may take to write `DevToolsActivePort` after it starts: about 1.5 s on an
/// idle 2-core machine, but more than 20 s once in the integration suite, beside a test whose
/// simulations kept both cores busy (2026-12-02). A deadline for a browser that hangs, not a
/// speed check.
const STARTUP_TIMEOUT: Duration = Duration::from_secs(90);
/// After the load event, the page counts as settled after this long without network activity
/// and with no request in flight.
const QUIET_PERIOD: Duration = Duration::from_millis(500);
/// A DevTools command (screenshot, evaluate) may take this long on a big page.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(60);
/// URLs in findings are cut to this many characters (data: URLs run to megabytes).
const URL_SHOWN: usize = 160;

#[derive(Debug, Clone)]
pub struct Options {
    /// Viewport in CSS pixels (device scale factor 1), also the screenshot size unless
    /// `full_page`.
    pub viewport: (u32, u32),
    /// Screenshot the whole page (`captureBeyondViewport`) instead of the viewport.
    pub full_page: bool,
    /// Limit for the page to load and settle.
    pub timeout: Duration,
    /// Where to write the PNG screenshot (one is always taken, so a page that cannot be
    /// rendered fails the check either way).
    pub screenshot: Option<PathBuf>,
    /// Opened as `FILE#fragment` (a page's anchor or a `:target` section).
    pub fragment: Option<String>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            viewport: (1280, 900),
            full_page: false,
            timeout: Duration::from_secs(60),
            screenshot: None,
            fragment: None,
        }
    }
}

/// What a page did while it loaded. [`PageCheck::problems`] lists what fails it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PageCheck {
    pub title: String,
    /// `console.error`, failed `console.assert`, and browser error entries (`Log.entryAdded`).
    pub console_errors: Vec<String>,
    /// Uncaught exceptions and unhandled promise rejections.
    pub exceptions: Vec<String>,
    /// Requests that failed, answered 400 or more, or were still in flight at the timeout.
    pub failed_requests: Vec<String>,
    /// Requests to anything but `file:`, `data:`, `blob:` or `about:` URLs.
    pub external_requests: Vec<String>,
    /// `<img>` elements that finished loading without an image.
    pub broken_images: u32,
    pub images: u32,
    /// Console warnings and browser warning entries: reported, never failing.
    pub warnings: Vec<String>,
    /// Size of the PNG screenshot taken.
    pub screenshot_bytes: usize,
    /// The load event did not fire, or the network did not settle, within the timeout.
    pub timed_out: bool,
}

impl PageCheck {
    /// Every finding that fails the check, one line each.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        out.extend(
            self.console_errors
                .iter()
                .map(|m| format!("console error: {m}")),
        );
        out.extend(
            self.exceptions
                .iter()
                .map(|m| format!("uncaught exception: {m}")),
        );
        out.extend(
            self.failed_requests
                .iter()
                .map(|m| format!("failed request: {m}")),
        );
        out.extend(
            self.external_requests
                .iter()
                .map(|m| format!("non-local request: {m}")),
        );
        if self.broken_images > 0 {
            out.push(format!(
                "{} of {} images are broken",
                self.broken_images, self.images
            ));
        }
        if self.timed_out {
            out.push("the page did not finish loading within the timeout".to_owned());
        }
        out
    }

    pub fn is_clean(&self) -> bool {
        self.problems().is_empty()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(
        "no Chromium found: set ASSAY_CHROMIUM or put chromium, chromium-browser or google-chrome \
         on PATH (Debian: `apt-get install chromium`)"
    )]
    NoChromium,
    #[error("{0}: {1}")]
    Io(String, #[source] io::Error),
    #[error("Chromium did not start: {0}")]
    Startup(String),
    #[error("DevTools websocket: {0}")]
    WebSocket(String),
    #[error("DevTools {method} failed: {message}")]
    Protocol { method: String, message: String },
    #[error("DevTools {0} got no answer in time")]
    CommandTimeout(String),
    #[error("the renderer crashed while loading {0}")]
    Crashed(String),
    #[error("navigation to {url} failed: {error}")]
    Navigate { url: String, error: String },
}

impl From<tungstenite::Error> for Error {
    fn from(e: tungstenite::Error) -> Self {
        Error::WebSocket(e.to_string())
    }
}

/// Loads `path` in a fresh headless Chromium and reports what happened. `Err` means the check
/// could not run (no Chromium, no file, protocol trouble); findings about the page are in the
/// returned [`PageCheck`].
pub fn check_file(path: &Path, options: &Options) -> Result<PageCheck, Error> {
    let abs = fs::canonicalize(path)
        .map_err(|e| Error::Io(format!("cannot open {}", path.display()), e))?;
    let mut url = file_url(&abs);
    if let Some(f) = &options.fragment {
        url.push('#');
        url.push_str(f);
    }
    let mut browser = Browser::launch(options.viewport)?;
    let result = run_check(&mut browser.cdp, &url, options);
    browser.close();
    result
}

fn run_check(cdp: &mut Cdp, url: &str, options: &Options) -> Result<PageCheck, Error> {
    let target = cdp.call(None, "Target.createTarget", json!({"url": "about:blank"}))?;
    let target_id = str_field(&target, "targetId");
    let attached = cdp.call(
        None,
        "Target.attachToTarget",
        json!({"targetId": target_id, "flatten": true}),
    )?;
    let session = str_field(&attached, "sessionId");
    let s = Some(session.as_str());
    for method in [
        "Page.enable",
        "Runtime.enable",
        "Log.enable",
        "Network.enable",
        "Inspector.enable",
    ] {
        cdp.call(s, method, json!({}))?;
    }
    let (width, height) = options.viewport;
    cdp.call(
        s,
        "Emulation.setDeviceMetricsOverride",
        json!({"width": width, "height": height, "deviceScaleFactor": 1, "mobile": false}),
    )?;
    // Anything about:blank said before the navigation is not the page's.
    cdp.events.clear();

    let mut watch = Watch::default();
    let nav = cdp.call(s, "Page.navigate", json!({"url": url}))?;
    if let Some(error) = nav
        .get("errorText")
        .and_then(Value::as_str)
        .filter(|e| !e.is_empty())
    {
        return Err(Error::Navigate {
            url: url.to_owned(),
            error: error.to_owned(),
        });
    }

    let deadline = Instant::now() + options.timeout;
    let mut last_network = Instant::now();
    loop {
        let now = Instant::now();
        if watch.loaded && watch.in_flight.is_empty() && now >= last_network + QUIET_PERIOD {
            break;
        }
        if now >= deadline {
            watch.timed_out = true;
            break;
        }
        let settling = watch.loaded && watch.in_flight.is_empty();
        let wait_until = if settling {
            (last_network + QUIET_PERIOD).min(deadline)
        } else {
            deadline
        };
        let Some(event) = cdp.next_event(wait_until.max(now + Duration::from_millis(10)))? else {
            continue;
        };
        if event.get("sessionId").and_then(Value::as_str) != s {
            continue;
        }
        if event["method"] == "Inspector.targetCrashed" {
            return Err(Error::Crashed(url.to_owned()));
        }
        if watch.observe(&event) {
            last_network = Instant::now();
        }
    }
    watch.check.timed_out = watch.timed_out;
    if watch.timed_out {
        // A script that never returns would also hold up the probes below: stop it.
        cdp.call(s, "Runtime.terminateExecution", json!({}))?;
        for url in watch.in_flight.values() {
            watch
                .check
                .failed_requests
                .push(format!("{} (still pending at the timeout)", shorten(url)));
        }
    }

    // Title and images. Broken: finished loading (`complete`) with no pixels. An SVG without
    // intrinsic size still reports a natural size (300x150) once decoded, so it is not counted.
    let probe = cdp.call(
        s,
        "Runtime.evaluate",
        json!({
            "expression": "(() => { const imgs = Array.from(document.images); return { title: document.title, \
                images: imgs.length, broken: imgs.filter(i => i.complete && i.naturalWidth === 0)\
                .map(i => i.currentSrc || i.getAttribute('src') || '(no src)') }; })()",
            "returnByValue": true,
        }),
    )?;
    let value = &probe["result"]["value"];
    watch.check.title = value["title"].as_str().unwrap_or_default().to_owned();
    watch.check.images = value["images"].as_u64().unwrap_or(0) as u32;
    let broken = value["broken"].as_array().cloned().unwrap_or_default();
    watch.check.broken_images = broken.len() as u32;
    for b in broken.iter().filter_map(Value::as_str) {
        watch
            .check
            .warnings
            .push(format!("broken image: {}", shorten(b)));
    }

    let mut shot = json!({"format": "png"});
    if options.full_page {
        let metrics = cdp.call(s, "Page.getLayoutMetrics", json!({}))?;
        let size = &metrics["cssContentSize"];
        let w = size["width"].as_f64().unwrap_or(width as f64).ceil();
        let h = size["height"].as_f64().unwrap_or(height as f64).ceil();
        shot = json!({"format": "png", "captureBeyondViewport": true,
            "clip": {"x": 0, "y": 0, "width": w, "height": h, "scale": 1}});
    }
    let shot = cdp.call(s, "Page.captureScreenshot", shot)?;
    let png = base64::engine::general_purpose::STANDARD
        .decode(shot["data"].as_str().unwrap_or_default())
        .map_err(|e| Error::WebSocket(format!("screenshot is not base64: {e}")))?;
    watch.check.screenshot_bytes = png.len();
    if let Some(out) = &options.screenshot {
        fs::write(out, &png)
            .map_err(|e| Error::Io(format!("cannot write {}", out.display()), e))?;
    }

    // Events that arrived while the commands above ran.
    while let Some(event) = cdp.events.pop_front() {
        if event.get("sessionId").and_then(Value::as_str) == s {
            watch.observe(&event);
        }
    }
    Ok(watch.check)
}

/// Event bookkeeping during a load.
#[derive(Default)]
struct Watch {
    check: PageCheck,
    navigated: bool,
    loaded: bool,
    timed_out: bool,
    /// requestId -> URL of every request seen, for naming failures.
    urls: HashMap<String, String>,
    in_flight: HashMap<String, String>,
}

impl Watch {
    /// Records one event; true when it was network activity.
    fn observe(&mut self, event: &Value) -> bool {
        let p = &event["params"];
        match event["method"].as_str().unwrap_or_default() {
            // The main frame committed the report: a load event from here on is the report's,
            // not a late one from the about:blank the target started with.
            "Page.frameNavigated" => {
                let frame = &p["frame"];
                if frame.get("parentId").is_none()
                    && frame["url"]
                        .as_str()
                        .is_some_and(|u| u.starts_with("file:"))
                {
                    self.navigated = true;
                }
            }
            "Page.loadEventFired" => self.loaded |= self.navigated,
            "Runtime.consoleAPICalled" => {
                let text = console_text(p);
                match p["type"].as_str().unwrap_or_default() {
                    "error" | "assert" => self.check.console_errors.push(text),
                    "warning" => self.check.warnings.push(text),
                    _ => {}
                }
            }
            "Runtime.exceptionThrown" => {
                let d = &p["exceptionDetails"];
                let text = d["exception"]["description"]
                    .as_str()
                    .or_else(|| d["text"].as_str())
                    .unwrap_or("exception")
                    .to_owned();
                self.check.exceptions.push(text);
            }
            "Log.entryAdded" => {
                let e = &p["entry"];
                let mut text = e["text"].as_str().unwrap_or_default().to_owned();
                if let Some(url) = e["url"].as_str().filter(|u| !u.is_empty()) {
                    text = format!("{text} ({})", shorten(url));
                }
                match e["level"].as_str().unwrap_or_default() {
                    "error" => self.check.console_errors.push(text),
                    "warning" => self.check.warnings.push(text),
                    _ => {}
                }
            }
            "Network.requestWillBeSent" => {
                let id = p["requestId"].as_str().unwrap_or_default().to_owned();
                let url = p["request"]["url"].as_str().unwrap_or_default().to_owned();
                if !is_local(&url) {
                    self.check.external_requests.push(shorten(&url));
                }
                self.urls.insert(id.clone(), url.clone());
                self.in_flight.insert(id, url);
                return true;
            }
            "Network.responseReceived" => {
                let r = &p["response"];
                let status = r["status"].as_f64().unwrap_or(0.0);
                if status >= 400.0 {
                    let url = r["url"].as_str().unwrap_or_default();
                    self.check
                        .failed_requests
                        .push(format!("{} (HTTP {status})", shorten(url)));
                }
                return true;
            }
            "Network.loadingFinished" => {
                self.in_flight
                    .remove(p["requestId"].as_str().unwrap_or_default());
                return true;
            }
            "Network.loadingFailed" => {
                let id = p["requestId"].as_str().unwrap_or_default();
                self.in_flight.remove(id);
                let url = self
                    .urls
                    .get(id)
                    .map(|u| shorten(u))
                    .unwrap_or_else(|| format!("request {id}"));
                let mut why = p["errorText"].as_str().unwrap_or("failed").to_owned();
                if let Some(reason) = p["blockedReason"].as_str() {
                    why = format!("{why}, blocked: {reason}");
                }
                self.check.failed_requests.push(format!("{url} ({why})"));
                return true;
            }
            m if m.starts_with("Network.") => return true,
            _ => {}
        }
        false
    }
}

fn console_text(params: &Value) -> String {
    let args = params["args"].as_array().cloned().unwrap_or_default();
    let parts: Vec<String> = args
        .iter()
        .map(|a| match (a.get("value"), a["description"].as_str()) {
            (Some(Value::String(s)), _) => s.clone(),
            (_, Some(d)) => d.to_owned(),
            (Some(v), None) => v.to_string(),
            (None, None) => a["type"].as_str().unwrap_or("?").to_owned(),
        })
        .collect();
    if parts.is_empty() {
        params["type"].as_str().unwrap_or("console").to_owned()
    } else {
        parts.join(" ")
    }
}

fn is_local(url: &str) -> bool {
    ["file:", "data:", "blob:", "about:"].iter().any(|scheme| {
        url.get(..scheme.len())
            .is_some_and(|p| p.eq_ignore_ascii_case(scheme))
    })
}

fn shorten(url: &str) -> String {
    if url.chars().count() <= URL_SHOWN {
        return url.to_owned();
    }
    let cut: String = url.chars().take(URL_SHOWN).collect();
    format!("{cut}… ({} chars)", url.len())
}

fn str_field(v: &Value, key: &str) -> String {
    v[key].as_str().unwrap_or_default().to_owned()
}

/// `file://` URL of an absolute path, percent-encoding everything but unreserved characters
/// and `/`.
fn file_url(abs: &Path) -> String {
    let mut url = String::from("file://");
    for &b in abs.to_string_lossy().as_bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
            url.push(b as char);
        } else {
            url.push_str(&format!("%{b:02X}"));
        }
    }
    url
}

/// The Chromium binary: `ASSAY_CHROMIUM`, else the first of the usual names on `PATH`.
pub fn find_chromium() -> Result<PathBuf, Error> {
    if let Some(p) = std::env::var_os("ASSAY_CHROMIUM").filter(|p| !p.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    for name in ["chromium", "chromium-browser", "google-chrome"] {
        for dir in std::env::split_paths(&path) {
            let candidate = dir.join(name);
            if candidate.is_file() {
                return Ok(candidate);
            }
        }
    }
    Err(Error::NoChromium)
}

/// A headless Chromium with its own profile; killed and cleaned up on drop.
struct Browser {
    child: Child,
    cdp: Cdp,
    // Dropped after `Drop::drop` has killed and reaped the child: nothing writes to it then.
    _dir: tempfile::TempDir,
}

impl Browser {
    fn launch((width, height): (u32, u32)) -> Result<Browser, Error> {
        let exe = find_chromium()?;
        let dir = tempfile::Builder::new()
            .prefix("assay-browser-check-")
            .tempdir()
            .map_err(|e| Error::Io("cannot create a temporary profile".into(), e))?;
        let profile = dir.path().join("profile");
        let log_path = dir.path().join("chromium.log");
        // stderr to a file: Chromium logs a lot (D-Bus complaints without a session bus), and
        // a pipe nobody reads would stall it once full.
        let log = fs::File::create(&log_path)
            .map_err(|e| Error::Io("cannot create the Chromium log".into(), e))?;
        let mut child = Command::new(&exe)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--hide-scrollbars",
                "--mute-audio",
                "--force-device-scale-factor=1",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(format!("--window-size={width},{height}"))
            .arg("about:blank")
            // Crashpad keeps its database under $XDG_CONFIG_HOME/chromium whatever the profile:
            // keep that in the temporary folder too instead of the user's ~/.config.
            .env("XDG_CONFIG_HOME", dir.path().join("config"))
            .env("XDG_CACHE_HOME", dir.path().join("cache"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| Error::Io(format!("cannot start {}", exe.display()), e))?;

        let ws_url = match wait_for_devtools(&mut child, &profile, &log_path) {
            Ok(url) => url,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        match Cdp::connect(&ws_url) {
            Ok(cdp) => Ok(Browser {
                child,
                cdp,
                _dir: dir,
            }),
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                Err(e)
            }
        }
    }

    /// `Browser.close`, then a few seconds for Chromium to exit before `Drop` kills it.
    fn close(&mut self) {
        let _ = self.cdp.send(None, "Browser.close", json!({}));
        let until = Instant::now() + Duration::from_secs(5);
        while Instant::now() < until {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// Reads `DevToolsActivePort` (port, then browser path) once Chromium has written it.
fn wait_for_devtools(child: &mut Child, profile: &Path, log: &Path) -> Result<String, Error> {
    let file = profile.join("DevToolsActivePort");
    let until = Instant::now() + STARTUP_TIMEOUT;
    loop {
        if let Ok(text) = fs::read_to_string(&file) {
            let mut lines = text.lines();
            if let (Some(port), Some(path)) = (lines.next(), lines.next())
                && port.trim().parse::<u16>().is_ok()
                && path.starts_with('/')
            {
                return Ok(format!("ws://127.0.0.1:{}{}", port.trim(), path.trim()));
            }
        }
        if let Ok(Some(status)) = child.try_wait() {
            return Err(Error::Startup(format!(
                "it exited ({status}); its log ends:\n{}",
                log_tail(log)
            )));
        }
        if Instant::now() >= until {
            return Err(Error::Startup(format!(
                "no DevToolsActivePort after {}s; its log ends:\n{}",
                STARTUP_TIMEOUT.as_secs(),
                log_tail(log)
            )));
        }
        std::thread::sleep(Duration::from_millis(25));
    }
}

/// The last lines of Chromium's log, without its D-Bus noise.
fn log_tail(log: &Path) -> String {
    let text = fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.contains("dbus")).collect();
    lines[lines.len().saturating_sub(15)..].join("\n")
}

/// One DevTools websocket. Command answers and events interleave on it: answers are matched
/// by id, events met meanwhile wait in `events`.
struct Cdp {
    ws: WebSocket<TcpStream>,
    next_id: u64,
    events: VecDeque<Value>,
}

impl Cdp {
    fn connect(url: &str) -> Result<Cdp, Error> {
        let addr = url
            .trim_start_matches("ws://")
            .split('/')
            .next()
            .unwrap_or_default()
            .to_owned();
        let stream = TcpStream::connect(&addr)
            .map_err(|e| Error::Io(format!("cannot connect to {addr}"), e))?;
        stream.set_nodelay(true).ok();
        // Screenshots of long pages are base64 in one message: allow up to 512 MiB.
        let config = WebSocketConfig::default()
            .max_message_size(Some(512 << 20))
            .max_frame_size(Some(512 << 20));
        let (ws, _) = tungstenite::client::client_with_config(url, stream, Some(config))
            .map_err(|e| Error::WebSocket(format!("handshake with {url}: {e}")))?;
        Ok(Cdp {
            ws,
            next_id: 1,
            events: VecDeque::new(),
        })
    }

    fn send(&mut self, session: Option<&str>, method: &str, params: Value) -> Result<u64, Error> {
        let id = self.next_id;
        self.next_id += 1;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if let Some(s) = session {
            msg["sessionId"] = json!(s);
        }
        self.ws.send(Message::text(msg.to_string()))?;
        Ok(id)
    }

    /// Sends a command and waits for its answer, keeping events that arrive meanwhile.
    fn call(&mut self, session: Option<&str>, method: &str, params: Value) -> Result<Value, Error> {
        let id = self.send(session, method, params)?;
        let until = Instant::now() + COMMAND_TIMEOUT;
        loop {
            let Some(msg) = self.read(until)? else {
                return Err(Error::CommandTimeout(method.to_owned()));
            };
            if msg.get("id").and_then(Value::as_u64) == Some(id) {
                if let Some(err) = msg.get("error") {
                    let message = err["message"]
                        .as_str()
                        .unwrap_or("unknown error")
                        .to_owned();
                    return Err(Error::Protocol {
                        method: method.to_owned(),
                        message,
                    });
                }
                return Ok(msg.get("result").cloned().unwrap_or(Value::Null));
            }
            if msg.get("method").is_some() {
                self.events.push_back(msg);
            }
        }
    }

    /// The next event, buffered or read before `until`; `None` at `until`.
    fn next_event(&mut self, until: Instant) -> Result<Option<Value>, Error> {
        if let Some(e) = self.events.pop_front() {
            return Ok(Some(e));
        }
        loop {
            match self.read(until)? {
                None => return Ok(None),
                Some(msg) if msg.get("method").is_some() => return Ok(Some(msg)),
                Some(_) => {} // an answer nobody waits for
            }
        }
    }

    /// One JSON message, or `None` when `until` passes first.
    fn read(&mut self, until: Instant) -> Result<Option<Value>, Error> {
        loop {
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.ws
                .get_ref()
                .set_read_timeout(Some(left))
                .map_err(|e| Error::Io("websocket read timeout".into(), e))?;
            match self.ws.read() {
                Ok(Message::Text(text)) => {
                    let value: Value = serde_json::from_str(text.as_str())
                        .map_err(|e| Error::WebSocket(format!("not JSON: {e}")))?;
                    return Ok(Some(value));
                }
                Ok(Message::Close(_)) => {
                    return Err(Error::WebSocket("Chromium closed the connection".into()));
                }
                Ok(_) => {}
                // A timeout mid-frame is fine: tungstenite keeps the partial frame buffered.
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                Err(e) => return Err(e.into()),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_urls_are_percent_encoded() {
        assert_eq!(
            file_url(Path::new("/tmp/a b/r#1.html")),
            "file:///tmp/a%20b/r%231.html"
        );
    }

    #[test]
    fn local_schemes() {
        assert!(is_local("file:///x"));
        assert!(is_local("DATA:image/png;base64,AA"));
        assert!(!is_local("http://127.0.0.1:9/x.png"));
        assert!(!is_local("https://cdn.example/x.js"));
    }
}
