//! `report.html`: one self-contained page with the paper's views of a batch — per-group success,
//! scene alignment against completion (figure 4), judge agreement (figure 3), text and dynamics
//! diversity (Tables 1 and 2), generalization (Table 3), policy ranking, invalid tasks, and one
//! page per task with its scene views, keyframes and scores.
//!
//! Owns: the page. Never fetches anything and never makes the browser fetch anything: figures are
//! inline SVG ([`crate::figures`]), pictures are `data:` URIs of downscaled thumbnails, there is no
//! script and no external font or style; the per-task "pages" are sections shown by CSS
//! `:target`. Never does IO itself: artifacts come through [`HtmlInputs::artifact`]. Every text
//! from the report is HTML-escaped. Deterministic: the same inputs give the same bytes.

use std::fmt::Write as _;

use base64::Engine as _;

use crate::agreement::{Agreement, AgreementTable, Estimate};
use crate::figures::{self, BarChart, Bars, Line};
use crate::quality::ScoreStats;
use crate::quality_report::{QualityResults, TaskQuality};
use crate::report::{EpisodeImagery, Report, RunInfo, TaskResult};
use crate::stats::Proportion;

/// What the page is made from.
pub struct HtmlInputs<'a> {
    pub report: &'a Report,
    /// Bytes of an artifact by its key (`imagery/<sha>.png`), None when missing (the page then
    /// says so, no broken `<img>`).
    pub artifact: &'a dyn Fn(&str) -> Option<Vec<u8>>,
    /// Human ratings agreement (figure 3), when the user gave ratings.
    pub human: Option<&'a AgreementTable>,
}

/// Width of the thumbnails, pixels.
pub const THUMB_WIDTH: u32 = 192;

/// Keyframes shown per task (of the 8 a render role draws), evenly spaced, the last included.
pub const KEYFRAMES_SHOWN: usize = 8;

const STYLE: &str = "\
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:0 auto;max-width:1200px;\
padding:0 16px 48px;color:#1a1a1a;background:#fff;line-height:1.4}\
header{border-bottom:1px solid #ccc;padding:8px 0}\
nav{position:sticky;top:0;background:#f6f6f6;border-bottom:1px solid #ccc;padding:6px 8px;\
z-index:1}nav a{margin-right:14px}\
table{border-collapse:collapse;margin:8px 0 16px}\
th,td{border:1px solid #ddd;padding:3px 8px;text-align:left;vertical-align:top}\
td.n{text-align:right;font-variant-numeric:tabular-nums}th{background:#f2f2f2}\
.fig{margin:8px 0}.fig svg{max-width:100%}.row{display:flex;flex-wrap:wrap;gap:16px;\
align-items:flex-start}\
.absent,.missing{color:#8a5a00;font-style:italic}.undefined{color:#8a5a00}\
figure.thumb{display:inline-block;margin:4px;text-align:center;font-size:12px}\
figure.thumb img{display:block;border:1px solid #ccc}\
section.task{display:none;border-top:2px solid #888;margin-top:24px}\
section.task:target{display:block}\
.ok{color:#1a7f37}.fail{color:#b3261e}caption,.caption{font-size:13px;color:#444;\
text-align:left;max-width:680px}";

/// The page.
pub fn report_html(inputs: &HtmlInputs<'_>) -> String {
    let r = &inputs.report.results;
    let mut out = String::new();
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>Assay report: {}</title>\n<link rel=\"icon\" href=\"data:,\">\n\
         <style>{STYLE}</style>\n</head>\n<body>\n",
        esc(&r.batch_name)
    );
    out.push_str(&header(inputs.report));
    out.push_str(
        "<nav><a href=\"#overview\">Overview</a><a href=\"#figure-4\">Figure 4</a>\
         <a href=\"#figure-3\">Figure 3</a><a href=\"#table-1\">Table 1</a>\
         <a href=\"#table-2\">Table 2</a><a href=\"#table-3\">Table 3</a>\
         <a href=\"#ranking\">Ranking</a><a href=\"#invalid\">Invalid tasks</a>\
         <a href=\"#tasks\">Tasks</a></nav>\n<main>\n",
    );
    out.push_str(&overview(inputs.report));
    out.push_str(&figure_4(r.quality.as_ref()));
    out.push_str(&figure_3(r.quality.as_ref(), inputs.human));
    out.push_str(&table_1(r.diversity.as_ref()));
    out.push_str(&table_2(r.diversity.as_ref()));
    out.push_str(&table_3(r.generalization.as_ref()));
    out.push_str(&ranking(r.ranking.as_ref()));
    out.push_str(&invalid(inputs.report));
    out.push_str(&task_index(inputs.report));
    for t in &r.tasks {
        out.push_str(&task_page(inputs, t));
    }
    out.push_str("</main>\n</body>\n</html>\n");
    out
}

/// Text for HTML content and attribute values.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// The id of a task's section: `task-` and the task id with every character other than ASCII
/// letters, digits, `-` and `.` written `_xx` (hex), so any id gives a distinct fragment that
/// needs no escaping.
fn task_anchor(id: &str) -> String {
    let mut out = String::from("task-");
    for c in id.chars() {
        if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
            out.push(c);
        } else {
            let mut buf = [0u8; 4];
            for b in c.encode_utf8(&mut buf).bytes() {
                let _ = write!(out, "_{b:02x}");
            }
        }
    }
    out
}

