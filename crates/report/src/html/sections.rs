//! The papers' views in `report.html`: figures 3 and 4, Tables 1, 2 and 3, and the policy
//! ranking, each a section with its figure and table.

use std::fmt::Write as _;

use super::*;

pub(super) fn figure_4(quality: Option<&QualityResults>) -> String {
    let mut out = String::from(
        "<section id=\"figure-4\">\n<h2>Figure 4: scene alignment against task completion</h2>\n",
    );
    let Some(q) = quality else {
        out.push_str(&absent("no judge ran: run with --judge"));
        out.push_str("</section>\n");
        return out;
    };
    let points = q.scene_points();
    out.push_str(&inline_svg(&figures::scene_vs_completion(&points)));
    let judges: Vec<String> = q
        .judges
        .iter()
        .enumerate()
        .map(|(i, j)| {
            format!(
                "{} ({})",
                esc(&j.judge),
                if i == 0 { "filled" } else { "outline" }
            )
        })
        .collect();
    let _ = writeln!(
        out,
        "<p class=\"caption\">One marker per (task, judge): the judge's mean scene alignment (1–5, \
         from the 4 views of the initial scene) against its mean task completion (0–10, from the \
         8 keyframes). Colour: the task's group. Size: the variance of the scores — {}. Judges: \
         {}. {} markers.</p>",
        esc(figures::SPREAD_RULE),
        if judges.is_empty() {
            "none".into()
        } else {
            judges.join(", ")
        },
        points.len()
    );
    out.push_str("<table>\n<tr><th>judge</th><th>backend / model</th><th>episodes judged</th>\
                  <th>scene alignment</th><th>completion</th><th>failed / unjudged items</th></tr>\n");
    for j in &q.judges {
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{} / {}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td class=\"n\">{}</td><td class=\"n\">{} / {}</td></tr>",
            esc(&j.judge),
            esc(&j.backend),
            esc(&j.model),
            j.episodes_judged,
            score(&j.scene_alignment),
            score(&j.completion),
            j.episodes_failed,
            j.items_unjudged
        );
    }
    out.push_str("</table>\n</section>\n");
    out
}

/// One judge's agreement with one reference, for figure 3.
pub(super) struct AgreementLine<'a> {
    judge: &'a str,
    reference: String,
    group: Option<&'a str>,
    agreement: &'a Agreement,
}

pub(super) fn figure_3(quality: Option<&QualityResults>, human: Option<&AgreementTable>) -> String {
    let mut out = String::from("<section id=\"figure-3\">\n<h2>Figure 3: judge agreement</h2>\n");
    let mut lines: Vec<AgreementLine<'_>> = Vec::new();
    if let Some(q) = quality {
        for j in &q.judges {
            if let Some(a) = &j.vs_sim {
                lines.push(AgreementLine {
                    judge: &j.judge,
                    reference: "simulator".into(),
                    group: None,
                    agreement: a,
                });
            }
        }
    }
    if let Some(h) = human {
        for row in &h.rows {
            lines.push(AgreementLine {
                judge: &row.judge,
                reference: format!("humans ({})", h.reference),
                group: row.group.as_deref(),
                agreement: &row.agreement,
            });
        }
    }
    if lines.is_empty() {
        if quality.is_none() {
            out.push_str(&absent("no judge ran: run with --judge"));
        } else {
            out.push_str(&absent(
                "no judge has an agreement with the simulator; human ratings: run with --human-ratings",
            ));
        }
        out.push_str("</section>\n");
        return out;
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
                };
                Bars {
                    name: format!("against {reference}"),
                    values: judges
                        .iter()
                        .map(|j| find(j).and_then(|l| defined(stat(l.agreement))))
                        .collect(),
                    intervals: judges
                        .iter()
                        .map(|j| find(j).and_then(|l| stat(l.agreement).ci95))
                        .collect(),
                }
            })
            .collect()
    };
    out.push_str("<div class=\"row\">\n");
    out.push_str(&inline_svg(&figures::bar_chart(&BarChart {
        title: "Pearson r per judge",
        y_desc: "Pearson r",
        categories: &judges,
        series: &series(|a| &a.pearson),
        y_range: Some((-1.0, 1.0)),
    })));
    out.push_str(&inline_svg(&figures::bar_chart(&BarChart {
        title: "Mean absolute error per judge",
        y_desc: "MAE",
        categories: &judges,
        series: &series(|a| &a.mae),
        y_range: None,
    })));
    out.push_str(
        "</div>\n<table>\n<tr><th>judge</th><th>against</th><th>group</th><th>n</th>\
                  <th>Pearson r [95 % CI]</th><th>MAE [95 % CI]</th><th>Spearman ρ</th>\
                  <th>Kendall τ</th></tr>\n",
    );
    for l in &lines {
        let a = l.agreement;
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            esc(l.judge),
            esc(&l.reference),
            esc(l.group.unwrap_or("all")),
            a.n,
            estimate(&a.pearson),
            estimate(&a.mae),
            estimate(&a.spearman),
            estimate(&a.kendall)
        );
    }
    out.push_str(
        "</table>\n<p class=\"caption\">Bars: over all rated items, with 95 % bootstrap intervals; \
         n/a marks a statistic that is undefined (its reason is in the table). Against the \
         simulator: the judge's completion score against the simulator's success.</p>\n",
    );
    if human.is_none() {
        out.push_str(&absent("human ratings: run with --human-ratings"));
    }
    out.push_str("</section>\n");
    out
}

