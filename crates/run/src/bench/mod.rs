//! `assay bench` as a library: the peer reference scene timed like `shared/bench/peers/peers.py`
//! (per-trial wall-clock and CPU-time rates, medians, one JSON line), the frame hand-off between
//! processes (`handoff`), and the coordinator at scale (`coordinator`).
//!
//! Owns: what each measurement times and the line it returns. Never prints.

pub mod churn;
pub mod coordinator;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use assay_framebus::monotonic_ns;
use assay_render::{Outputs, Renderer};
use assay_sim::reference::{self, Contract, Workload};
use serde_json::json;

/// What a peer-scene measurement runs.
#[derive(Debug, Clone)]
pub struct PeerBench {
    /// The scene contract.
    pub scene: PathBuf,
    pub trials: u32,
    /// Timed physics steps per trial (default: the contract's).
    pub steps: Option<u32>,
    /// Frames per `render` trial.
    pub frames: u32,
    /// `rollout`: render the contract's 8 frames per episode.
    pub render: bool,
    /// Image size (default: the contract camera's).
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Also read back depth and segmentation images per frame.
    pub depth: bool,
    pub seg: bool,
}

/// This process's CPU time, in seconds (the CPU-time rates).
pub(crate) fn cpu_s() -> f64 {
    use nix::time::{ClockId, clock_gettime};
    let t = clock_gettime(ClockId::CLOCK_PROCESS_CPUTIME_ID).expect("process CPU clock");
    t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

fn round(x: f64) -> f64 {
    if x >= 100.0 {
        (x * 10.0).round() / 10.0
    } else {
        (x * 1000.0).round() / 1000.0
    }
}

/// Per-trial rates: wall clock and CPU time.
type Rates = (Vec<f64>, Vec<f64>);

/// Times `trials` runs of `work`, which returns how many units (steps, frames, episodes) it did.
fn time_trials(
    trials: u32,
    mut work: impl FnMut() -> anyhow::Result<f64>,
) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    for _ in 0..trials {
        let (t0, c0) = (Instant::now(), cpu_s());
        let units = work()?;
        let (dt, dc) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
        wall.push(units / dt);
        cpu.push(units / dc);
    }
    Ok((wall, cpu))
}

/// One measurement of the peer reference scene — `physics`, `render`, `rollout` or `handoff` —
/// as the JSON line `peers.py` prints.
pub fn peers(measure: &str, a: &PeerBench) -> anyhow::Result<serde_json::Value> {
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("reading {}", a.scene.display()))?;
    let sha = assay_spec::hash::sha256_hex(text.as_bytes());
    let c = Contract::parse(&text)?;
    let camera = reference::camera(
        &c,
        a.width.unwrap_or(c.camera.width),
        a.height.unwrap_or(c.camera.height),
    );
    let outputs = Outputs {
        depth: a.depth,
        segments: a.seg,
    };
    let (measure, unit, (wall, cpu), extra) = match measure {
        "physics" => {
            let (rates, extra) = physics(&c, a)?;
            ("physics_steps_per_s", "steps/s", rates, extra)
        }
        "render" => {
            let (rates, extra) = render(&c, a, &camera, outputs)?;
            ("render_frames_per_s", "frames/s", rates, extra)
        }
        "rollout" => {
            let (rates, extra) = rollout(&c, a, &camera, outputs)?;
            ("rollout_episodes_per_s", "episodes/s", rates, extra)
        }
        "handoff" => {
            let (json, rates) = handoff(&camera, (a.frames * 10).max(100))?;
            ("handoff_frames_per_s", "frames/s", rates, json)
        }
        other => anyhow::bail!("unknown measure '{other}' (physics, render, rollout, handoff)"),
    };
    let mut line = json!({
        "engine": "assay-rapier3d",
        "measure": measure,
        "unit": unit,
        "trials": wall.iter().copied().map(round).collect::<Vec<_>>(),
        "median": round(median(&wall)),
        "cpu_time_trials": cpu.iter().copied().map(round).collect::<Vec<_>>(),
        "cpu_time_rate": round(median(&cpu)),
        "conditions": {
            "engine_version": assay_sim::RAPIER_VERSION,
            "gripper": "kinematic position-based body, next position set before every step",
            "solver": "rapier3d defaults (TGS-soft, 4 solver iterations)",
            "build": if cfg!(debug_assertions) { "debug (dependencies optimised)" } else { "release" },
            "scene": {"sha256": sha, "dt": c.dt, "boxes": c.boxes.positions.len()},
            "env": {"LP_NUM_THREADS": std::env::var("LP_NUM_THREADS").ok(), "WGPU_BACKEND": std::env::var("WGPU_BACKEND").ok()},
        }
    });
    if let (Some(obj), Some(more)) = (line.as_object_mut(), extra.as_object()) {
        obj.extend(more.clone());
    }
    Ok(line)
}

