//! `assay bench`: the peer reference scene in rapier3d, timed like `shared/bench/peers/peers.py`
//! (per-trial wall-clock and CPU-time rates, medians, one JSON line on stdout).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use assay_sim::reference::{self, Contract, Workload};
use nix::time::{ClockId, clock_gettime};
use serde_json::json;

#[derive(clap::Args)]
pub struct Args {
    /// physics | rollout
    pub measure: String,
    /// The scene contract.
    #[arg(long, default_value = "bench/reference-scene.json")]
    pub scene: PathBuf,
    #[arg(long, default_value_t = 5)]
    pub trials: u32,
    /// Timed physics steps per trial (default: the contract's).
    #[arg(long)]
    pub steps: Option<u32>,
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

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("reading {}", a.scene.display()))?;
    let sha = assay_core::hash::sha256_hex(text.as_bytes());
    let c = Contract::parse(&text)?;
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let mut extra = json!({});
    match a.measure.as_str() {
        "physics" => {
            let steps = a.steps.unwrap_or(c.measurement.timed_steps);
            let mut w = Workload::default();
            let mut scene = reference::physics_setup(&c);
            reference::physics_run(&c, &mut scene, steps, Some(&mut w)); // warm-up, measures the workload
            for _ in 0..a.trials {
                let mut scene = reference::physics_setup(&c);
                let (t0, c0) = (Instant::now(), cpu_s());
                reference::physics_run(&c, &mut scene, steps, None);
                let (dt, dc) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
                wall.push(f64::from(steps) / dt);
                cpu.push(f64::from(steps) / dc);
            }
            extra = json!({
                "workload": {"contact_points_per_step": round(w.contact_points_per_step), "gripper_contact_fraction": round(w.gripper_contact_fraction), "source": "warm-up trial, same steps"},
                "steps_per_trial": steps,
            });
        }
        "rollout" => {
            let mut placed = Vec::new();
            reference::rollout_episode(&c); // warm-up
            for _ in 0..a.trials {
                let (t0, c0) = (Instant::now(), cpu_s());
                placed.push(reference::rollout_episode(&c));
                let (dt, dc) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
                wall.push(1.0 / dt);
                cpu.push(1.0 / dc);
            }
            extra = json!({"boxes_placed": placed, "rendering": "none (physics only; the render role comes with issue 3)"});
        }
        other => anyhow::bail!("unknown measure '{other}' (physics, rollout)"),
    }
    let (measure, unit) = if a.measure == "physics" {
        ("physics_steps_per_s", "steps/s")
    } else {
        ("rollout_episodes_per_s", "episodes/s")
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
            "threads": 1,
        }
    });
    if let (Some(obj), Some(more)) = (line.as_object_mut(), extra.as_object()) {
        obj.extend(more.clone());
    }
    println!("{line}");
    Ok(ExitCode::SUCCESS)
}
