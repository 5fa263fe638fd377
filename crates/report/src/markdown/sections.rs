//! The sections of `report.md` after success: quality, diversity, generalization and the policy
//! ranking, each its headings, prose and [`crate::tables`].

use std::fmt::Write as _;

use assay_stats::agreement::BOOTSTRAP_RESAMPLES;
use assay_stats::ranking::{Comparison, Ranking};
use assay_stats::stats::Proportion;

use crate::diversity::DiversityResults;
use crate::generalization::GeneralizationResults;
use crate::quality::{ERRORS_SHOWN, OFFLINE_JUDGE_NOTE, QualityResults, TaskQuality};
use crate::ranking::{
    ACTION_TEST_NOTE, JUDGE_AGREEMENT_NOTE, PER_GROUP_NOTE, PER_POLICY_NOTE, RELIABILITY_FIGURE,
    RELIABILITY_NOTE, REPEAT_NOTE, RETEST_NOTE, RankingResults, ranking_figure, source_note,
};
use crate::tables;
use crate::view::{Table, abbreviations, md_text};

impl QualityResults {
    /// The "## Quality" section of report.md. `figure`: relative path of the SVG to link as an
    /// image, if one was written.
    pub fn markdown(&self, figure: Option<&str>) -> String {
        let mut md = String::new();
        let _ = writeln!(md, "## Quality\n");
        let _ = writeln!(
            md,
            "Each episode is judged on two items, as in the generative-simulation evaluation paper: \
             scene alignment (1–5, from the 4 views of the initial scene) and task completion \
             (0–10, from 8 keyframes of the rollout), each asked `repeats` times. Scores read \
             `mean (var sample variance, n count)`; a group's or a judge's values are over its \
             task means.\n"
        );
        let _ = writeln!(md, "### Judges\n");
        md.push_str(&tables::judges(self).markdown());
        for j in self.judges.iter().filter(|j| j.offline) {
            let _ = writeln!(md, "\n`{}` {OFFLINE_JUDGE_NOTE}", md_text(&j.judge));
        }

        let _ = writeln!(md, "\n### Quality per group\n");
        for j in &self.judges {
            let _ = writeln!(md, "#### `{}`\n", md_text(&j.judge));
            md.push_str(&tables::quality_per_group(j).markdown());
            md.push('\n');
        }

        let _ = writeln!(md, "### Judge against simulator\n");
        let _ = writeln!(
            md,
            "Completion (an episode's mean over its repeats, 0–10) against the simulator's \
             ground-truth success × 10, over the judged episodes; 95 % percentile bootstrap \
             intervals over {BOOTSTRAP_RESAMPLES} resamples of the episodes.\n"
        );
        md.push_str(&tables::agreement(&tables::against_simulator(self)).markdown());
        for j in self.judges.iter().filter(|j| j.vs_sim.is_none()) {
            let _ = writeln!(
                md,
                "- `{}`: no judged episode has a completion score and a simulator outcome",
                md_text(&j.judge)
            );
        }

        if let Some(path) = figure {
            let _ = writeln!(md, "\n### Scene alignment against completion\n");
            let _ = writeln!(
                md,
                "As the paper's figure 4: one marker per task and judge at the judge's mean scores, \
                 coloured by group, its area growing with the variance of the scores (the first judge \
                 filled, others as outlines).\n"
            );
            let _ = writeln!(
                md,
                "![Scene alignment against task completion per group]({path})"
            );
        }

        let _ = writeln!(md, "\n### Quality per task\n");
        let _ = writeln!(
            md,
            "Over every valid answer to every repeat of every episode of the task.\n"
        );
        md.push_str(&tables::quality_per_task(self).markdown());

        let errors: Vec<(&TaskQuality, &String)> = self
            .tasks
            .iter()
            .flat_map(|t| t.errors.iter().map(move |e| (t, e)))
            .collect();
        if !errors.is_empty() {
            let _ = writeln!(md, "\n### Item errors\n");
            let _ = writeln!(
                md,
                "Repeats that gave no valid score, and judge shards that failed ({} in all).\n",
                errors.len()
            );
            for (t, e) in errors.iter().take(ERRORS_SHOWN) {
                let _ = writeln!(
                    md,
                    "- `{}` · `{}` · {}",
                    md_text(&t.task_id),
                    md_text(&t.judge),
                    md_text(e)
                );
            }
            if errors.len() > ERRORS_SHOWN {
                let _ = writeln!(
                    md,
                    "- … and {} more (all in report.json)",
                    errors.len() - ERRORS_SHOWN
                );
            }
        }
        let unjudged: Vec<&TaskQuality> = self.tasks.iter().filter(|t| t.unjudged > 0).collect();
        if !unjudged.is_empty() {
            let _ = writeln!(md, "\n### Unjudged items\n");
            let _ = writeln!(
                md,
                "Items with repeats left unasked because the judge budget was spent: {}.\n",
                self.judges
                    .iter()
                    .map(|j| format!("`{}` {}", md_text(&j.judge), j.items_unjudged))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            for t in unjudged.iter().take(ERRORS_SHOWN) {
                let _ = writeln!(
                    md,
                    "- `{}` · `{}`: {} item{}",
                    md_text(&t.task_id),
                    md_text(&t.judge),
                    t.unjudged,
                    if t.unjudged == 1 { "" } else { "s" }
                );
            }
            if unjudged.len() > ERRORS_SHOWN {
                let _ = writeln!(md, "- … and {} more tasks", unjudged.len() - ERRORS_SHOWN);
            }
        }
        md
    }
}

/// The diversity section: the paper's Tables 1 and 2.
pub(super) fn diversity(d: &DiversityResults) -> String {
    let mut md = String::from("\n## Diversity\n");
    if let Some(t) = &d.text {
        md.push_str(
            "\n### Text diversity (eq. 1; higher is more diverse)\n\n\
             Embeddings of each task's text; `div = -mean_i log(mean_{j≠i} cos(e_i, e_j))`.\n\n",
        );
        md.push_str(&tables::text_diversity(t).markdown());
    }
    if let Some(f) = d.dynamics.first() {
        let _ = write!(
            md,
            "\n### Dynamics diversity (world-model prediction error, ×10⁻³)\n\n\
             A latent dynamics model (RSSM, DreamerV3-style) trained per group on the first N \
             episodes, evaluated on the group's first {} episodes: mean squared error of the \
             one-step prediction of the next {}×{} frame. For a diverse group the error falls as \
             episodes are added; a group whose error is low already at the smallest budget has \
             dynamics a few episodes cover. {} Device: {}.\n\n",
            f.eval_episodes,
            f.config.image_size,
            f.config.image_size,
            crate::diversity::training_length(&f.config),
            f.device
        );
        md.push_str(&tables::dynamics_diversity(d).markdown());
        if d.dynamics.iter().any(|f| f.train_episodes < f.budget) {
            md.push_str(crate::diversity::FEWER_THAN_BUDGET);
            md.push('\n');
        }
    }
    if !d.errors.is_empty() {
        md.push('\n');
        md.push_str(&tables::diversity_errors(d, "").markdown());
    }
    md
}

impl GeneralizationResults {
    /// Table 3 of the paper, with intervals and the training side beside it.
    pub fn markdown(&self) -> String {
        let mut out = tables::generalization(self).markdown();
        out.push('\n');
        out.push_str(crate::generalization::HELD_OUT_NOTE);
        out.push('\n');
        for (group, e) in &self.errors {
            let _ = writeln!(
                out,
                "\nTraining the policy of group {} failed: {}",
                md_text(group),
                md_text(e)
            );
        }
        for g in &self.groups {
            for e in g.errors.iter().take(3) {
                let _ = writeln!(out, "\n{}: {}", md_text(&g.group), md_text(e));
            }
        }
        out
    }
}

fn rate(p: &Proportion) -> String {
    match p.rate {
        Some(r) => format!("{:.0} % ({}/{})", r * 100.0, p.successes, p.trials),
        None => "–".into(),
    }
}

impl RankingResults {
    /// The section of `report.md`.
    pub fn markdown(&self) -> String {
        let compared = tables::ranking_compared(self);
        let models = tables::proxy_models(self);
        let per_policy = tables::ranking_per_policy(self);
        let actions = tables::action_test(self);
        let repeats = tables::repeat_consistency(self);
        let rows = tables::ranking_rows(self);
        let mut out = String::from("### What was compared\n\n");
        out.push_str(&compared.markdown());
        if !models.rows.is_empty() {
            out.push_str("\nPer group, the world model and the frame judge:\n\n");
            out.push_str(&models.markdown());
        }
        for caution in crate::ranking::late_frame_cautions(self) {
            let _ = writeln!(out, "\n**Caution.** {}", md_text(&caution));
        }
        match self.ladder_seeds.as_ref().map(|l| l.describe()) {
            Some((true, text)) => {
                let _ = writeln!(out, "\n**Caution.** {}", md_text(&text));
            }
            Some((false, text)) => {
                let _ = writeln!(out, "\n{}", md_text(&text));
            }
            None => {}
        }
        if !per_policy.rows.is_empty() {
            out.push_str("\n### Real and predicted success per policy\n\n");
            let _ = writeln!(out, "{}\n", md_text(PER_POLICY_NOTE));
            out.push_str(&per_policy.markdown());
        }
        if !actions.rows.is_empty() {
            out.push_str("\n### Does the world model use its actions?\n\n");
            let _ = writeln!(out, "{}\n", md_text(ACTION_TEST_NOTE));
            out.push_str(&actions.markdown());
        }
        if !repeats.rows.is_empty() {
            out.push_str("\n### Judge repeat consistency on imagined rollouts\n\n");
            let _ = writeln!(out, "{}\n", md_text(REPEAT_NOTE));
            out.push_str(&repeats.markdown());
        }
        let agreement = tables::judge_agreement(self);
        if !agreement.rows.is_empty() {
            out.push_str("\n### Judges' agreement\n\n");
            let _ = writeln!(out, "{}\n", md_text(JUDGE_AGREEMENT_NOTE));
            out.push_str(&agreement.markdown());
        }
        let reliability = tables::reliability(self);
        if !reliability.rows.is_empty() {
            out.push_str("\n### Reliability of the predicted probabilities\n\n");
            let _ = writeln!(out, "{}\n", md_text(RELIABILITY_NOTE));
            let _ = writeln!(
                out,
                "![reliability of the proxy's probabilities on the ranked episodes]({RELIABILITY_FIGURE})\n"
            );
            out.push_str(&reliability.markdown());
        }
        out.push_str("\n### Per task and policy\n\n");
        out.push_str(&rows.markdown());
        out.push('\n');
        if let Some(a) = &self.proxy_agreement {
            let _ = write!(
                out,
                "Proxy verdicts matching the real outcome: {}.",
                rate(a)
            );
        }
        if let Some(a) = &self.judge_agreement_real_frames {
            let _ = write!(
                out,
                " The frame judge on the real last frames: {} (its own error, without the world \
                 model's).",
                rate(a)
            );
        }
        out.push_str("\n\n");
        let mut shown = vec![compared, per_policy, repeats, rows];
        match (&self.ranking, &self.ranking_missing) {
            (Some(r), _) => {
                for c in &r.comparisons {
                    out.push_str(&comparison(r, c, &self.labels));
                    let _ = writeln!(
                        out,
                        "![{}: predicted against real success, one point per policy]({})\n",
                        md_text(&crate::ranking::source_title(&c.proxy)),
                        ranking_figure(&c.proxy)
                    );
                    shown.push(tables::ranking_policies(c, &self.labels));
                }
            }
            (None, Some(why)) => {
                let _ = writeln!(out, "No ranking: {}.", md_text(why));
            }
            (None, None) => {}
        }
        let per_group = tables::ranking_per_group(self);
        if !per_group.rows.is_empty() {
            out.push_str("### Per task group\n\n");
            let _ = writeln!(out, "{}\n", md_text(PER_GROUP_NOTE));
            out.push_str(&per_group.markdown());
        }
        out.push_str(&full_names(&shown));
        for (group, e) in &self.errors {
            let _ = writeln!(
                out,
                "\nProxy of group {} failed: {}",
                md_text(group),
                md_text(e)
            );
        }
        if let Some((judge, task, policy, seed, e)) = self.judging_errors.first() {
            let _ = writeln!(
                out,
                "\n{} imagined rollouts could not be judged; the first: {judge} on {task} / \
                 {policy} / seed {seed}: {}",
                self.judging_errors.len(),
                md_text(e)
            );
        }
        out
    }
}

/// The full names of the policies `tables` show shortened, as a list (nothing when none is).
pub(super) fn full_names(tables: &[Table]) -> String {
    let names = abbreviations(tables);
    let mut out = String::new();
    if names.is_empty() {
        return out;
    }
    out.push_str("\nPolicy names shortened in the tables:\n\n");
    for (short, full) in names {
        let _ = writeln!(out, "- {}: `{}`", md_text(&short), md_text(&full));
    }
    out
}

/// A ranking for people (`assay rank` prints it; report.md's ranking section holds it): per
/// comparison, the policies by real success with R and R_S, the four statistics with their
/// intervals, the reasons for anything undefined and what was left out; the full names of
/// policies shown shortened.
pub fn ranking(r: &Ranking) -> String {
    let mut out = String::new();
    for c in &r.comparisons {
        out.push_str(&comparison(r, c, &[]));
    }
    let shown: Vec<Table> = r
        .comparisons
        .iter()
        .map(|c| tables::ranking_policies(c, &[]))
        .collect();
    out.push_str(&full_names(&shown));
    out
}

/// One comparison of a ranking, the policies with `labels` named by them.
fn comparison(r: &Ranking, c: &Comparison, labels: &[(String, String)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "## Policy ranking: {} against {}\n",
        md_text(&crate::ranking::source_title(&c.proxy)),
        md_text(&c.real)
    );
    if let Some(note) = source_note(&c.proxy) {
        let _ = writeln!(out, "{}\n", md_text(note));
    }
    let _ = writeln!(
        out,
        "{} policies, {} tasks. R: a policy's mean over tasks of its success rate in \
         '{}'; R_S: the same in '{}'.\n",
        c.policies.len(),
        c.tasks.len(),
        md_text(&c.real),
        md_text(&c.proxy)
    );
    if !c.policies.is_empty() {
        out.push_str(&tables::ranking_policies(c, labels).markdown());
        out.push('\n');
    }
    out.push_str(&tables::ranking_statistics(c).markdown());
    let _ = writeln!(
        out,
        "\nIntervals: 95 % percentile bootstrap, {} resamples, seed {}: {}.",
        r.resamples,
        r.seed,
        c.bootstrap.describe()
    );
    if c.retest.is_some() {
        let _ = writeln!(out, "\n{}", md_text(RETEST_NOTE));
    }
    for n in &c.notes {
        let _ = writeln!(out, "- {}", md_text(n));
    }
    if !c.excluded.is_empty() {
        let _ = writeln!(out, "\nLeft out:\n");
        for x in &c.excluded {
            match &x.task {
                Some(t) => {
                    let _ = writeln!(
                        out,
                        "- task `{}`, policy `{}`: {}",
                        md_text(t),
                        md_text(&x.policy),
                        md_text(&x.reason)
                    );
                }
                None => {
                    let _ = writeln!(
                        out,
                        "- policy `{}`: {}",
                        md_text(&x.policy),
                        md_text(&x.reason)
                    );
                }
            }
        }
    }
    out.push('\n');
    out
}

#[cfg(test)]
mod tests {
    use assay_stats::ranking::{RankingConfig, parse_success_table, rank};

