//! Every table of the report, built once from the results: `report.md` writes them as Markdown
//! and `report.html` as HTML, so the two show the same columns, rows and numbers.
//!
//! Owns: which rows and columns a table has and how each value reads. Never formats for a
//! medium (see [`crate::view`]) and never aggregates (the sections did).

use assay_stats::ranking::{Comparison, PolicyPoint};

use crate::diversity::DiversityResults;
use crate::generalization::{GeneralizationResults, LEARNT_THRESHOLD};
use crate::quality::{JudgeSummary, QualityResults};
use crate::ranking::{RankingResults, is_ablation, source_title};
use crate::report::{PolicySuccess, Results};
use crate::view::{Cell, Span, Table, estimate, label_rank, num2, proportion, score};
use assay_model::proxy::{CALIBRATED_SOURCE, LEAK_SOURCE, PROXY_SOURCE, REAL_SOURCE};

mod judges;
mod run;

use assay_model::quality::ScoreStats;
use assay_stats::agreement::Agreement;
use assay_stats::diversity::TextDiversityTable;
pub use judges::{judge_agreement, reliability};
pub use run::{provenance, run, utc};

fn n(v: impl ToString) -> Cell {
    Cell::text(v.to_string())
}

fn stats(s: &ScoreStats) -> Cell {
    score(s.mean, s.variance, s.n)
}

/// The batch in numbers.
pub fn summary(r: &Results) -> Table {
    let t = &r.totals;
    let mut table = Table::new(["measure", "value"]);
    let mut row = |k: &str, v: Cell| table.row(vec![k.into(), v]);
    row("tasks (valid)", n(t.tasks));
    row("tasks rejected as invalid", n(t.invalid_tasks));
    row("episodes planned", n(t.episodes_planned));
    row("episodes completed", n(t.episodes_completed));
    row("episodes failed (errors)", n(t.episodes_failed));
    if t.episodes_cancelled > 0 {
        row("episodes cancelled", n(t.episodes_cancelled));
    }
    // The generalization policies' evaluation episodes run in the batch (the command line's
    // count includes them) but are counted in their own section only: said here, not left out.
    if let Some(g) = &r.generalization {
        let (done, failed, open) = g.groups.iter().fold((0, 0, 0), |(d, f, o), g| {
            (
                d + g.train.trials + g.held_out.trials,
                f + g.errors.len() as u64,
                o + u64::from(g.pending),
            )
        });
        let mut text = format!("{done} completed, {failed} failed");
        if open > 0 {
            text.push_str(&format!(", {open} not finished"));
        }
        row(
            "episodes of the generalization policies (in their section only)",
            Cell::text(text),
        );
    }
    row(
        "ground-truth success, all policies (Wilson 95 %)",
        proportion(&t.success),
    );
    row(
        "simulated steps",
        Cell::text(format!(
            "{} ({:.0} s of sim time)",
            t.sim_steps, t.sim_time_s
        )),
    );
    table
}

/// Ground-truth success of each policy over every task.
pub fn success_per_policy(r: &Results) -> Table {
    let mut table = Table::new(["policy", "#episodes", "#success (Wilson 95 %)"]);
    for p in r.shown(&r.by_policy, |p| &p.policy) {
        table.row(vec![
            Cell::policy(&p.policy, r.policy_labels()),
            n(p.success.trials),
            proportion(&p.success),
        ]);
    }
    table
}

/// With several policies, a column per policy (pooling them would mislead); with one, its
/// success.
fn policy_columns(r: &Results) -> Vec<String> {
    if r.policies.len() > 1 {
        let labels = r.policy_labels();
        r.policies_shown()
            .into_iter()
            .map(|p| {
                format!(
                    "#{}",
                    crate::view::policy_label(p, labels).unwrap_or_else(|| p.clone())
                )
            })
            .collect()
    } else {
        vec!["#success (Wilson 95 %)".into()]
    }
}

fn policy_cells(r: &Results, all: &crate::view::Cell, by: &[PolicySuccess]) -> Vec<Cell> {
    if r.policies.len() > 1 {
        r.policies_shown()
            .into_iter()
            .map(|p| {
                by.iter()
                    .find(|x| &x.policy == p)
                    .map_or_else(Cell::missing, |x| proportion(&x.success))
            })
            .collect()
    } else {
        vec![all.clone()]
    }
}

