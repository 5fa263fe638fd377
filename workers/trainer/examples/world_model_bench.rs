//! Training speed of the world model with the default config on synthetic 64×64 clips.
//!
//! `cargo run --release -p assay-trainer --example world_model_bench [-- STEPS [--fits] [--cpu]
//! [--config JSON]]`, or `[-- STEPS --video]` for the video model
//!
//! Prints one JSON line `{"bench":"world-model-train",...}`: a warm-up fit, then a fit of
//! `STEPS` (default 20) full steps (`batch` chunks of `chunk` frames each). With `--fits`, also
//! one line per default fit of 10, 20 and 40 training episodes of 60 frames, evaluated on 40,
//! for a diverse family (random colours, places and velocities) and an identical one (copies).

use std::time::Instant;

use assay_model::clip::Clip;
use assay_model::dynamics::{DEFAULT_BUDGETS, DynamicsConfig};
use assay_spec::rng::Rng;
use assay_trainer::world_model::{FitRequest, device_name, fit};
use tch::Device;

/// A clip of a square of a random colour moved by random velocity commands.
fn clip(len: usize, size: usize, seed: u64) -> Clip {
    let mut rng = Rng::new(seed, "world-model-bench");
    let color = [
        rng.uniform(60.0, 255.0) as u8,
        rng.uniform(60.0, 255.0) as u8,
        rng.uniform(60.0, 255.0) as u8,
    ];
    let side = size / 6;
    let free = (size - side) as f64;
    let (mut x, mut y) = (rng.unit(), rng.unit());
    let (vx, vy) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
    let (mut rgb, mut proprio, mut actions) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..len {
        let (px, py) = ((x * free) as usize, (y * free) as usize);
        for r in 0..size {
            for c in 0..size {
                let inside = (px..px + side).contains(&c) && (py..py + side).contains(&r);
                rgb.extend_from_slice(if inside { &color } else { &[30, 30, 40] });
            }
        }
        proprio.extend_from_slice(&[x as f32, y as f32, 0.0, 0.0]);
        let a = if t + 1 < len {
            [
                (vx + rng.uniform(-0.5, 0.5)) as f32,
                (vy + rng.uniform(-0.5, 0.5)) as f32,
                0.0,
                0.0,
            ]
        } else {
            [0.0; 4]
        };
        actions.extend_from_slice(&a);
        x = (x + 0.1 * f64::from(a[0])).clamp(0.0, 1.0);
        y = (y + 0.1 * f64::from(a[1])).clamp(0.0, 1.0);
    }
    Clip {
        height: size as u32,
        width: size as u32,
        interval_s: 0.1,
        proprio_dims: 4,
        action_dims: 4,
        rgb,
        proprio,
        actions,
        interface: String::new(),
        views: Vec::new(),
        object_dims: 0,
        objects: Vec::new(),
    }
}

/// `--video`: training throughput of the video model with its default settings (one thread) on
/// 16 synthetic clips of 40 frames, as `python/assay-policy-kit/examples/torch_video_model.py
/// bench` measures the same network in PyTorch: a warm-up fit of 3 steps, then `steps`.
fn video_bench(steps: usize, device: Device) {
    use assay_model::video::VideoModelConfig;
    use assay_trainer::video_model;
    let train: Vec<Clip> = (0..16).map(|i| clip(40, 64, 2000 + i)).collect();
    let run = |steps: u64| {
        let cfg = VideoModelConfig {
            steps,
            checkpoint_every: 0,
            ..VideoModelConfig::default()
        };
        let (cpu0, wall0) = (cpu_seconds(), Instant::now());
        let (model, fit) =
            video_model::fit(&cfg, &train, device, None, &mut |_, _| Ok(())).expect("fit");
        (
            model,
            fit,
            cpu_seconds() - cpu0,
            wall0.elapsed().as_secs_f64(),
            cfg,
        )
    };
    let _warm = run(3);
    let (model, fit, cpu, wall, cfg) = run(steps as u64);
    println!(
        "{}",
        serde_json::json!({
            "bench": "video-model-train",
            "implementation": "assay (tch)",
            "device": device_name(device),
            "threads": cfg.threads,
            "image_size": 64,
            "batch": cfg.batch,
            "horizon": cfg.horizon,
            "parameters": model.parameters(),
            "steps": fit.steps,
            "seconds": wall,
            "cpu_seconds": cpu,
            "steps_per_s": fit.steps as f64 / wall,
            "steps_per_cpu_s": fit.steps as f64 / cpu,
            "final_loss": fit.final_train_loss,
        })
    );
}

