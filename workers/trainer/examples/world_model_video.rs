//! The world models' video prediction and action test on real clips (issue 44): each candidate
//! (the RSSM, the video model) trained per group on demonstrations plus other policies'
//! rollouts, and on demonstrations alone, then measured open loop over 16 frames on held-out
//! seeds — demonstrations (in distribution) and a policy no model saw (out of distribution).
//!
//! `cargo run --release -p assay-trainer --example world_model_video -- MANIFEST OUT_PREFIX
//! [--video-steps N] [--rssm-steps N] [--groups a,b] [--jobs N]`
//!
//! MANIFEST is JSON: group → list of `{task, seed, policy, success, clip}` with `clip` a path to
//! a `.clip` file (an `assay eval` run's `artifacts/clips/…`, listed by its report.json; see
//! `bench/results/README.md`). Seeds from the last quarter of each group's seeds are held out.
//! Demonstrations are the policy `oracle`; training rollouts `oracle:noise=0.02` and
//! `random:…`; the out-of-distribution policy `oracle:noise=0.05`. Writes
//! `OUT_PREFIX-world-model-actions.json` and `OUT_PREFIX-world-model-video.json`.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Instant;

use assay_model::clip::Clip;
use assay_model::dynamics::DynamicsConfig;
use assay_model::video::VideoModelConfig;
use assay_model::world::WorldModelService;
use assay_trainer::video_eval::{OpenLoop, StartName, open_loop};
use assay_trainer::{video_model, world_model};
use serde::Deserialize;
use serde_json::json;
use tch::Device;

const HORIZON: usize = 16;
const DEMO: &str = "oracle";
const OOD: &str = "oracle:noise=0.05";

#[derive(Deserialize, Clone)]
struct Entry {
    task: String,
    seed: u64,
    policy: String,
    clip: String,
    /// `train`, `dev` (held out while choosing settings) or `test` (held out for the figures
    /// reported); absent: the last quarter of the group's seeds is `test`.
    #[serde(default)]
    split: Option<String>,
}

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

struct Split {
    full: Vec<Clip>,
    demos: Vec<Clip>,
    id: Vec<(Entry, Clip)>,
    ood: Vec<(Entry, Clip)>,
}