/// Success per group, with a total row.
pub fn success_per_group(r: &Results) -> Table {
    let mut columns: Vec<String> = vec!["group".into(), "#tasks".into(), "#episodes".into()];
    columns.extend(policy_columns(r));
    let mut table = Table::new(columns);
    for g in &r.groups {
        let mut cells = vec![g.group.as_str().into(), n(g.tasks), n(g.success.trials)];
        cells.extend(policy_cells(r, &proportion(&g.success), &g.by_policy));
        table.row(cells);
    }
    let mut cells = vec!["all".into(), n(r.totals.tasks), n(r.totals.success.trials)];
    cells.extend(policy_cells(
        r,
        &proportion(&r.totals.success),
        &r.by_policy,
    ));
    table.total(cells);
    table
}

/// Success per task, each linked to its page, with the predicate most often unmet.
pub fn success_per_task(r: &Results) -> Table {
    let mut columns: Vec<String> = vec![
        "group".into(),
        "task".into(),
        "source".into(),
        "#episodes".into(),
    ];
    columns.extend(policy_columns(r));
    columns.push("most often unmet".into());
    // The generators' own rewards (GenSim's), beside success, where any task has one.
    let rewarded = r
        .tasks
        .iter()
        .any(|t| t.episodes.iter().any(|e| e.generator_reward.is_some()));
    if rewarded {
        columns.push("generator's reward".into());
    }
    let mut table = Table::new(columns);
    for task in &r.tasks {
        let unmet = task
            .predicates
            .iter()
            .filter(|p| p.holds < p.of)
            .max_by_key(|p| p.of - p.holds)
            .map_or_else(Cell::default, |p| {
                Cell::code(&p.label).and(Span::Text(format!(" ({}/{})", p.of - p.holds, p.of)))
            });
        // Episodes stopped by the step limit fail whatever their predicates say: said so.
        let cut = task.episodes.iter().filter(|e| e.cutoff.is_some()).count();
        let unmet = match (unmet.0.is_empty(), cut) {
            (_, 0) => unmet,
            (true, n) => Cell::text(format!("step limit ({n}/{})", task.episodes.len())),
            (false, n) => unmet.and(Span::Break).and(Span::Text(format!(
                "step limit ({n}/{})",
                task.episodes.len()
            ))),
        };
        let mut cells = vec![
            task.group.as_str().into(),
            Cell(vec![Span::TaskLink(task.id.clone())]).and(Span::Text(format!(" {}", task.name))),
            task.pipeline.as_str().into(),
            n(task.success.trials),
        ];
        cells.extend(policy_cells(r, &proportion(&task.success), &task.by_policy));
        cells.push(unmet);
        if rewarded {
            cells.push(generator_reward(&task.episodes).map_or_else(Cell::default, Cell::text));
        }
        table.row(cells);
    }
    table
}

/// The mean of the episodes' generator rewards, of their most, and whose: `0.83 of 1
/// (GenSim's, 12 episodes)`; `None` where no episode has one.
pub fn generator_reward(episodes: &[crate::report::EpisodeRow]) -> Option<String> {
    let rewards: Vec<&assay_model::episode::GeneratorReward> = episodes
        .iter()
        .filter_map(|e| e.generator_reward.as_ref())
        .collect();
    let first = rewards.first()?;
    let n = rewards.len() as f64;
    let mean = rewards.iter().map(|r| r.value).sum::<f64>() / n;
    let max = rewards.iter().map(|r| r.max).sum::<f64>() / n;
    let whose = match first.by.as_str() {
        "gensim" => "GenSim's".to_string(),
        other => format!("{other}'s"),
    };
    Some(format!(
        "{mean:.2} of {max:.2} ({whose}, {} episodes)",
        rewards.len()
    ))
}

/// Episodes that ran out of attempts or were cancelled.
pub fn failures(r: &Results) -> Table {
    let mut table = Table::new(["task", "#seed", "policy", "#attempts", "error"]);
    for t in &r.tasks {
        for f in &t.failures {
            let mut error = Cell::default();
            if f.cancelled {
                error = error.and(Span::Text("(cancelled) ".into()));
            }
            table.row(vec![
                Cell::code(&t.id),
                n(f.seed),
                Cell::policy(&f.policy, r.policy_labels()),
                n(f.attempts),
                error.and(Span::Text(f.error.clone())),
            ]);
        }
    }
    table
}

/// Task specs refused, each problem with its field.
pub fn invalid_tasks(r: &Results) -> Table {
    let mut table = Table::new(["task", "file", "field", "reason"]);
    for e in &r.invalid_tasks {
        table.row(vec![
            e.task
                .as_deref()
                .map_or_else(|| Cell::text("(no id)"), Cell::from),
            e.origin.as_str().into(),
            Cell::code(&e.path),
            e.reason.as_str().into(),
        ]);
    }
    table
}

