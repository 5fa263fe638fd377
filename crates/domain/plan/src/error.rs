//! What planning refuses, by kind. Each message names what is wrong and why, in the words the
//! coordinator has always answered with; the coordinator turns them into gRPC status codes
//! (`assay_coordinator::error`), a client prints them.

use crate::settings::SettingsError;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// The batch's settings do not fit together (see [`SettingsError`]).
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// A text template that names neither `{name}` nor `{description}`: it would embed the same
    /// text for every task.
    #[error("text template for {pipeline:?}: it names neither {{name}} nor {{description}}")]
    TextTemplate { pipeline: String },
    /// A policy whose spec declares an interface one of the batch's tasks cannot fill.
    #[error("policy '{policy}' does not fit task '{task}': {reason}")]
    Interface {
        policy: String,
        task: String,
        reason: String,
    },
    /// A planned task's canonical JSON no longer reads as a spec (a bug, not bad input).
    #[error("task {task}: {reason}")]
    PlannedSpec { task: String, reason: String },
}

impl PlanError {
    /// Whether the batch's submitter can fix it (everything but a planned spec that does not
    /// read back).
    pub fn is_invalid_input(&self) -> bool {
        !matches!(self, PlanError::PlannedSpec { .. })
    }
}
