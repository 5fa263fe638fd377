//! Statistics used by reports.

use serde::{Deserialize, Serialize};

/// A proportion with its Wilson score interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Proportion {
    pub successes: u64,
    pub trials: u64,
    /// `successes / trials`; absent when there were no trials.
    pub rate: Option<f64>,
    /// 95 % Wilson interval, absent when there were no trials.
    pub ci95: Option<[f64; 2]>,
}

/// z for a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

impl Proportion {
    pub fn new(successes: u64, trials: u64) -> Self {
        assert!(
            successes <= trials,
            "successes {successes} exceed trials {trials}"
        );
        if trials == 0 {
            return Self {
                successes,
                trials,
                rate: None,
                ci95: None,
            };
        }
        Self {
            successes,
            trials,
            rate: Some(successes as f64 / trials as f64),
            ci95: Some(wilson(successes, trials, Z95)),
        }
    }
}

/// Wilson score interval for `k` successes in `n` trials at normal quantile `z`.
pub fn wilson(k: u64, n: u64, z: f64) -> [f64; 2] {
    assert!(n > 0);
    let n = n as f64;
    let p = k as f64 / n;
    let z2 = z * z;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / denom;
    [(centre - half).max(0.0), (centre + half).min(1.0)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_reference_values() {
        // statsmodels.stats.proportion.proportion_confint(8, 10, method="wilson")
        let [lo, hi] = wilson(8, 10, Z95);
        assert!((lo - 0.490_162_4).abs() < 1e-6, "{lo}");
        assert!((hi - 0.943_317_8).abs() < 1e-6, "{hi}");
        // proportion_confint(0, 5, method="wilson") -> (0.0, 0.4345)
        let [lo, hi] = wilson(0, 5, Z95);
        assert_eq!(lo, 0.0);
        assert!((hi - 0.434_482_3).abs() < 1e-6, "{hi}");
        let [lo, hi] = wilson(5, 5, Z95);
        assert!((lo - 0.565_517_7).abs() < 1e-6, "{lo}");
        assert!((hi - 1.0).abs() < 1e-12);
    }

    #[test]
    fn empty_proportion_has_no_rate() {
        let p = Proportion::new(0, 0);
        assert_eq!(p.rate, None);
        assert_eq!(p.ci95, None);
    }
}
