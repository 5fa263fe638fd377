//! `assay bench`: the peer reference scene, timed like `shared/bench/peers/peers.py` (per-trial
//! wall-clock and CPU-time rates, medians, one JSON line on stdout).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use assay_render::{Outputs, Renderer};
use assay_sim::reference::{self, Contract, Workload};
use nix::time::{ClockId, clock_gettime};
use serde_json::json;

#[derive(clap::Args)]
pub struct Args {
    /// physics | render | rollout | handoff
    pub measure: String,
    /// The scene contract.
    #[arg(long, default_value = "bench/reference-scene.json")]
    pub scene: PathBuf,
    #[arg(long, default_value_t = 5)]
    pub trials: u32,
    /// Timed physics steps per trial (default: the contract's).
    #[arg(long)]
    pub steps: Option<u32>,
    /// Frames per `render` trial.
    #[arg(long, default_value_t = 20)]
    pub frames: u32,
    /// `rollout`: render the contract's 8 frames per episode.
    #[arg(long)]
    pub render: bool,
    /// Image width (default: the contract camera's, 640).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the contract camera's, 480).
    #[arg(long)]
    pub height: Option<u32>,
    /// Also read back a depth image per frame.
    #[arg(long)]
    pub depth: bool,
    /// Also read back a segmentation image per frame.
    #[arg(long)]
    pub seg: bool,
}

fn cpu_s() -> f64 {
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

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("reading {}", a.scene.display()))?;
    let sha = assay_core::hash::sha256_hex(text.as_bytes());
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
    let outputs_name = match (a.depth, a.seg) {
        (false, false) => "rgb",
        (true, false) => "rgb+depth",
        (false, true) => "rgb+seg",
        (true, true) => "rgb+depth+seg",
    };
    let (measure, unit, (wall, cpu), extra) = match a.measure.as_str() {
        "physics" => {
            let steps = a.steps.unwrap_or(c.measurement.timed_steps);
            let mut w = Workload::default();
            let mut scene = reference::physics_setup(&c);
            reference::physics_run(&c, &mut scene, steps, Some(&mut w)); // warm-up, measures the workload
            let rates = time_trials(a.trials, || {
                let mut scene = reference::physics_setup(&c);
                reference::physics_run(&c, &mut scene, steps, None);
                Ok(f64::from(steps))
            })?;
            let extra = json!({
                "workload": {"contact_points_per_step": round(w.contact_points_per_step), "gripper_contact_fraction": round(w.gripper_contact_fraction), "source": "warm-up trial, same steps"},
                "steps_per_trial": steps,
            });
            ("physics_steps_per_s", "steps/s", rates, extra)
        }
        "render" => {
            let mut r = Renderer::new()?;
            let scene = reference::snapshot(&reference::render_state(&c));
            r.render_with(&scene, &camera, outputs)?; // warm-up
            let rates = time_trials(a.trials, || {
                for _ in 0..a.frames {
                    r.render_with(&scene, &camera, outputs)?;
                }
                Ok(f64::from(a.frames))
            })?;
            let extra = json!({
                "frames_per_trial": a.frames,
                "width": camera.width,
                "height": camera.height,
                "outputs": outputs_name,
                "adapter": r.adapter(),
                "timed": "per frame: scene upload, one render pass, readback of the requested images into CPU memory",
            });
            ("render_frames_per_s", "frames/s", rates, extra)
        }
        "rollout" => {
            let mut renderer = if a.render {
                Some(Renderer::new()?)
            } else {
                None
            };
            let episode = |renderer: &mut Option<Renderer>| -> anyhow::Result<(usize, u32)> {
                let (mut err, mut frames) = (None, 0);
                let placed = reference::rollout_episode_with(&c, &mut |scene| {
                    if let Some(r) = renderer.as_mut() {
                        match r.render_with(&reference::snapshot(scene), &camera, outputs) {
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
                    json!({"adapter": r.adapter(), "outputs": outputs_name, "width": camera.width, "height": camera.height, "frames_per_episode": frames})
                }
                None => json!("none (physics only)"),
            };
            (
                "rollout_episodes_per_s",
                "episodes/s",
                rates,
                json!({"boxes_placed": placed, "rendering": rendering}),
            )
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
    println!("{line}");
    Ok(ExitCode::SUCCESS)
}

fn pct(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Frame hand-off between two processes of a node: iceoryx2 (publisher here, a spinning
/// subscriber process reading in place) against a plain memcpy of the same frame.
fn handoff(
    camera: &assay_core::spec::Camera,
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

    // iceoryx2: a subscriber process spins on the stream; latency = its clock at receipt minus
    // the publisher's stamp (CLOCK_MONOTONIC, shared by the node).
    let stream = format!("assay-bench/handoff/{}", std::process::id());
    let dir = std::env::temp_dir().join(format!("assay-handoff-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let ready = dir.join("ready");
    let exe = std::env::current_exe()?;
    let child = std::process::Command::new(&exe)
        .args([
            "frames",
            "subscribe",
            "--stream",
            &stream,
            "--count",
            &frames.to_string(),
            "--timeout-s",
            "120",
            "--spin",
            "--ready-file",
        ])
        .arg(&ready)
        .stdout(std::process::Stdio::piped())
        .spawn()?;
    let deadline = Instant::now() + std::time::Duration::from_secs(30);
    while !ready.exists() {
        anyhow::ensure!(
            Instant::now() < deadline,
            "the subscriber process did not connect"
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let bus = assay_framebus::FrameBus::open("assay-bench-handoff")?;
    let publisher = bus.publisher(&stream, len)?;
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let mut sent = 0u64;
    // Paced (0.5 ms apart) so the subscriber keeps up and latency has no queueing in it.
    for _ in 0..5 {
        let (t0, c0) = (Instant::now(), cpu_s());
        for _ in 0..frames / 5 {
            let header = assay_framebus::FrameHeader {
                step: sent,
                width: w,
                height: h,
                stride: w * 4,
                format: assay_framebus::format::RGBA8,
                ..Default::default()
            };
            publisher.publish(header, len, |buf| {
                crate::cmd::frames::fill_pattern(sent, buf)
            })?;
            sent += 1;
            std::thread::sleep(std::time::Duration::from_micros(500));
        }
        let n = f64::from(frames / 5);
        wall.push(n / t0.elapsed().as_secs_f64());
        cpu.push(n / (cpu_s() - c0));
    }
    let out = child.wait_with_output()?;
    let _ = std::fs::remove_dir_all(&dir);
    let sub: serde_json::Value =
        serde_json::from_slice(&out.stdout).context("subscriber report")?;
    Ok((
        json!({
            "frame_bytes": len,
            "iceoryx2": {"sent": sent, "subscriber": sub, "note": "latency from publish (frame already written in the shared-memory sample) to the subscriber process holding it; publisher paced 0.5 ms apart"},
            "memcpy_us": {"in_cache_p50": pct(&warm, 0.5), "in_cache_p99": pct(&warm, 0.99), "fresh_buffer_p50": pct(&cold, 0.5), "fresh_buffer_p99": pct(&cold, 0.99)},
        }),
        (wall, cpu),
    ))
}
