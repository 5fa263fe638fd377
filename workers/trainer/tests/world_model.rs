//! The world model on synthetic clips: a coloured square on a dark background moved by the
//! action (its commanded velocity), with its position as the proprioception.

use assay_model::clip::Clip;
use assay_model::dynamics::{DynamicsConfig, DynamicsFit};
use assay_spec::rng::Rng;
use assay_trainer::world_model::{
    CheckpointSink, FitRequest, WorldModelError, fit, fit_to_checkpoint,
};
use tch::Device;

const SIZE: u32 = 32;
const SQUARE: f32 = 8.0;

/// A clip of `len` frames: a square of `color` starting at `start` (fractions of the free
/// range) driven by `vel` (fractions per second) plus per-step action noise from `seed`.
fn square_clip(len: usize, color: [u8; 3], start: (f32, f32), vel: (f32, f32), seed: u64) -> Clip {
    let n = SIZE as usize;
    let free = SIZE as f32 - SQUARE;
    let mut rng = Rng::new(seed, "square");
    let (mut x, mut y) = start;
    let mut rgb = Vec::with_capacity(len * n * n * 3);
    let mut proprio = Vec::new();
    let mut actions = Vec::new();
    for t in 0..len {
        let (px, py) = ((x * free).round() as usize, (y * free).round() as usize);
        for r in 0..n {
            for c in 0..n {
                let inside = (px..px + SQUARE as usize).contains(&c)
                    && (py..py + SQUARE as usize).contains(&r);
                rgb.extend_from_slice(if inside { &color } else { &[20, 20, 30] });
            }
        }
        proprio.extend_from_slice(&[x, y, 0.0, 0.0]);
        let (ax, ay) = if t + 1 < len {
            (
                vel.0 + rng.uniform(-0.3, 0.3) as f32,
                vel.1 + rng.uniform(-0.3, 0.3) as f32,
            )
        } else {
            (0.0, 0.0)
        };
        actions.extend_from_slice(&[ax, ay, 0.0, 0.0]);
        x = (x + 0.1 * ax).clamp(0.0, 1.0);
        y = (y + 0.1 * ay).clamp(0.0, 1.0);
    }
    Clip {
        height: SIZE,
        width: SIZE,
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

/// One dynamic: a red square drifting right and down, different action noise per clip.
fn simple_family(n: usize) -> Vec<Clip> {
    (0..n)
        .map(|i| square_clip(20, [230, 40, 40], (0.1, 0.2), (0.4, 0.2), i as u64))
        .collect()
}

/// Squares of different colours moving in different directions from different places.
fn diverse_family(n: usize) -> Vec<Clip> {
    const COLORS: [[u8; 3]; 8] = [
        [230, 40, 40],
        [40, 230, 40],
        [60, 60, 240],
        [240, 240, 40],
        [240, 40, 240],
        [40, 240, 240],
        [250, 250, 250],
        [250, 140, 0],
    ];
    (0..n)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / 8.0;
            let (dx, dy) = (a.cos(), a.sin());
            let start = (0.5 - 0.4 * dx, 0.5 - 0.4 * dy);
            square_clip(
                20,
                COLORS[i % 8],
                start,
                (0.8 * dx, 0.8 * dy),
                100 + i as u64,
            )
        })
        .collect()
}

fn tiny() -> DynamicsConfig {
    DynamicsConfig {
        image_size: SIZE,
        chunk: 10,
        batch: 4,
        steps: 0,
        epochs: 10,
        deter: 64,
        stoch: 4,
        classes: 4,
        hidden: 64,
        depth: 8,
        lr: 2e-3,
        free_nats: 1.0,
        seed: 7,
        checkpoint_every: 0,
        threads: 1,
    }
}

fn keys(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("clip-{i}")).collect()
}

fn run(
    cfg: &DynamicsConfig,
    train: &[Clip],
    eval: &[Clip],
    resume: Option<&[u8]>,
    on_checkpoint: &mut CheckpointSink<'_>,
) -> Result<DynamicsFit, WorldModelError> {
    let eval_keys = keys(eval.len());
    fit(
        &FitRequest {
            config: cfg,
            group: "g",
            budget: train.len() as u32,
            train,
            eval,
            eval_keys: &eval_keys,
            device: Device::Cpu,
            normalize_actions: false,
        },
        resume,
        on_checkpoint,
    )
}

fn quick(cfg: &DynamicsConfig, train: &[Clip], eval: &[Clip]) -> DynamicsFit {
    run(cfg, train, eval, None, &mut |_, _| Ok(())).expect("fit")
}

