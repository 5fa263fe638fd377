//! Value parsers several commands share.

/// `--resamples`: a count that can make a 95 % interval (or 0 for none).
pub fn resamples(s: &str) -> Result<usize, String> {
    let n: usize = s.parse().map_err(|e| format!("{e}"))?;
    assay_stats::agreement::check_resamples(n)
}
