//! Platt scaling (Platt 1999, with the Newton iteration of Lin, Lin and Weng 2007): the logistic
//! map `P(y = 1 | s) = σ(a + b · s)` of a score `s` that maximises the likelihood of binary
//! outcomes, with Platt's smoothed targets `(N₊ + 1) / (N₊ + 2)` for a positive and
//! `1 / (N₋ + 2)` for a negative — the prior's correction that keeps `a` and `b` finite when the
//! scores separate the outcomes. And the reliability diagram that shows how well predicted
//! probabilities match the outcomes they predict, with its expected calibration error.

use serde::{Deserialize, Serialize};

use crate::stats::Proportion;

/// `(a, b)` of Platt scaling of `scores` against `outcomes` (same length). `None` with fewer than
/// two examples, with one class only, or with a score that is not finite.
pub fn platt(scores: &[f64], outcomes: &[bool]) -> Option<(f64, f64)> {
    if scores.len() != outcomes.len() || scores.len() < 2 || scores.iter().any(|s| !s.is_finite()) {
        return None;
    }
    let positives = outcomes.iter().filter(|y| **y).count() as f64;
    let negatives = outcomes.len() as f64 - positives;
    if positives == 0.0 || negatives == 0.0 {
        return None;
    }
    let (hi, lo) = (
        (positives + 1.0) / (positives + 2.0),
        1.0 / (negatives + 2.0),
    );
    let targets: Vec<f64> = outcomes.iter().map(|y| if *y { hi } else { lo }).collect();
    // Negative log-likelihood, computed stably: log(1 + e^z) − t·z.
    let loss = |a: f64, b: f64| -> f64 {
        scores
            .iter()
            .zip(&targets)
            .map(|(s, t)| {
                let z = a + b * s;
                let softplus = if z > 0.0 {
                    z + (-z).exp().ln_1p()
                } else {
                    z.exp().ln_1p()
                };
                softplus - t * z
            })
            .sum()
    };
    let (mut a, mut b) = (((positives + 1.0) / (negatives + 1.0)).ln(), 0.0);
    let mut current = loss(a, b);
    for _ in 0..100 {
        let (mut ga, mut gb, mut haa, mut hab, mut hbb) = (0.0, 0.0, 1e-12, 0.0, 1e-12);
        for (s, t) in scores.iter().zip(&targets) {
            let p = 1.0 / (1.0 + (-(a + b * s)).exp());
            let (d, w) = (p - t, p * (1.0 - p));
            ga += d;
            gb += d * s;
            haa += w;
            hab += w * s;
            hbb += w * s * s;
        }
        if ga.abs() < 1e-10 && gb.abs() < 1e-10 {
            break;
        }
        let det = haa * hbb - hab * hab;
        let (da, db) = if det.abs() > 1e-300 {
            ((hbb * ga - hab * gb) / det, (haa * gb - hab * ga) / det)
        } else {
            (ga / haa, 0.0)
        };
        // Backtracking: halve the Newton step until the loss does not rise.
        let mut step = 1.0;
        loop {
            let (na, nb) = (a - step * da, b - step * db);
            let next = loss(na, nb);
            if next <= current + 1e-12 {
                (a, b, current) = (na, nb, next);
                break;
            }
            step /= 2.0;
            if step < 1e-10 {
                return Some((a, b));
            }
        }
    }
    Some((a, b))
}

/// A reliability diagram (DeGroot and Fienberg 1983; Niculescu-Mizil and Caruana 2005): the
/// predictions dealt into equal-width bins of their probability, and per bin the mean predicted
/// probability beside the share of outcomes that happened. A calibrated predictor's points lie
/// on the diagonal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Reliability {
    /// The bins holding at least one prediction, lowest first.
    pub bins: Vec<ReliabilityBin>,
    /// Predictions binned (every finite probability in [0, 1]).
    pub predictions: u64,
    /// Expected calibration error: the mean over predictions of |its bin's mean predicted
    /// probability − its bin's observed rate| (Naeini et al. 2015, equal-width bins); absent
    /// without predictions.
    pub ece: Option<f64>,
}

/// One bin of a [`Reliability`] diagram: predictions with a probability in `[lower, upper)`
/// (the last bin also holds `upper` = 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ReliabilityBin {
    pub lower: f64,
    pub upper: f64,
    /// The mean of the bin's predicted probabilities.
    pub mean_predicted: f64,
    /// Its outcomes: how many happened, of how many, with a Wilson interval.
    pub observed: Proportion,
}