/// An imported generator tree: each task, whether it was imported, why not, and how many
/// fields were inferred or left out.
pub fn imports(i: &crate::report::ImportSummary) -> Table {
    let mut table = Table::new(["task", "imported", "#inferred", "#not mapped", "why not"]);
    for t in &i.tasks {
        table.row(vec![
            Cell::code(&t.id),
            Cell::text(if t.imported { "yes" } else { "no" }),
            n(t.inferred.len()),
            n(t.not_mapped.len()),
            if t.errors.is_empty() {
                Cell::default()
            } else {
                Cell::text(t.errors.join("; "))
            },
        ]);
    }
    table
}

/// The judges: what they are, what they judged and what it cost.
pub fn judges(q: &QualityResults) -> Table {
    let mut table = Table::new([
        "judge",
        "backend",
        "model",
        "prompt versions",
        "#repeats",
        "#episodes judged",
        "#failed",
        "#pending",
        "#cancelled",
        "#item errors",
        "#unjudged items",
        "#calls",
        "#cached",
        "#tokens in",
        "#tokens out",
        "#cost USD",
    ]);
    for j in &q.judges {
        table.row(vec![
            Cell::code(&j.judge),
            Cell::or_missing(&j.backend),
            Cell::or_missing(&j.model),
            Cell::or_missing(&j.prompts.join(", ")),
            n(j.repeats),
            n(j.episodes_judged),
            n(j.episodes_failed),
            n(j.episodes_pending),
            n(j.episodes_cancelled),
            n(j.item_errors),
            n(j.items_unjudged),
            n(j.usage.calls),
            n(j.usage.cached),
            n(j.usage.tokens_in),
            n(j.usage.tokens_out),
            Cell::text(cost(j.usage.cost_usd)),
        ]);
    }
    table
}

fn cost(usd: f64) -> String {
    if usd > 0.0 && usd < 0.01 {
        format!("{usd:.4}")
    } else {
        num2(usd)
    }
}

/// One judge's scores per group, with the judge's own over all its tasks.
pub fn quality_per_group(j: &JudgeSummary) -> Table {
    let mut table = Table::new([
        "group",
        "#tasks",
        "#scene alignment (1–5)",
        "#completion (0–10)",
    ]);
    for g in &j.groups {
        table.row(vec![
            g.group.as_str().into(),
            n(g.tasks),
            stats(&g.scene_alignment),
            stats(&g.completion),
        ]);
    }
    let tasks: u64 = j.groups.iter().map(|g| g.tasks).sum();
    table.total(vec![
        "all".into(),
        n(tasks),
        stats(&j.scene_alignment),
        stats(&j.completion),
    ]);
    table
}

/// Scores per task and judge.
pub fn quality_per_task(q: &QualityResults) -> Table {
    let mut table = Table::new([
        "task",
        "group",
        "judge",
        "#scene alignment (1–5)",
        "#completion (0–10)",
        "#completion variance over repeats",
        "#completion variance over episodes",
        "#unjudged",
    ]);
    let var = |v: Option<f64>| v.map_or_else(Cell::missing, |v| Cell::text(format!("{v:.3}")));
    for t in &q.tasks {
        table.row(vec![
            Cell(vec![Span::TaskLink(t.task_id.clone())]),
            t.group.as_str().into(),
            Cell::code(&t.judge),
            stats(&t.scene_alignment),
            stats(&t.completion),
            var(t.completion_split.over_repeats),
            var(t.completion_split.over_episodes),
            n(t.unjudged),
        ]);
    }
    table
}

/// One judge's agreement with one reference (the simulator, or human ratings).
pub struct AgreementLine<'a> {
    pub judge: &'a str,
    pub reference: String,
    pub group: Option<&'a str>,
    /// None: nothing to compare (no judged episode with a reference score).
    pub agreement: Option<&'a Agreement>,
}

/// The judges against the simulator (every judge, also one with nothing to compare).
pub fn against_simulator(q: &QualityResults) -> Vec<AgreementLine<'_>> {
    q.judges
        .iter()
        .map(|j| AgreementLine {
            judge: &j.judge,
            reference: "simulator".into(),
            group: None,
            agreement: j.vs_sim.as_ref(),
        })
        .collect()
}

