//! The generalization section of a report (the generative-simulation paper's Table 3): per task
//! group, the success of its trained diffusion policy on the variations it was trained on and on
//! held-out ones. The plan is [`assay_model::generalization`]'s.
//!
//! Owns: the aggregation. Never trains or runs a policy.

use serde::{Deserialize, Serialize};

use assay_model::diffusion::DiffusionFit;
#[cfg(test)]
use assay_model::generalization::GeneralizationPlan;
use assay_stats::stats::Proportion;

/// An evaluation episode as the report builder reads it from the store.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalEpisode {
    pub group: String,
    pub task_id: String,
    pub held_out: bool,
    /// None while it runs; Some(Err) when it failed.
    pub success: Option<Result<bool, String>>,
}

/// One group's trained policy and its success.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GroupGeneralization {
    pub group: String,
    /// The model's key in the artifact store.
    pub model: String,
    pub fit: DiffusionFit,
    /// Success on the variations it was trained on, and on held-out ones (Wilson 95 %).
    pub train: Proportion,
    pub held_out: Proportion,
    /// Episodes that failed to run (not counted in either rate), with their errors.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<String>,
    /// Episodes still queued or running.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub pending: u32,
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// The generalization section of a report: the paper's Table 3.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct GeneralizationResults {
    pub groups: Vec<GroupGeneralization>,
    /// Training jobs that failed: (group, error).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<(String, String)>,
}

/// Success on the training variations below which a policy is reported as not having learnt its
/// group.
pub const LEARNT_THRESHOLD: f64 = 0.5;

impl GroupGeneralization {
    /// Builds a group's row from its trained model and the evaluation episodes of that model.
    pub fn build(group: &str, model: &str, fit: DiffusionFit, episodes: &[EvalEpisode]) -> Self {
        let mut train = (0, 0);
        let mut held = (0, 0);
        let mut errors = Vec::new();
        let mut pending = 0;
        for e in episodes.iter().filter(|e| e.group == group) {
            match &e.success {
                None => pending += 1,
                Some(Err(msg)) => errors.push(format!("{}: {msg}", e.task_id)),
                Some(Ok(ok)) => {
                    let side = if e.held_out { &mut held } else { &mut train };
                    side.0 += u64::from(*ok);
                    side.1 += 1;
                }
            }
        }
        Self {
            group: group.to_owned(),
            model: model.to_owned(),
            fit,
            train: Proportion::new(train.0, train.1),
            held_out: Proportion::new(held.0, held.1),
            errors,
            pending,
        }
    }

    /// Whether the policy solved less than half of its own training variations.
    pub fn did_not_learn(&self) -> bool {
        self.train.rate.is_some_and(|r| r < LEARNT_THRESHOLD)
    }
}

/// Said under Table 3: what its rates and variations are.
pub const HELD_OUT_NOTE: &str = "Success rates with Wilson 95 % intervals, in percent. Held-out \
variations: the same tasks under seeds never trained on, redrawing what each task's variations \
declare (object poses, the tool's start, colours).";

#[cfg(test)]
mod tests {
    use super::*;

    fn fit() -> DiffusionFit {
        crate::testing::diffusion_fit()
    }

    fn ep(group: &str, held_out: bool, success: Option<Result<bool, String>>) -> EvalEpisode {
        EvalEpisode {
            group: group.into(),
            task_id: "t".into(),
            held_out,
            success,
        }
    }

    #[test]
    fn a_group_row_counts_each_side_and_flags_a_policy_that_did_not_learn() {
        let eps = [
            ep("a", false, Some(Ok(true))),
            ep("a", false, Some(Ok(true))),
            ep("a", false, Some(Ok(false))),
            ep("a", true, Some(Ok(false))),
            ep("a", true, Some(Ok(true))),
            ep("a", true, Some(Err("policy unavailable".into()))),
            ep("a", true, None),
            ep("b", true, Some(Ok(true))),
        ];
        let g = GroupGeneralization::build("a", "policies/x", fit(), &eps);
        assert_eq!((g.train.successes, g.train.trials), (2, 3));
        assert_eq!((g.held_out.successes, g.held_out.trials), (1, 2));
        assert_eq!((g.errors.len(), g.pending), (1, 1));
        assert!(!g.did_not_learn());
        let bad = GroupGeneralization::build("b", "m", fit(), &[ep("b", false, Some(Ok(false)))]);
        assert!(bad.did_not_learn());
        let md = GeneralizationResults {
            groups: vec![g, bad],
            errors: vec![],
        }
        .markdown();
        assert!(
            md.contains("| a | policies/x | 4 episodes, 10 steps | 67 % (2/3) [21, 94] |"),
            "{md}"
        );
        assert!(md.contains("it did not learn the group"), "{md}");
        assert!(md.contains("1 episodes still running"), "{md}");
    }

    #[test]
    fn plans_are_checked_and_name_their_policy() {
        let p = GeneralizationPlan::default();
        p.validate().unwrap();
        assert_eq!(
            p.policy_name("policies/ab.dp"),
            "diffusion:model=policies/ab.dp,max_steps=6000"
        );
        let bad = GeneralizationPlan {
            episodes: 1,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().starts_with("episodes"));
        let mut cfg = GeneralizationPlan::default();
        cfg.config.image_size = 60;
        assert!(cfg.validate().unwrap_err().starts_with("config.image_size"));
    }
}