fn absent(what: &str) -> String {
    format!(
        "<p class=\"absent\">Not in this batch ({}).</p>\n",
        esc(what)
    )
}

fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => "–".into(),
    }
}

/// `80 % (4/5), 95 % CI 38–96 %`, or `–` without trials.
fn prop(p: &Proportion) -> String {
    match (p.rate, p.ci95) {
        (Some(r), Some([lo, hi])) => format!(
            "{:.0} % ({}/{}), 95 % CI {:.0}–{:.0} %",
            r * 100.0,
            p.successes,
            p.trials,
            lo * 100.0,
            hi * 100.0
        ),
        (Some(r), None) => format!("{:.0} % ({}/{})", r * 100.0, p.successes, p.trials),
        _ => "–".into(),
    }
}

/// An estimate with its interval; an undefined one as `undefined — reason`, never 0 or NaN.
fn estimate(e: &Estimate) -> String {
    match e.value {
        Some(v) if v.is_finite() => {
            let mut s = format!("{v:.3}");
            match (e.ci95, &e.no_interval) {
                (Some([lo, hi]), _) => {
                    let _ = write!(s, " [{lo:.3}, {hi:.3}]");
                }
                (None, Some(why)) => {
                    let _ = write!(s, " (no interval: {})", esc(why));
                }
                (None, None) => {}
            }
            s
        }
        _ => format!(
            "<span class=\"undefined\">undefined — {}</span>",
            esc(e.undefined.as_deref().unwrap_or("no value"))
        ),
    }
}

fn defined(e: &Estimate) -> Option<f64> {
    e.value.filter(|v| v.is_finite())
}

fn score(s: &ScoreStats) -> String {
    match s.mean {
        Some(m) => format!("{m:.2} (var {}, n {})", num(s.variance, 2), s.n),
        None => "–".into(),
    }
}

/// An SVG string placed in the page (without an XML prolog, if the drawer wrote one).
fn inline_svg(svg: &str) -> String {
    let body = match svg.trim_start().strip_prefix("<?xml") {
        Some(rest) => rest.split_once("?>").map_or("", |(_, b)| b),
        None => svg,
    };
    format!("<div class=\"fig\">{}</div>\n", body.trim())
}

/// Formats unix milliseconds as UTC `YYYY-MM-DD hh:mm:ss`.
fn utc(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

fn header(report: &Report) -> String {
    let r = &report.results;
    let t = &r.totals;
    let mut out = format!(
        "<header>\n<h1>{}</h1>\n<p>{} tasks ({} invalid), policies {}, seeds {}. Episodes: {} \
         planned, {} completed, {} failed, {} cancelled; {} simulated steps.</p>\n\
         <p><strong>Success (simulator ground truth, all policies): {}</strong></p>\n",
        esc(&r.batch_name),
        t.tasks,
        t.invalid_tasks,
        esc(&r.policies.join(", ")),
        esc(&r
            .seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(", ")),
        t.episodes_planned,
        t.episodes_completed,
        t.episodes_failed,
        t.episodes_cancelled,
        t.sim_steps,
        prop(&t.success)
    );
    if r.by_policy.len() > 1 {
        out.push_str("<ul>\n");
        for p in &r.by_policy {
            let _ = writeln!(out, "<li>{}: {}</li>", esc(&p.policy), prop(&p.success));
        }
        out.push_str("</ul>\n");
    }
    out.push_str(&provenance_section(&report.run, &report.provenance));
    out.push_str("</header>\n");
    out
}

/// Where the run happened and how long it took: the report's `run` part (ids, timing, workers).
/// The place for provenance (code versions, machine, configuration) when the report carries it.
pub fn provenance_section(run: &RunInfo, p: &crate::report::Provenance) -> String {
    let mut out =
        String::from("<details id=\"provenance\"><summary>Run and provenance</summary>\n<table>\n");
    let mut row = |k: &str, v: String| {
        let _ = writeln!(out, "<tr><th>{k}</th><td>{v}</td></tr>");
    };
    row("batch id", esc(&run.batch_id));
    row("state", esc(&run.state));
    row("submitted", utc(run.submitted_at_unix_ms));
    row("finished", run.finished_at_unix_ms.map_or("–".into(), utc));
    row(
        "wall time",
        run.wall_time_s.map_or("–".into(), |s| format!("{s:.1} s")),
    );
    row("episodes / s", num(run.episodes_per_s, 3));
    row("simulated steps / s", num(run.sim_steps_per_s, 1));
    row("extra attempts", run.extra_attempts.to_string());
    row(
        "workers",
        format!("{} ({})", run.workers.len(), esc(&run.workers.join(", "))),
    );
    for (what, values) in p.rows() {
        let value = match values.as_slice() {
            [] => "–".to_owned(),
            [hash] if what.contains("SHA-256") => format!("<code>{}</code>", esc(hash)),
            v => v.iter().map(|x| esc(x)).collect::<Vec<_>>().join("<br>"),
        };
        row(what, value);
    }
    out.push_str("</table>\n</details>\n");
    out
}

fn overview(report: &Report) -> String {
    let r = &report.results;
    let mut out = String::from(
        "<section id=\"overview\">\n<h2>Overview: success per group</h2>\n\
         <table>\n<tr><th>group</th><th>tasks</th><th>all policies</th>",
    );
    let multi = r.policies.len() > 1;
    if multi {
        for p in &r.policies {
            let _ = write!(out, "<th>{}</th>", esc(p));
        }
    }
    out.push_str("</tr>\n");
    let per_policy = |out: &mut String, rows: &[crate::report::PolicySuccess]| {
        if multi {
            for p in &r.policies {
                let cell = rows
                    .iter()
                    .find(|x| &x.policy == p)
                    .map_or("–".into(), |x| prop(&x.success));
                let _ = write!(out, "<td class=\"n\">{cell}</td>");
            }
        }
    };
    for g in &r.groups {
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>",
            esc(&g.group),
            g.tasks,
            prop(&g.success)
        );
        per_policy(&mut out, &g.by_policy);
        out.push_str("</tr>\n");
    }
    let _ = write!(
        out,
        "<tr><th>all</th><th class=\"n\">{}</th><th class=\"n\">{}</th>",
        r.totals.tasks,
        prop(&r.totals.success)
    );
    per_policy(&mut out, &r.by_policy);
    out.push_str(
        "</tr>\n</table>\n<p class=\"caption\">Success is the simulator's ground truth (goal \
         predicates) over completed episodes, with the 95 % Wilson interval.</p>\n</section>\n",
    );
    out
}

