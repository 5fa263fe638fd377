//! A batch's task documents, parsed and validated: each becomes a [`PlannedTask`] (its canonical
//! JSON and what reports say of it) or the errors that name its file, task, field and reason.
//! Duplicate task ids are refused (the first keeps the id), and so is a task whose asset root lies
//! outside the folders the operator gave.

use std::collections::BTreeMap;
use std::path::PathBuf;

use assay_model::episode::TaskInfo;
use assay_spec::spec::{Format, parse_task};
use assay_spec::{SpecError, SpecErrors};

/// One task document as a client sends it: its text, where it came from (a file path, or the
/// imported task's source) and its format (`yaml`, `yml`, `json`, or empty to go by the origin's
/// extension).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TaskDocument {
    pub origin: String,
    pub format: String,
    pub content: String,
}

/// A task accepted by the planner.
#[derive(Debug, Clone)]
pub struct PlannedTask {
    pub info: TaskInfo,
    pub spec_json: String,
}

/// Parses and validates every document against the operator's `asset_roots`; returns the
/// accepted tasks and every problem found, in document order.
pub fn plan_tasks(
    docs: &[TaskDocument],
    asset_roots: &[PathBuf],
) -> (Vec<PlannedTask>, Vec<SpecError>) {
    let mut planned: Vec<PlannedTask> = Vec::new();
    let mut errors = Vec::new();
    let mut seen: BTreeMap<String, String> = BTreeMap::new();
    for doc in docs {
        let format = match format(doc) {
            Ok(f) => f,
            Err(e) => {
                errors.push(e);
                continue;
            }
        };
        let spec = match parse_task(&doc.content, format, &doc.origin) {
            Ok(spec) => spec,
            Err(SpecErrors(es)) => {
                errors.extend(es);
                continue;
            }
        };
        let refuse = |path: String, reason: String| SpecError {
            task: Some(spec.id.clone()),
            origin: doc.origin.clone(),
            path,
            reason,
        };
        if let Err((path, reason)) = spec.check_asset_roots(asset_roots) {
            errors.push(refuse(path, reason));
            continue;
        }
        if let Some(first) = seen.get(&spec.id) {
            let reason = format!("duplicate task id '{}': already used by {first}", spec.id);
            errors.push(refuse("id".into(), reason));
            continue;
        }
        seen.insert(spec.id.clone(), doc.origin.clone());
        planned.push(PlannedTask {
            info: TaskInfo {
                id: spec.id.clone(),
                name: spec.name.clone(),
                group: spec.group.clone(),
                pipeline: spec.source.pipeline.clone(),
                origin: doc.origin.clone(),
                spec_hash: spec.spec_hash(),
            },
            spec_json: spec.canonical_json(),
        });
    }
    (planned, errors)
}

/// The document's format: named, or from its origin's extension.
fn format(doc: &TaskDocument) -> Result<Format, SpecError> {
    let refuse = |reason: String| SpecError {
        task: None,
        origin: doc.origin.clone(),
        path: String::new(),
        reason,
    };
    match doc.format.as_str() {
        "yaml" | "yml" => Ok(Format::Yaml),
        "json" => Ok(Format::Json),
        "" => Format::from_path(&doc.origin)
            .ok_or_else(|| refuse("unknown format: name the file .yaml, .yml or .json".into())),
        other => Err(refuse(format!("unknown format '{other}' (yaml or json)"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(origin: &str, format: &str, content: &str) -> TaskDocument {
        TaskDocument {
            origin: origin.into(),
            format: format.into(),
            content: content.into(),
        }
    }

    #[test]
    fn a_document_of_no_known_format_is_refused_naming_its_origin() {
        let (tasks, errors) = plan_tasks(
            &[doc("a.txt", "", "id: a"), doc("b.yaml", "toml", "id: b")],
            &[],
        );
        assert!(tasks.is_empty());
        assert_eq!(errors.len(), 2);
        assert_eq!(errors[0].origin, "a.txt");
        assert_eq!(
            errors[0].reason,
            "unknown format: name the file .yaml, .yml or .json"
        );
        assert_eq!(errors[1].reason, "unknown format 'toml' (yaml or json)");
    }
}
