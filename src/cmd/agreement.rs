//! `assay agreement`: a judge's scores against human ratings, from a CSV table (the paper's figure
//! 3 and its tables 4 and 5): Pearson r, MAE, r/MAE, Spearman ρ, Kendall τ with bootstrap 95 %
//! intervals, per group (dataset) and over all rows.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use assay_stats::agreement::{AgreementTable, BOOTSTRAP_RESAMPLES, Estimate, parse_ratings};

#[derive(clap::Args)]
pub struct Args {
    /// CSV: one row per rated item; a reference column, one column per judge (cells like `3.2` or
    /// `2.56(0.9)`, mean and variance as the paper writes them; empty = not rated), optionally a
    /// `dataset` or `group` column. Lines starting with # are comments.
    pub csv: PathBuf,
    /// The reference column (human ratings).
    #[arg(long, default_value = "human")]
    pub reference: String,
    /// The grouping column (default: `dataset` or `group` when present).
    #[arg(long)]
    pub by: Option<String>,
    /// Bootstrap resamples for the 95 % intervals (at least 40; 0 for none).
    #[arg(long, default_value_t = BOOTSTRAP_RESAMPLES, value_parser = crate::args::resamples)]
    pub resamples: usize,
    /// Seed of the bootstrap.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print JSON (undefined statistics are null, with the reason beside them).
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let text =
        std::fs::read_to_string(&a.csv).with_context(|| format!("reading {}", a.csv.display()))?;
    let ratings = parse_ratings(&text, &a.reference, a.by.as_deref())
        .map_err(|e| anyhow::anyhow!("{}: {e}", a.csv.display()))?;
    let table = ratings.agreement(a.resamples, a.seed);
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&table)?);
    } else {
        out!("{}", render(&table));
    }
    Ok(ExitCode::SUCCESS)
}

fn cell(e: &Estimate) -> String {
    match (e.value, e.ci95) {
        (Some(v), Some([lo, hi])) => format!("{v:.3} [{lo:.2}, {hi:.2}]"),
        (Some(v), None) => format!("{v:.3}"),
        (None, _) => "undefined".into(),
    }
}

/// A plain-text table, one line per (group, judge), with the reasons for undefined values after.
pub fn render(t: &AgreementTable) -> String {
    let mut out = format!(
        "{:<12} {:<18} {:>3}  {:<24} {:<24} {:<24} {:<24} {:<24}\n",
        t.group_column.as_deref().unwrap_or("group"),
        "judge",
        "n",
        "Pearson r",
        "MAE",
        "r/MAE",
        "Spearman rho",
        "Kendall tau"
    );
    let mut notes = Vec::new();
    for r in &t.rows {
        let a = &r.agreement;
        let group = r.group.as_deref().unwrap_or("(all)");
        out.push_str(&format!(
            "{:<12} {:<18} {:>3}  {:<24} {:<24} {:<24} {:<24} {:<24}\n",
            group,
            r.judge,
            a.n,
            cell(&a.pearson),
            cell(&a.mae),
            cell(&a.r_over_mae),
            cell(&a.spearman),
            cell(&a.kendall)
        ));
        if let Some(why) = &a.pearson.undefined {
            notes.push(format!(
                "{group} / {}: correlations undefined: {why}",
                r.judge
            ));
        } else if let Some(why) = &a.pearson.no_interval {
            notes.push(format!("{group} / {}: no interval for r: {why}", r.judge));
        }
    }
    let mut out: String = out.lines().map(|l| format!("{}\n", l.trim_end())).collect();
    out.push_str(&format!(
        "\nreference: {}; 95 % percentile bootstrap intervals over {} resamples of the rated items\n",
        t.reference, t.resamples
    ));
    for n in notes {
        out.push_str(&n);
        out.push('\n');
    }
    out
}
