//! The jobs of the trainer role and what they report: plain data, so the coordinator queues them
//! and builds reports without linking torch.

use serde::{Deserialize, Serialize};

use crate::diffusion::{DiffusionConfig, DiffusionFit};
use crate::diversity::TextDiversityTable;
use crate::dynamics::{DynamicsConfig, DynamicsFit};
use crate::proxy::{ProxyConfig, ProxyEpisode, ProxyResult};

/// One trainer shard's job (the assignment's `input_json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TrainerJob {
    /// Text diversity of the batch's task texts per group and for all of them, with each model.
    Text {
        models: Vec<String>,
        /// (group, texts) in report order; the last is every task ("All").
        groups: Vec<(String, Vec<String>)>,
    },
    /// One world-model fit: trained on the first `budget` clips, evaluated on all of `clips`.
    Dynamics {
        group: String,
        budget: u32,
        /// Content addresses of the group's dynamics clips, in planning order.
        clips: Vec<String>,
        config: DynamicsConfig,
    },
    /// A diffusion policy for one group, imitating the given clips (see
    /// [`crate::generalization`]).
    Diffusion {
        group: String,
        clips: Vec<String>,
        config: DiffusionConfig,
    },
    /// The world-model proxy of one group's ranked episodes (see [`crate::proxy`]).
    Proxy {
        group: String,
        /// Episodes of the training policies, with their real outcomes.
        train: Vec<ProxyEpisode>,
        /// Episodes of the ranked policies, without them.
        eval: Vec<ProxyEpisode>,
        config: ProxyConfig,
    },
}

/// What a trainer shard reports (the result's `outcome_json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TrainerOutcome {
    Text {
        table: TextDiversityTable,
    },
    Dynamics {
        fit: Box<DynamicsFit>,
    },
    Proxy {
        result: Box<ProxyResult>,
    },
    /// A trained diffusion policy: its checkpoint's key in the artifact store and its fit.
    Diffusion {
        group: String,
        model: String,
        fit: Box<DiffusionFit>,
    },
}

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