/// Agreement statistics with their 95 % bootstrap intervals.
pub fn agreement(lines: &[AgreementLine<'_>]) -> Table {
    let mut table = Table::new([
        "judge",
        "against",
        "group",
        "#n",
        "#Pearson r",
        "#MAE",
        "#Spearman ρ",
        "#Kendall τ",
    ]);
    for l in lines {
        let mut cells = vec![
            Cell::code(l.judge),
            l.reference.as_str().into(),
            l.group.unwrap_or("all").into(),
        ];
        match l.agreement {
            Some(a) => cells.extend([
                n(a.n),
                estimate(&a.pearson),
                estimate(&a.mae),
                estimate(&a.spearman),
                estimate(&a.kendall),
            ]),
            None => {
                cells.push(n(0));
                cells.extend((0..4).map(|_| Cell::missing()));
            }
        }
        table.row(cells);
    }
    table
}

/// Table 1: text diversity per group and embedding model.
pub fn text_diversity(t: &TextDiversityTable) -> Table {
    let mut columns = vec!["group".to_owned(), "#N".to_owned()];
    columns.extend(
        t.models
            .iter()
            .map(|m| format!("#{} ({}, {} d)", m.name, m.model, m.dimensions)),
    );
    let mut table = Table::new(columns);
    for r in &t.rows {
        let mut cells = vec![r.group.as_str().into(), n(r.n)];
        for m in 0..t.models.len() {
            cells.push(
                match (
                    r.div.get(m).copied().flatten(),
                    r.errors.get(m).cloned().flatten(),
                ) {
                    (Some(v), _) => Cell::text(format!("{v:.3}")),
                    (None, Some(e)) => Cell(vec![Span::Undefined(e)]),
                    (None, None) => Cell::missing(),
                },
            );
        }
        table.row(cells);
    }
    table
}

/// Table 2: world-model evaluation image MSE ×10³ per group and training budget.
pub fn dynamics_diversity(d: &DiversityResults) -> Table {
    let mut budgets: Vec<u32> = d.dynamics.iter().map(|f| f.budget).collect();
    budgets.sort_unstable();
    budgets.dedup();
    let mut groups: Vec<&str> = Vec::new();
    for f in &d.dynamics {
        if !groups.contains(&f.group.as_str()) {
            groups.push(&f.group);
        }
    }
    let mut columns = vec!["group".to_owned(), "#evaluated on".to_owned()];
    columns.extend(budgets.iter().map(|b| format!("#{b} episodes")));
    let mut table = Table::new(columns);
    for g in groups {
        let fits: Vec<_> = d.dynamics.iter().filter(|f| f.group == g).collect();
        let eval = fits.iter().map(|f| f.eval_episodes).max().unwrap_or(0);
        let mut cells = vec![g.into(), n(eval)];
        for b in &budgets {
            cells.push(match fits.iter().find(|f| f.budget == *b) {
                Some(f) if f.train_episodes < f.budget => Cell::text(format!(
                    "{:.3} ({} trained)",
                    f.eval_image_mse * 1e3,
                    f.train_episodes
                )),
                Some(f) => Cell::text(format!("{:.3}", f.eval_image_mse * 1e3)),
                None => Cell::missing(),
            });
        }
        table.row(cells);
    }
    table
}

/// Diversity jobs that failed, those whose name starts with `prefix`.
pub fn diversity_errors(d: &DiversityResults, prefix: &str) -> Table {
    let mut table = Table::new(["diversity job", "error"]);
    for (job, e) in d.errors.iter().filter(|(j, _)| j.starts_with(prefix)) {
        table.row(vec![job.as_str().into(), e.as_str().into()]);
    }
    table
}

/// Table 3: each group's trained policy on its training and held-out variations.
pub fn generalization(g: &GeneralizationResults) -> Table {
    let mut table = Table::new([
        "group",
        "model",
        "trained on",
        "#training variations",
        "#held-out variations",
        "notes",
    ]);
    for x in &g.groups {
        let mut notes = Vec::new();
        if x.did_not_learn() {
            notes.push(format!(
                "fails on its own training variations (< {:.0} %): it did not learn the group, \
                 so the held-out rate says nothing about generalization",
                LEARNT_THRESHOLD * 100.0
            ));
        }
        if x.pending > 0 {
            notes.push(format!("{} episodes still running", x.pending));
        }
        if !x.errors.is_empty() {
            notes.push(format!("{} episodes failed to run", x.errors.len()));
        }
        table.row(vec![
            x.group.as_str().into(),
            x.model.as_str().into(),
            Cell::text(format!("{} episodes, {} steps", x.fit.clips, x.fit.steps)),
            proportion(&x.train),
            proportion(&x.held_out),
            notes.join("; ").into(),
        ]);
    }
    table
}

/// Lines of a cell.
fn lines(items: impl IntoIterator<Item = String>) -> Cell {
    let mut c = Cell::default();
    for (i, x) in items.into_iter().enumerate() {
        if i > 0 {
            c = c.and(Span::Break);
        }
        c = c.and(Span::Text(x));
    }
    if c.0.is_empty() { Cell::missing() } else { c }
}

/// What the ranking compared: the two policy sets, the world models, the frame judge and the
/// judge role's judges with the rules of their verdicts, and the leak ablation.
pub fn ranking_compared(r: &RankingResults) -> Table {
    let mut table = Table::new(["what", "value"]);
    table.row(vec![
        "training policies (their episodes train the world model and the frame judge)".into(),
        Cell::policies(r.train_policies.iter().map(String::as_str), &r.labels),
    ]);
    table.row(vec![
        "ranked policies (never trained on)".into(),
        Cell::policies(r.ranked_policies.iter().map(String::as_str), &r.labels),
    ]);
    let mut models: Vec<(&str, Vec<&str>)> = Vec::new();
    for g in &r.groups {
        let name = g.world_model_name.as_str();
        match models.iter_mut().find(|(m, _)| *m == name) {
            Some((_, groups)) => groups.push(&g.group),
            None => models.push((name, vec![&g.group])),
        }
    }
    table.row(vec![
        "world model".into(),
        lines(models.iter().map(|(m, groups)| {
            let m = if m.is_empty() { "(not named)" } else { m };
            format!("{m} (groups {})", groups.join(", "))
        })),
    ]);
    let Some(cfg) = &r.config else {
        return table;
    };
    table.row(vec![
        "policy interface (of the clips the world model learns and of the ranked policies)".into(),
        Cell::from(if cfg.interface.is_empty() {
            "the original: the task camera, tool position + holding, tool velocities".to_owned()
        } else {
            cfg.interface.clone()
        }),
    ]);
    table.row(vec![
        "frame judge".into(),
        lines([
            format!(
                "a small CNN per group, trained on the training episodes' real and imagined \
                 frames (last frames labelled with their outcome, earlier ones not done; counts \
                 below); it calls a frame done when its probability is ≥ {}",
                num2(cfg.threshold)
            ),
            format!(
                "an imagined rollout stops as a success once the frame judge calls {} frames in \
                 a row done; otherwise it runs the task's whole step budget",
                cfg.done_frames
            ),
        ]),
    ]);
    let judges: Vec<String> = r
        .repeat_consistency
        .iter()
        .filter(|c| c.policy.is_none())
        .map(|c| format!("{}: k = {} repeats", c.judge, c.repeats))
        .collect();
    table.row(vec![
        "judges of imagined rollouts (world-model+<judge>)".into(),
        if judges.is_empty() {
            Cell::text("none (no judge that looks at images)")
        } else {
            let rule = format!(
                "a rollout succeeds when its mean completion over k repeats is ≥ {} (0–10)",
                num2(cfg.completion_threshold)
            );
            lines(judges.into_iter().chain([rule]))
        },
    ]);
    let calibrations = judges::calibration_lines(r);
    if !calibrations.is_empty() {
        table.row(vec![
            format!("calibration ({CALIBRATED_SOURCE}; training policies only)").into(),
            lines(calibrations),
        ]);
    }
    let leak = cfg.leak_ablation || r.rows.iter().any(|x| x.leak.is_some());
    table.row(vec![
        "leak ablation".into(),
        Cell::text(if leak {
            "every ranked episode also imagined for exactly as many frames as its real episode \
             had and judged on that last frame: the real episode's length given to the proxy. \
             An ablation, never the proxy"
        } else {
            "off"
        }),
    ]);
    table
}

/// Per ranked policy: real success and each proxy's predicted success, episodes pooled over
/// tasks, with Wilson intervals. Best real success first, the ladder's policies last in ladder
/// order (episodes, step).
pub fn ranking_per_policy(r: &RankingResults) -> Table {
    let mut sources: Vec<&str> = Vec::new();
    for s in r.policies.iter().flat_map(|p| &p.predicted) {
        if !sources.contains(&s.source.as_str()) {
            sources.push(&s.source);
        }
    }
    sources.sort_by_key(|s| (is_ablation(s), *s != PROXY_SOURCE, *s));
    let mut columns = vec![
        "policy".to_owned(),
        "#tasks".to_owned(),
        format!("#R real ({REAL_SOURCE})"),
    ];
    columns.extend(sources.iter().map(|s| format!("#R_S {}", source_title(s))));
    let mut table = Table::new(columns);
    let mut policies: Vec<_> = r.policies.iter().collect();
    policies.sort_by_key(|p| label_rank(&p.policy, &r.labels));
    for p in policies {
        let mut cells = vec![
            Cell::policy(&p.policy, &r.labels),
            n(p.tasks),
            proportion(&p.real),
        ];
        cells.extend(sources.iter().map(|s| {
            p.predicted
                .iter()
                .find(|x| x.source == *s)
                .map_or_else(Cell::missing, |x| proportion(&x.success))
        }));
        table.row(cells);
    }
    table
}

/// Per task group (with tasks of several groups), each proxy's ranking over that group's tasks
/// alone, beside the pooled one: policies, Pearson, MMRV, Spearman, Kendall with their 95 %
/// intervals, the calibration (mean |predicted − real|), and the Pearson r the real evaluation
/// itself would reach rerun in the proxy's place (the bar its trial noise sets).
pub fn ranking_per_group(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "group",
        "proxy",
        "#policies",
        "#tasks",
        "#Pearson r",
        "#MMRV",
        "#Spearman ρ",
        "#Kendall τ-b",
        "#calibration |pred − real|",
        "#simulator rerun: Pearson r",
    ]);
    let pooled = r.ranking.iter().map(|rk| ("(pooled)", rk));
    let groups = r
        .per_group
        .iter()
        .filter_map(|g| g.ranking.as_ref().map(|rk| (g.group.as_str(), rk)));
    if r.per_group.is_empty() {
        return table;
    }
    for (group, rk) in groups.chain(pooled) {
        for c in &rk.comparisons {
            table.row(vec![
                group.into(),
                source_title(&c.proxy).into(),
                n(c.policies.len() as u64),
                n(c.tasks.len() as u64),
                estimate(&c.pearson),
                estimate(&c.mmrv),
                estimate(&c.spearman),
                estimate(&c.kendall),
                c.calibration_mae
                    .as_ref()
                    .map_or_else(Cell::missing, estimate),
                c.retest
                    .as_ref()
                    .map_or_else(Cell::missing, |t| estimate(&t.pearson)),
            ]);
        }
    }
    for g in r.per_group.iter().filter(|g| g.ranking.is_none()) {
        let why = g.missing.as_deref().unwrap_or("no ranking");
        let mut row = vec![g.group.as_str().into(), Cell::text(why.to_owned())];
        row.extend((0..8).map(|_| Cell::missing()));
        table.row(row);
    }
    table
}

