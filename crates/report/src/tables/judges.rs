//! The ranking section's tables about its judges: the frame judge's calibration per group, its
//! reliability on the ranked episodes and every judge's agreement with the simulator and with
//! the frame judge.

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

/// The reliability diagrams' bins ([`crate::ranking::ReliabilityCurve`]): per proxy (and group),
/// each bin's episodes, mean predicted probability and observed rate, the curve's ECE on its
/// first row.
pub fn reliability(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "proxy",
        "group",
        "ECE",
        "predicted in",
        "episodes",
        "mean predicted",
        "observed [95 %]",
    ]);
    for curve in &r.reliability {
        for (i, b) in curve.reliability.bins.iter().enumerate() {
            let first = i == 0;
            table.row(vec![
                if first {
                    Cell::code(&curve.source)
                } else {
                    Cell::text("")
                },
                match (&curve.group, first) {
                    (Some(g), true) => Cell::text(g),
                    (None, true) => Cell::text("all"),
                    _ => Cell::text(""),
                },
                match (curve.reliability.ece, first) {
                    (Some(e), true) => Cell::text(format!("{e:.3}")),
                    _ => Cell::text(""),
                },
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
    table
}
