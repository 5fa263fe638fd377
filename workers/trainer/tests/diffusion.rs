//! The diffusion policy on synthetic clips: a coloured square (the target) at a random place in a
//! 64×64 frame, a small grey square where the tool is, proprioception = the tool's position, and
//! actions = the tool's velocity toward the target (hold commanded once it is there).

use assay_model::clip::Clip;
use assay_model::diffusion::{Backbone, DiffusionConfig, TransformerSize};
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_spec::rng::Rng;
use assay_trainer::diffusion::{DiffusionError, DiffusionPolicy, train};
use tch::Device;

const SIZE: usize = 64;
/// The frame shows x, y in [−HALF, HALF] metres.
const HALF: f32 = 0.4;
const GAIN: f32 = 2.0;
const MAX_SPEED: f32 = 0.4;
const REACHED: f32 = 0.03;
const COLORS: [[u8; 3]; 4] = [[230, 40, 40], [40, 220, 60], [60, 90, 250], [240, 220, 40]];

fn pixel(v: f32) -> usize {
    (((v + HALF) / (2.0 * HALF)) * (SIZE - 1) as f32).round() as usize
}

/// A frame with the target square (10 px) and the tool (4 px, drawn over it).
fn frame(target: (f32, f32), color: [u8; 3], tool: (f32, f32)) -> Vec<u8> {
    let mut rgb = vec![0u8; SIZE * SIZE * 3];
    for px in rgb.chunks_exact_mut(3) {
        px.copy_from_slice(&[20, 20, 30]);
    }
    let mut square = |centre: (f32, f32), half: usize, c: [u8; 3]| {
        let (cx, cy) = (pixel(centre.0), pixel(centre.1));
        for r in cy.saturating_sub(half)..(cy + half).min(SIZE) {
            for col in cx.saturating_sub(half)..(cx + half).min(SIZE) {
                let at = (r * SIZE + col) * 3;
                rgb[at..at + 3].copy_from_slice(&c);
            }
        }
    };
    square(target, 5, color);
    square(tool, 2, [170, 170, 170]);
    rgb
}

/// The scripted action from `tool` toward `target`: velocity (clipped) and hold once there.
fn expert(tool: (f32, f32), target: (f32, f32)) -> [f32; 4] {
    let (dx, dy) = (target.0 - tool.0, target.1 - tool.1);
    let (mut vx, mut vy) = (GAIN * dx, GAIN * dy);
    let speed = (vx * vx + vy * vy).sqrt();
    if speed > MAX_SPEED {
        vx *= MAX_SPEED / speed;
        vy *= MAX_SPEED / speed;
    }
    let there = (dx * dx + dy * dy).sqrt() < REACHED;
    [vx, vy, 0.0, if there { 1.0 } else { 0.0 }]
}

struct Start {
    target: (f32, f32),
    tool: (f32, f32),
    color: [u8; 3],
}

fn draw_start(rng: &mut Rng) -> Start {
    let mut at = || (rng.uniform(-0.3, 0.3) as f32, rng.uniform(-0.3, 0.3) as f32);
    let (target, tool) = (at(), at());
    Start {
        target,
        tool,
        color: COLORS[(rng.next_u64() % COLORS.len() as u64) as usize],
    }
}