/// Per group: the world model's open-loop error over windows of the ranked episodes' clips with
/// their true actions, another episode's and zero actions, and the video figures (PSNR, SSIM)
/// of the true-action predictions.
pub fn action_test(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "group",
        "world model",
        "#episodes",
        "#frames per window",
        "#image MSE ×10³, true actions",
        "#shuffled actions",
        "#zero actions",
        "#shuffled ÷ true",
        "#zero ÷ true",
        "#PSNR (dB)",
        "#SSIM",
    ]);
    for g in &r.groups {
        let Some(a) = &g.action_test else { continue };
        let ratio = |x: f64| {
            if a.true_actions_mse > 0.0 && x > 0.0 {
                Cell::text(num2(x / a.true_actions_mse))
            } else {
                Cell::missing()
            }
        };
        // Figures a report from before issue 44 did not have are shown as missing.
        let known = a.horizon > 0;
        table.row(vec![
            g.group.as_str().into(),
            Cell::or_missing(&g.world_model_name),
            n(a.episodes),
            if known {
                n(a.horizon)
            } else {
                Cell::text("whole episode")
            },
            Cell::text(format!("{:.3}", a.true_actions_mse * 1e3)),
            Cell::text(format!("{:.3}", a.shuffled_actions_mse * 1e3)),
            if known {
                Cell::text(format!("{:.3}", a.zero_actions_mse * 1e3))
            } else {
                Cell::missing()
            },
            ratio(a.shuffled_actions_mse),
            if known {
                ratio(a.zero_actions_mse)
            } else {
                Cell::missing()
            },
            if known {
                Cell::text(format!("{:.2}", a.psnr))
            } else {
                Cell::missing()
            },
            if known {
                Cell::text(format!("{:.3}", a.ssim))
            } else {
                Cell::missing()
            },
        ]);
    }
    table
}

