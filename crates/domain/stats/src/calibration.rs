//! Platt scaling (Platt 1999, with the Newton iteration of Lin, Lin and Weng 2007): the logistic
//! map `P(y = 1 | s) = σ(a + b · s)` of a score `s` that maximises the likelihood of binary
//! outcomes, with Platt's smoothed targets `(N₊ + 1) / (N₊ + 2)` for a positive and
//! `1 / (N₋ + 2)` for a negative — the prior's correction that keeps `a` and `b` finite when the
//! scores separate the outcomes.

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

#[cfg(test)]
mod tests {
    use super::*;

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