/// The reliability diagram of `(probability, outcome)` pairs over `bins` equal-width bins of
/// [0, 1]. Probabilities that are not finite or lie outside [0, 1] are left out.
pub fn reliability(pairs: &[(f64, bool)], bins: usize) -> Reliability {
    assert!(bins > 0, "a reliability diagram needs at least one bin");
    let mut sums = vec![(0.0f64, 0u64, 0u64); bins];
    for &(p, outcome) in pairs {
        if !p.is_finite() || !(0.0..=1.0).contains(&p) {
            continue;
        }
        let i = ((p * bins as f64).floor() as usize).min(bins - 1);
        sums[i].0 += p;
        sums[i].1 += u64::from(outcome);
        sums[i].2 += 1;
    }
    let predictions: u64 = sums.iter().map(|s| s.2).sum();
    let bins_out: Vec<ReliabilityBin> = sums
        .iter()
        .enumerate()
        .filter(|(_, s)| s.2 > 0)
        .map(|(i, &(sum, happened, n))| ReliabilityBin {
            lower: i as f64 / bins as f64,
            upper: (i + 1) as f64 / bins as f64,
            mean_predicted: sum / n as f64,
            observed: Proportion::new(happened, n),
        })
        .collect();
    let ece = (predictions > 0).then(|| {
        bins_out
            .iter()
            .map(|b| {
                let n = b.observed.trials as f64;
                n * (b.mean_predicted - b.observed.rate.unwrap_or(0.0)).abs()
            })
            .sum::<f64>()
            / predictions as f64
    });
    Reliability {
        bins: bins_out,
        predictions,
        ece,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reliability_bins_the_predictions_and_weighs_each_bin_by_its_count() {
        // Five bins of 0.2. 0.1 and 0.15 (one happened); 0.5 (happened); 0.9, 0.95, 1.0 (two
        // happened; 1.0 belongs to the last bin); 0.2 opens the second bin.
        let pairs = [
            (0.1, false),
            (0.15, true),
            (0.2, false),
            (0.5, true),
            (0.9, true),
            (0.95, false),
            (1.0, true),
            (f64::NAN, true),
            (1.5, true),
        ];
        let r = reliability(&pairs, 5);
        assert_eq!(r.predictions, 7);
        let got: Vec<(f64, f64, u64, u64)> = r
            .bins
            .iter()
            .map(|b| {
                (
                    b.lower,
                    b.mean_predicted,
                    b.observed.successes,
                    b.observed.trials,
                )
            })
            .collect();
        let want = [
            (0.0, 0.125, 1, 2),
            (0.2, 0.2, 0, 1),
            (0.4, 0.5, 1, 1),
            (0.8, 0.95, 2, 3),
        ];
        assert_eq!(got.len(), want.len(), "{got:?}");
        for (g, w) in got.iter().zip(want) {
            assert!(
                (g.0 - w.0).abs() < 1e-12 && (g.1 - w.1).abs() < 1e-12,
                "{g:?} {w:?}"
            );
            assert_eq!((g.2, g.3), (w.2, w.3));
        }
        // ECE = (2·|0.125 − 0.5| + 1·|0.2 − 0| + 1·|0.5 − 1| + 3·|0.95 − 2/3|) / 7.
        let ece = (2.0 * 0.375 + 0.2 + 0.5 + 3.0 * (0.95 - 2.0 / 3.0)) / 7.0;
        assert!((r.ece.unwrap() - ece).abs() < 1e-12, "{:?}", r.ece);
    }

    #[test]
    fn a_calibrated_predictor_has_no_error_and_no_predictions_no_diagram() {
        // Each bin's predictions happen at the rate they claim.
        let mut pairs = vec![(0.25, true), (0.25, false), (0.25, false), (0.25, false)];
        pairs.extend([(0.75, true), (0.75, true), (0.75, true), (0.75, false)]);
        let r = reliability(&pairs, 4);
        assert!(r.ece.unwrap().abs() < 1e-12, "{:?}", r.ece);
        let empty = reliability(&[], 5);
        assert_eq!(
            (empty.bins.len(), empty.predictions, empty.ece),
            (0, 0, None)
        );
    }

    fn sigmoid(z: f64) -> f64 {
        1.0 / (1.0 + (-z).exp())
    }

    #[test]
    fn a_score_that_says_nothing_maps_to_the_smoothed_base_rate() {
        // Every score the same: b has nothing to fit, and the map gives the mean of the
        // smoothed targets (3 of 4/5 and 1 of 1/3).
        let scores = [0.3; 4];
        let outcomes = [true, true, true, false];
        let (a, b) = platt(&scores, &outcomes).unwrap();
        let mean_target = (3.0 * 4.0 / 5.0 + 1.0 / 3.0) / 4.0;
        assert!((sigmoid(a + b * 0.3) - mean_target).abs() < 1e-9, "{a} {b}");
    }

    #[test]
    fn separable_scores_give_a_finite_increasing_map() {
        let scores = [-2.0, -1.0, 1.0, 2.0];
        let outcomes = [false, false, true, true];
        let (a, b) = platt(&scores, &outcomes).unwrap();
        assert!(a.is_finite() && b.is_finite() && b > 0.0, "{a} {b}");
        // The targets are 3/4 and 1/4: the fit cannot claim more certainty than them.
        assert!(sigmoid(a + b * 2.0) < 0.9 && sigmoid(a + b * -2.0) > 0.1);
        // A reversed score gives a decreasing map.
        let reversed: Vec<f64> = scores.iter().map(|s| -s).collect();
        let (_, b2) = platt(&reversed, &outcomes).unwrap();
        assert!((b2 + b).abs() < 1e-9, "{b} {b2}");
    }

    #[test]
    fn the_fit_is_the_likelihood_maximum() {
        // Overlapping classes: the gradient of the likelihood is zero at the answer.
        let scores = [-1.5, -0.5, 0.0, 0.2, 0.4, 1.0, 1.3, -0.2];
        let outcomes = [false, false, true, false, true, true, true, false];
        let (a, b) = platt(&scores, &outcomes).unwrap();
        let (n1, n0) = (4.0, 4.0);
        let (hi, lo) = ((n1 + 1.0) / (n1 + 2.0), 1.0 / (n0 + 2.0));
        let (mut ga, mut gb) = (0.0, 0.0);
        for (s, y) in scores.iter().zip(outcomes) {
            let d = sigmoid(a + b * s) - if y { hi } else { lo };
            ga += d;
            gb += d * s;
        }
        assert!(ga.abs() < 1e-8 && gb.abs() < 1e-8, "{ga} {gb}");
    }

    #[test]
    fn one_class_or_too_little_is_no_fit() {
        assert_eq!(platt(&[0.1, 0.2], &[true, true]), None);
        assert_eq!(platt(&[0.1], &[true]), None);
        assert_eq!(platt(&[0.1, f64::NAN], &[true, false]), None);
        assert_eq!(platt(&[0.1, 0.2], &[true]), None);
    }
}
