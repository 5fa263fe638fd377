//! The report bundle a run leaves in its folder: `report.json`, `report.md`, `report.html`,
//! `episodes.parquet` and the figures as SVG files, written from one [`Report`]; the human
//! ratings the HTML compares judges with; and the refusal to overwrite another batch's report.
//!
//! Owns: which files a report folder holds and how each is written. Never builds a report (the
//! coordinator and `assay-report` do) or reads the job store.

use std::path::{Path, PathBuf};

use anyhow::Context;
use assay_proto::v1 as pb;
use assay_report::report::Report;

/// Human ratings for the report's judge-agreement view (the paper's figure 3).
#[derive(clap::Args, Clone, Default)]
#[command(next_help_heading = "Judging")]
pub struct HumanArgs {
    /// CSV of human ratings beside the judges' scores of the same items, as `assay agreement`
    /// reads it (a `human` column, one column per judge, optionally `dataset`/`group`).
    #[arg(long, value_name = "CSV")]
    pub human_ratings: Option<PathBuf>,
}

impl HumanArgs {
    /// The agreement table of the ratings, when given.
    pub fn table(&self) -> anyhow::Result<Option<assay_stats::agreement::AgreementTable>> {
        let Some(path) = &self.human_ratings else {
            return Ok(None);
        };
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let ratings = assay_stats::agreement::parse_ratings(&text, "human", None)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Some(
            ratings.agreement(assay_stats::agreement::BOOTSTRAP_RESAMPLES, 0),
        ))
    }
}

/// Writes `report.json`, `report.md`, `report.html` and `episodes.parquet` (one row per episode)
/// into `out`, and the figures (quality, ranking) as SVG files beside them. Pictures in report.html come from `artifacts`.
pub fn write(
    out: &Path,
    report: &Report,
    artifacts: &Path,
    human: Option<&assay_stats::agreement::AgreementTable>,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(
        out.join("report.json"),
        format!("{}\n", serde_json::to_string_pretty(report)?),
    )?;
    std::fs::write(out.join("report.md"), report.to_markdown())?;
    std::fs::write(
        out.join(assay_export::episodes_table::EPISODES_TABLE),
        assay_export::episodes_table::episodes_parquet(&report.results)
            .map_err(anyhow::Error::msg)?,
    )?;
    let read = |key: &str| -> Option<Vec<u8>> {
        // Keys are relative paths inside the store; never follow one out of it.
        let rel = Path::new(key);
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| !matches!(c, std::path::Component::Normal(_)))
        {
            return None;
        }
        std::fs::read(artifacts.join(rel)).ok()
    };
    let html = assay_report::html::report_html(&assay_report::html::HtmlInputs {
        report,
        artifact: &read,
        human,
    });
    std::fs::write(out.join("report.html"), html)?;
    if let Some(q) = &report.results.quality {
        std::fs::write(
            out.join(assay_report::report::QUALITY_FIGURE),
            q.figure_svg(),
        )?;
    }
    if let Some((k, ranking)) = report
        .results
        .ranking
        .as_ref()
        .and_then(|k| Some((k, k.ranking.as_ref()?)))
    {
        for (i, c) in ranking.comparisons.iter().enumerate() {
            std::fs::write(
                out.join(assay_report::ranking::ranking_figure(&c.proxy)),
                assay_report::figures::ranking_labelled(ranking, i, &k.labels),
            )?;
        }
    }
    if let Some(svg) = report
        .results
        .ranking
        .as_ref()
        .and_then(assay_report::figures::ranking_reliability)
    {
        std::fs::write(out.join(assay_report::ranking::RELIABILITY_FIGURE), svg)?;
    }
    Ok(())
}

/// The coordinator's report, parsed.
pub fn parse(r: &pb::GetReportResponse) -> anyhow::Result<Report> {
    serde_json::from_str(&r.report_json).context("the coordinator's report")
}

/// Refuses to write `report` into `out` when `out` holds the report of another batch.
pub fn check_out(out: &Path, report: &Report, force: bool) -> anyhow::Result<()> {
    let existing = out.join("report.json");
    let Ok(text) = std::fs::read_to_string(&existing) else {
        return Ok(());
    };
    let theirs = serde_json::from_str::<Report>(&text)
        .map(|r| r.run.batch_id)
        .unwrap_or_else(|_| "(unreadable)".into());
    if theirs != report.run.batch_id && !force {
        anyhow::bail!(
            "{} is the report of batch {theirs}, not {}: refusing to replace it; choose another \
             --out, or pass --force",
            existing.display(),
            report.run.batch_id
        );
    }
    Ok(())
}

/// `assay report --from`: the bundle written again from `from` (a report.json), into `out`
/// (default: beside it), with the pictures from `artifacts` (default: the `artifacts` folder
/// beside it). Returns the folder written.
pub fn rewrite(
    from: &Path,
    out: Option<&Path>,
    artifacts: Option<&Path>,
    force: bool,
    human: Option<&assay_stats::agreement::AgreementTable>,
) -> anyhow::Result<std::path::PathBuf> {
    let text =
        std::fs::read_to_string(from).with_context(|| format!("reading {}", from.display()))?;
    let report: Report =
        serde_json::from_str(&text).with_context(|| format!("{}", from.display()))?;
    let beside = from
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let out = out.unwrap_or(beside).to_path_buf();
    let artifacts = artifacts.map_or_else(
        || beside.join(assay_report::report::ARTIFACTS_LINK),
        Path::to_path_buf,
    );
    check_out(&out, &report, force)?;
    write(&out, &report, &artifacts, human)?;
    Ok(out)
}

/// `assay report BATCH`: the coordinator at `addr` builds the batch's report and its bundle is
/// written into `out` (default `report-BATCH`), with the pictures from `artifacts` (default:
/// `OUT/artifacts`). Returns the folder and whether the report is final (the batch finished).
pub async fn fetch(
    addr: &str,
    batch: &str,
    out: Option<&Path>,
    artifacts: Option<&Path>,
    force: bool,
    human: Option<&assay_stats::agreement::AgreementTable>,
) -> anyhow::Result<(std::path::PathBuf, bool)> {
    let out = out.map_or_else(
        || std::path::PathBuf::from(format!("report-{batch}")),
        Path::to_path_buf,
    );
    let artifacts = artifacts.map_or_else(
        || out.join(assay_report::report::ARTIFACTS_LINK),
        Path::to_path_buf,
    );
    let mut c = crate::client::connect(addr).await?;
    let r = c
        .get_report(pb::GetReportRequest {
            batch_id: batch.to_owned(),
        })
        .await?
        .into_inner();
    let report = parse(&r)?;
    check_out(&out, &report, force)?;
    write(&out, &report, &artifacts, human)?;
    Ok((out, r.r#final))
}