fn figure_4(quality: Option<&QualityResults>) -> String {
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
struct AgreementLine<'a> {
    judge: &'a str,
    reference: String,
    group: Option<&'a str>,
    agreement: &'a Agreement,
}

fn figure_3(quality: Option<&QualityResults>, human: Option<&AgreementTable>) -> String {
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

fn table_1(diversity: Option<&crate::trainer::DiversityResults>) -> String {
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
fn diversity_errors(d: Option<&crate::trainer::DiversityResults>, prefix: &str) -> String {
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

fn table_2(diversity: Option<&crate::trainer::DiversityResults>) -> String {
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
        let fits: Vec<&crate::dynamics::DynamicsFit> =
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

fn table_3(g: Option<&crate::generalization::GeneralizationResults>) -> String {
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

fn ranking(r: Option<&crate::proxy::RankingResults>) -> String {
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
                out.push_str(&inline_svg(&rk.svg(i)));
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

fn invalid(report: &Report) -> String {
    let mut out = String::from("<section id=\"invalid\">\n<h2>Invalid tasks</h2>\n");
    let errors = &report.results.invalid_tasks;
    if errors.is_empty() {
        out.push_str("<p>None: every task spec was valid.</p>\n</section>\n");
        return out;
    }
    out.push_str("<table>\n<tr><th>task</th><th>origin</th><th>field</th><th>reason</th></tr>\n");
    for e in errors {
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{}</td><td><code>{}</code></td><td>{}</td></tr>",
            esc(e.task.as_deref().unwrap_or("–")),
            esc(&e.origin),
            esc(&e.path),
            esc(&e.reason)
        );
    }
    out.push_str("</table>\n</section>\n");
    out
}

fn judges_of(report: &Report) -> Vec<&str> {
    report
        .results
        .quality
        .as_ref()
        .map(|q| q.judges.iter().map(|j| j.judge.as_str()).collect())
        .unwrap_or_default()
}

fn task_quality<'a>(report: &'a Report, task: &str) -> Vec<&'a TaskQuality> {
    report
        .results
        .quality
        .as_ref()
        .map(|q| q.tasks.iter().filter(|t| t.task_id == task).collect())
        .unwrap_or_default()
}

fn task_index(report: &Report) -> String {
    let judges = judges_of(report);
    let mut out = String::from(
        "<section id=\"tasks\">\n<h2>Tasks</h2>\n<p class=\"caption\">Open a task for its scene \
         views, keyframes and scores. Judge columns: mean scene alignment (1–5) / mean \
         completion (0–10).</p>\n<table>\n<tr><th>task</th><th>group</th><th>success</th>",
    );
    for j in &judges {
        let _ = write!(out, "<th>{}</th>", esc(j));
    }
    out.push_str("</tr>\n");
    for t in &report.results.tasks {
        let _ = write!(
            out,
            "<tr><td><a href=\"#{}\">{}</a></td><td>{}</td><td class=\"n\">{}</td>",
            task_anchor(&t.id),
            esc(&t.id),
            esc(&t.group),
            prop(&t.success)
        );
        let tq = task_quality(report, &t.id);
        for j in &judges {
            let cell = tq.iter().find(|q| q.judge == *j).map_or("–".into(), |q| {
                format!(
                    "{} / {}",
                    num(q.scene_alignment.mean, 1),
                    num(q.completion.mean, 1)
                )
            });
            let _ = write!(out, "<td class=\"n\">{cell}</td>");
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</table>\n</section>\n");
    out
}

fn task_page(inputs: &HtmlInputs<'_>, t: &TaskResult) -> String {
    let mut out = format!(
        "<section class=\"task\" id=\"{}\">\n<h2>Task {}</h2>\n<p><a href=\"#tasks\">← all \
         tasks</a></p>\n<table>\n",
        task_anchor(&t.id),
        esc(&t.name)
    );
    for (k, v) in [
        ("id", &t.id),
        ("name", &t.name),
        ("group", &t.group),
        ("pipeline", &t.pipeline),
        ("origin", &t.origin),
        ("spec hash", &t.spec_hash),
    ] {
        let _ = writeln!(out, "<tr><th>{k}</th><td>{}</td></tr>", esc(v));
    }
    let _ = writeln!(
        out,
        "<tr><th>success</th><td>{}</td></tr>\n</table>",
        prop(&t.success)
    );
    if t.by_policy.len() > 1 {
        out.push_str("<h3>Success by policy</h3>\n<table>\n");
        for p in &t.by_policy {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td class=\"n\">{}</td></tr>",
                esc(&p.policy),
                prop(&p.success)
            );
        }
        out.push_str("</table>\n");
    }
    if !t.predicates.is_empty() {
        out.push_str(
            "<h3>Goal predicates</h3>\n<table>\n<tr><th>predicate</th><th>held</th></tr>\n",
        );
        for p in &t.predicates {
            let _ = writeln!(
                out,
                "<tr><td><code>{}</code></td><td class=\"n\">{} / {}</td></tr>",
                esc(&p.label),
                p.holds,
                p.of
            );
        }
        out.push_str("</table>\n");
    }
    match t
        .episodes
        .iter()
        .find_map(|e| e.imagery.as_ref().map(|i| (e, i)))
    {
        Some((e, imagery)) => {
            let _ = writeln!(
                out,
                "<h3>Pictures of episode seed {}, policy {}</h3>",
                e.seed,
                esc(&e.policy)
            );
            out.push_str(&pictures(inputs, imagery));
        }
        None => out
            .push_str("<p class=\"absent\">No pictures: the batch did not render this task.</p>\n"),
    }
    let tq = task_quality(inputs.report, &t.id);
    if !tq.is_empty() {
        out.push_str(
            "<h3>Judges</h3>\n<table>\n<tr><th>judge</th><th>scene alignment (1–5)</th>\
                      <th>completion (0–10)</th><th>unjudged</th><th>errors</th></tr>\n",
        );
        for q in &tq {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td>{}</td></tr>",
                esc(&q.judge),
                score(&q.scene_alignment),
                score(&q.completion),
                q.unjudged,
                esc(&q.errors.join("; "))
            );
        }
        out.push_str("</table>\n");
    }
    let failed: Vec<_> = t.episodes.iter().filter(|e| !e.success).collect();
    if !failed.is_empty() {
        out.push_str(
            "<h3>Unsuccessful episodes</h3>\n<table>\n<tr><th>seed</th><th>policy</th>\
                      <th>unmet predicates</th></tr>\n",
        );
        for e in failed {
            let unmet: Vec<String> = e
                .unmet
                .iter()
                .map(|p| format!("<code>{}</code>: {}", esc(&p.label), esc(&p.detail)))
                .collect();
            let _ = writeln!(
                out,
                "<tr><td class=\"n\">{}</td><td>{}</td><td>{}</td></tr>",
                e.seed,
                esc(&e.policy),
                unmet.join("<br>")
            );
        }
        out.push_str("</table>\n");
    }
    if !t.failures.is_empty() {
        out.push_str(
            "<h3>Episodes that did not finish</h3>\n<table>\n<tr><th>seed</th>\
                      <th>policy</th><th>attempts</th><th>error</th></tr>\n",
        );
        for f in &t.failures {
            let _ = writeln!(
                out,
                "<tr><td class=\"n\">{}</td><td>{}</td><td class=\"n\">{}</td><td>{}{}</td></tr>",
                f.seed,
                esc(&f.policy),
                f.attempts,
                if f.cancelled { "(cancelled) " } else { "" },
                esc(&f.error)
            );
        }
        out.push_str("</table>\n");
    }
    out.push_str("</section>\n");
    out
}

/// Indices of `shown` of `n` items, evenly spaced, first and last included.
fn spaced(n: usize, shown: usize) -> Vec<usize> {
    if n <= shown {
        return (0..n).collect();
    }
    if shown <= 1 {
        return vec![n - 1];
    }
    (0..shown).map(|i| i * (n - 1) / (shown - 1)).collect()
}

fn pictures(inputs: &HtmlInputs<'_>, imagery: &EpisodeImagery) -> String {
    let mut out = String::from("<h4>Initial scene</h4>\n<div>\n");
    for v in &imagery.views {
        out.push_str(&thumb_figure(inputs, &v.artifact, &v.name));
    }
    out.push_str("</div>\n<h4>Keyframes</h4>\n<div>\n");
    for i in spaced(imagery.keyframes.len(), KEYFRAMES_SHOWN) {
        let k = &imagery.keyframes[i];
        let caption = format!("step {} ({}), goals met {}", k.step, k.camera, k.goals_met);
        out.push_str(&thumb_figure(inputs, &k.artifact, &caption));
    }
    out.push_str("</div>\n");
    if imagery.keyframes.len() > KEYFRAMES_SHOWN {
        let _ = writeln!(
            out,
            "<p class=\"caption\">{KEYFRAMES_SHOWN} of {} keyframes shown.</p>",
            imagery.keyframes.len()
        );
    }
    out
}

fn thumb_figure(inputs: &HtmlInputs<'_>, key: &str, caption: &str) -> String {
    let body = match (inputs.artifact)(key) {
        None => format!(
            "<span class=\"missing\">(artifact missing: {})</span>",
            esc(key)
        ),
        Some(bytes) => match thumbnail(&bytes, THUMB_WIDTH) {
            Ok((png, w, h)) => format!(
                "<img src=\"data:image/png;base64,{}\" width=\"{w}\" height=\"{h}\" alt=\"{}\">",
                base64::engine::general_purpose::STANDARD.encode(png),
                esc(caption)
            ),
            Err(why) => format!(
                "<span class=\"missing\">(image format not shown: {})</span>",
                esc(&why)
            ),
        },
    };
    format!(
        "<figure class=\"thumb\">{body}<figcaption>{}</figcaption></figure>\n",
        esc(caption)
    )
}

/// A PNG downscaled (box filter) to at most `width` pixels wide, re-encoded as PNG, with its
/// size; 8-bit greyscale, greyscale with alpha, RGB and RGBA are kept as they are; any other
/// format is an error that says which.
pub fn thumbnail(bytes: &[u8], width: u32) -> Result<(Vec<u8>, u32, u32), String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader
        .output_buffer_size()
        .ok_or("image too large".to_owned())?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("{:?}-bit {:?}", info.bit_depth, info.color_type));
    }
    let channels: usize = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => return Err(format!("{other:?}")),
    };
    let (w, h) = (info.width as usize, info.height as usize);
    if w == 0 || h == 0 {
        return Err("empty image".into());
    }
    let tw = (width as usize).min(w).max(1);
    let th = ((h * tw + w / 2) / w).max(1);
    let mut small = vec![0u8; tw * th * channels];
    for oy in 0..th {
        let (y0, y1) = (oy * h / th, ((oy + 1) * h / th).max(oy * h / th + 1));
        for ox in 0..tw {
            let (x0, x1) = (ox * w / tw, ((ox + 1) * w / tw).max(ox * w / tw + 1));
            let count = ((y1 - y0) * (x1 - x0)) as u32;
            for c in 0..channels {
                let mut sum = 0u32;
                for y in y0..y1 {
                    let row = &buf[y * info.line_size..];
                    for x in x0..x1 {
                        sum += u32::from(row[x * channels + c]);
                    }
                }
                small[(oy * tw + ox) * channels + c] = ((sum + count / 2) / count) as u8;
            }
        }
    }
    let mut png_out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_out, tw as u32, th as u32);
        enc.set_color(info.color_type);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::High);
        let mut writer = enc.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(&small).map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())?;
    }
    Ok((png_out, tw as u32, th as u32))
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::agreement::{AgreementRow, agreement};
    use crate::diversity::{EmbeddingModel, TextDiversityRow, TextDiversityTable};
    use crate::dynamics::{DynamicsConfig, DynamicsFit};
    use crate::generalization::{EvalEpisode, GeneralizationResults, GroupGeneralization};
    use crate::proxy::RankingResults;
    use crate::quality::{Item, ItemOutcome, JudgeOutcome, Usage};
    use crate::quality_report::{JudgeRecord, build_quality};
    use crate::ranking::{Cell, RankingConfig, rank};
    use crate::report::{
        EpisodeOutcome, Keyframe, LabelSource, NamedArtifact, PredicateValue, ShardRecord,
        TaskInfo, build_results,
    };
    use crate::trainer::DiversityResults;

    const EVIL: &str = "<script>alert(1)</script>";

    fn tiny_png(w: u32, h: u32, colour: png::ColorType, depth: png::BitDepth) -> Vec<u8> {
        let channels = match colour {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            _ => 4,
        };
        let bytes_per = if depth == png::BitDepth::Sixteen {
            2
        } else {
            1
        };
        let data: Vec<u8> = (0..w * h * channels * bytes_per)
            .map(|i| (i * 7) as u8)
            .collect();
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        let mut writer = enc.write_header().unwrap();
        writer.write_image_data(&data).unwrap();
        writer.finish().unwrap();
        out
    }

    fn artifact(key: &str) -> Option<Vec<u8>> {
        match key {
            "imagery/ok.png" => Some(tiny_png(4, 3, png::ColorType::Rgb, png::BitDepth::Eight)),
            "imagery/big.png" => Some(tiny_png(
                640,
                480,
                png::ColorType::Rgba,
                png::BitDepth::Eight,
            )),
            "imagery/grey.png" => Some(tiny_png(
                5,
                5,
                png::ColorType::Grayscale,
                png::BitDepth::Eight,
            )),
            "imagery/deep.png" => Some(tiny_png(2, 2, png::ColorType::Rgb, png::BitDepth::Sixteen)),
            "imagery/junk.png" => Some(b"not a png".to_vec()),
            _ => None,
        }
    }

    fn info(id: &str, name: &str, group: &str) -> TaskInfo {
        TaskInfo {
            id: id.into(),
            name: name.into(),
            group: group.into(),
            pipeline: "assay".into(),
            origin: format!("tasks/{id}.yaml"),
            spec_hash: "h".into(),
        }
    }

    fn imagery() -> EpisodeImagery {
        let views = ["ok", "missing", "grey", "deep"];
        let frames = ["big", "ok", "junk", "ok"];
        EpisodeImagery {
            adapter: "test".into(),
            views: views
                .iter()
                .map(|v| NamedArtifact {
                    name: format!("view {v}"),
                    artifact: format!("imagery/{v}.png"),
                })
                .collect(),
            keyframes: frames
                .iter()
                .enumerate()
                .map(|(i, f)| Keyframe {
                    step: i as u64 * 10,
                    camera: "front".into(),
                    artifact: format!("imagery/{f}.png"),
                    goals_met: 0,
                })
                .collect(),
            contact_sheet: "imagery/sheet.png".into(),
            video: None,
            caption: None,
            clip: None,
        }
    }

    fn outcome(task: &str, seed: u64, success: bool, pictures: bool) -> EpisodeOutcome {
        EpisodeOutcome {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            success,
            label_source: LabelSource::Sim,
            predicates: vec![PredicateValue {
                label: "on(cube, plate)".into(),
                holds: success,
                detail: format!("distance {} m", if success { 0.01 } else { 0.3 }),
            }],
            steps: 100,
            sim_time_s: 1.0,
            artifact: format!("episodes/{task}-{seed}"),
            spec_hash: "h".into(),
            versions: BTreeMap::new(),
            imagery: pictures.then(imagery),
        }
    }

    fn judged(judge: &str, task: &str, seed: u64, sa: &[f64], c: &[f64]) -> JudgeRecord {
        let item = |item: Item, scores: &[f64]| ItemOutcome {
            item,
            prompt: "p".into(),
            scores: scores.to_vec(),
            errors: Vec::new(),
            unjudged: 0,
        };
        JudgeRecord {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            judge: judge.into(),
            attempts: 1,
            outcome: Some(JudgeOutcome {
                judge: judge.into(),
                backend: "offline".into(),
                model: "caption".into(),
                task_id: task.into(),
                seed,
                policy: "oracle".into(),
                repeats: 2,
                items: vec![item(Item::SceneAlignment, sa), item(Item::Completion, c)],
                usage: Usage::default(),
                transcript: None,
            }),
            error: None,
            cancelled: false,
        }
    }

    fn fit(group: &str, budget: u32, trained: u32, mse: f64) -> DynamicsFit {
        DynamicsFit {
            group: group.into(),
            budget,
            train_episodes: trained,
            eval_episodes: 6,
            eval_image_mse: mse,
            eval_proprio_mse: 0.0,
            per_episode: Vec::new(),
            episodes: Vec::new(),
            final_train_loss: 0.1,
            steps: 10,
            epochs: 1.0,
            resumed_from_step: None,
            steps_per_s: 1.0,
            libtorch: String::new(),
            device: "cpu".into(),
            config: DynamicsConfig::default(),
        }
    }

    fn generalization() -> GeneralizationResults {
        let fit: crate::diffusion::DiffusionFit = serde_json::from_value(serde_json::json!({
            "steps": 10, "final_loss": 0.1, "mean_last_100_loss": 0.1,
            "parameters": 5, "clips": 4, "samples": 40, "device": "cpu", "config": {}
        }))
        .unwrap();
        let ep = |group: &str, held_out: bool, ok: bool| EvalEpisode {
            group: group.into(),
            task_id: "a".into(),
            held_out,
            success: Some(Ok(ok)),
        };
        let eps = [
            ep("g1", false, true),
            ep("g1", false, true),
            ep("g1", true, false),
            ep("g2", false, false),
        ];
        GeneralizationResults {
            groups: vec![
                GroupGeneralization::build("g1", "policies/g1", fit.clone(), &eps),
                GroupGeneralization::build("g2", "policies/g2", fit, &eps),
            ],
            errors: vec![("g3".into(), "out of <memory>".into())],
        }
    }

    fn ranking() -> RankingResults {
        let mut cells = Vec::new();
        for (p, real, proxy) in [("good", 0.9, 0.8), ("fair", 0.5, 0.6), ("poor", 0.1, 0.2)] {
            for (source, rate) in [("real", real), ("world-model", proxy)] {
                cells.push(Cell {
                    task: "a".into(),
                    policy: p.into(),
                    source: source.into(),
                    trials: None,
                    successes: None,
                    rate,
                });
            }
        }
        let cfg = RankingConfig {
            resamples: 50,
            ..RankingConfig::default()
        };
        RankingResults {
            train_policies: vec!["oracle".into()],
            ranked_policies: vec!["good".into(), "fair".into(), "poor".into()],
            rows: Vec::new(),
            groups: Vec::new(),
            ranking: Some(rank(&cells, &cfg).unwrap()),
            ranking_missing: None,
            proxy_agreement: Some(Proportion::new(5, 6)),
            judge_agreement_real_frames: None,
            errors: Vec::new(),
            judging_errors: Vec::new(),
        }
    }

    /// Two groups, three tasks (one named like a script), two judges, every section.
    fn report() -> Report {
        let tasks = vec![
            info("a", EVIL, "g1"),
            info("b c/é", "b", "g1"),
            info("c", "c", "g2"),
        ];
        let outcomes = vec![
            outcome("a", 0, true, true),
            outcome("a", 1, false, true),
            outcome("b c/é", 0, true, false),
            outcome("c", 0, false, false),
        ];
        let mut shards: Vec<ShardRecord> = outcomes
            .iter()
            .map(|o| ShardRecord {
                task_id: o.task_id.clone(),
                seed: o.seed,
                policy: o.policy.clone(),
                attempts: 1,
                outcome: Some(o.clone()),
                error: None,
                cancelled: false,
            })
            .collect();
        shards.push(ShardRecord {
            task_id: "c".into(),
            seed: 1,
            policy: "oracle".into(),
            attempts: 3,
            outcome: None,
            error: Some("worker <lost>".into()),
            cancelled: false,
        });
        let invalid = vec![crate::SpecError {
            task: Some("bad".into()),
            origin: "tasks/bad.yaml".into(),
            path: "scene.objects[0]".into(),
            reason: "unknown shape <blob>".into(),
        }];
        let mut results = build_results(
            "demo & test",
            &["oracle".into()],
            &[0, 1],
            &tasks,
            &shards,
            &invalid,
        );
        let records = vec![
            judged("offline", "a", 0, &[4.0, 4.0], &[10.0, 9.0]),
            judged("offline", "a", 1, &[2.0, 3.0], &[1.0, 0.0]),
            judged("offline", "b c/é", 0, &[5.0, 5.0], &[8.0, 8.0]),
            judged("offline", "c", 0, &[1.0, 1.0], &[2.0, 2.0]),
            judged("vlm", "a", 0, &[3.0, 3.0], &[5.0, 5.0]),
            judged("vlm", "c", 0, &[3.0, 3.0], &[5.0, 5.0]),
        ];
        results.quality = build_quality(&tasks, &outcomes, &records);
        let model = |name: &str| EmbeddingModel {
            name: name.into(),
            model: format!("{name}-model"),
            dimensions: 384,
        };
        results.diversity = Some(DiversityResults {
            text: Some(TextDiversityTable {
                models: vec![model("minilm"), model("mpnet")],
                rows: vec![
                    TextDiversityRow {
                        group: "g1".into(),
                        n: 2,
                        div: vec![Some(0.4), None],
                        errors: vec![None, Some("endpoint down".into())],
                    },
                    TextDiversityRow {
                        group: "All".into(),
                        n: 3,
                        div: vec![Some(0.5), Some(0.45)],
                        errors: Vec::new(),
                    },
                ],
            }),
            dynamics: vec![
                fit("g1", 10, 10, 0.002),
                fit("g1", 20, 12, 0.0015),
                fit("g2", 10, 4, 0.003),
            ],
            errors: vec![("dynamics g2 @ 20".into(), "trainer crashed".into())],
        });
        results.generalization = Some(generalization());
        results.ranking = Some(ranking());
        Report {
            report_version: crate::report::REPORT_VERSION,
            provenance: Default::default(),
            results,
            run: RunInfo {
                batch_id: "b00001".into(),
                state: "completed".into(),
                submitted_at_unix_ms: 1_700_000_000_000,
                finished_at_unix_ms: Some(1_700_000_060_000),
                wall_time_s: Some(60.0),
                episodes_per_s: Some(0.1),
                sim_steps_per_s: Some(10.0),
                extra_attempts: 0,
                workers: vec!["local/worker-0".into()],
            },
        }
    }

    fn human() -> AgreementTable {
        AgreementTable {
            reference: "human".into(),
            group_column: None,
            resamples: 50,
            rows: vec![
                AgreementRow {
                    group: None,
                    judge: "offline".into(),
                    agreement: agreement(&[1.0, 5.0, 7.0, 9.0], &[2.0, 4.0, 8.0, 9.0], 50, 0),
                },
                AgreementRow {
                    group: None,
                    judge: "vlm".into(),
                    agreement: agreement(&[3.0, 3.0, 3.0], &[2.0, 4.0, 8.0], 50, 0),
                },
            ],
        }
    }

    fn render(report: &Report, human: Option<&AgreementTable>) -> String {
        report_html(&HtmlInputs {
            report,
            artifact: &artifact,
            human,
        })
    }

    /// Every `data:image/png;base64,` payload of `html`.
    fn data_pngs(html: &str) -> Vec<Vec<u8>> {
        let prefix = "data:image/png;base64,";
        html.match_indices(prefix)
            .map(|(i, _)| {
                let rest = &html[i + prefix.len()..];
                let end = rest.find('"').unwrap();
                base64::engine::general_purpose::STANDARD
                    .decode(&rest[..end])
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn the_page_is_self_contained_and_valid_enough() {
        let report = report();
        let human = human();
        let html = render(&report, Some(&human));
        assert!(html.starts_with("<!DOCTYPE html>\n<html lang=\"en\">"));
        assert!(html.contains("<meta charset=\"utf-8\">"));
        assert!(html.contains("<title>Assay report: demo &amp; test</title>"));
        assert!(html.contains("<link rel=\"icon\" href=\"data:,\">"));
        let lower = html.to_lowercase();
        for bad in [
            "src=\"http",
            "href=\"http",
            "url(http",
            "<script",
            "@import",
            "<?xml",
        ] {
            assert!(!lower.contains(bad), "found {bad}");
        }
        // Every reference points into the page or is inline data.
        for attr in ["src=\"", "href=\""] {
            for (i, _) in html.match_indices(attr) {
                let target = &html[i + attr.len()..];
                assert!(
                    target.starts_with('#') || target.starts_with("data:"),
                    "{}",
                    &target[..target.len().min(60)]
                );
            }
        }
        assert!(!html.contains("NaN"));
        assert_eq!(html.matches("<svg").count(), html.matches("</svg>").count());
        for id in [
            "overview", "figure-4", "figure-3", "table-1", "table-2", "table-3", "ranking",
            "invalid", "tasks",
        ] {
            assert!(html.contains(&format!("id=\"{id}\"")), "{id}");
            assert!(html.contains(&format!("href=\"#{id}\"")), "{id}");
        }
        assert!(
            !lower.contains("not in this batch"),
            "every section is present"
        );
    }

    #[test]
    fn every_task_has_a_page_linked_from_the_index() {
        let report = report();
        let html = render(&report, None);
        assert_eq!(report.results.tasks.len(), 3);
        for t in &report.results.tasks {
            let anchor = task_anchor(&t.id);
            assert!(anchor.starts_with("task-"));
            assert!(
                anchor
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-._".contains(c)),
                "{anchor}"
            );
            assert!(html.contains(&format!("<section class=\"task\" id=\"{anchor}\">")));
            assert!(html.contains(&format!("href=\"#{anchor}\"")));
        }
        assert_ne!(task_anchor("a b"), task_anchor("a_20b"));
        assert!(html.contains("section.task:target{display:block}"));
        // The failed shard and the unmet predicate are on their task's page.
        assert!(html.contains("worker &lt;lost&gt;"));
        assert!(html.contains("distance 0.3 m"));
    }

    #[test]
    fn pictures_are_inline_thumbnails_or_say_why_not() {
        let html = render(&report(), None);
        let pngs = data_pngs(&html);
        // Task a's first episode: views ok + grey, keyframes big + ok + ok.
        assert_eq!(pngs.len(), 5);
        assert_eq!(html.matches("<img ").count(), 5);
        for bytes in &pngs {
            let reader = png::Decoder::new(std::io::Cursor::new(bytes))
                .read_info()
                .unwrap();
            assert!(reader.info().width <= THUMB_WIDTH);
        }
        assert!(html.contains("width=\"192\" height=\"144\""));
        assert!(html.contains("(artifact missing: imagery/missing.png)"));
        assert_eq!(html.matches("(image format not shown").count(), 2);
        assert!(html.contains("No pictures"));
    }

    #[test]
    fn thumbnails_keep_the_colour_type_and_refuse_other_formats() {
        let big = tiny_png(640, 480, png::ColorType::Rgba, png::BitDepth::Eight);
        let (png_bytes, w, h) = thumbnail(&big, 192).unwrap();
        assert_eq!((w, h), (192, 144));
        let reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
            .read_info()
            .unwrap();
        assert_eq!(reader.info().color_type, png::ColorType::Rgba);
        let grey = tiny_png(1, 1, png::ColorType::GrayscaleAlpha, png::BitDepth::Eight);
        assert_eq!(thumbnail(&grey, 192).unwrap().1, 1);
        let deep = tiny_png(2, 2, png::ColorType::Rgb, png::BitDepth::Sixteen);
        assert!(thumbnail(&deep, 192).is_err());
        assert!(thumbnail(b"junk", 192).is_err());
    }

    #[test]
    fn report_text_is_escaped() {
        let html = render(&report(), None);
        assert!(!html.contains(EVIL));
        assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert!(html.contains("unknown shape &lt;blob&gt;"));
        assert!(html.contains("out of &lt;memory&gt;"));
    }

    #[test]
    fn undefined_agreement_is_shown_with_its_reason() {
        let human = human();
        assert!(human.rows[1].agreement.pearson.value.is_none());
        let html = render(&report(), Some(&human));
        assert!(html.contains("undefined — the reference scores are constant"));
        assert!(html.contains("humans (human)"));
        let e = Estimate {
            value: None,
            ci95: None,
            undefined: Some("needs 2".into()),
            no_interval: None,
        };
        assert!(estimate(&e).contains("undefined — needs 2"));
    }

    #[test]
    fn absent_sections_say_how_to_get_them() {
        let mut report = report();
        report.results.quality = None;
        report.results.diversity = None;
        report.results.ranking = None;
        report.results.generalization = None;
        let html = render(&report, None);
        for flag in ["--rank-train-policies", "--generalization"] {
            assert!(
                html.contains(&format!("Not in this batch (run with {flag})")),
                "{flag}"
            );
        }
        assert!(html.contains("Not in this batch (no judge ran: run with --judge)"));
        assert_eq!(html.matches("<svg").count(), 0);
        let with_quality = render(&self::report(), None);
        assert!(
            with_quality.contains("Not in this batch (human ratings: run with --human-ratings)")
        );
    }

    #[test]
    fn the_same_inputs_give_the_same_page() {
        let (a, b) = (report(), report());
        let human = human();
        assert_eq!(render(&a, Some(&human)), render(&b, Some(&human)));
    }

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc(1_700_000_000_000), "2023-11-14 22:13:20 UTC");
    }

    /// The demo batch's page, for looking at by hand: writes /tmp/report.html.
    /// `ASSAY_DEMO_DIR` (default /work/main/out/demo) holds report.json and artifacts/.
    #[test]
    #[ignore = "needs a demo run's report and artifacts"]
    fn demo_report_html() {
        let dir = std::path::PathBuf::from(
            std::env::var("ASSAY_DEMO_DIR").unwrap_or_else(|_| "/work/main/out/demo".into()),
        );
        let report: Report =
            serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
        let artifacts = dir.join("artifacts");
        let html = report_html(&HtmlInputs {
            report: &report,
            artifact: &|key: &str| std::fs::read(artifacts.join(key)).ok(),
            human: None,
        });
        std::fs::write("/tmp/report.html", &html).unwrap();
        println!(
            "/tmp/report.html: {} bytes, {} images",
            html.len(),
            html.matches("<img ").count()
        );
    }
}
