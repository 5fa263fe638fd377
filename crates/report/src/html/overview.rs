//! The top of `report.html`: its header, provenance, the overview of success per group and
//! policy, and the invalid tasks.

use std::fmt::Write as _;

use super::*;

pub(super) fn header(report: &Report) -> String {
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

pub(super) fn overview(report: &Report) -> String {
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

pub(super) fn invalid(report: &Report) -> String {
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
