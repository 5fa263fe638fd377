//! The texts text diversity embeds: one group per task group (in order of first appearance),
//! then "All" with every task (the paper's eq. 1 is computed per group and for All).

use std::collections::HashMap;

use assay_stats::diversity::task_text;

use crate::PlanError;
use crate::documents::PlannedTask;

/// The texts of `tasks` by group, "All" last ("All tasks" when a group is itself called "All").
/// `templates` maps a source pipeline to its template; one that names neither `{name}` nor
/// `{description}` is refused (it would embed the same text for every task).
pub fn text_groups(
    tasks: &[PlannedTask],
    templates: &HashMap<String, String>,
) -> Result<Vec<(String, Vec<String>)>, PlanError> {
    for (pipeline, t) in templates {
        if !t.contains("{name}") && !t.contains("{description}") {
            return Err(PlanError::TextTemplate {
                pipeline: pipeline.clone(),
            });
        }
    }
    let mut groups: Vec<(String, Vec<String>)> = Vec::new();
    let mut all = Vec::with_capacity(tasks.len());
    for t in tasks {
        let description = serde_json::from_str::<serde_json::Value>(&t.spec_json)
            .ok()
            .and_then(|v| {
                v.get("description")
                    .and_then(|d| d.as_str())
                    .map(str::to_owned)
            })
            .unwrap_or_default();
        let text = task_text(
            &t.info.pipeline,
            &t.info.name,
            &description,
            templates.get(&t.info.pipeline).map(String::as_str),
        );
        match groups.iter_mut().find(|(g, _)| *g == t.info.group) {
            Some((_, texts)) => texts.push(text.clone()),
            None => groups.push((t.info.group.clone(), vec![text.clone()])),
        }
        all.push(text);
    }
    let total = if groups.iter().any(|(g, _)| g == "All") {
        "All tasks"
    } else {
        "All"
    };
    groups.push((total.to_owned(), all));
    Ok(groups)
}

/// Every task's text, as the "All" group of [`text_groups`] has them.
pub fn all_texts(
    tasks: &[PlannedTask],
    templates: &HashMap<String, String>,
) -> Result<Vec<String>, PlanError> {
    Ok(text_groups(tasks, templates)?
        .pop()
        .map(|(_, all)| all)
        .unwrap_or_default())
}