/// CPU seconds of this process (user + system), from /proc.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    let Some(rest) = stat.rsplit_once(')').map(|r| r.1) else {
        return f64::NAN;
    };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let steps: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(20);
    let device = if args.iter().any(|a| a == "--cpu") {
        Device::Cpu
    } else {
        Device::cuda_if_available()
    };
    if args.iter().any(|a| a == "--video") {
        video_bench(steps, device);
        return;
    }
    // `--config JSON`: settings over the defaults, e.g. `--config '{"lr":1e-3}'`.
    let cfg: DynamicsConfig = match args.iter().position(|a| a == "--config") {
        Some(i) => serde_json::from_str(args.get(i + 1).map_or("{}", String::as_str))
            .expect("--config: a JSON object of DynamicsConfig fields"),
        None => DynamicsConfig::default(),
    };
    let size = cfg.image_size as usize;
    // `batch` clips of exactly `chunk` frames: one full step per epoch.
    let train: Vec<Clip> = (0..cfg.batch)
        .map(|i| clip(cfg.chunk, size, i as u64))
        .collect();
    let eval = &train[..1];
    let keys = vec!["bench".to_string()];
    let run = |steps: usize| {
        let config = DynamicsConfig {
            steps: steps as u64,
            checkpoint_every: 0,
            ..cfg.clone()
        };
        let started = cpu_seconds();
        let fit = fit(
            &FitRequest {
                config: &config,
                group: "bench",
                budget: train.len() as u32,
                train: &train,
                eval,
                eval_keys: &keys,
                device,
                normalize_actions: false,
            },
            None,
            &mut |_, _| Ok(()),
        )
        .expect("fit");
        (fit, cpu_seconds() - started)
    };
    let _warm = run(3);
    let (timed, cpu) = run(steps);
    println!(
        "{}",
        serde_json::json!({
            "bench": "world-model-train",
            "device": device_name(device),
            "threads": cfg.threads,
            "image_size": cfg.image_size,
            "batch": cfg.batch,
            "chunk": cfg.chunk,
            "steps": timed.steps,
            "steps_per_s": timed.steps_per_s,
            "frames_per_s": timed.steps_per_s * (cfg.batch * cfg.chunk) as f64,
            "cpu_seconds": cpu,
        })
    );

    if args.iter().any(|a| a == "--fits") {
        let diverse: Vec<Clip> = (0..40).map(|i| clip(60, size, 1000 + i)).collect();
        let identical: Vec<Clip> = (0..40).map(|_| diverse[0].clone()).collect();
        let keys: Vec<String> = (0..40).map(|i| format!("episode-{i}")).collect();
        for (family, episodes) in [("diverse", &diverse), ("identical", &identical)] {
            for budget in DEFAULT_BUDGETS {
                let started = Instant::now();
                let cpu0 = cpu_seconds();
                let f = fit(
                    &FitRequest {
                        config: &cfg,
                        group: family,
                        budget,
                        train: &episodes[..budget as usize],
                        eval: episodes,
                        eval_keys: &keys,
                        device,
                        normalize_actions: false,
                    },
                    None,
                    &mut |_, _| Ok(()),
                )
                .expect("fit");
                println!(
                    "{}",
                    serde_json::json!({
                        "bench": "world-model-fit",
                        "family": family,
                        "device": f.device,
                        "train_episodes": budget,
                        "frames_per_episode": 60,
                        "eval_episodes": 40,
                        "steps": f.steps,
                        "seconds": started.elapsed().as_secs_f64(),
                        "cpu_seconds": cpu_seconds() - cpu0,
                        "steps_per_s": f.steps_per_s,
                        "eval_image_mse": f.eval_image_mse,
                        "eval_proprio_mse": f.eval_proprio_mse,
                        "final_train_loss": f.final_train_loss,
                    })
                );
            }
        }
    }
}
