//! The ranking section's tables about its judges: the frame judge's calibration per group and
//! every judge's agreement with the simulator and with the frame judge.

use crate::ranking::{FRAME_JUDGE, RankingResults};
use crate::view::{Cell, Table, proportion};

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
