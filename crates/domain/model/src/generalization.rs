//! Generalization (the generative-simulation paper's §3.5 and §4.3, Table 3): per task group, a
//! diffusion policy trained on the group's episodes of one policy (the oracle's: 40 trajectories
//! by default, as the paper), then run on **held-out variations** — the same tasks under seeds
//! never trained on, which redraw whatever the task's `variations` declare (object poses, the
//! tool's start, the colours of the objects it recolours) — and on the variations it was
//! trained on. A policy that fails even on its training variations
//! did not learn the group; its held-out rate says nothing about generalization, and the report
//! says so. Plain data: training lives in `assay-trainer`, the episodes in the sim role.

use serde::{Deserialize, Serialize};

use crate::diffusion::DiffusionConfig;

/// The generalization part of a batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct GeneralizationPlan {
    /// Whose episodes the policy imitates.
    pub train_policy: String,
    /// Training episodes per group: the group's first ones in planning order (seed-major, so
    /// every task contributes before any contributes twice).
    pub episodes: u32,
    /// Held-out seeds per task, numbered from `held_out_seed_base` (far from the batch's seeds).
    pub held_out_seeds: u32,
    pub held_out_seed_base: u64,
    /// Horizon of the policy's episodes, physics steps (the oracle's plans take 1000–3700 on the
    /// example corpus); the task's own `physics.max_steps` when smaller.
    pub max_steps: u32,
    pub config: DiffusionConfig,
    /// The task groups that get a policy; empty: every group of the batch.
    pub groups: Vec<String>,
}

impl Default for GeneralizationPlan {
    fn default() -> Self {
        Self {
            train_policy: "oracle".into(),
            episodes: 40,
            held_out_seeds: 3,
            held_out_seed_base: 1_000_000,
            max_steps: 6000,
            config: DiffusionConfig::default(),
            groups: Vec::new(),
        }
    }
}

impl GeneralizationPlan {
    pub fn validate(&self) -> Result<(), String> {
        if self.episodes < 2 {
            return Err("episodes: at least 2 training episodes per group".into());
        }
        if self.held_out_seeds == 0 {
            return Err("held_out_seeds: at least 1 held-out seed per task".into());
        }
        if !seeds_fit(self.held_out_seed_base, self.held_out_seeds) {
            return Err(format!(
                "held_out_seed_base: {} + {} held-out seeds passes the largest seed",
                self.held_out_seed_base, self.held_out_seeds
            ));
        }
        if self.max_steps == 0 {
            return Err("max_steps: must be at least 1".into());
        }
        if self.groups.iter().any(|g| g.trim().is_empty()) {
            return Err("groups: a group name is empty".into());
        }
        self.config.validate().map_err(|e| format!("config.{e}"))
    }

    /// Whether `group` gets a policy.
    pub fn covers(&self, group: &str) -> bool {
        self.groups.is_empty() || self.groups.iter().any(|g| g == group)
    }

    /// The policy name of a trained model's episodes.
    pub fn policy_name(&self, model: &str) -> String {
        format!("diffusion:model={model},max_steps={}", self.max_steps)
    }
}

/// The job names of a trained policy's evaluation episodes, by the variations they run on; their
/// kinds are [`crate::job::JobKind::GeneralizationTrainEpisode`] and
/// [`crate::job::JobKind::GeneralizationHeldOutEpisode`].
pub const TRAIN_VARIATIONS: &str = "generalization train";
pub const HELD_OUT_VARIATIONS: &str = "generalization held-out";

/// Whether `n` seeds from `base` are all seeds a shard can hold (the store keeps them as i64).
pub(crate) fn seeds_fit(base: u64, n: u32) -> bool {
    base.checked_add(u64::from(n))
        .is_some_and(|end| end <= i64::MAX as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_out_seeds_past_the_largest_seed_are_refused() {
        assert_eq!(GeneralizationPlan::default().validate(), Ok(()));
        let far = GeneralizationPlan {
            held_out_seed_base: i64::MAX as u64 - 1,
            ..GeneralizationPlan::default()
        };
        let e = far.validate().unwrap_err();
        assert!(
            e.starts_with("held_out_seed_base: 9223372036854775806 + 3 held-out seeds passes"),
            "{e}"
        );
    }
}