    #[test]
    fn a_ranking_reads_best_first_with_its_statistics_and_what_was_left_out() {
        let cells = parse_success_table(
            "task,policy,source,trials,successes\n\
             a,good,real,10,9\nb,good,real,10,8\na,good,world-model,10,8\nb,good,world-model,10,9\n\
             a,fair,real,10,5\nb,fair,real,10,6\na,fair,world-model,10,6\nb,fair,world-model,10,4\n\
             a,poor,real,10,1\nb,poor,real,10,2\na,poor,world-model,10,2\nb,poor,world-model,10,1\n\
             a,lone,real,10,3\nc,lone,world-model,10,3\n",
        )
        .unwrap();
        let cfg = RankingConfig {
            resamples: 200,
            ..RankingConfig::default()
        };
        let md = super::ranking(&rank(&cells, &cfg).unwrap());
        assert!(
            md.contains("## Policy ranking: world-model against real\n"),
            "{md}"
        );
        assert!(
            md.contains("| policy | tasks | R (real) | R_S (world-model) |\n|---|---:|---:|---:|"),
            "{md}"
        );
        let at = |p: &str| md.find(&format!("| {p} |")).unwrap();
        assert!(at("good") < at("fair") && at("fair") < at("poor"), "{md}");
        assert!(
            md.contains("| good | 2 | 0.850 (20 trials) | 0.850 (20 trials) |"),
            "{md}"
        );
        for s in [
            "| Pearson r | ",
            "| MMRV (lower is better) | ",
            "Spearman ρ",
            "Kendall τ-b",
        ] {
            assert!(md.contains(s), "{s} in {md}");
        }
        assert!(md.contains("200 resamples, seed 0"), "{md}");
        assert!(md.contains("\nLeft out:\n"), "{md}");
        assert!(md.contains("policy `lone`"), "{md}");
    }
}
