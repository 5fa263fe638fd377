//! `assay-stats`: the statistics behind every figure of a report, as pure functions over numbers —
//! Wilson intervals, agreement between raters (Pearson r, MAE, Spearman ρ, Kendall τ-b, percentile
//! bootstrap), MMRV and the ranking of policies from success tables, and text diversity
//! (equation 1 of the generative-simulation paper).
//!
//! Owns: the arithmetic, its degenerate cases (an undefined statistic is reported as undefined with
//! its reason, never as 0 or NaN) and the parsing of the tables it is given. Never reads files,
//! never draws, never knows a batch, a shard or a report.

pub mod agreement;
pub mod calibration;
pub mod diversity;
mod draws;
pub mod ranking;
pub mod retest;
pub mod stats;
