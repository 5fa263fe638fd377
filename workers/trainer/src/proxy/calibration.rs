//! The proxy's calibration (see `assay_model::proxy::Calibration`): out-of-fold frame-judge
//! probabilities on the training episodes' imagined last frames, then Platt scaling
//! (`assay_stats::calibration::platt`) against their real outcomes.

use std::ops::Range;

use assay_model::proxy::{Calibration, ProxyConfig, RELIABILITY_BINS, TrainReliability};
use assay_stats::calibration::reliability;
use tch::Device;

use super::train_frame_judge_at;

/// Folds of the out-of-fold probabilities.
pub(super) const FOLDS: usize = 2;

/// One training episode's frame-judge examples.
pub(super) struct Span {
    /// Its examples in the judge's training set.
    pub examples: Range<usize>,
    /// The index there of its imagined last frame (a replay of its real actions).
    pub imagined_last: usize,
    pub success: bool,
}

/// Fits the calibration on the training episodes `spans` of `examples`; `None` when fewer than
/// `2 · FOLDS` episodes or one outcome only (nothing to fit). Episode `i` is in fold `i % FOLDS`.
pub(super) fn fit(
    examples: &[(Vec<u8>, bool)],
    spans: &[Span],
    frame: (u32, u32),
    size: u32,
    config: &ProxyConfig,
    device: Device,
) -> Option<Calibration> {
    let positives = spans.iter().filter(|s| s.success).count();
    if spans.len() < 2 * FOLDS || positives == 0 || positives == spans.len() {
        return None;
    }
    let mut scores = vec![0.0; spans.len()];
    for fold in 0..FOLDS {
        let others: Vec<(&[u8], bool)> = spans
            .iter()
            .enumerate()
            .filter(|(i, _)| i % FOLDS != fold)
            .flat_map(|(_, s)| examples[s.examples.clone()].iter())
            .map(|(f, ok)| (f.as_slice(), *ok))
            .collect();
        let (judge, _) = train_frame_judge_at(
            &others,
            frame,
            size,
            config.judge_steps,
            config.judge_lr,
            config.world_model.seed,
            device,
        );
        for (i, s) in spans.iter().enumerate().filter(|(i, _)| i % FOLDS == fold) {
            scores[i] = judge.probability_of(&[examples[s.imagined_last].0.as_slice()])[0];
        }
    }
    let logits: Vec<f64> = scores.iter().map(|p| logit(*p)).collect();
    let outcomes: Vec<bool> = spans.iter().map(|s| s.success).collect();
    let (a, b) = assay_stats::calibration::platt(&logits, &outcomes)?;
    let mut calibration = Calibration {
        a,
        b,
        episodes: spans.len() as u32,
        positives: positives as u32,
        folds: FOLDS as u32,
        train_error: 0.0,
        train_error_uncalibrated: 0.0,
        train_reliability: None,
    };
    let error = |p: &dyn Fn(f64) -> f64| {
        scores
            .iter()
            .zip(&outcomes)
            .map(|(s, y)| (p(*s) - f64::from(u8::from(*y))).abs())
            .sum::<f64>()
            / scores.len() as f64
    };
    calibration.train_error = error(&|s| calibration.apply(s));
    calibration.train_error_uncalibrated = error(&|s| s);
    let diagram = |p: &dyn Fn(f64) -> f64| {
        let pairs: Vec<(f64, bool)> = scores
            .iter()
            .map(|s| p(*s))
            .zip(outcomes.iter().copied())
            .collect();
        reliability(&pairs, RELIABILITY_BINS)
    };
    calibration.train_reliability = Some(TrainReliability {
        raw: diagram(&|s| s),
        calibrated: diagram(&|s| calibration.apply(s)),
    });
    Some(calibration)
}

/// `ln(p / (1 − p))`, `p` clamped as [`Calibration::apply`] clamps it.
fn logit(p: f64) -> f64 {
    let p = p.clamp(1e-4, 1.0 - 1e-4);
    (p / (1.0 - p)).ln()
}
