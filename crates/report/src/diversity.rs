//! The diversity section of a report: text diversity (the paper's Table 1) and the dynamics
//! diversity fits (Table 2) as the trainer role reported them.
//!
//! Owns: the section and its dynamics table. Never embeds a text or fits a model.

use serde::{Deserialize, Serialize};

use assay_model::dynamics::DynamicsFit;
use assay_stats::diversity::TextDiversityTable;

/// The diversity section of a report.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DiversityResults {
    /// Text diversity (the paper's Table 1), when the batch asked for it and it finished.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<TextDiversityTable>,
    /// Dynamics diversity fits (the paper's Table 2), by group then budget.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dynamics: Vec<DynamicsFit>,
    /// Trainer shards that failed, with their errors ("text" or "dynamics GROUP @ BUDGET").
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<(String, String)>,
}

/// Said under the dynamics table when a group had fewer episodes than a budget.
pub const FEWER_THAN_BUDGET: &str = "\nA group with fewer episodes than a budget is fitted once \
on all of them (\"n trained\"); the larger budgets would repeat that fit and are left empty.";

/// How long the fits of a dynamics table trained, said so the budget curve can be read.
pub fn training_length(c: &assay_model::dynamics::DynamicsConfig) -> String {
    if c.steps > 0 {
        format!(
            "Every fit trains {} steps of {} chunks of {} frames, whatever its budget.",
            c.steps, c.batch, c.chunk
        )
    } else {
        format!(
            "Every fit trains {} epochs of batches of {} chunks of {} frames (the paper's \
             protocol), so a larger budget also trains longer.",
            c.epochs, c.batch, c.chunk
        )
    }
}
