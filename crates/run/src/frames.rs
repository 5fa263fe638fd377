//! `assay frames` as a library: publish or subscribe to a frame stream on this node's frame bus,
//! or relay a node's streams to other nodes over gRPC (`assay.v1.Frames`). Used by the
//! multi-process tests and the hand-off benchmark; handy for checking a node's shared memory.
//!
//! Owns: the test pattern, the subscriber's statistics, the relay's threads. Never prints: each
//! function returns what the command prints.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use assay_framebus::{FrameBus, FrameHeader, format, monotonic_ns};
use serde_json::json;

/// The test pattern: the sequence number (little endian) in the first 8 bytes, its low byte in
/// every other byte.
pub fn fill_pattern(seq: u64, buf: &mut [u8]) {
    buf.fill(seq as u8);
    let n = buf.len().min(8);
    buf[..n].copy_from_slice(&seq.to_le_bytes()[..n]);
}

pub fn check_pattern(buf: &[u8]) -> Option<u64> {
    let mut b = [0u8; 8];
    b.copy_from_slice(buf.get(..8)?);
    let seq = u64::from_le_bytes(b);
    buf[8..].iter().all(|x| *x == seq as u8).then_some(seq)
}

fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    (!sorted.is_empty()).then(|| sorted[((sorted.len() - 1) as f64 * p).round() as usize])
}

