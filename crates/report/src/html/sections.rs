//! The papers' views in `report.html`: figures 3 and 4, Tables 1, 2 and 3, and the policy
//! ranking, each a section with its figure and the tables report.md shows.

use super::*;
use crate::diversity::DiversityResults;
use crate::figures::{self, BarChart, Bars, Line};
use crate::generalization::{GeneralizationResults, GroupGeneralization, HELD_OUT_NOTE};
use crate::quality::{OFFLINE_JUDGE_NOTE, QualityResults};
use crate::ranking::{
    ACTION_TEST_NOTE, JUDGE_AGREEMENT_NOTE, PER_GROUP_NOTE, PER_POLICY_NOTE, RELIABILITY_NOTE,
    REPEAT_NOTE, RETEST_NOTE, RankingResults, source_note,
};
use crate::tables::{self, AgreementLine};
use crate::view::proportion;
use assay_stats::agreement::{Agreement, Estimate};
use assay_stats::stats::Proportion;

pub(super) fn figure_4(quality: Option<&QualityResults>) -> Markup {
    let Some(q) = quality else {
        return html! {
            section id="figure-4" {
                h2 { "Scene alignment against task completion (figure 4)" }
                (absent("no judge ran: run with --judge"))
            }
        };
    };
    let points = q.scene_points();
    let judges: Vec<String> = q
        .judges
        .iter()
        .enumerate()
        .map(|(i, j)| {
            format!(
                "{} ({})",
                j.judge,
                if i == 0 { "filled" } else { "outline" }
            )
        })
        .collect();
    html! {
        section id="figure-4" {
            h2 { "Scene alignment against task completion (figure 4)" }
            (inline_svg(&figures::scene_vs_completion(&points)))
            p.caption {
                "One marker per (task, judge): the judge's mean scene alignment (1–5, from the 4 \
                 views of the initial scene) against its mean task completion (0–10, from the 8 \
                 keyframes). Colour: the task's group. Size: the variance of the scores — "
                (figures::SPREAD_RULE) ". Judges: "
                @if judges.is_empty() { "none" } @else { (judges.join(", ")) }
                ". " (points.len()) " markers."
            }
            h3 { "Judges" }
            (table(&tables::judges(q)))
            @for j in q.judges.iter().filter(|j| j.offline) {
                p.caption { code { (j.judge) } " " (OFFLINE_JUDGE_NOTE) }
            }
            @for j in &q.judges {
                h3 { "Quality per group: " code { (j.judge) } }
                (table(&tables::quality_per_group(j)))
            }
        }
    }
}

fn defined(e: &Estimate) -> Option<f64> {
    e.value.filter(|v| v.is_finite())
}

