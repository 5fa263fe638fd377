//! `assay rank`: policies ranked by a proxy's predicted success against their real success, from a
//! success table (the video-world-model policy-evaluation paper, section III.A): per policy R and
//! R_S, then Pearson r, MMRV, Spearman ρ and Kendall τ-b with bootstrap 95 % intervals, and
//! optionally the correlation plot as SVG.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use assay_stats::agreement::BOOTSTRAP_RESAMPLES;
use assay_stats::ranking::{Ranking, RankingConfig, parse_success_table, rank};

#[derive(clap::Args)]
pub struct Args {
    /// CSV with a header: `task`, `policy`, `source`, and `trials` + `successes` or `success_rate`
    /// (also `rate` or `success`), one row per (task, policy, source). Lines starting with # are
    /// comments.
    pub table: PathBuf,
    /// The source that is the ground truth.
    #[arg(long, default_value = "real")]
    pub real: String,
    /// A source to compare with the real one (repeatable; default: every other source).
    #[arg(long = "proxy", value_name = "NAME")]
    pub proxies: Vec<String>,
    /// Print the ranking as JSON (undefined statistics are null, with the reason beside them).
    #[arg(long)]
    pub json: bool,
    /// Write the correlation plot: to FILE.svg (one proxy; with several, FILE-<proxy>.svg beside
    /// it), or into a folder as rank-<proxy>.svg.
    #[arg(long, value_name = "DIR_OR_FILE.svg")]
    pub plot: Option<PathBuf>,
    /// Bootstrap resamples for the 95 % intervals (at least 40; 0 for none).
    #[arg(long, default_value_t = BOOTSTRAP_RESAMPLES, value_parser = crate::args::resamples)]
    pub resamples: usize,
    /// Seed of the bootstrap.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let path = a.table.display();
    let text = std::fs::read_to_string(&a.table).with_context(|| format!("reading {path}"))?;
    let cells = parse_success_table(&text).map_err(|e| anyhow::anyhow!("{path}: {e}"))?;
    let cfg = RankingConfig {
        real: a.real,
        proxies: a.proxies,
        resamples: a.resamples,
        seed: a.seed,
    };
    let ranking = rank(&cells, &cfg).map_err(|e| anyhow::anyhow!("{path}: {e}"))?;
    if let Some(plot) = &a.plot {
        for (file, i) in plot_files(plot, &ranking)? {
            std::fs::write(&file, assay_report::figures::ranking(&ranking, i))
                .with_context(|| format!("writing {}", file.display()))?;
            eprintln!("wrote {}", file.display());
        }
    }
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&ranking)?);
    } else {
        out!("{}", assay_report::markdown::ranking(&ranking));
    }
    Ok(ExitCode::SUCCESS)
}

/// A proxy's name as part of a file name.
fn slug(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Where each comparison's plot goes, with its index.
fn plot_files(plot: &Path, ranking: &Ranking) -> anyhow::Result<Vec<(PathBuf, usize)>> {
    let is_svg = plot
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    let n = ranking.comparisons.len();
    // Two proxies whose names differ only in characters a file name cannot hold get one each.
    let mut names: Vec<String> = Vec::new();
    for (i, c) in ranking.comparisons.iter().enumerate() {
        let s = slug(&c.proxy);
        names.push(if names.contains(&s) {
            format!("{s}-{i}")
        } else {
            s
        });
    }
    if is_svg {
        if let Some(parent) = plot.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        if n == 1 {
            return Ok(vec![(plot.to_owned(), 0)]);
        }
        let stem = plot.file_stem().unwrap_or_default().to_string_lossy();
        return Ok(names
            .iter()
            .enumerate()
            .map(|(i, s)| (plot.with_file_name(format!("{stem}-{s}.svg")), i))
            .collect());
    }
    std::fs::create_dir_all(plot).with_context(|| format!("creating {}", plot.display()))?;
    Ok(names
        .iter()
        .enumerate()
        .map(|(i, s)| (plot.join(format!("rank-{s}.svg")), i))
        .collect())
}
