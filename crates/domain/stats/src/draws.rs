//! Random draws from an [`assay_spec::rng::Rng`] stream: standard normal, Gamma, Beta and
//! Binomial, for the ranking's bootstrap and its simulator rerun.

use assay_spec::rng::Rng;

/// A standard normal draw (Box–Muller; one of the pair is used, so a stream's draws stay simple to
/// follow).
pub(crate) fn normal(rng: &mut Rng) -> f64 {
    let u = 1.0 - rng.unit(); // (0, 1]
    let v = rng.unit();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// A Gamma(shape, 1) draw: Marsaglia and Tsang's method (2000) for shape ≥ 1; below 1, a
/// Gamma(shape + 1) draw times U^(1/shape).
fn gamma(rng: &mut Rng, shape: f64) -> f64 {
    if shape < 1.0 {
        let u = 1.0 - rng.unit();
        return gamma(rng, shape + 1.0) * u.powf(1.0 / shape);
    }
    let d = shape - 1.0 / 3.0;
    let c = 1.0 / (9.0 * d).sqrt();
    loop {
        let x = normal(rng);
        let v = (1.0 + c * x).powi(3);
        if v <= 0.0 {
            continue;
        }
        let u = 1.0 - rng.unit();
        if u.ln() < 0.5 * x * x + d - d * v + d * v.ln() {
            return d * v;
        }
    }
}

/// A Beta(a, b) draw, as X / (X + Y) with X ~ Gamma(a), Y ~ Gamma(b).
pub(crate) fn beta(rng: &mut Rng, a: f64, b: f64) -> f64 {
    let x = gamma(rng, a);
    let y = gamma(rng, b);
    x / (x + y)
}

/// A Binomial(n, p) draw: by inversion (walking the distribution from 0 on the side of the smaller
/// of p and 1 − p) while its mean there is at most 50, else the normal approximation, rounded and
/// kept within 0..=n.
pub(crate) fn binomial(rng: &mut Rng, n: u64, p: f64) -> u64 {
    let (q, flip) = if p > 0.5 { (1.0 - p, true) } else { (p, false) };
    let k = if q <= 0.0 {
        0
    } else if n as f64 * q <= 50.0 {
        let ratio = q / (1.0 - q);
        let mut pmf = (1.0 - q).powf(n as f64);
        let mut cdf = pmf;
        let u = rng.unit();
        let mut k = 0;
        while u > cdf && k < n {
            pmf *= ratio * (n - k) as f64 / (k + 1) as f64;
            cdf += pmf;
            k += 1;
        }
        k
    } else {
        let mean = n as f64 * q;
        let sd = (mean * (1.0 - q)).sqrt();
        (mean + sd * normal(rng)).round().clamp(0.0, n as f64) as u64
    };
    if flip { n - k } else { k }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binomial_draws_have_the_binomial_mean_and_variance() {
        for (n, p) in [(10u64, 0.05), (10, 0.7), (40, 0.3), (1000, 0.4)] {
            let mut rng = Rng::new(7, "binomial test");
            let draws: Vec<f64> = (0..20_000)
                .map(|_| binomial(&mut rng, n, p) as f64)
                .collect();
            let mean = draws.iter().sum::<f64>() / draws.len() as f64;
            let var =
                draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (draws.len() - 1) as f64;
            let (m, v) = (n as f64 * p, n as f64 * p * (1.0 - p));
            assert!(
                (mean - m).abs() < 0.03 * m.max(1.0),
                "n {n} p {p}: mean {mean} vs {m}"
            );
            assert!(
                (var - v).abs() < 0.06 * v,
                "n {n} p {p}: variance {var} vs {v}"
            );
            assert!(draws.iter().all(|d| *d <= n as f64));
        }
    }
}