pub(super) fn figure_3(quality: Option<&QualityResults>, human: Option<&AgreementTable>) -> Markup {
    let mut lines: Vec<AgreementLine<'_>> = quality
        .map(tables::against_simulator)
        .unwrap_or_default()
        .into_iter()
        .filter(|l| l.agreement.is_some())
        .collect();
    if let Some(h) = human {
        for row in &h.rows {
            lines.push(AgreementLine {
                judge: &row.judge,
                reference: format!("humans ({})", h.reference),
                group: row.group.as_deref(),
                agreement: Some(&row.agreement),
            });
        }
    }
    if lines.is_empty() {
        return html! {
            section id="figure-3" {
                h2 { "Judge agreement with the simulator and with people (figure 3)" }
                @if quality.is_none() {
                    (absent("no judge ran: run with --judge"))
                } @else {
                    (absent("no judge has an agreement with the simulator; human ratings: run \
                             with --human-ratings"))
                }
            }
        };
    }
    let mut judges: Vec<String> = Vec::new();
    let mut references: Vec<String> = Vec::new();
    for l in lines.iter().filter(|l| l.group.is_none()) {
        if !judges.iter().any(|j| j == l.judge) {
            judges.push(l.judge.to_owned());
        }
        if !references.contains(&l.reference) {
            references.push(l.reference.clone());
        }
    }
    let series = |stat: fn(&Agreement) -> &Estimate| -> Vec<Bars> {
        references
            .iter()
            .map(|reference| {
                let find = |j: &String| {
                    lines
                        .iter()
                        .find(|l| l.group.is_none() && &l.reference == reference && l.judge == j)
                        .and_then(|l| l.agreement)
                };
                Bars {
                    name: format!("against {reference}"),
                    values: judges
                        .iter()
                        .map(|j| find(j).and_then(|a| defined(stat(a))))
                        .collect(),
                    intervals: judges
                        .iter()
                        .map(|j| find(j).and_then(|a| stat(a).ci95))
                        .collect(),
                }
            })
            .collect()
    };
    html! {
        section id="figure-3" {
            h2 { "Judge agreement with the simulator and with people (figure 3)" }
            div.row {
                (inline_svg(&figures::bar_chart(&BarChart {
                    title: "Pearson r per judge",
                    y_desc: "Pearson r",
                    categories: &judges,
                    series: &series(|a| &a.pearson),
                    y_range: Some((-1.0, 1.0)),
                })))
                (inline_svg(&figures::bar_chart(&BarChart {
                    title: "Mean absolute error per judge",
                    y_desc: "MAE",
                    categories: &judges,
                    series: &series(|a| &a.mae),
                    y_range: None,
                })))
            }
            (table(&tables::agreement(&lines)))
            p.caption {
                "Bars: over all rated items, with 95 % bootstrap intervals; n/a marks a statistic \
                 that is undefined (its reason is in the table). Against the simulator: the \
                 judge's completion score against the simulator's success."
            }
            @if human.is_none() { (absent("human ratings: run with --human-ratings")) }
        }
    }
}

/// The diversity jobs that failed whose name starts with `prefix`.
fn diversity_errors(d: Option<&DiversityResults>, prefix: &str) -> Markup {
    html! { @if let Some(d) = d { (table_if_any(&tables::diversity_errors(d, prefix))) } }
}

pub(super) fn table_1(diversity: Option<&DiversityResults>) -> Markup {
    let Some(t) = diversity.and_then(|d| d.text.as_ref()) else {
        return html! {
            section id="table-1" {
                h2 { "Text diversity per group (Table 1)" }
                (absent("text diversity was not measured: run without --no-diversity"))
                (diversity_errors(diversity, "text"))
            }
        };
    };
    let groups: Vec<String> = t.rows.iter().map(|r| r.group.clone()).collect();
    let series: Vec<Bars> = t
        .models
        .iter()
        .enumerate()
        .map(|(m, model)| Bars {
            name: model.name.clone(),
            values: t
                .rows
                .iter()
                .map(|r| r.div.get(m).copied().flatten())
                .collect(),
            intervals: Vec::new(),
        })
        .collect();
    html! {
        section id="table-1" {
            h2 { "Text diversity per group (Table 1)" }
            (inline_svg(&figures::bar_chart(&BarChart {
                title: "Text diversity per group and embedding model",
                y_desc: "diversity",
                categories: &groups,
                series: &series,
                y_range: None,
            })))
            (table(&tables::text_diversity(t)))
            (diversity_errors(diversity, "text"))
        }
    }
}

pub(super) fn table_2(diversity: Option<&DiversityResults>) -> Markup {
    let Some(d) = diversity.filter(|d| !d.dynamics.is_empty()) else {
        return html! {
            section id="table-2" {
                h2 { "Dynamics diversity against episode budget (Table 2)" }
                (absent("dynamics diversity was not measured: it needs rendering and a trainer \
                         worker"))
                (diversity_errors(diversity, "dynamics"))
            }
        };
    };
    let mut groups: Vec<&str> = Vec::new();
    for f in &d.dynamics {
        if !groups.contains(&f.group.as_str()) {
            groups.push(&f.group);
        }
    }
    let lines: Vec<Line> = groups
        .iter()
        .map(|g| {
            let mut points: Vec<(f64, f64)> = d
                .dynamics
                .iter()
                .filter(|f| f.group == *g)
                .map(|f| (f64::from(f.train_episodes), f.eval_image_mse * 1e3))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Line {
                name: (*g).to_owned(),
                points,
            }
        })
        .collect();
    html! {
        section id="table-2" {
            h2 { "Dynamics diversity against episode budget (Table 2)" }
            (inline_svg(&figures::line_chart(
                "World-model error against training episodes",
                "episodes trained on",
                "evaluation image MSE ×10³",
                &lines,
            )))
            (table(&tables::dynamics_diversity(d)))
            p.caption {
                "Evaluation image MSE ×10³ of a world model trained on the group's first \
                 episodes, evaluated on all of them: lower means the group's dynamics are easier \
                 to learn (less diverse). "
                (crate::diversity::training_length(&d.dynamics[0].config))
                (crate::diversity::FEWER_THAN_BUDGET)
            }
            (diversity_errors(diversity, "dynamics"))
        }
    }
}

