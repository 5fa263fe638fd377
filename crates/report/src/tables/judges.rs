//! The ranking section's tables about its judges: the frame judge's calibration per group, its
//! reliability on the ranked episodes and every judge's agreement with the simulator and with
//! the frame judge.

use assay_model::proxy::{CALIBRATED_SOURCE, PROXY_SOURCE};
use assay_stats::calibration::Reliability;

use crate::ranking::{FRAME_JUDGE, RankingResults};
use crate::view::{Cell, Table, num2, proportion};

/// Per group, its frame judge's calibration (or why it has none), for "what was compared".
pub(super) fn calibration_lines(r: &RankingResults) -> Vec<String> {
    r.groups
        .iter()
        .map(|g| match &g.calibration {
            Some(c) => format!(
                "{}: P(success) = σ({:.2} {} {:.2}·logit p), fitted on {} training episodes \
                 ({} successes, {} folds); mean |p − outcome| on them {:.2} (uncalibrated \
                 {:.2})",
                g.group,
                c.a,
                if c.b < 0.0 { '−' } else { '+' },
                c.b.abs(),
                c.episodes,
                c.positives,
                c.folds,
                c.train_error,
                c.train_error_uncalibrated
            ),
            None => format!(
                "{}: none (its training episodes are too few or all of one outcome)",
                g.group
            ),
        })
        .collect()
}

/// The frame judge's and each judge's agreement with the simulator and with each other
/// ([`crate::ranking::JudgeAgreement`]): rate (agreeing/episodes) [95 % Wilson interval].
pub fn judge_agreement(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "judge",
        "#real rollouts: agrees with the simulator",
        "#imagined rollouts: agrees with the simulator",
        "#imagined rollouts: agrees with the frame judge",
    ]);
    let cell = |p: &Option<assay_stats::stats::Proportion>| {
        p.as_ref().map_or_else(Cell::missing, proportion)
    };
    for a in &r.judge_agreements {
        table.row(vec![
            if a.judge == FRAME_JUDGE {
                Cell::text(&a.judge)
            } else {
                Cell::code(&a.judge)
            },
            cell(&a.real_vs_sim),
            cell(&a.imagined_vs_sim),
            cell(&a.imagined_vs_frame_judge),
        ]);
    }
    table
}

/// The reliability diagrams' bins: on the ranked episodes ([`crate::ranking::ReliabilityCurve`],
/// per proxy and group), then on each group's training episodes, where its calibration was
/// fitted (in sample; [`assay_model::proxy::Calibration::train_reliability`]). Per bin its
/// episodes, mean predicted probability and observed rate; each diagram's ECE on its first row.
pub fn reliability(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "proxy",
        "episodes of",
        "group",
        "ECE",
        "predicted in",
        "episodes",
        "mean predicted",
        "observed [95 %]",
    ]);
    for curve in &r.reliability {
        let group = curve.group.as_deref().unwrap_or("all");
        let of = "ranked policies";
        diagram(&mut table, &curve.source, of, group, &curve.reliability);
    }
    for g in &r.groups {
        if let Some(t) = g
            .calibration
            .as_ref()
            .and_then(|c| c.train_reliability.as_ref())
        {
            let of = "training policies (the fit's, in sample)";
            diagram(&mut table, PROXY_SOURCE, of, &g.group, &t.raw);
            diagram(&mut table, CALIBRATED_SOURCE, of, &g.group, &t.calibrated);
        }
    }
    table
}

/// The rows of one reliability diagram, its labels and ECE on the first.
fn diagram(table: &mut Table, source: &str, of: &str, group: &str, d: &Reliability) {
    for (i, b) in d.bins.iter().enumerate() {
        let first = |c: Cell| if i == 0 { c } else { Cell::text("") };
        table.row(vec![
            first(Cell::code(source)),
            first(Cell::text(of)),
            first(Cell::text(group)),
            first(Cell::text(
                d.ece.map_or_else(|| "–".to_owned(), |e| format!("{e:.3}")),
            )),
            Cell::text(format!(
                "[{:.1}, {:.1}{}",
                b.lower,
                b.upper,
                if b.upper >= 1.0 { ']' } else { ')' }
            )),
            Cell::text(b.observed.trials.to_string()),
            Cell::text(num2(b.mean_predicted)),
            proportion(&b.observed),
        ]);
    }
}