fn outputs_name(outputs: Outputs) -> &'static str {
    match (outputs.depth, outputs.segments) {
        (false, false) => "rgb",
        (true, false) => "rgb+depth",
        (false, true) => "rgb+seg",
        (true, true) => "rgb+depth+seg",
    }
}

/// Physics steps of the scene, the workload measured on a warm-up trial.
fn physics(c: &Contract, a: &PeerBench) -> anyhow::Result<(Rates, serde_json::Value)> {
    let steps = a.steps.unwrap_or(c.measurement.timed_steps);
    let mut w = Workload::default();
    let mut scene = reference::physics_setup(c);
    reference::physics_run(c, &mut scene, steps, Some(&mut w)); // warm-up, measures the workload
    let rates = time_trials(a.trials, || {
        let mut scene = reference::physics_setup(c);
        reference::physics_run(c, &mut scene, steps, None);
        Ok(f64::from(steps))
    })?;
    let extra = json!({
        "workload": {"contact_points_per_step": round(w.contact_points_per_step), "gripper_contact_fraction": round(w.gripper_contact_fraction), "source": "warm-up trial, same steps"},
        "steps_per_trial": steps,
    });
    Ok((rates, extra))
}

/// Frames of the scene rendered and read back.
fn render(
    c: &Contract,
    a: &PeerBench,
    camera: &assay_spec::spec::Camera,
    outputs: Outputs,
) -> anyhow::Result<(Rates, serde_json::Value)> {
    let mut r = Renderer::new()?;
    let scene = reference::snapshot(&reference::render_state(c));
    r.render_with(&scene, camera, outputs)?; // warm-up
    let rates = time_trials(a.trials, || {
        for _ in 0..a.frames {
            r.render_with(&scene, camera, outputs)?;
        }
        Ok(f64::from(a.frames))
    })?;
    let extra = json!({
        "frames_per_trial": a.frames,
        "width": camera.width,
        "height": camera.height,
        "outputs": outputs_name(outputs),
        "adapter": r.adapter(),
        "timed": "per frame: scene upload, one render pass, readback of the requested images into CPU memory",
    });
    Ok((rates, extra))
}

/// Whole pick-and-place episodes, optionally rendering the contract's frames.
fn rollout(
    c: &Contract,
    a: &PeerBench,
    camera: &assay_spec::spec::Camera,
    outputs: Outputs,
) -> anyhow::Result<(Rates, serde_json::Value)> {
    let mut renderer = if a.render {
        Some(Renderer::new()?)
    } else {
        None
    };
    let episode = |renderer: &mut Option<Renderer>| -> anyhow::Result<(usize, u32)> {
        let (mut err, mut frames) = (None, 0);
        let placed = reference::rollout_episode_with(c, &mut |scene| {
            if let Some(r) = renderer.as_mut() {
                match r.render_with(&reference::snapshot(scene), camera, outputs) {
                    Ok(_) => frames += 1,
                    Err(e) => err = Some(e),
                }
            }
        });
        match err {
            Some(e) => Err(e.into()),
            None => Ok((placed, frames)),
        }
    };
    episode(&mut renderer)?; // warm-up
    let (mut placed, mut frames) = (Vec::new(), 0);
    let rates = time_trials(a.trials, || {
        let (p, f) = episode(&mut renderer)?;
        placed.push(p);
        frames = f;
        Ok(1.0)
    })?;
    let rendering = match &renderer {
        Some(r) => {
            json!({"adapter": r.adapter(), "outputs": outputs_name(outputs), "width": camera.width, "height": camera.height, "frames_per_episode": frames})
        }
        None => json!("none (physics only)"),
    };
    Ok((
        rates,
        json!({"boxes_placed": placed, "rendering": rendering}),
    ))
}