pub(super) fn table_3(g: Option<&GeneralizationResults>) -> Markup {
    let Some(g) = g else {
        return html! {
            section id="table-3" {
                h2 { "Generalization to held-out variations (Table 3)" }
                (absent("run with --generalization"))
            }
        };
    };
    let groups: Vec<String> = g.groups.iter().map(|x| x.group.clone()).collect();
    let side = |name: &str, f: fn(&GroupGeneralization) -> &Proportion| Bars {
        name: name.to_owned(),
        values: g.groups.iter().map(|x| f(x).rate).collect(),
        intervals: g.groups.iter().map(|x| f(x).ci95).collect(),
    };
    let series = [
        side("training variations", |x| &x.train),
        side("held-out variations", |x| &x.held_out),
    ];
    html! {
        section id="table-3" {
            h2 { "Generalization to held-out variations (Table 3)" }
            (inline_svg(&figures::bar_chart(&BarChart {
                title: "Success of the trained policy per group",
                y_desc: "success rate",
                categories: &groups,
                series: &series,
                y_range: Some((0.0, 1.0)),
            })))
            (table(&tables::generalization(g)))
            p.caption { (HELD_OUT_NOTE) }
            @for (group, e) in &g.errors {
                p.undefined { "Training for group " (group) " failed: " (e) }
            }
            @for x in &g.groups {
                @for e in x.errors.iter().take(3) {
                    p.undefined { (x.group) ": " (e) }
                }
            }
        }
    }
}

