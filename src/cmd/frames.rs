//! `assay frames`: publish or subscribe to a frame stream on this node's frame bus. Used by the
//! multi-process tests and the hand-off benchmark; handy for checking a node's shared memory.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use assay_framebus::{FrameBus, FrameHeader, format, monotonic_ns};
use serde_json::json;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(clap::Subcommand)]
pub enum Cmd {
    /// Publish a test pattern (frame number in every byte, sequence number up front).
    Publish {
        #[arg(long)]
        stream: String,
        #[arg(long, default_value_t = 100)]
        count: u64,
        #[arg(long, default_value_t = 640)]
        width: u32,
        #[arg(long, default_value_t = 480)]
        height: u32,
        /// Pause between frames, in microseconds.
        #[arg(long, default_value_t = 1000)]
        interval_us: u64,
    },
    /// Receive frames, check them, and report counts and hand-off latency as JSON.
    Subscribe {
        #[arg(long)]
        stream: String,
        /// Stop after this many frames.
        #[arg(long, default_value_t = 100)]
        count: u64,
        /// Stop after this long without reaching `count`.
        #[arg(long, default_value_t = 30.0)]
        timeout_s: f64,
        /// Written once the subscriber is connected.
        #[arg(long)]
        ready_file: Option<PathBuf>,
        /// Poll without sleeping (lowest latency; uses a whole core).
        #[arg(long)]
        spin: bool,
    },
}

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

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.cmd {
        Cmd::Publish {
            stream,
            count,
            width,
            height,
            interval_us,
        } => {
            let bus = FrameBus::open("assay-frames-publish")?;
            let len = (width * height * 4) as usize;
            let publisher = bus.publisher(&stream, len)?;
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
            println!(
                "{}",
                json!({"sent": count, "reached_min": reached_min, "reached_max": reached_max, "elapsed_s": elapsed, "frames_per_s": count as f64 / elapsed})
            );
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Subscribe {
            stream,
            count,
            timeout_s,
            ready_file,
            spin,
        } => {
            let bus = FrameBus::open("assay-frames-subscribe")?;
            let subscriber = bus.subscriber(&stream)?;
            if let Some(f) = ready_file {
                std::fs::write(f, "ready\n")?;
            }
            let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
            let (mut received, mut corrupt, mut out_of_order) = (0u64, 0u64, 0u64);
            let (mut first, mut last) = (None::<u64>, None::<u64>);
            let mut latencies = Vec::new();
            while received < count && Instant::now() < deadline {
                let got = subscriber.receive(|h, payload| {
                    let now = monotonic_ns();
                    let ok = check_pattern(payload) == Some(h.step)
                        && payload.len() as u32 == h.stride * h.height;
                    (h.step, ok, now.saturating_sub(h.timestamp_ns))
                })?;
                match got {
                    Some((seq, ok, latency)) => {
                        received += 1;
                        corrupt += u64::from(!ok);
                        if last.is_some_and(|l| seq <= l) {
                            out_of_order += 1;
                        }
                        first.get_or_insert(seq);
                        last = Some(seq);
                        latencies.push(latency as f64 / 1000.0);
                    }
                    None if spin => std::hint::spin_loop(),
                    None => std::thread::sleep(Duration::from_micros(50)),
                }
            }
            latencies.sort_by(f64::total_cmp);
            println!(
                "{}",
                json!({
                    "received": received, "corrupt": corrupt, "out_of_order": out_of_order,
                    "first": first, "last": last,
                    "latency_us_p50": percentile(&latencies, 0.5), "latency_us_p99": percentile(&latencies, 0.99),
                })
            );
            Ok(if corrupt == 0 && out_of_order == 0 {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
    }
}