/// Per judge of imagined rollouts: the spread of its completion scores over each rollout's k
/// repeats, per policy (the ladder's policies last in ladder order) and over all.
pub fn repeat_consistency(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "judge",
        "policy",
        "#k (repeats)",
        "#rollouts",
        "#mean variance over repeats",
        "#rollouts split by the threshold",
    ]);
    let mut repeats: Vec<_> = r.repeat_consistency.iter().collect();
    let judge_rank = |judge: &str| r.repeat_consistency.iter().position(|x| x.judge == judge);
    repeats.sort_by_key(|c| {
        (
            judge_rank(&c.judge),
            c.policy.is_none(),
            c.policy.as_deref().and_then(|p| label_rank(p, &r.labels)),
        )
    });
    for c in repeats {
        let cells = vec![
            Cell::code(&c.judge),
            c.policy
                .as_deref()
                .map_or_else(|| "all".into(), |p| Cell::policy(p, &r.labels)),
            n(c.repeats),
            n(c.rollouts),
            c.mean_variance
                .map_or_else(Cell::missing, |v| Cell::text(format!("{v:.3}"))),
            n(c.split),
        ];
        if c.policy.is_none() {
            table.total(cells);
        } else {
            table.row(cells);
        }
    }
    table
}

/// Per task and policy: real success, the proxy's verdicts and the judges' view. Within a task,
/// the ladder's policies last in ladder order (episodes, step).
pub fn ranking_rows(r: &RankingResults) -> Table {
    let rate = |p: &assay_stats::stats::Proportion| match p.rate {
        Some(x) => Cell::text(format!("{:.0} % ({}/{})", x * 100.0, p.successes, p.trials)),
        None => Cell::missing(),
    };
    let leak = r.rows.iter().any(|x| x.leak.is_some());
    let mut columns = vec![
        "task".to_owned(),
        "policy".to_owned(),
        "#real (sim)".to_owned(),
        "#world-model proxy".to_owned(),
        "#proxy mean p".to_owned(),
        "imagined, judged (mean completion)".to_owned(),
        "#judged completion".to_owned(),
    ];
    if leak {
        columns.push(format!("#{}", source_title(LEAK_SOURCE)));
    }
    let mut table = Table::new(columns);
    let mut rows: Vec<_> = r.rows.iter().collect();
    let task_rank = |task: &str| r.rows.iter().position(|x| x.task_id == task);
    rows.sort_by_key(|x| (task_rank(&x.task_id), label_rank(&x.policy, &r.labels)));
    for row in rows {
        let mut judged = Cell::default();
        for (i, j) in row.judged_proxy.iter().enumerate() {
            if i > 0 {
                judged = judged.and(Span::Break);
            }
            judged = judged.and(Span::Text(format!(
                "{}: {} ({})",
                j.judge,
                rate(&j.success).plain(),
                j.mean_completion.map_or("–".into(), |c| format!("{c:.1}"))
            )));
        }
        if judged.0.is_empty() {
            judged = Cell::missing();
        }
        let mut cells = vec![
            Cell(vec![Span::TaskLink(row.task_id.clone())]),
            Cell::policy(&row.policy, &r.labels),
            rate(&row.real),
            row.proxy.as_ref().map_or_else(Cell::missing, rate),
            row.proxy_mean_p
                .map_or_else(Cell::missing, |p| Cell::text(format!("{p:.2}"))),
            judged,
            row.judged_completion
                .map_or_else(Cell::missing, |c| Cell::text(format!("{c:.1}"))),
        ];
        if leak {
            cells.push(row.leak.as_ref().map_or_else(Cell::missing, rate));
        }
        table.row(cells);
    }
    table
}