pub(super) fn ranking(inputs: &HtmlInputs<'_>, r: Option<&RankingResults>) -> Markup {
    let Some(r) = r else {
        return html! {
            section id="ranking" {
                h2 { "Policy ranking: predicted against real success" }
                (absent("run with --rank-train-policies P,… --rank-ladder: learned policies acting \
                         inside a world model trained on other policies' episodes; \
                         scripts/rank-learned takes about 18 minutes on 2 cores"))
            }
        };
    };
    let models = tables::proxy_models(r);
    let per_policy = tables::ranking_per_policy(r);
    let actions = tables::action_test(r);
    let repeats = tables::repeat_consistency(r);
    let agreement = tables::judge_agreement(r);
    let per_group = tables::ranking_per_group(r);
    html! {
        section id="ranking" {
            h2 { "Policy ranking: predicted against real success" }
            h3 { "What was compared" }
            (table(&tables::ranking_compared(r)))
            @if !models.rows.is_empty() {
                p.caption { "Per group, the world model and the frame judge:" }
                (table(&models))
            }
            @for caution in crate::ranking::late_frame_cautions(r) {
                p.undefined { strong { "Caution. " } (caution) }
            }
            @if let Some((caution, text)) = r.ladder_seeds.as_ref().map(|l| l.describe()) {
                @if caution {
                    p.undefined { strong { "Caution. " } (text) }
                } @else {
                    p.caption { (text) }
                }
            }
            @if !per_policy.rows.is_empty() {
                h3 { "Real and predicted success per policy" }
                p.caption { (PER_POLICY_NOTE) }
                (table(&per_policy))
            }
            @if !actions.rows.is_empty() {
                h3 { "Does the world model use its actions?" }
                p.caption { (ACTION_TEST_NOTE) }
                (table(&actions))
            }
            @if !repeats.rows.is_empty() {
                h3 { "Judge repeat consistency on imagined rollouts" }
                p.caption { (REPEAT_NOTE) }
                (table(&repeats))
            }
            @if !agreement.rows.is_empty() {
                h3 { "Judges' agreement" }
                p.caption { (JUDGE_AGREEMENT_NOTE) }
                (table(&agreement))
            }
            @if let Some(svg) = figures::ranking_reliability(r) {
                h3 { "Reliability of the predicted probabilities" }
                p.caption { (RELIABILITY_NOTE) }
                div.row {
                    (inline_svg(&svg))
                    div { (table(&tables::reliability(r))) }
                }
            }
            @match (&r.ranking, &r.ranking_missing) {
                (Some(rk), _) => {
                    @for (i, c) in rk.comparisons.iter().enumerate() {
                        h3 { (crate::ranking::source_title(&c.proxy)) " against " (c.real) }
                        @if let Some(note) = source_note(&c.proxy) {
                            p.caption { (note) }
                        }
                        div.row {
                            (inline_svg(&figures::ranking_labelled(rk, i, &r.labels)))
                            div {
                                (table(&tables::ranking_statistics(c)))
                                (table_if_any(&tables::ranking_policies(c, &r.labels)))
                            }
                        }
                        p.caption {
                            "Intervals: 95 % percentile bootstrap, " (rk.resamples)
                            " resamples, seed " (rk.seed) ": " (c.bootstrap.describe()) "."
                        }
                        @if c.retest.is_some() { p.caption { (RETEST_NOTE) } }
                        @if !c.notes.is_empty() || !c.excluded.is_empty() {
                            ul {
                                @for n in &c.notes { li { (n) } }
                                @for x in &c.excluded {
                                    li {
                                        "left out: task " (x.task.as_deref().unwrap_or("(all)"))
                                        ", policy " (x.policy) ": " (x.reason)
                                    }
                                }
                            }
                        }
                    }
                },
                (None, Some(why)) => p.absent { "No ranking: " (why) "." },
                (None, None) => p.absent { "No ranking." },
            }
            @if !per_group.rows.is_empty() {
                h3 { "Per task group" }
                p.caption { (PER_GROUP_NOTE) }
                (table(&per_group))
                div.row {
                    @for g in &r.per_group {
                        @if let Some(rk) = &g.ranking {
                            figure {
                                (inline_svg(&figures::ranking_labelled(rk, 0, &r.labels)))
                                figcaption {
                                    "group " (g.group) ": "
                                    (crate::ranking::source_title(&rk.comparisons[0].proxy))
                                }
                            }
                        }
                    }
                }
            }
            (imagined_rollouts(inputs, r))
            @if let Some(a) = &r.proxy_agreement {
                p { "Proxy verdicts matching the real outcome: " (cell(&proportion(a))) "." }
            }
            @if let Some(a) = &r.judge_agreement_real_frames {
                p { "The frame judge on the real last frames: " (cell(&proportion(a))) "." }
            }
            @if !r.rows.is_empty() {
                details {
                    summary { "Per task and policy" }
                    (table(&tables::ranking_rows(r)))
                }
            }
            @for (group, e) in &r.errors {
                p.undefined { "Proxy of group " (group) " failed: " (e) }
            }
            @if let Some((judge, task, policy, seed, e)) = r.judging_errors.first() {
                p.undefined {
                    (r.judging_errors.len()) " imagined rollouts could not be judged; the first: "
                    (judge) " on " (task) " / " (policy) " / seed " (seed) ": " (e)
                }
            }
        }
    }
}

/// Frames shown of an imagined rollout (the proxy stores [`assay_model::proxy::IMAGINED_KEYFRAMES`]).
const IMAGINED_SHOWN: usize = 8;

