use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use assay_proto::v1 as pb;

#[derive(clap::Args)]
pub struct Args {
    pub batch: String,
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Folder for report.json and report.md.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
}

/// Writes `report.json` and `report.md` into `out`, and the quality figure when judges ran.
pub fn write(out: &Path, r: &pb::GetReportResponse) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("report.json"), format!("{}\n", r.report_json))?;
    std::fs::write(out.join("report.md"), &r.report_markdown)?;
    let report: assay_core::report::Report =
        serde_json::from_str(&r.report_json).context("the coordinator's report")?;
    if let Some(q) = &report.results.quality {
        std::fs::write(out.join(assay_core::report::QUALITY_FIGURE), q.figure_svg())?;
    }
    if let Some(ranking) = report
        .results
        .ranking
        .as_ref()
        .and_then(|k| k.ranking.as_ref())
    {
        for (i, c) in ranking.comparisons.iter().enumerate() {
            std::fs::write(
                out.join(assay_core::proxy::ranking_figure(&c.proxy)),
                ranking.svg(i),
            )?;
        }
    }
    Ok(())
}

/// One line per ranking comparison of `report` (for a terminal), empty without a ranking.
pub fn ranking_lines(report: &assay_core::report::Report) -> Vec<String> {
    let Some(ranking) = report
        .results
        .ranking
        .as_ref()
        .and_then(|k| k.ranking.as_ref())
    else {
        return Vec::new();
    };
    let est = |e: &assay_core::agreement::Estimate| match (e.value, e.ci95) {
        (Some(v), Some([lo, hi])) => format!("{v:.3} [{lo:.3}, {hi:.3}]"),
        (Some(v), None) => format!("{v:.3}"),
        (None, _) => "undefined".into(),
    };
    ranking
        .comparisons
        .iter()
        .map(|c| {
            format!(
                "policy ranking, {} against {} ({} policies): Pearson r {}, MMRV {}, Spearman {}, Kendall {}",
                c.proxy,
                c.real,
                c.policies.len(),
                est(&c.pearson),
                est(&c.mmrv),
                est(&c.spearman),
                est(&c.kendall)
            )
        })
        .collect()
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    super::block_on(async move {
        let mut c = super::client(&a.coordinator).await?;
        let r = c
            .get_report(pb::GetReportRequest { batch_id: a.batch })
            .await?
            .into_inner();
        write(&a.out, &r)?;
        eprintln!(
            "wrote {} and {}{}",
            a.out.join("report.json").display(),
            a.out.join("report.md").display(),
            if r.r#final {
                ""
            } else {
                " (partial: the batch is still running)"
            }
        );
        Ok(ExitCode::SUCCESS)
    })
}