/// One episode of `len` frames at 10 Hz.
fn episode(len: usize, s: &Start) -> Clip {
    let mut tool = s.tool;
    let mut holding = 0.0;
    let (mut rgb, mut proprio, mut actions) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..len {
        rgb.extend(frame(s.target, s.color, tool));
        proprio.extend_from_slice(&[tool.0, tool.1, 0.1, holding]);
        let a = if t + 1 < len {
            expert(tool, s.target)
        } else {
            [0.0; 4]
        };
        actions.extend_from_slice(&a);
        tool = (tool.0 + 0.1 * a[0], tool.1 + 0.1 * a[1]);
        holding = a[3];
    }
    Clip {
        height: SIZE as u32,
        width: SIZE as u32,
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

/// Long episodes (the size of real clips): each time the tool has held at the target for 3
/// frames, the target moves elsewhere and the hold is released.
fn long_episode(len: usize, rng: &mut Rng) -> Clip {
    let mut s = draw_start(rng);
    let mut held = 0;
    let mut holding = 0.0;
    let (mut rgb, mut proprio, mut actions) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..len {
        rgb.extend(frame(s.target, s.color, s.tool));
        proprio.extend_from_slice(&[s.tool.0, s.tool.1, 0.1, holding]);
        let a = if t + 1 < len {
            expert(s.tool, s.target)
        } else {
            [0.0; 4]
        };
        actions.extend_from_slice(&a);
        s.tool = (s.tool.0 + 0.1 * a[0], s.tool.1 + 0.1 * a[1]);
        holding = a[3];
        held = if a[3] > 0.5 { held + 1 } else { 0 };
        if held == 3 {
            let next = draw_start(rng);
            s.target = next.target;
            s.color = next.color;
            held = 0;
        }
    }
    Clip {
        height: SIZE as u32,
        width: SIZE as u32,
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

fn clips(n: usize, len: usize, seed: u64) -> Vec<Clip> {
    let mut rng = Rng::new(seed, "diffusion-test/clips");
    (0..n)
        .map(|_| episode(len, &draw_start(&mut rng)))
        .collect()
}

fn observation(step: u32, s: &Start) -> PolicyObservation {
    PolicyObservation::legacy(
        step,
        SIZE as u32,
        SIZE as u32,
        frame(s.target, s.color, s.tool),
        [s.tool.0, s.tool.1, 0.1, 0.0],
    )
}

/// Small and quick: for the tests that do not need a good policy.
fn tiny_config() -> DiffusionConfig {
    DiffusionConfig {
        steps: 4,
        batch: 4,
        encoder_depth: 4,
        obs_features: 16,
        down_dims: vec![16, 32],
        time_embed: 16,
        ..DiffusionConfig::default()
    }
}

fn tiny_policy(seed: u64) -> DiffusionPolicy {
    let cfg = DiffusionConfig {
        seed,
        ..tiny_config()
    };
    train(&clips(3, 12, 1), &cfg, Device::Cpu, &mut |_, _| {})
        .unwrap()
        .0
}

fn episode_context(seed: u64) -> EpisodeContext {
    EpisodeContext {
        task_id: "reach-square".into(),
        seed,
        instruction: "move to the square".into(),
        arm: None,
    }
}

/// On 24 unseen starts (target at least 10 cm away), the cosine between the first executed
/// action's velocity and the direction to the target, and that action's hold value.
fn unseen_first_actions(policy: &DiffusionPolicy) -> (f32, Vec<f32>, Vec<f32>) {
    let cfg = policy.config();
    let mut rng = Rng::new(99, "diffusion-test/unseen");
    let (mut cosines, mut holds) = (Vec::new(), Vec::new());
    while cosines.len() < 24 {
        let s = draw_start(&mut rng);
        let (dx, dy) = (s.target.0 - s.tool.0, s.target.1 - s.tool.1);
        let dist = (dx * dx + dy * dy).sqrt();
        if dist < 0.1 {
            continue;
        }
        let chunk = policy
            .predict(&[observation(0, &s)], cosines.len() as u64)
            .unwrap();
        assert_eq!(chunk.len(), cfg.pred_horizon);
        let a = chunk[cfg.obs_horizon - 1];
        let norm = (a[0] * a[0] + a[1] * a[1]).sqrt().max(1e-6);
        cosines.push((a[0] * dx + a[1] * dy) / (norm * dist));
        holds.push(a[3]);
    }
    let mean = cosines.iter().sum::<f32>() / cosines.len() as f32;
    (mean, cosines, holds)
}

#[test]
fn learns_to_move_toward_the_target() {
    // The default model with a narrower U-Net, trained briefly on many short episodes.
    learns_toward_the_target(DiffusionConfig {
        steps: 1000,
        batch: 32,
        lr: 2e-3,
        down_dims: vec![16, 32, 64],
        ..DiffusionConfig::default()
    });
}

#[test]
fn the_transformer_family_learns_to_move_toward_the_target() {
    // The second family (Chi et al.'s transformer denoiser) at its default size, the same data
    // and training as the U-Net's test above.
    learns_toward_the_target(DiffusionConfig {
        steps: 1000,
        batch: 32,
        lr: 2e-3,
        backbone: Backbone::Transformer,
        ..DiffusionConfig::default()
    });
}

fn learns_toward_the_target(cfg: DiffusionConfig) {
    let data = clips(80, 12, 7);
    let mut losses = Vec::new();
    let (policy, fit) = train(&data, &cfg, Device::Cpu, &mut |_, l| losses.push(l)).unwrap();
    assert_eq!(fit.steps, 1000);
    assert_eq!(losses.len(), 1000);
    assert_eq!(fit.clips, 80);
    assert_eq!(fit.samples, 80 * 11);
    assert_eq!(fit.device, "cpu");
    let first: f64 = losses[..20].iter().sum::<f64>() / 20.0;
    println!(
        "loss {first:.3} → {:.3} in {:.1} s, {} parameters",
        fit.mean_last_100_loss, fit.train_seconds, fit.parameters
    );
    assert!(
        fit.mean_last_100_loss < 0.5 * first,
        "loss fell only from {first} to {}",
        fit.mean_last_100_loss
    );

    let (mean, cosines, holds) = unseen_first_actions(&policy);
    println!("cosines {cosines:.2?} mean {mean:.3}; holds {holds:.2?}");
    assert!(mean > 0.8, "mean cosine {mean} (cosines {cosines:?})");
    // Far from the target it does not command a hold (on average: the samples are noisy after
    // so short a training).
    let hold = holds.iter().sum::<f32>() / holds.len() as f32;
    assert!(
        hold < 0.5,
        "mean hold {hold} 10 cm or more from the target: {holds:?}"
    );
    let mut policy = policy;
    let (reached, steps) = closed_loop(&mut policy);
    println!("closed loop: {reached} of 20 reached the target, in {steps:.1} steps on average");
}

#[test]
fn bytes_round_trip_gives_the_same_predictions() {
    round_trip(tiny_policy(3));
    let transformer = DiffusionConfig {
        backbone: Backbone::Transformer,
        transformer: TransformerSize {
            layers: 2,
            heads: 2,
            width: 16,
        },
        ..tiny_config()
    };
    let policy = train(&clips(3, 12, 1), &transformer, Device::Cpu, &mut |_, _| {})
        .unwrap()
        .0;
    // Its parameters are the transformer's, not the U-Net's.
    assert!(
        policy.to_bytes().len() < tiny_policy(3).to_bytes().len(),
        "a 2-layer, 16-wide transformer is smaller than the tiny U-Net"
    );
    round_trip(policy);
    // A U-Net checkpoint is not read as a transformer's (its config says which it is).
    let bytes = tiny_policy(3).to_bytes();
    assert_eq!(
        DiffusionPolicy::from_bytes(&bytes, Device::Cpu)
            .unwrap()
            .config()
            .backbone,
        Backbone::Unet
    );
}

fn round_trip(policy: DiffusionPolicy) {
    let bytes = policy.to_bytes();
    let again = DiffusionPolicy::from_bytes(&bytes, Device::Cpu).unwrap();
    assert_eq!(again.config(), policy.config());
    assert_eq!(again.to_bytes(), bytes);
    let mut rng = Rng::new(5, "diffusion-test/round-trip");
    let (a, b) = (draw_start(&mut rng), draw_start(&mut rng));
    let history = [observation(0, &a), observation(1, &b)];
    for seed in [0, 1, 77] {
        let x = policy.predict(&history, seed).unwrap();
        let y = again.predict(&history, seed).unwrap();
        assert_eq!(x, y, "seed {seed}");
        assert!(x.iter().flatten().all(|v| v.is_finite()));
    }
    // Another seed draws other noise.
    assert_ne!(
        policy.predict(&history, 0).unwrap(),
        policy.predict(&history, 1).unwrap()
    );
}

#[test]
fn the_policy_returns_action_horizon_actions_and_uses_its_history() {
    let bytes = tiny_policy(4).to_bytes();
    let load = || DiffusionPolicy::from_bytes(&bytes, Device::Cpu).unwrap();
    let mut rng = Rng::new(6, "diffusion-test/history");
    let (a, b, c) = (
        draw_start(&mut rng),
        draw_start(&mut rng),
        draw_start(&mut rng),
    );
    let run = |p: &mut DiffusionPolicy, first: &Start, second: &Start| -> Vec<Vec<Action>> {
        p.reset(&episode_context(11)).unwrap();
        vec![
            p.act(&observation(0, first)).unwrap(),
            p.act(&observation(1, second)).unwrap(),
        ]
    };
    let mut p = load();
    let ab = run(&mut p, &a, &b);
    let horizon = p.config().action_horizon;
    assert!(ab.iter().all(|chunk| chunk.len() == horizon));
    // Same episode, same answers; reset forgets the last episode's observations.
    assert_eq!(run(&mut p, &a, &b), ab);
    assert_eq!(run(&mut load(), &a, &b), ab);
    // Only the earlier observation differs: the second answer changes with it.
    let cb = run(&mut load(), &c, &b);
    assert_eq!(cb[0].len(), horizon);
    assert_ne!(
        cb[1], ab[1],
        "the second answer ignores the first observation"
    );
    // The simulator's driver asks once per chunk: without the frame of step 7, the window at
    // step 8 repeats the current observation, as training does at a clip's first frame.
    assert_eq!(
        p.predict(&[observation(0, &a), observation(8, &b)], 3)
            .unwrap(),
        p.predict(&[observation(8, &b)], 3).unwrap()
    );
    // Another episode seed samples other noise.
    let mut q = load();
    q.reset(&episode_context(12)).unwrap();
    assert_ne!(q.act(&observation(0, &a)).unwrap(), ab[0]);
    // The executed slice is the predicted chunk from the current step on (index
    // obs_horizon − 1), sampled with the episode stream's seeds (see the module docs).
    let cfg = p.config().clone();
    let mut stream = Rng::new(cfg.seed, "diffusion/episode/11/reach-square");
    let history = [observation(0, &a), observation(1, &b)];
    for (k, answer) in ab.iter().enumerate() {
        let full = p.predict(&history[..=k], stream.next_u64()).unwrap();
        assert_eq!(full.len(), cfg.pred_horizon);
        let start = cfg.obs_horizon - 1;
        assert_eq!(answer[..], full[start..start + cfg.action_horizon]);
    }
}

#[test]
fn bad_inputs_are_errors_that_say_what_is_wrong() {
    let cfg = tiny_config();
    let good = clips(2, 6, 2);
    let err = |clips: &[Clip], cfg: &DiffusionConfig| match train(
        clips,
        cfg,
        Device::Cpu,
        &mut |_, _| {},
    ) {
        Ok(_) => panic!("training accepted bad input"),
        Err(e) => e,
    };
    assert!(matches!(err(&[], &cfg), DiffusionError::NoClips));

    let mut small = good.clone();
    small[1] = Clip {
        height: 32,
        width: 32,
        rgb: vec![0; 6 * 32 * 32 * 3],
        ..good[1].clone()
    };
    let e = err(&small, &cfg);
    assert!(matches!(e, DiffusionError::BadClip { index: 1, .. }), "{e}");
    assert!(e.to_string().contains("32x32"), "{e}");

    let mut dims = good.clone();
    dims[0].action_dims = 3;
    dims[0].actions.truncate(6 * 3);
    let e = err(&dims, &cfg).to_string();
    assert!(
        e.contains("training clip 0") && e.contains("3 action dims"),
        "{e}"
    );

    let mut short = good.clone();
    short[0] = Clip {
        rgb: good[0].rgb[..SIZE * SIZE * 3].to_vec(),
        proprio: good[0].proprio[..4].to_vec(),
        actions: vec![0.0; 4],
        ..good[0].clone()
    };
    let e = err(&short, &cfg).to_string();
    assert!(e.contains("1 frame(s)"), "{e}");

    let mut torn = good.clone();
    torn[1].proprio.pop();
    let e = err(&torn, &cfg).to_string();
    assert!(
        e.contains("training clip 1") && e.contains("proprioception"),
        "{e}"
    );

    let mut nan = good.clone();
    nan[0].actions[2] = f32::NAN;
    assert!(err(&nan, &cfg).to_string().contains("non-finite"));

    let bad_cfg = DiffusionConfig {
        pred_horizon: 6,
        ..cfg.clone()
    };
    let e = err(&good, &bad_cfg);
    assert!(matches!(e, DiffusionError::Config(_)), "{e}");
    assert!(e.to_string().contains("pred_horizon"), "{e}");

    // Checkpoints.
    let refused = |bytes: &[u8]| match DiffusionPolicy::from_bytes(bytes, Device::Cpu) {
        Ok(_) => panic!("a damaged checkpoint was read"),
        Err(e) => e.to_string(),
    };
    assert!(refused(b"ASYWM001 a world model").contains("no ASYDP001 header"));
    assert!(refused(b"").contains("no ASYDP001 header"));
    let policy = tiny_policy(5);
    let bytes = policy.to_bytes();
    assert!(refused(&bytes[..20]).contains("truncated"));
    assert!(refused(&bytes[..bytes.len() - 10]).contains("unreadable tensors"));
    // A header whose config does not describe the weights.
    let len = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&bytes[16..16 + len]).unwrap();
    let wider = header.replace("\"obs_features\":16", "\"obs_features\":24");
    assert_ne!(wider, header);
    let mut other = b"ASYDP001".to_vec();
    other.extend_from_slice(&(wider.len() as u64).to_le_bytes());
    other.extend_from_slice(wider.as_bytes());
    other.extend_from_slice(&bytes[16 + len..]);
    assert!(refused(&other).contains("has shape"), "{}", refused(&other));

    // Observations.
    let mut p = policy;
    p.reset(&episode_context(1)).unwrap();
    let mut obs = observation(0, &draw_start(&mut Rng::new(1, "x")));
    obs.width = 32;
    obs.height = 32;
    obs.rgb.truncate(32 * 32 * 3);
    match p.act(&obs) {
        Err(PolicyError::Load(m)) => assert!(m.contains("32x32") && m.contains("64x64"), "{m}"),
        other => panic!("expected a load error, got {other:?}"),
    }
    let mut torn = observation(0, &draw_start(&mut Rng::new(1, "x")));
    torn.rgb.pop();
    assert!(matches!(p.act(&torn), Err(PolicyError::Load(m)) if m.contains("RGB bytes")));
    let e = p.predict(&[], 0).unwrap_err().to_string();
    assert!(e.contains("no observation"), "{e}");
}

#[test]
fn same_config_and_data_give_the_same_weights() {
    let data = clips(3, 10, 3);
    let cfg = tiny_config();
    let fit = |cfg: &DiffusionConfig| {
        let mut losses = Vec::new();
        let (p, _) = train(&data, cfg, Device::Cpu, &mut |_, l| losses.push(l)).unwrap();
        (p.to_bytes(), losses)
    };
    let (a, la) = fit(&cfg);
    let (b, lb) = fit(&cfg);
    assert_eq!(la, lb);
    assert!(a == b, "the same fit gave different weights");
    let (c, _) = fit(&DiffusionConfig { seed: 1, ..cfg });
    assert!(a != c, "another seed gave the same weights");
}

/// A fit's weights do not depend on what the trainer runs beside it, when every fit uses the
/// same intra-op thread count (every model's default, 1): a ladder's policies come out the same
/// in a batch of one group as in a batch of several. The fit is the default U-Net's, alone, then
/// on its own thread beside a transformer fit and a U-Net fit of other seeds. (A probe of
/// 2026-12-02, 60 steps beside two U-Net fits: at 1 thread all, the same weights in 6 runs of 6;
/// with the two others at 2 threads, the fit drifted from its 4th step in 2 runs of 5 — hence
/// the advice on `threads` to keep one count for every model a trainer runs.)
#[test]
fn a_fit_beside_other_fits_gives_the_same_weights_as_alone() {
    let data = clips(20, 12, 7);
    let fit = |cfg: &DiffusionConfig| {
        let mut losses = Vec::new();
        let (p, _) = train(&data, cfg, Device::Cpu, &mut |_, l| losses.push(l)).unwrap();
        (p.to_bytes(), losses)
    };
    let cfg = DiffusionConfig {
        steps: 12,
        batch: 16,
        ..DiffusionConfig::default()
    };
    let other = DiffusionConfig {
        steps: 16,
        batch: 8,
        seed: 5,
        ..cfg.clone()
    };
    let (alone, losses_alone) = fit(&cfg);
    let (beside, losses_beside) = std::thread::scope(|s| {
        let transformer = s.spawn(|| {
            fit(&DiffusionConfig {
                backbone: Backbone::Transformer,
                ..other.clone()
            })
        });
        let unet = s.spawn(|| fit(&other));
        let ours = s.spawn(|| fit(&cfg));
        transformer.join().unwrap();
        unet.join().unwrap();
        ours.join().unwrap()
    });
    assert_eq!(losses_alone, losses_beside);
    assert!(alone == beside, "the fit beside others gave other weights");
}

/// Closed loop through the [`Policy`] interface, as the simulator's driver runs it (a chunk of
/// `action_horizon` actions per call): of 20 unseen starts, how many commanded a hold within
/// 5 cm of the target within 40 control steps, and the mean steps those took.
fn closed_loop(policy: &mut DiffusionPolicy) -> (usize, f64) {
    let mut rng = Rng::new(123, "diffusion-test/closed-loop");
    let (mut reached, mut steps) = (0, 0.0);
    for episode in 0..20 {
        let mut s = draw_start(&mut rng);
        policy.reset(&episode_context(episode)).unwrap();
        let mut chunk: std::collections::VecDeque<Action> = Default::default();
        for step in 0..40u32 {
            if chunk.is_empty() {
                chunk = policy.act(&observation(step, &s)).unwrap().into();
            }
            let a = chunk.pop_front().unwrap();
            let (dx, dy) = (s.target.0 - s.tool.0, s.target.1 - s.tool.1);
            if a[3] >= 0.5 && (dx * dx + dy * dy).sqrt() < 0.05 {
                reached += 1;
                steps += f64::from(step);
                break;
            }
            s.tool = (s.tool.0 + 0.1 * a[0], s.tool.1 + 0.1 * a[1]);
        }
    }
    (reached, steps / reached.max(1) as f64)
}

/// CPU seconds (user + system) this process has used so far.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // Fields 14 and 15 of stat(5), counted from the state (field 3) here; 100 ticks/s.
    (ticks(11) + ticks(12)) / 100.0
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg").unwrap_or_default()
}

/// Speed at the default config on 40 clips of 100 frames, on 1 and 2 libtorch threads:
/// `cargo test -p assay-trainer --release --test diffusion bench_speed -- --ignored --nocapture`.
#[test]
#[ignore]
fn bench_speed() {
    let cfg = DiffusionConfig::default();
    let mut rng = Rng::new(8, "diffusion-test/bench");
    let data: Vec<Clip> = (0..40).map(|_| long_episode(100, &mut rng)).collect();
    let history = [
        observation(0, &draw_start(&mut rng)),
        observation(1, &draw_start(&mut rng)),
    ];
    println!("load average before: {}", load_average());
    for threads in [1, 2, 1, 2] {
        let steps = 50;
        let c = DiffusionConfig {
            steps,
            threads,
            ..cfg.clone()
        };
        let cpu = cpu_seconds();
        let (policy, fit) = train(&data, &c, Device::Cpu, &mut |_, _| {}).unwrap();
        let cpu = cpu_seconds() - cpu;
        let per_s = steps as f64 / fit.train_seconds;
        tch::set_num_threads(threads as i32);
        policy.predict(&history, 0).unwrap();
        let (started, cpu_inf) = (std::time::Instant::now(), cpu_seconds());
        let n = 40;
        for seed in 0..n {
            policy.predict(&history, seed).unwrap();
        }
        let ms = started.elapsed().as_secs_f64() * 1e3 / n as f64;
        let cpu_ms = (cpu_seconds() - cpu_inf) * 1e3 / n as f64;
        println!(
            "threads {threads}: {per_s:.2} training steps/s (batch {}; {:.3} CPU-s per step), \
             {ms:.1} ms per chunk ({} DDIM steps; {cpu_ms:.1} CPU-ms); {} steps ≈ {:.1} min; \
             {} parameters, {} samples",
            cfg.batch,
            cpu / steps as f64,
            cfg.inference_steps,
            cfg.steps,
            cfg.steps as f64 / per_s / 60.0,
            fit.parameters,
            fit.samples
        );
    }
    println!("load average after: {}", load_average());
}

/// A whole default training run on 40 clips of 100 frames, and what the policy learnt:
/// `cargo test -p assay-trainer --release --test diffusion bench_default_run -- --ignored --nocapture`.
#[test]
#[ignore]
fn bench_default_run() {
    let cfg = DiffusionConfig::default();
    let mut rng = Rng::new(8, "diffusion-test/bench");
    let data: Vec<Clip> = (0..40).map(|_| long_episode(100, &mut rng)).collect();
    println!("load average before: {}", load_average());
    let mut losses = Vec::new();
    let (policy, fit) = train(&data, &cfg, Device::Cpu, &mut |step, l| {
        losses.push(l);
        if step % 500 == 0 {
            let tail = &losses[losses.len() - 100..];
            println!("step {step}: loss {:.4}", tail.iter().sum::<f64>() / 100.0);
        }
    })
    .unwrap();
    let (mean, cosines, holds) = unseen_first_actions(&policy);
    let mut policy = policy;
    let (reached, steps) = closed_loop(&mut policy);
    println!("closed loop: {reached} of 20 reached the target, in {steps:.1} steps on average");
    println!(
        "{} steps in {:.1} min ({:.2} steps/s), final loss {:.4}; cosines {cosines:.2?} mean \
         {mean:.3}; holds {holds:.2?}",
        fit.steps,
        fit.train_seconds / 60.0,
        fit.steps as f64 / fit.train_seconds,
        fit.mean_last_100_loss
    );
    println!("load average after: {}", load_average());
}

/// A diffusion job run twice in one batch — a ladder's run with checkpoints, then a
/// generalization policy on the same clips and settings — trains once: the second takes the
/// first's policy and fit as they are, without reading a clip. Another batch, or other settings,
/// trains its own.
#[test]
fn the_same_training_twice_in_a_batch_trains_once() {
    use assay_embed::{Config, Embedders};
    use assay_model::proxy::ExternalWorldModel;
    use assay_model::trainer::{TrainerJob, TrainerOutcome};
    use assay_model::world::{WorldError, WorldModelService};
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let store_clips = || {
        std::fs::create_dir_all(root.join("clips")).unwrap();
        for (i, c) in clips(2, 12, 5).iter().enumerate() {
            std::fs::write(root.join(format!("clips/{i}.clip")), c.encode()).unwrap();
        }
    };
    store_clips();
    let keys: Vec<String> = (0..2).map(|i| format!("clips/{i}.clip")).collect();
    let read = |k: &str| std::fs::read(root.join(k));
    let embedders = std::sync::Mutex::new(Embedders::new(Config::default(), Device::Cpu));
    let policies =
        |p: &str| -> Result<Box<dyn Policy>, PolicyError> { panic!("no policy is loaded: {p}") };
    let worlds = |_: &ExternalWorldModel| -> Result<Box<dyn WorldModelService>, WorldError> {
        panic!("no world model is served")
    };
    let run = |checkpoints: Vec<u64>, config: DiffusionConfig, batch: &str| {
        let job = TrainerJob::Diffusion {
            group: "g".into(),
            clips: keys.clone(),
            config,
            checkpoints,
        };
        assay_trainer::jobs::run(
            &job,
            batch,
            root,
            &read,
            &embedders,
            &policies,
            &worlds,
            Device::Cpu,
        )
        .map(|outcome| match outcome {
            TrainerOutcome::Diffusion {
                model,
                fit,
                checkpoints,
                ..
            } => (model, *fit, checkpoints),
            other => panic!("{other:?}"),
        })
        .map_err(|e| e.message)
    };
    let (model, fit, kept) = run(vec![2], tiny_config(), "b1").unwrap();
    assert_eq!(kept.len(), 1);
    // The clips are gone: only a policy taken as it is can come back.
    std::fs::remove_dir_all(root.join("clips")).unwrap();
    let (again, again_fit, again_kept) = run(Vec::new(), tiny_config(), "b1").unwrap();
    assert_eq!(again, model);
    assert_eq!(
        (again_fit.steps, again_fit.final_loss, again_fit.samples),
        (fit.steps, fit.final_loss, fit.samples)
    );
    assert!(again_kept.is_empty());
    // Another batch, or other settings, trains its own: it reads the clips.
    let e = run(Vec::new(), tiny_config(), "b2").unwrap_err();
    assert!(e.contains("clips/0.clip"), "{e}");
    let seeded = DiffusionConfig {
        seed: 1,
        ..tiny_config()
    };
    let e = run(Vec::new(), seeded.clone(), "b1").unwrap_err();
    assert!(e.contains("clips/0.clip"), "{e}");
    store_clips();
    let (other, _, _) = run(Vec::new(), seeded, "b1").unwrap();
    assert_ne!(other, model);
}
