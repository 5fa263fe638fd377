//! The top of `report.html`: its header, provenance, the overview of success per group and
//! policy, and the invalid tasks.

use super::*;
use crate::figures::{self, BarChart, Bars};
use crate::tables;

pub(super) fn header(report: &Report) -> Markup {
    let r = &report.results;
    html! {
        header {
            h1 { (r.batch_name) }
            p {
                "Policies " (cell(&Cell::policies(r.policies_shown().into_iter().map(String::as_str), r.policy_labels())))
                ", seeds "
                (r.seeds.iter().map(u64::to_string).collect::<Vec<_>>().join(", "))
                ". Success rates read rate (successes/trials) [95 % Wilson interval]; success is \
                 the simulator's ground truth (goal predicates) over completed episodes."
            }
            (table(&tables::summary(r)))
            @if r.policies.len() > 1 { (table(&tables::success_per_policy(r))) }
            details id="provenance" {
                summary { "Run and provenance" }
                (table(&tables::run(&report.run)))
                (table(&tables::provenance(&report.provenance)))
            }
        }
    }
}

pub(super) fn overview(report: &Report) -> Markup {
    let r = &report.results;
    // Success per group and policy, each bar with its 95 % Wilson interval; "All" last.
    let mut categories: Vec<String> = r.groups.iter().map(|g| g.group.clone()).collect();
    categories.push("All".into());
    let series: Vec<Bars> = r
        .policies_shown()
        .into_iter()
        .map(|p| {
            let of = |by: &[crate::report::PolicySuccess]| {
                by.iter()
                    .find(|s| s.policy == *p)
                    .map(|s| (s.success.rate, s.success.ci95))
                    .unwrap_or((None, None))
            };
            let cells: Vec<_> = r
                .groups
                .iter()
                .map(|g| of(&g.by_policy))
                .chain(std::iter::once(of(&r.by_policy)))
                .collect();
            Bars {
                name: crate::view::policy_label(p, r.policy_labels()).unwrap_or_else(|| p.clone()),
                values: cells.iter().map(|c| c.0).collect(),
                intervals: cells.iter().map(|c| c.1).collect(),
            }
        })
        .collect();
    html! {
        section id="overview" {
            h2 { "Overview: success per group and policy" }
            @if !r.groups.is_empty() {
                (inline_svg(&figures::bar_chart(&BarChart {
                    title: "Success per group and policy (95 % Wilson intervals)",
                    y_desc: "success rate",
                    categories: &categories,
                    series: &series,
                    y_range: Some((0.0, 1.0)),
                })))
            }
            (table(&tables::success_per_group(r)))
        }
    }
}

pub(super) fn invalid(report: &Report) -> Markup {
    html! {
        section id="invalid" {
            h2 { "Invalid tasks" }
            @if report.results.invalid_tasks.is_empty() {
                p { "None: every task spec was valid." }
            } @else {
                (table(&tables::invalid_tasks(&report.results)))
            }
        }
    }
}

pub(super) fn imports(report: &Report) -> Markup {
    html! {
        section id="imports" {
            h2 { "Import" }
            @if report.imports.is_empty() {
                p { "The tasks were task specs: nothing was imported." }
            }
            @for i in &report.imports {
                p {
                    "From " code { (i.pipeline) } " output at " code { (i.root) } ": "
                    (i.tasks.iter().filter(|t| t.imported).count()) " of " (i.tasks.len())
                    " tasks imported; every mapping line is in "
                    code { (i.mapping_file) } " beside this report."
                }
                (table(&tables::imports(i)))
            }
        }
    }
}