pub(super) fn table_1(diversity: Option<&crate::diversity::DiversityResults>) -> String {
    let mut out = String::from("<section id=\"table-1\">\n<h2>Table 1: text diversity</h2>\n");
    let Some(t) = diversity.and_then(|d| d.text.as_ref()) else {
        out.push_str(&absent(
            "text diversity was not measured: run without --no-diversity",
        ));
        out.push_str(&diversity_errors(diversity, "text"));
        out.push_str("</section>\n");
        return out;
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
    out.push_str(&inline_svg(&figures::bar_chart(&BarChart {
        title: "Text diversity per group and embedding model",
        y_desc: "diversity",
        categories: &groups,
        series: &series,
        y_range: None,
    })));
    out.push_str("<table>\n<tr><th>group</th><th>texts</th>");
    for m in &t.models {
        let _ = write!(
            out,
            "<th>{} <small>({}, {} d)</small></th>",
            esc(&m.name),
            esc(&m.model),
            m.dimensions
        );
    }
    out.push_str("</tr>\n");
    for r in &t.rows {
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"n\">{}</td>",
            esc(&r.group),
            r.n
        );
        for m in 0..t.models.len() {
            let cell = match (
                r.div.get(m).copied().flatten(),
                r.errors.get(m).cloned().flatten(),
            ) {
                (Some(v), _) => format!("{v:.3}"),
                (None, Some(e)) => format!("<span class=\"undefined\">{}</span>", esc(&e)),
                (None, None) => "–".into(),
            };
            let _ = write!(out, "<td class=\"n\">{cell}</td>");
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</table>\n");
    out.push_str(&diversity_errors(diversity, "text"));
    out.push_str("</section>\n");
    out
}

/// The diversity shards that failed whose name starts with `prefix`.
pub(super) fn diversity_errors(
    d: Option<&crate::diversity::DiversityResults>,
    prefix: &str,
) -> String {
    let Some(d) = d else {
        return String::new();
    };
    let errors: Vec<&(String, String)> = d
        .errors
        .iter()
        .filter(|(w, _)| w.starts_with(prefix))
        .collect();
    if errors.is_empty() {
        return String::new();
    }
    let mut out = String::from("<ul class=\"errors\">\n");
    for (what, e) in errors {
        let _ = writeln!(out, "<li>{} failed: {}</li>", esc(what), esc(e));
    }
    out.push_str("</ul>\n");
    out
}

pub(super) fn table_2(diversity: Option<&crate::diversity::DiversityResults>) -> String {
    let mut out = String::from("<section id=\"table-2\">\n<h2>Table 2: dynamics diversity</h2>\n");
    let Some(d) = diversity.filter(|d| !d.dynamics.is_empty()) else {
        out.push_str(&absent(
            "dynamics diversity was not measured: it needs rendering and a trainer worker",
        ));
        out.push_str(&diversity_errors(diversity, "dynamics"));
        out.push_str("</section>\n");
        return out;
    };
    let mut groups: Vec<&str> = Vec::new();
    for f in &d.dynamics {
        if !groups.contains(&f.group.as_str()) {
            groups.push(&f.group);
        }
    }
    let mut budgets: Vec<u32> = d.dynamics.iter().map(|f| f.budget).collect();
    budgets.sort_unstable();
    budgets.dedup();
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
    out.push_str(&inline_svg(&figures::line_chart(
        "World-model error against training episodes",
        "episodes trained on",
        "evaluation image MSE ×10³",
        &lines,
    )));
    out.push_str("<table>\n<tr><th>group</th><th>evaluated on</th>");
    for b in &budgets {
        let _ = write!(out, "<th>{b} episodes</th>");
    }
    out.push_str("</tr>\n");
    for g in &groups {
        let fits: Vec<&assay_model::dynamics::DynamicsFit> =
            d.dynamics.iter().filter(|f| f.group == *g).collect();
        let eval = fits.iter().map(|f| f.eval_episodes).max().unwrap_or(0);
        let _ = write!(out, "<tr><td>{}</td><td class=\"n\">{eval}</td>", esc(g));
        for b in &budgets {
            let cell = match fits.iter().find(|f| f.budget == *b) {
                Some(f) if f.train_episodes < f.budget => format!(
                    "{:.3} ({} trained)",
                    f.eval_image_mse * 1e3,
                    f.train_episodes
                ),
                Some(f) => format!("{:.3}", f.eval_image_mse * 1e3),
                None => "–".into(),
            };
            let _ = write!(out, "<td class=\"n\">{cell}</td>");
        }
        out.push_str("</tr>\n");
    }
    out.push_str(
        "</table>\n<p class=\"caption\">Evaluation image MSE ×10³ of a world model trained on the \
         group's first episodes, evaluated on all of them: lower means the group's dynamics are \
         easier to learn (less diverse). A group with fewer episodes than a budget is fitted once \
         on all of them (\"n trained\").</p>\n",
    );
    out.push_str(&diversity_errors(diversity, "dynamics"));
    out.push_str("</section>\n");
    out
}

pub(super) fn table_3(g: Option<&crate::generalization::GeneralizationResults>) -> String {
    let mut out =
        String::from("<section id=\"table-3\">\n<h2>Table 3: generalization per group</h2>\n");
    let Some(g) = g else {
        out.push_str(&absent("run with --generalization"));
        out.push_str("</section>\n");
        return out;
    };
    let groups: Vec<String> = g.groups.iter().map(|x| x.group.clone()).collect();
    let side =
        |name: &str, f: fn(&crate::generalization::GroupGeneralization) -> &Proportion| Bars {
            name: name.to_owned(),
            values: g.groups.iter().map(|x| f(x).rate).collect(),
            intervals: g.groups.iter().map(|x| f(x).ci95).collect(),
        };
    let series = [
        side("training variations", |x| &x.train),
        side("held-out variations", |x| &x.held_out),
    ];
    out.push_str(&inline_svg(&figures::bar_chart(&BarChart {
        title: "Success of the trained policy per group",
        y_desc: "success rate",
        categories: &groups,
        series: &series,
        y_range: Some((0.0, 1.0)),
    })));
    out.push_str(
        "<table>\n<tr><th>group</th><th>model</th><th>training variations</th>\
                  <th>held-out variations</th><th>notes</th></tr>\n",
    );
    for x in &g.groups {
        let mut notes = Vec::new();
        if x.did_not_learn() {
            notes.push("did not learn its training variations: the held-out rate says nothing about generalization".to_owned());
        }
        if x.pending > 0 {
            notes.push(format!("{} episodes pending", x.pending));
        }
        for e in &x.errors {
            notes.push(esc(e));
        }
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            esc(&x.group),
            esc(&x.model),
            prop(&x.train),
            prop(&x.held_out),
            notes.join("; ")
        );
    }
    out.push_str("</table>\n");
    for (group, e) in &g.errors {
        let _ = writeln!(
            out,
            "<p class=\"undefined\">Training for group {} failed: {}</p>",
            esc(group),
            esc(e)
        );
    }
    out.push_str("</section>\n");
    out
}

pub(super) fn ranking(r: Option<&crate::ranking::RankingResults>) -> String {
    let mut out = String::from("<section id=\"ranking\">\n<h2>Policy ranking</h2>\n");
    let Some(r) = r else {
        out.push_str(&absent("run with --rank-train-policies"));
        out.push_str("</section>\n");
        return out;
    };
    let _ = writeln!(
        out,
        "<p>Ranked: {}. World model and frame judge trained on the episodes of: {}.</p>",
        esc(&r.ranked_policies.join(", ")),
        esc(&r.train_policies.join(", "))
    );
    match (&r.ranking, &r.ranking_missing) {
        (Some(rk), _) => {
            for (i, c) in rk.comparisons.iter().enumerate() {
                let _ = writeln!(
                    out,
                    "<h3>{} against {}</h3>\n<div class=\"row\">",
                    esc(&c.proxy),
                    esc(&c.real)
                );
                out.push_str(&inline_svg(&figures::ranking(rk, i)));
                out.push_str("<table>\n<tr><th>statistic</th><th>value [95 % CI]</th></tr>\n");
                for (name, e) in c.statistics() {
                    let _ = writeln!(
                        out,
                        "<tr><td>{}</td><td class=\"n\">{}</td></tr>",
                        esc(name),
                        estimate(e)
                    );
                }
                let _ = writeln!(
                    out,
                    "<tr><td>policies / tasks</td><td class=\"n\">{} / {}</td></tr>\n</table>\n</div>",
                    c.policies.len(),
                    c.tasks.len()
                );
                if !c.notes.is_empty() || !c.excluded.is_empty() {
                    out.push_str("<ul>\n");
                    for n in &c.notes {
                        let _ = writeln!(out, "<li>{}</li>", esc(n));
                    }
                    for x in &c.excluded {
                        let _ = writeln!(
                            out,
                            "<li>left out: task {}, policy {}: {}</li>",
                            esc(x.task.as_deref().unwrap_or("(all)")),
                            esc(&x.policy),
                            esc(&x.reason)
                        );
                    }
                    out.push_str("</ul>\n");
                }
            }
        }
        (None, Some(why)) => {
            let _ = writeln!(out, "<p class=\"absent\">No ranking: {}.</p>", esc(why));
        }
        (None, None) => out.push_str("<p class=\"absent\">No ranking.</p>\n"),
    }
    if let Some(a) = &r.proxy_agreement {
        let _ = writeln!(
            out,
            "<p>Proxy verdicts matching the real outcome: {}.</p>",
            prop(a)
        );
    }
    if let Some(a) = &r.judge_agreement_real_frames {
        let _ = writeln!(
            out,
            "<p>The frame judge on the real last frames: {}.</p>",
            prop(a)
        );
    }
    if !r.rows.is_empty() {
        out.push_str(
            "<details><summary>Per task and policy</summary>\n<table>\n<tr><th>task</th>\
                      <th>policy</th><th>real (sim)</th><th>world-model proxy</th></tr>\n",
        );
        for row in &r.rows {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
                esc(&row.task_id),
                esc(&row.policy),
                prop(&row.real),
                row.proxy.as_ref().map_or("–".into(), prop)
            );
        }
        out.push_str("</table>\n</details>\n");
    }
    for (group, e) in &r.errors {
        let _ = writeln!(
            out,
            "<p class=\"undefined\">Proxy of group {} failed: {}</p>",
            esc(group),
            esc(e)
        );
    }
    out.push_str("</section>\n");
    out
}