#[test]
fn training_lowers_loss_and_prediction_error() {
    let clips = simple_family(8);
    let mut cfg = tiny();
    cfg.epochs = 0;
    let untrained = quick(&cfg, &clips, &clips);
    cfg.epochs = 1;
    let one = quick(&cfg, &clips, &clips);
    cfg.epochs = 25;
    let trained = quick(&cfg, &clips, &clips);
    eprintln!(
        "untrained {:.5}/{:.5}, 1 epoch loss {:.1}, trained {:.5}/{:.5} loss {:.1} ({} steps)",
        untrained.eval_image_mse,
        untrained.eval_proprio_mse,
        one.final_train_loss,
        trained.eval_image_mse,
        trained.eval_proprio_mse,
        trained.final_train_loss,
        trained.steps
    );
    assert_eq!(untrained.steps, 0);
    assert_eq!(trained.steps, 25 * 4);
    assert_eq!(trained.epochs, 25.0);
    assert_eq!(trained.per_episode.len(), 8);
    assert_eq!(trained.episodes, keys(8));
    assert!(trained.final_train_loss < 0.5 * one.final_train_loss);
    assert!(trained.eval_image_mse < 0.5 * untrained.eval_image_mse);
    assert!(trained.eval_proprio_mse < untrained.eval_proprio_mse);
    assert_eq!(trained.device, "cpu");
}

/// The paper's signal: for a diverse group, more training episodes lower the error on the
/// group; for a group of identical episodes a small budget already suffices. Both budgets get
/// the same number of training steps (`steps`, as the default config does).
#[test]
fn diversity_shows_in_the_budget_curve() {
    let mut cfg = tiny();
    cfg.steps = 240;
    let diverse = diverse_family(8);
    let same: Vec<Clip> = (0..8).map(|_| diverse[0].clone()).collect();
    let at = |clips: &[Clip], budget: usize| {
        let fit = quick(&cfg, &clips[..budget], clips);
        assert_eq!(fit.steps, 240);
        fit.eval_image_mse
    };
    let (d2, d8) = (at(&diverse, 2), at(&diverse, 8));
    let (s2, s8) = (at(&same, 2), at(&same, 8));
    eprintln!("diverse: 2 → {d2:.5}, 8 → {d8:.5}; identical: 2 → {s2:.5}, 8 → {s8:.5}");
    assert!(d2 > 1.5 * d8, "diverse: {d2} vs {d8}");
    assert!(
        s2 < 0.5 * d2 && s8 < 0.5 * d2,
        "identical {s2}, {s8} vs diverse {d2}"
    );
    assert!(s2 < 1.5 * s8 && s8 < 1.5 * s2, "identical: {s2} vs {s8}");
}

#[test]
fn resumed_fit_matches_an_uninterrupted_one_exactly() {
    let clips = simple_family(6);
    let mut cfg = tiny();
    cfg.steps = 11; // 12 chunks → 3 steps per epoch: 3⅔ epochs
    cfg.checkpoint_every = 4;
    let mut seen = Vec::new();
    let full = run(&cfg, &clips, &clips[..3], None, &mut |step, bytes| {
        seen.push((step, bytes.to_vec()));
        Ok(())
    })
    .expect("uninterrupted fit");
    assert_eq!(full.steps, 11);
    assert!((full.epochs - 11.0 / 3.0).abs() < 1e-12, "{}", full.epochs);
    assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), [4, 8]);

    // A worker killed after storing its second checkpoint (mid-epoch: step 8 of 3-step epochs).
    let mut stored = None;
    let err = run(&cfg, &clips, &clips[..3], None, &mut |step, bytes| {
        stored = Some(bytes.to_vec());
        if step >= 8 {
            Err("killed".into())
        } else {
            Ok(())
        }
    })
    .expect_err("interrupted");
    assert!(
        matches!(err, WorldModelError::Checkpoint { step: 8, .. }),
        "{err}"
    );
    let stored = stored.expect("a checkpoint");
    assert!(stored == seen[1].1, "checkpoints of the same step differ");

    let resumed =
        run(&cfg, &clips, &clips[..3], Some(&stored), &mut |_, _| Ok(())).expect("resumed fit");
    assert_eq!(resumed.resumed_from_step, Some(8));
    let strip = |f: &DynamicsFit| DynamicsFit {
        steps_per_s: 0.0,
        resumed_from_step: None,
        ..f.clone()
    };
    assert_eq!(strip(&resumed), strip(&full));

    // Another config (or other clips) must not resume from it.
    let mut other = cfg.clone();
    other.lr *= 2.0;
    let err = run(&other, &clips, &clips[..3], Some(&stored), &mut |_, _| {
        Ok(())
    })
    .expect_err("other config");
    assert!(
        matches!(err, WorldModelError::CheckpointRefused(_)),
        "{err}"
    );
    assert!(
        err.to_string().contains("another world-model config"),
        "{err}"
    );
    let err = run(
        &cfg,
        &clips[..5],
        &clips[..3],
        Some(&stored),
        &mut |_, _| Ok(()),
    )
    .expect_err("other clips");
    assert!(err.to_string().contains("other training clips"), "{err}");
    let err = run(&cfg, &clips, &clips[..3], Some(b"garbage"), &mut |_, _| {
        Ok(())
    })
    .expect_err("garbage");
    assert!(
        matches!(err, WorldModelError::CheckpointRefused(_)),
        "{err}"
    );
    // Settings that do not change the computation may differ.
    let mut threads = cfg.clone();
    threads.checkpoint_every = 5;
    let again = run(&threads, &clips, &clips[..3], Some(&stored), &mut |_, _| {
        Ok(())
    })
    .expect("resumed with another checkpoint interval");
    assert_eq!(again.eval_image_mse, full.eval_image_mse);
}

