//! Errors that name the task, the field and the reason.

use serde::{Deserialize, Serialize};

/// One problem with one task spec.
#[derive(
    Debug, Clone, PartialEq, Eq, Serialize, Deserialize, thiserror::Error, schemars::JsonSchema,
)]
#[error("task {}: {}: {}{}", task.as_deref().unwrap_or("<unknown id>"), if path.is_empty() { "<document>" } else { path }, reason, origin_suffix(origin))]
pub struct SpecError {
    /// The task id, when the document got far enough to have one.
    pub task: Option<String>,
    /// The file or record the task came from.
    pub origin: String,
    /// Field path in the document (`scene.objects[2].shape.box.half_extents[0]`).
    pub path: String,
    pub reason: String,
}

fn origin_suffix(origin: &str) -> String {
    if origin.is_empty() {
        String::new()
    } else {
        format!(" (in {origin})")
    }
}

/// All problems found in one task spec.
#[derive(
    Debug, Clone, PartialEq, Eq, Serialize, Deserialize, thiserror::Error, schemars::JsonSchema,
)]
#[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "))]
pub struct SpecErrors(pub Vec<SpecError>);