/// Per group and ranked policy (the ladder's in its order, then the others), the ranked episode
/// of the lowest seed as the world model imagined it, beside the same episode's keyframes in the
/// simulator: what the proxy's verdicts were taken on.
fn imagined_rollouts(inputs: &HtmlInputs<'_>, r: &RankingResults) -> Markup {
    let mut order: Vec<&str> = r
        .labels
        .iter()
        .map(|(p, _)| p.as_str())
        .filter(|p| r.ranked_policies.iter().any(|q| q == p))
        .collect();
    for p in &r.ranked_policies {
        if !order.contains(&p.as_str()) {
            order.push(p);
        }
    }
    let shown: Vec<(&str, &assay_model::proxy::ProxyPrediction)> = r
        .groups
        .iter()
        .flat_map(|g| {
            order.iter().filter_map(move |policy| {
                g.predictions
                    .iter()
                    .filter(|p| p.policy == *policy && !p.imagined_keyframes.is_empty())
                    .min_by_key(|p| (p.seed, p.task_id.clone()))
                    .map(|p| (g.group.as_str(), p))
            })
        })
        .collect();
    let real_episode = |p: &assay_model::proxy::ProxyPrediction| {
        inputs
            .report
            .results
            .tasks
            .iter()
            .filter(|t| t.id == p.task_id)
            .flat_map(|t| &t.episodes)
            .find(|e| e.seed == p.seed && e.policy == p.policy)
    };
    html! {
        @if !shown.is_empty() {
            h3 { "What the world model imagined" }
            p.caption { (IMAGINED_NOTE) }
            @for (group, p) in &shown {
                @let label = crate::view::policy_label(&p.policy, &r.labels)
                    .unwrap_or_else(|| p.policy.clone());
                @let real = real_episode(p);
                // The real episode's own frames at the imagined ones' indices, from its clip.
                @let clip = real
                    .and_then(|e| e.imagery.as_ref())
                    .and_then(|i| i.clip.as_deref())
                    .and_then(|key| (inputs.artifact)(key))
                    .and_then(|bytes| assay_model::clip::Clip::decode(&bytes).ok())
                    .filter(|c| !c.is_empty());
                div.imagined {
                    p {
                        b { (label) } ", group " (group) ", task " (p.task_id) ", seed " (p.seed)
                        ": in the simulator "
                        @match real.map(|e| e.success) {
                            Some(true) => span.ok { "a success" },
                            Some(false) => span.fail { "a failure" },
                            None => span.missing { "not in this report" },
                        }
                        "; in the world model "
                        @if p.success { span.ok { "a success" } } @else { span.fail { "a failure" } }
                        " (frame judge " (format!("{:.2}", p.p_success))
                        @if let Some(c) = p.p_calibrated { ", calibrated " (format!("{c:.2}")) }
                        "; " (p.imagined_frames) " frames, "
                        (if p.done_by_judge { "stopped by the judge" } else { "to the step budget" })
                        ")"
                    }
                    div {
                        @for i in super::tasks::spaced(p.imagined_keyframes.len(), IMAGINED_SHOWN) {
                            @let k = &p.imagined_keyframes[i];
                            (super::tasks::thumb_figure(inputs, &k.artifact, &format!("imagined, frame {}", k.step)))
                        }
                    }
                    @if let Some(c) = &clip {
                        div {
                            @for i in super::tasks::spaced(p.imagined_keyframes.len(), IMAGINED_SHOWN) {
                                @let step = p.imagined_keyframes[i].step as usize;
                                @let t = step.min(c.len() - 1);
                                (super::tasks::rgb_figure(
                                    c.frame(t),
                                    c.width,
                                    c.height,
                                    &if t < step {
                                        format!("real, frame {t} (its last)")
                                    } else {
                                        format!("real, frame {t}")
                                    },
                                ))
                            }
                        }
                    } @else if let Some(img) = real.and_then(|e| e.imagery.as_ref()) {
                        div {
                            @for i in super::tasks::spaced(img.keyframes.len(), IMAGINED_SHOWN) {
                                @let k = &img.keyframes[i];
                                (super::tasks::thumb_figure(
                                    inputs,
                                    &k.artifact,
                                    &format!("real, step {} ({})", k.step, k.camera),
                                ))
                            }
                        }
                    }
                }
            }
        }
    }
}

/// What [`imagined_rollouts`] shows.
const IMAGINED_NOTE: &str = "Per group and ranked policy, its ranked episode of the lowest \
seed: first row, the rollout the policy acted out inside the world model, from the real first \
frame (frame 0) to the frame the verdict was taken on, at the clips' size and camera, enlarged; \
second row, the same episode in the simulator at the same frames, from its dynamics clip (where \
the real episode ended sooner, its last frame) — or, for an episode without a clip, its \
keyframes from the render role's camera and steps.";
