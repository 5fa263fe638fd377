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

impl DiversityResults {
    /// The dynamics table: one row per group, one column per budget, the evaluation image MSE
    /// (×10³) with the episodes actually trained on when fewer than asked.
    pub fn dynamics_markdown(&self) -> String {
        let mut budgets: Vec<u32> = self.dynamics.iter().map(|f| f.budget).collect();
        budgets.sort_unstable();
        budgets.dedup();
        let mut groups: Vec<&str> = Vec::new();
        for f in &self.dynamics {
            if !groups.contains(&f.group.as_str()) {
                groups.push(&f.group);
            }
        }
        let mut out = String::from("| group | evaluated on |");
        for b in &budgets {
            out.push_str(&format!(" {b} episodes |"));
        }
        out.push_str("\n|---|---:|");
        out.push_str(&"---:|".repeat(budgets.len()));
        out.push('\n');
        for g in groups {
            let fits: Vec<&DynamicsFit> = self.dynamics.iter().filter(|f| f.group == g).collect();
            let eval = fits.iter().map(|f| f.eval_episodes).max().unwrap_or(0);
            out.push_str(&format!("| {} | {eval} |", g.replace('|', "\\|")));
            for b in &budgets {
                match fits.iter().find(|f| f.budget == *b) {
                    Some(f) if f.train_episodes < f.budget => out.push_str(&format!(
                        " {:.3} ({} trained) |",
                        f.eval_image_mse * 1e3,
                        f.train_episodes
                    )),
                    Some(f) => out.push_str(&format!(" {:.3} |", f.eval_image_mse * 1e3)),
                    None => out.push_str(" – |"),
                }
            }
            out.push('\n');
        }
        if self.dynamics.iter().any(|f| f.train_episodes < f.budget) {
            out.push_str(
                "\nA group with fewer episodes than a budget is fitted once on all of them \
                 (\"n trained\"); the larger budgets would repeat that fit and are left empty.\n",
            );
        }
        out
    }
}