/// Per group: the world model and the frame judge the proxy used, and how the imagined
/// rollouts ended.
pub fn proxy_models(r: &RankingResults) -> Table {
    let mut table = Table::new([
        "group",
        "world model",
        "#world-model steps",
        "#one-step image MSE ×10³",
        "#frame-judge examples (successes)",
        "#frame-judge train accuracy",
        "#stopped by the frame judge",
        "#mean imagined frames",
        "#mean last-frame MSE ×10³",
        "#judge's latest not-done frame / rollouts' last",
    ]);
    for g in &r.groups {
        let served = g.world_model.device == assay_model::proxy::SERVED_DEVICE;
        let count = g.predictions.len().max(1) as f64;
        let mean = |f: fn(&assay_model::proxy::ProxyPrediction) -> f64| {
            g.predictions.iter().map(f).sum::<f64>() / count
        };
        table.row(vec![
            g.group.as_str().into(),
            Cell::or_missing(&g.world_model_name),
            // A served world model was not trained here: no steps, no one-step error.
            if served {
                Cell::missing()
            } else {
                n(g.world_model.steps)
            },
            if served {
                Cell::missing()
            } else {
                Cell::text(format!("{:.3}", g.world_model.eval_image_mse * 1e3))
            },
            Cell::text(format!("{} ({})", g.judge_examples, g.judge_positives)),
            Cell::text(num2(g.judge_train_accuracy)),
            Cell::text(format!(
                "{}/{}",
                g.predictions.iter().filter(|p| p.done_by_judge).count(),
                g.predictions.len()
            )),
            Cell::text(format!("{:.1}", mean(|p| f64::from(p.imagined_frames)))),
            Cell::text(format!("{:.3}", mean(|p| p.last_frame_mse) * 1e3)),
            match (g.judge_latest_not_done, g.ranked_last_frame) {
                (Some(seen), Some(last)) => Cell::text(format!("{seen} / {last}")),
                _ => Cell::missing(),
            },
        ]);
    }
    table
}

