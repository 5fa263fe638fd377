//! `report.md`: the report for people who read Markdown (and for diffs in review). Its tables
//! come from [`crate::tables`], as the HTML page's do; this module adds the headings and the
//! prose around them.
//!
//! Owns: the Markdown document. Never aggregates and never builds a table of its own.
//! Deterministic: everything above the Run section depends only on the batch and the code.

use std::fmt::Write as _;

use crate::report::{ARTIFACTS_LINK, QUALITY_FIGURE, Report, TaskResult};
use crate::tables;
use crate::view::md_text;
use assay_model::episode::EpisodeImagery;

mod sections;

pub use sections::ranking;

impl Report {
    /// The report as Markdown, for people.
    pub fn to_markdown(&self) -> String {
        let r = &self.results;
        let mut md = String::new();
        let _ = writeln!(md, "# Assay report — {}\n", md_text(&r.batch_name));
        let _ = writeln!(
            md,
            "Policies {} · seeds {}. Everything above the Run section depends only on the batch, \
             its seeds and the versions of the code: the same batch gives the same text. Success \
             rates read `rate (successes/trials) [95 % Wilson interval]`.\n",
            crate::view::md_cell(
                &crate::view::Cell::policies(
                    r.policies_shown().into_iter().map(String::as_str),
                    r.policy_labels()
                ),
                false
            ),
            r.seeds
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
        let _ = writeln!(md, "## Summary\n");
        md.push_str(&tables::summary(r).markdown());
        if r.policies.len() > 1 {
            let _ = writeln!(md, "\n## Success per policy\n");
            let table = tables::success_per_policy(r);
            md.push_str(&table.markdown());
            md.push_str(&sections::full_names(std::slice::from_ref(&table)));
        }
        let _ = writeln!(md, "\n## Success per group\n");
        md.push_str(&tables::success_per_group(r).markdown());
        let _ = writeln!(md, "\n## Success per task\n");
        md.push_str(&tables::success_per_task(r).markdown());
        if let Some(q) = &r.quality {
            md.push('\n');
            md.push_str(&q.markdown(Some(QUALITY_FIGURE)));
        }
        if let Some(d) = &r.diversity {
            md.push_str(&sections::diversity(d));
        }
        if let Some(g) = &r.generalization {
            md.push_str(
                "\n## Generalization (diffusion policy per group, the paper's Table 3)\n\n",
            );
            md.push_str(&g.markdown());
        }
        if let Some(k) = &r.ranking {
            md.push_str("\n## Policy ranking (world-model proxy against the simulator)\n\n");
            md.push_str(&k.markdown());
        }
        if r.tasks.iter().any(|t| !t.failures.is_empty()) {
            let _ = writeln!(md, "\n## Episodes that did not complete\n");
            md.push_str(&tables::failures(r).markdown());
        }
        if !r.invalid_tasks.is_empty() {
            let _ = writeln!(md, "\n## Invalid task specs (not run)\n");
            md.push_str(&tables::invalid_tasks(r).markdown());
        }
        for i in &self.imports {
            let _ = writeln!(
                md,
                "\n## Import ({})\n\nFrom `{}`: {} of {} tasks imported; every mapping line is in [{}]({}).\n",
                i.pipeline,
                i.root,
                i.tasks.iter().filter(|t| t.imported).count(),
                i.tasks.len(),
                i.mapping_file,
                i.mapping_file
            );
            md.push_str(&tables::imports(i).markdown());
        }
        md.push_str(&imagery(&r.tasks));
        let _ = writeln!(md, "\n## Run\n");
        md.push_str(&tables::run(&self.run).markdown());
        let _ = writeln!(md, "\n## Provenance\n");
        md.push_str(&tables::provenance(&self.provenance).markdown());
        md
    }
}

/// Each task's first pictured episode: its contact sheet and video.
fn imagery(tasks: &[TaskResult]) -> String {
    let pictured: Vec<(&TaskResult, _, &EpisodeImagery)> = tasks
        .iter()
        .filter_map(|t| {
            t.episodes
                .iter()
                .find_map(|e| e.imagery.as_ref().map(|i| (t, e, i)))
        })
        .collect();
    let mut md = String::new();
    let Some(first) = pictured.first() else {
        return md;
    };
    let _ = writeln!(md, "\n## Episode imagery\n");
    let _ = writeln!(
        md,
        "For each task, the first episode's contact sheet: the initial scene from the top, the \
         front and two obliques, then {} keyframes over the rollout. Every episode's views, \
         keyframes and sheet are in `report.json` (paths relative to the artifact store, \
         `{ARTIFACTS_LINK}` beside this report). Drawn by: {}.\n",
        first.2.keyframes.len(),
        md_text(&first.2.adapter)
    );
    for (t, e, img) in pictured {
        let _ = writeln!(
            md,
            "### `{}` — seed {}, {}, {}\n\n![{}]({ARTIFACTS_LINK}/{})\n",
            md_text(&t.id),
            e.seed,
            md_text(&e.policy),
            if e.success { "succeeded" } else { "failed" },
            md_text(&t.id),
            img.contact_sheet
        );
        if let Some(v) = &img.video {
            let _ = writeln!(md, "[Video of the rollout]({ARTIFACTS_LINK}/{v})\n");
        }
    }
    md
}