fn pct(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Frame hand-off between two processes of a node: iceoryx2 (publisher here, a spinning
/// subscriber process reading in place) against a plain memcpy of the same frame.
fn handoff(
    camera: &assay_spec::spec::Camera,
    frames: u32,
) -> anyhow::Result<(serde_json::Value, Rates)> {
    let (w, h) = (camera.width, camera.height);
    let len = (w * h * 4) as usize;
    // memcpy of one frame, into a buffer that stays in cache and into a fresh one.
    let src = vec![7u8; len];
    let mut dst = vec![0u8; len];
    let mut warm = Vec::new();
    for _ in 0..200 {
        let t = Instant::now();
        dst.copy_from_slice(std::hint::black_box(&src));
        warm.push(t.elapsed().as_secs_f64() * 1e6);
        std::hint::black_box(&dst);
    }
    warm.sort_by(f64::total_cmp);
    let mut cold = Vec::new();
    for _ in 0..50 {
        let mut fresh = vec![0u8; len];
        let t = Instant::now();
        fresh.copy_from_slice(std::hint::black_box(&src));
        cold.push(t.elapsed().as_secs_f64() * 1e6);
        std::hint::black_box(&fresh);
    }
    cold.sort_by(f64::total_cmp);

    let iceoryx2 = Transport::Iceoryx2.measure(w, h, frames)?;
    let grpc = Transport::Grpc.measure(w, h, frames)?;
    let rate = |t: &serde_json::Value, side: &str| t["burst"][side]["frames_per_s"].as_f64();
    let ratio = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| round(a / b));
    let p50 = |t: &serde_json::Value| t["latency"]["subscriber"]["latency_us_p50"].as_f64();
    let summary = json!({
        "delivered_frames_per_s": {"iceoryx2": rate(&iceoryx2, "subscriber"), "grpc": rate(&grpc, "subscriber"),
            "iceoryx2_over_grpc": ratio(rate(&iceoryx2, "subscriber"), rate(&grpc, "subscriber"))},
        "latency_us_p50": {"iceoryx2": p50(&iceoryx2), "grpc": p50(&grpc), "memcpy_in_cache": pct(&warm, 0.5),
            "grpc_over_iceoryx2": ratio(p50(&grpc), p50(&iceoryx2))},
    });
    // The line's rates: frames the iceoryx2 publisher put out per second in its burst.
    let published = (
        vec![
            iceoryx2["burst"]["publisher"]["frames_per_s"]
                .as_f64()
                .unwrap_or(0.0),
        ],
        vec![
            iceoryx2["burst"]["publisher"]["frames_per_cpu_s"]
                .as_f64()
                .unwrap_or(0.0),
        ],
    );
    Ok((
        json!({
            "frame_bytes": len,
            "summary": summary,
            "iceoryx2": iceoryx2,
            "grpc": grpc,
            "memcpy_us": {"in_cache_p50": pct(&warm, 0.5), "in_cache_p99": pct(&warm, 0.99), "fresh_buffer_p50": pct(&cold, 0.5), "fresh_buffer_p99": pct(&cold, 0.99)},
            "method": "per transport, two subscriber processes on this node: one for latency (frames paced 1 ms apart so nothing queues; latency = the subscriber's CLOCK_MONOTONIC at receipt minus the stamp put in the frame just before publishing) and one for throughput (one unpaced burst; delivered frames/s measured by the subscriber, frames it lost counted). Every frame is checked byte for byte. iceoryx2: the frame is written into the loaned shared-memory sample and read in place. gRPC: the frame is written into a fresh buffer, which becomes the message (assay.v1.Frames/Subscribe, HTTP/2 on loopback), encoded, sent, decoded.",
        }),
        published,
    ))
}

#[derive(Clone, Copy)]
enum Transport {
    Iceoryx2,
    Grpc,
}

/// Where the sending side of a hand-off measurement publishes.
enum Sender {
    Bus {
        publisher: assay_framebus::FramePublisher,
        _bus: assay_framebus::FrameBus,
    },
    Grpc {
        tx: tokio::sync::broadcast::Sender<assay_proto::v1::Frame>,
        /// Runs the gRPC server until dropped.
        _rt: tokio::runtime::Runtime,
    },
}

impl Transport {
    fn name(self) -> &'static str {
        match self {
            Transport::Iceoryx2 => "iceoryx2",
            Transport::Grpc => "grpc",
        }
    }

    /// Latency (paced frames) and throughput (one burst) through this transport, each with its
    /// own subscriber process.
    fn measure(self, w: u32, h: u32, frames: u32) -> anyhow::Result<serde_json::Value> {
        let latency = self.run(w, h, u64::from(frames), Some(Duration::from_millis(1)))?;
        let burst = self.run(w, h, u64::from(frames) * 5, None)?;
        Ok(json!({"latency": latency, "burst": burst}))
    }

    fn run(
        self,
        w: u32,
        h: u32,
        count: u64,
        pace: Option<Duration>,
    ) -> anyhow::Result<serde_json::Value> {
        let len = (w * h * 4) as usize;
        let tag = format!("{}-{}", std::process::id(), monotonic_ns());
        let stream = format!("assay-bench/handoff/{tag}");
        let dir = std::env::temp_dir().join(format!("assay-handoff-{tag}"));
        std::fs::create_dir_all(&dir)?;
        let ready = dir.join("ready");
        let (sender, url) = match self {
            Transport::Iceoryx2 => {
                let bus = assay_framebus::FrameBus::open("assay-bench-handoff")?;
                (
                    Sender::Bus {
                        publisher: bus.publisher(&stream, len)?,
                        _bus: bus,
                    },
                    None,
                )
            }
            Transport::Grpc => {
                let rt = tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(1)
                    .enable_all()
                    .build()?;
                let hub = assay_worker::relay::FrameHub::default();
                let tx = hub.sender(&stream);
                let listener = rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))?;
                let url = format!("http://{}", listener.local_addr()?);
                rt.spawn(
                    assay_worker::relay::server_builder()
                        .add_service(hub.server(None))
                        .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(
                            listener,
                        )),
                );
                (Sender::Grpc { tx, _rt: rt }, Some(url))
            }
        };
        let mut cmd = std::process::Command::new(std::env::current_exe()?);
        cmd.args(["frames", "subscribe", "--stream", &stream])
            .args(["--count", &count.to_string(), "--timeout-s", "120"])
            .arg("--ready-file")
            .arg(&ready)
            .stdout(std::process::Stdio::piped());
        match &url {
            Some(url) => cmd.args(["--grpc", url]),
            None => cmd.arg("--spin"),
        };
        let child = cmd.spawn()?;
        let deadline = Instant::now() + Duration::from_secs(30);
        while !ready.exists() {
            anyhow::ensure!(
                Instant::now() < deadline,
                "the {} subscriber process did not connect",
                self.name()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let (t0, c0) = (Instant::now(), cpu_s());
        for seq in 0..count {
            let header = assay_framebus::FrameHeader {
                step: seq,
                width: w,
                height: h,
                stride: w * 4,
                format: assay_framebus::format::RGBA8,
                ..Default::default()
            };
            match &sender {
                Sender::Bus { publisher, .. } => {
                    publisher.publish(header, len, |buf| crate::frames::fill_pattern(seq, buf))?;
                }
                Sender::Grpc { tx, .. } => {
                    let mut data = vec![0u8; len];
                    crate::frames::fill_pattern(seq, &mut data);
                    let _ = tx.send(assay_proto::v1::Frame {
                        episode: header.episode,
                        step: seq,
                        timestamp_ns: monotonic_ns(),
                        camera: header.camera,
                        format: header.format,
                        width: w,
                        height: h,
                        stride: w * 4,
                        data: data.into(),
                        dropped: 0,
                    });
                }
            }
            if let Some(p) = pace {
                std::thread::sleep(p);
            }
        }
        let (wall, cpu) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
        let out = child.wait_with_output()?;
        drop(sender);
        let _ = std::fs::remove_dir_all(&dir);
        let sub: serde_json::Value = serde_json::from_slice(&out.stdout)
            .with_context(|| format!("{} subscriber report", self.name()))?;
        anyhow::ensure!(
            sub["corrupt"] == 0 && sub["out_of_order"] == 0,
            "{} delivered damaged frames: {sub}",
            self.name()
        );
        Ok(json!({
            "sent": count,
            "paced_us": pace.map(|p| p.as_micros() as u64),
            "publisher": {"frames_per_s": round(count as f64 / wall), "frames_per_cpu_s": round(count as f64 / cpu)},
            "subscriber": sub,
        }))
    }
}