fn split(entries: &[Entry], held_out: &str) -> Split {
    let mut seeds: Vec<u64> = entries.iter().map(|e| e.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    let cut = seeds[(seeds.len() * 3).div_ceil(4).min(seeds.len() - 1)];
    let load =
        |e: &Entry| Clip::decode(&std::fs::read(&e.clip).expect("read clip")).expect("decode clip");
    let mut s = Split {
        full: Vec::new(),
        demos: Vec::new(),
        id: Vec::new(),
        ood: Vec::new(),
    };
    for e in entries {
        let part = e
            .split
            .clone()
            .unwrap_or_else(|| if e.seed >= cut { "test" } else { "train" }.into());
        if part != "train" && part != held_out {
            continue;
        }
        let held_out = part == held_out;
        match (held_out, e.policy.as_str()) {
            (false, DEMO) => {
                s.full.push(load(e));
                s.demos.push(load(e));
            }
            (false, OOD) => {}
            (false, _) => s.full.push(load(e)),
            (true, DEMO) => s.id.push((e.clone(), load(e))),
            (true, OOD) => s.ood.push((e.clone(), load(e))),
            (true, _) => {}
        }
    }
    s
}

fn measure(world: &dyn WorldModelService, set: &[(Entry, Clip)]) -> OpenLoop {
    let clips: Vec<&Clip> = set.iter().map(|(_, c)| c).collect();
    let names: Vec<StartName<'_>> = set
        .iter()
        .map(|(e, _)| StartName {
            task_id: &e.task,
            seed: e.seed,
            instruction: "",
        })
        .collect();
    open_loop(world, &clips, &names, HORIZON).expect("open loop")
}

/// Rows of 16 frames for the first three held-out windows: real, true actions, another
/// clip's actions, zero actions (`ASSAY_DUMP=DIR`, to look at).
fn strip(world: &dyn WorldModelService, set: &[(Entry, Clip)], path: &str) {
    use assay_trainer::imagination::{replay, sheet_png};
    let (w, h) = (set[0].1.width as usize, set[0].1.height as usize);
    let frame = w * h * 3;
    let mut rows: Vec<Vec<Vec<u8>>> = Vec::new();
    for i in 0..3.min(set.len()) {
        let clip = &set[i].1;
        let donor = &set[(i + 1) % set.len()].1;
        let n = HORIZON.min(clip.len() - 1).min(donor.len() - 1);
        let start = assay_model::world::WorldStart {
            task_id: set[i].0.task.clone(),
            seed: set[i].0.seed,
            instruction: String::new(),
            width: w as u32,
            height: h as u32,
            rgb: clip.rgb[..frame].to_vec(),
            state: clip.proprio[..4].to_vec(),
            interface: Default::default(),
            views: Vec::new(),
            objects: Vec::new(),
        };
        let acts = |c: &Clip| {
            (0..n)
                .map(|t| c.actions[t * 4..t * 4 + 4].to_vec())
                .collect::<Vec<_>>()
        };
        rows.push(
            (1..=n)
                .map(|t| clip.rgb[t * frame..(t + 1) * frame].to_vec())
                .collect(),
        );
        rows.push(replay(world, &start, &acts(clip)).unwrap());
        rows.push(replay(world, &start, &acts(donor)).unwrap());
        rows.push(replay(world, &start, &vec![vec![0.0; 4]; n]).unwrap());
    }
    let rows: Vec<Vec<&[u8]>> = rows
        .iter()
        .map(|r| r.iter().map(Vec::as_slice).collect())
        .collect();
    std::fs::write(path, sheet_png(&rows, w, h)).expect("write the sheet");
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let manifest: BTreeMap<String, Vec<Entry>> =
        serde_json::from_slice(&std::fs::read(&args[0]).expect("read the manifest"))
            .expect("a manifest of group -> entries");
    let prefix = args[1].clone();
    let video_steps: u64 = arg(&args, "--video-steps", 0);
    // `--video-config JSON`: settings over the defaults.
    let video_config: String = arg(&args, "--video-config", "{}".to_string());
    let dump: Option<String> = std::env::var("ASSAY_DUMP").ok();
    let rssm_steps: u64 = arg(&args, "--rssm-steps", DynamicsConfig::default().steps);
    let jobs: usize = arg(&args, "--jobs", 2);
    // `--held-out dev`: measure on the seeds held out for choosing settings.
    let held_out: String = arg(&args, "--held-out", "test".to_string());
    let trainings: Vec<String> = arg(&args, "--trainings", "demos+rollouts,demos".to_string())
        .split(',')
        .map(str::to_string)
        .collect();
    let models: Vec<String> = arg(&args, "--models", "video,rssm".to_string())
        .split(',')
        .map(str::to_string)
        .collect();
    let groups: Vec<String> = match args.iter().position(|a| a == "--groups") {
        Some(i) => args[i + 1].split(',').map(str::to_string).collect(),
        None => manifest.keys().cloned().collect(),
    };
    let splits: BTreeMap<String, Split> = groups
        .iter()
        .map(|g| (g.clone(), split(&manifest[g], &held_out)))
        .collect();
    let mut work = Vec::new();
    for g in &groups {
        for model in ["video", "rssm"] {
            if !models.iter().any(|m| m == model) {
                continue;
            }
            for data in ["demos+rollouts", "demos"] {
                if !trainings.iter().any(|t| t == data) {
                    continue;
                }
                work.push((g.clone(), model, data));
            }
        }
    }
    let queue = Mutex::new(work.into_iter());
    let rows = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| {
                loop {
                    let Some((group, model, data)) = queue.lock().unwrap().next() else {
                        break;
                    };
                    let s = &splits[&group];
                    let train = if data == "demos" { &s.demos } else { &s.full };
                    let started = Instant::now();
                    let (id, ood, steps_per_s, steps) = if model == "video" {
                        let mut cfg: VideoModelConfig =
                            serde_json::from_str(&video_config).expect("--video-config: JSON");
                        if video_steps > 0 {
                            cfg.steps = video_steps;
                        }
                        let (m, fit) =
                            video_model::fit(&cfg, train, Device::Cpu, None, &mut |_, _| Ok(()))
                                .expect("video fit");
                        let (id, ood) = tch::no_grad(|| (measure(&m, &s.id), measure(&m, &s.ood)));
                        if let Some(dir) = &dump {
                            let tag = std::env::var("ASSAY_DUMP_TAG").unwrap_or_default();
                            strip(&m, &s.id, &format!("{dir}/{group}-{model}-{data}{tag}.png"));
                        }
                        (id, ood, fit.steps_per_s, fit.steps)
                    } else {
                        let cfg = DynamicsConfig {
                            steps: rssm_steps,
                            checkpoint_every: 0,
                            ..DynamicsConfig::default()
                        };
                        let keys = vec!["eval".to_string()];
                        let req = world_model::FitRequest {
                            config: &cfg,
                            group: &group,
                            budget: train.len() as u32,
                            train,
                            eval: std::slice::from_ref(&s.id[0].1),
                            eval_keys: &keys,
                            device: Device::Cpu,
                            normalize_actions: true,
                        };
                        let (m, fit) = world_model::fit_model(&req, None, &mut |_, _| Ok(()))
                            .expect("rssm fit");
                        let service = m.service();
                        let (id, ood) =
                            tch::no_grad(|| (measure(&service, &s.id), measure(&service, &s.ood)));
                        (id, ood, fit.steps_per_s, fit.steps)
                    };
                    let row = json!({
                        "group": group, "model": model, "training": data, "held_out": held_out,
                        "train_clips": train.len(), "steps": steps, "steps_per_s": steps_per_s,
                        "seconds": started.elapsed().as_secs_f64(),
                        "in_distribution": id, "out_of_distribution": ood,
                    });
                    eprintln!("{row}");
                    rows.lock().unwrap().push(row);
                }
            });
        }
    });
    let mut rows = rows.into_inner().unwrap();
    rows.sort_by_key(|r| {
        (
            r["group"].as_str().unwrap_or("").to_string(),
            r["model"].as_str().unwrap_or("").to_string(),
            r["training"].as_str().unwrap_or("").to_string(),
        )
    });
    let actions: Vec<_> = rows
        .iter()
        .filter(|r| r["training"] == "demos+rollouts")
        .map(|r| {
            let id = &r["in_distribution"];
            json!({
                "group": r["group"], "model": r["model"],
                "mse_true": id["mse_true"], "mse_shuffled": id["mse_shuffled"],
                "mse_zero": id["mse_zero"], "ratio_shuffled": id["ratio_shuffled"],
                "windows": id["windows"], "horizon": HORIZON,
            })
        })
        .collect();
    let build = if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    };
    let machine = format!("2-core CPU, no GPU, {build} build, one libtorch thread per fit");
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let write = |name: &str, rows: &[serde_json::Value]| {
        let doc = json!({"command": command, "machine": machine, "horizon": HORIZON, "rows": rows});
        let path = format!("{prefix}-{name}.json");
        std::fs::write(&path, serde_json::to_vec_pretty(&doc).unwrap()).expect("write");
        eprintln!("wrote {path}");
    };
    write("world-model-actions", &actions);
    write("world-model-video", &rows);
}