/// A fit's last checkpoint (the proxy's world model, fitted ahead of the proxy) is the trained
/// model: a fit resumed from it trains no further step and evaluates exactly as the model that
/// wrote it — on clips it never saw while it was fitted.
#[test]
fn a_fit_resumed_from_its_last_checkpoint_is_the_fitted_model() {
    let clips = simple_family(6);
    let mut cfg = tiny();
    cfg.steps = 7;
    let eval_keys = keys(3);
    let (train, held_out) = (&clips[..4], &clips[3..]);
    let req = || FitRequest {
        config: &cfg,
        group: "g",
        budget: 4,
        train,
        eval: held_out,
        eval_keys: &eval_keys,
        device: Device::Cpu,
        normalize_actions: true,
    };
    // Evaluated on one clip only, as the trainer's job does.
    let ahead_req = FitRequest {
        eval: &held_out[..1],
        eval_keys: &eval_keys[..1],
        ..req()
    };
    let (ahead, last) = fit_to_checkpoint(&ahead_req, None, &mut |_, _| Ok(()))
        .expect("fit to its last checkpoint");
    assert_eq!(ahead.steps, 7);
    let full = fit(&req(), None, &mut |_, _| Ok(())).expect("a fit of its own");
    let resumed = fit(&req(), Some(&last), &mut |_, _| {
        panic!("a fit resumed at its last step trains nothing, so writes no checkpoint")
    })
    .expect("resumed from the last checkpoint");
    assert_eq!(resumed.resumed_from_step, Some(7));
    assert_eq!(resumed.steps, 7);
    assert_eq!(resumed.eval_image_mse, full.eval_image_mse);
    assert_eq!(resumed.per_episode, full.per_episode);
    assert_eq!(resumed.final_train_loss, full.final_train_loss);
    // Fitted on other clips, it is refused.
    let other = FitRequest {
        train: &clips[1..5],
        ..req()
    };
    let err = fit(&other, Some(&last), &mut |_, _| Ok(())).expect_err("other clips");
    assert!(
        matches!(err, WorldModelError::CheckpointRefused(_)),
        "{err}"
    );
}

/// `steps` fixes the training length whatever the budget; `epochs` (with `steps` 0) scales it
/// with the number of training chunks, as the paper did.
#[test]
fn steps_or_epochs_set_the_training_length() {
    let clips = simple_family(6);
    let mut cfg = tiny();
    cfg.steps = 5;
    for (n, epochs) in [(2, 5.0), (6, 5.0 / 3.0)] {
        let fit = quick(&cfg, &clips[..n], &clips);
        assert_eq!((fit.steps, fit.epochs), (5, epochs), "{n} clips");
    }
    cfg.steps = 0;
    cfg.epochs = 2;
    for (n, steps) in [(2, 2), (6, 6)] {
        let fit = quick(&cfg, &clips[..n], &clips);
        assert_eq!((fit.steps, fit.epochs), (steps, 2.0), "{n} clips");
    }
    // Nothing to train on: an error, not a division by zero.
    cfg.steps = 5;
    let err = run(&cfg, &[], &clips, None, &mut |_, _| Ok(())).expect_err("no chunks");
    assert!(err.to_string().contains("no chunk of 2 frames"), "{err}");
}

#[test]
fn bad_clips_are_named() {
    let cfg = tiny();
    let good = simple_family(2);
    let message = |train: &[Clip], eval: &[Clip]| {
        run(&cfg, train, eval, None, &mut |_, _| Ok(()))
            .expect_err("bad clip")
            .to_string()
    };

    let mut small = good[1].clone();
    small.width = 16;
    small.height = 16;
    small.rgb.truncate(small.rgb.len() / 4);
    let m = message(&good, &[good[0].clone(), small]);
    assert!(
        m.contains("eval clip 1 (clip-1)") && m.contains("16x16"),
        "{m}"
    );

    let mut short = good[0].clone();
    short.rgb.truncate((SIZE * SIZE * 3) as usize);
    short.proprio.truncate(4);
    short.actions.truncate(4);
    let m = message(&[good[0].clone(), short], &good);
    assert!(
        m.contains("train clip 1") && m.contains("at least 2"),
        "{m}"
    );

    let mut dims = good[0].clone();
    dims.proprio_dims = 2;
    dims.proprio.truncate(dims.proprio.len() / 2);
    let m = message(&[dims], &good);
    assert!(
        m.contains("train clip 0") && m.contains("proprioception"),
        "{m}"
    );

    let mut torn = good[0].clone();
    torn.actions.pop();
    let m = message(&good, &[torn]);
    assert!(
        m.contains("eval clip 0") && m.contains("action values"),
        "{m}"
    );

    let mut odd = cfg.clone();
    odd.image_size = 40;
    let err = run(&odd, &good, &good, None, &mut |_, _| Ok(())).expect_err("size");
    assert!(matches!(err, WorldModelError::Request(_)), "{err}");
}