/// One comparison's policies, by real success: R and R_S; a policy with one of `labels` (see
/// [`RankingResults::labels`]) shown by it.
pub fn ranking_policies(c: &Comparison, labels: &[(String, String)]) -> Table {
    let mut table = Table::new([
        "policy".to_owned(),
        "#tasks".to_owned(),
        format!("#R ({})", c.real),
        format!("#R_S ({})", source_title(&c.proxy)),
    ]);
    let with_trials = |rate: f64, trials: Option<u64>| match trials {
        Some(t) => Cell::text(format!("{rate:.3} ({t} trials)")),
        None => Cell::text(format!("{rate:.3}")),
    };
    let mut order: Vec<&PolicyPoint> = c.policies.iter().collect();
    order.sort_by(|a, b| {
        b.real
            .total_cmp(&a.real)
            .then(b.proxy.total_cmp(&a.proxy))
            .then(a.policy.cmp(&b.policy))
    });
    for p in order {
        table.row(vec![
            Cell::policy(&p.policy, labels),
            n(p.tasks),
            with_trials(p.real, p.real_trials),
            with_trials(p.proxy, p.proxy_trials),
        ]);
    }
    table
}

/// One comparison's four statistics with their intervals.
pub fn ranking_statistics(c: &Comparison) -> Table {
    let mut table = Table::new(["statistic", "#value [95 % interval]"]);
    for (name, e) in c.statistics() {
        table.row(vec![name.into(), estimate(e)]);
    }
    if let Some(e) = &c.calibration_mae {
        table.row(vec![
            "calibration: mean |predicted − real| (lower is better)".into(),
            estimate(e),
        ]);
    }
    if let Some(t) = &c.retest {
        table.row(vec![
            "the simulator rerun in the proxy's place (its trials, new seeds): Pearson r".into(),
            estimate(&t.pearson),
        ]);
        table.row(vec![
            "the simulator rerun in the proxy's place: MMRV".into(),
            estimate(&t.mmrv),
        ]);
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_counts_the_generalization_episodes_apart() {
        use crate::generalization::{EvalEpisode, GeneralizationResults, GroupGeneralization};
        let mut r = crate::report::build_results("x", &["oracle".into()], &[0], &[], &[], &[]);
        let without = summary(&r).markdown();
        assert!(!without.contains("generalization"), "{without}");
        let ep = |held_out: bool, success: Option<Result<bool, String>>| EvalEpisode {
            group: "g".into(),
            task_id: "a".into(),
            held_out,
            success,
        };
        let eps = [
            ep(false, Some(Ok(true))),
            ep(false, Some(Ok(false))),
            ep(true, Some(Ok(false))),
            ep(true, Some(Err("worker lost".into()))),
            ep(true, None),
        ];
        r.generalization = Some(GeneralizationResults {
            groups: vec![GroupGeneralization::build(
                "g",
                "m",
                crate::testing::diffusion_fit(),
                &eps,
            )],
            errors: vec![],
        });
        let with = summary(&r).markdown();
        assert!(
            with.contains(
                "| episodes of the generalization policies (in their section only) | 3 completed, \
                 1 failed, 1 not finished |"
            ),
            "{with}"
        );
    }
}