/// Publishes `count` test-pattern frames of `width` × `height` RGBA on `stream`, `interval_us`
/// apart; returns what was sent and how many subscribers each frame reached, as JSON.
pub fn publish(
    stream: &str,
    count: u64,
    (width, height): (u32, u32),
    interval_us: u64,
) -> anyhow::Result<serde_json::Value> {
    let bus = FrameBus::open("assay-frames-publish")?;
    let len = (width * height * 4) as usize;
    let publisher = bus.publisher(stream, len)?;
    let (mut reached_min, mut reached_max) = (usize::MAX, 0);
    let start = Instant::now();
    for seq in 0..count {
        let header = FrameHeader {
            episode: 1,
            step: seq,
            camera: 0,
            format: format::RGBA8,
            width,
            height,
            stride: width * 4,
            ..Default::default()
        };
        let reached = publisher.publish(header, len, |buf| fill_pattern(seq, buf))?;
        reached_min = reached_min.min(reached);
        reached_max = reached_max.max(reached);
        if interval_us > 0 {
            std::thread::sleep(Duration::from_micros(interval_us));
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    Ok(
        json!({"sent": count, "reached_min": reached_min, "reached_max": reached_max, "elapsed_s": elapsed, "frames_per_s": count as f64 / elapsed}),
    )
}

/// How a subscription runs.
pub struct Subscription {
    pub stream: String,
    /// Stop after this many frames.
    pub count: u64,
    /// Stop after this long without reaching `count`.
    pub timeout_s: f64,
    /// Written once the subscriber is connected.
    pub ready_file: Option<PathBuf>,
    /// Poll without sleeping.
    pub spin: bool,
    /// A frame relay to receive from over gRPC instead of this node's shared memory.
    pub grpc: Option<String>,
    /// Save every RGBA frame as a PNG here instead of checking it (shared memory only).
    pub save: Option<PathBuf>,
}

/// Receives and checks frames; returns the counts and hand-off latency as JSON, and whether
/// every frame was whole and in order.
pub fn subscribe(s: &Subscription) -> anyhow::Result<(serde_json::Value, bool)> {
    if let Some(dir) = &s.save {
        std::fs::create_dir_all(dir)?;
    }
    let deadline = Instant::now() + Duration::from_secs_f64(s.timeout_s);
    let stats = match &s.grpc {
        Some(url) => crate::rt::block_on(from_relay(s, url, deadline))?,
        None => from_bus(s, deadline)?,
    };
    Ok(stats.summary())
}

/// Frames from a relay over gRPC.
async fn from_relay(s: &Subscription, url: &str, deadline: Instant) -> anyhow::Result<Stats> {
    let mut stats = Stats::default();
    let mut frames = assay_worker::relay::subscribe(url, &s.stream).await?;
    if let Some(f) = &s.ready_file {
        std::fs::write(f, "ready\n")?;
    }
    while !stats.done(s.count) {
        let left = deadline.saturating_duration_since(Instant::now());
        let Ok(next) = tokio::time::timeout(left, frames.message()).await else {
            break;
        };
        let Some(f) = next? else { break };
        let now = monotonic_ns();
        stats.dropped += f.dropped;
        let ok = check_pattern(&f.data) == Some(f.step)
            && f.data.len() as u64 == u64::from(f.stride) * u64::from(f.height);
        stats.record(f.step, ok, f.timestamp_ns, now);
    }
    Ok(stats)
}

/// Frames from this node's shared memory.
fn from_bus(s: &Subscription, deadline: Instant) -> anyhow::Result<Stats> {
    let mut stats = Stats::default();
    let bus = FrameBus::open("assay-frames-subscribe")?;
    let subscriber = bus.subscriber(&s.stream)?;
    if let Some(f) = &s.ready_file {
        std::fs::write(f, "ready\n")?;
    }
    while !stats.done(s.count) && Instant::now() < deadline {
        let seq = stats.received;
        let got = subscriber.receive(|h, payload| {
            let now = monotonic_ns();
            let sized = payload.len() as u32 == h.stride * h.height;
            let (seq, ok) = match &s.save {
                Some(dir) => (seq, sized && save_frame(dir, h, payload)),
                None => (h.step, sized && check_pattern(payload) == Some(h.step)),
            };
            (seq, ok, h.timestamp_ns, now)
        })?;
        match got {
            Some((seq, ok, sent, now)) => stats.record(seq, ok, sent, now),
            None if s.spin => std::hint::spin_loop(),
            None => std::thread::sleep(Duration::from_micros(50)),
        }
    }
    Ok(stats)
}

/// Writes an RGBA frame as a PNG named after its header; false if it is not RGBA or not written.
fn save_frame(dir: &Path, h: &FrameHeader, payload: &[u8]) -> bool {
    if h.format != format::RGBA8 || h.stride != h.width * 4 {
        return false;
    }
    let png = assay_render::image::Rgb::from_rgba(h.width, h.height, payload).png();
    let name = format!("{}-{}-{}.png", h.episode, h.camera, h.step);
    std::fs::write(dir.join(name), png).is_ok()
}

#[derive(Default)]
struct Stats {
    received: u64,
    corrupt: u64,
    out_of_order: u64,
    /// Frames the sender said this subscription lost (gRPC only; the bus drops silently).
    dropped: u64,
    /// Frames missing between the sequence numbers received.
    lost: u64,
    first: Option<u64>,
    last: Option<u64>,
    latencies: Vec<f64>,
    /// `CLOCK_MONOTONIC` at the first and the latest receipt.
    first_ns: u64,
    last_ns: u64,
}

impl Stats {
    /// Frame `seq`, stamped `sent_ns` by its publisher, arrived at `now` (both CLOCK_MONOTONIC).
    fn record(&mut self, seq: u64, ok: bool, sent_ns: u64, now: u64) {
        if self.received == 0 {
            self.first_ns = now;
        }
        self.last_ns = now;
        self.received += 1;
        self.corrupt += u64::from(!ok);
        match self.last {
            Some(l) if seq <= l => self.out_of_order += 1,
            Some(l) => self.lost += seq - l - 1,
            None => {}
        }
        self.first.get_or_insert(seq);
        self.last = Some(seq);
        self.latencies
            .push(now.saturating_sub(sent_ns) as f64 / 1000.0);
    }

    /// Done when `count` frames arrived, or the last one (sequence `count - 1`) did: frames
    /// dropped on the way (a subscriber that falls behind loses the oldest) are counted as lost.
    fn done(&self, count: u64) -> bool {
        self.received >= count || self.last.is_some_and(|l| l + 1 >= count)
    }

    /// The counts and latency percentiles as JSON, and whether nothing was corrupt or out of
    /// order.
    fn summary(self) -> (serde_json::Value, bool) {
        let Stats {
            received,
            corrupt,
            out_of_order,
            dropped,
            lost,
            first,
            last,
            mut latencies,
            first_ns,
            last_ns,
        } = self;
        let span_s = last_ns.saturating_sub(first_ns) as f64 / 1e9;
        let frames_per_s = (received > 1 && span_s > 0.0).then(|| (received - 1) as f64 / span_s);
        latencies.sort_by(f64::total_cmp);
        let summary = json!({
            "received": received, "corrupt": corrupt, "out_of_order": out_of_order,
            "lost": lost, "dropped_reported": dropped, "first": first, "last": last,
            "frames_per_s": frames_per_s,
            "latency_us_p50": percentile(&latencies, 0.5), "latency_us_p99": percentile(&latencies, 0.99),
        });
        (summary, corrupt == 0 && out_of_order == 0)
    }
}

/// Serves `streams` of this node's frame bus over gRPC until SIGTERM or Ctrl-C. One thread per
/// stream reads the bus; a frame is copied into a message only when some client is subscribed.
pub fn relay(
    streams: Vec<String>,
    listen: std::net::SocketAddr,
    addr_file: Option<PathBuf>,
) -> anyhow::Result<()> {
    let hub = assay_worker::relay::FrameHub::default();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut threads = Vec::new();
    for (i, name) in streams.into_iter().enumerate() {
        let (tx, stop) = (hub.sender(&name), stop.clone());
        // iceoryx2 ports stay on the thread that made them.
        let (opened_tx, opened) = std::sync::mpsc::channel();
        threads.push(
            std::thread::Builder::new()
                .name(format!("relay-{i}"))
                .spawn(move || -> anyhow::Result<()> {
                    let opened_on_bus = FrameBus::open(&format!("assay-frames-relay-{i}"))
                        .and_then(|bus| Ok((bus.subscriber(&name)?, bus)));
                    let (subscriber, _bus) = match opened_on_bus {
                        Ok(x) => {
                            let _ = opened_tx.send(Ok(()));
                            x
                        }
                        Err(e) => {
                            let _ = opened_tx.send(Err(e.to_string()));
                            return Ok(());
                        }
                    };
                    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                        let got = subscriber.receive(|h, payload| {
                            (tx.receiver_count() > 0).then(|| assay_proto::v1::Frame {
                                episode: h.episode,
                                step: h.step,
                                timestamp_ns: h.timestamp_ns,
                                camera: h.camera,
                                format: h.format,
                                width: h.width,
                                height: h.height,
                                stride: h.stride,
                                data: payload.to_vec().into(),
                                dropped: 0,
                            })
                        })?;
                        match got {
                            Some(Some(frame)) => {
                                let _ = tx.send(frame);
                            }
                            Some(None) => {}
                            None => std::thread::sleep(Duration::from_micros(100)),
                        }
                    }
                    Ok(())
                })?,
        );
        opened
            .recv()
            .context("relay thread")?
            .map_err(anyhow::Error::msg)?;
    }
    crate::rt::block_on(async {
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .with_context(|| format!("cannot listen on {listen}"))?;
        let bound = listener.local_addr()?;
        tracing::info!(%bound, "frame relay serving");
        if let Some(f) = addr_file {
            // Whole or absent: a reader polling for the file never sees it half written.
            let tmp = f.with_extension("tmp");
            std::fs::write(&tmp, bound.to_string())?;
            std::fs::rename(&tmp, &f)?;
        }
        // The relay is worker-side: it takes the cluster token or a worker key.
        let token =
            assay_proto::auth::Credential::token_from_env(&[assay_proto::auth::Access::Worker])
                .map_err(anyhow::Error::msg)?;
        assay_worker::relay::server_builder()
            .add_service(hub.server(token))
            .serve_with_incoming_shutdown(
                tokio_stream::wrappers::TcpListenerStream::new(listener),
                crate::rt::terminated(),
            )
            .await?;
        anyhow::Ok(())
    })?;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for t in threads {
        t.join().expect("relay thread")?;
    }
    Ok(())
}
