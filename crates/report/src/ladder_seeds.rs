//! Where a batch's ladder of learned policies ran: on held-out seeds, or on the batch's seeds,
//! whose first ones are the layouts of the demonstrations the policies imitate. A reader of the
//! ranking needs to know which: on their demonstrations' layouts the policies' real success is
//! partly recall of what they were shown (`bench/results/2026-12-01-rank-groups-seeds-20.json`:
//! 0–40 % there against 0–20 % on other seeds).

use serde::{Deserialize, Serialize};

use assay_model::proxy::LadderPlan;

/// Where the ladder's policies ran (`RankingResults::ladder_seeds`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LadderSeeds {
    /// The policy whose episodes the ladder's policies imitate.
    pub train_policy: String,
    /// Episodes the largest run trained on, per group: the group's first ones in planning order.
    pub demonstrations: u32,
    /// Held-out seeds per task the policies ran on, numbered from `held_out_seed_base`; 0: they
    /// ran on the batch's seeds.
    pub held_out_seeds: u32,
    pub held_out_seed_base: u64,
}

impl LadderSeeds {
    pub fn of(plan: &LadderPlan) -> Self {
        Self {
            train_policy: plan.train_policy.clone(),
            demonstrations: plan.runs().last().copied().unwrap_or(0),
            held_out_seeds: plan.held_out_seeds,
            held_out_seed_base: plan.held_out_seed_base,
        }
    }

    /// What the report says of it, and whether it is a caution (the policies ran on their
    /// demonstrations' layouts).
    pub fn describe(&self) -> (bool, String) {
        let (n, policy) = (self.demonstrations, &self.train_policy);
        if self.held_out_seeds > 0 {
            let (first, k) = (self.held_out_seed_base, u64::from(self.held_out_seeds));
            return (
                false,
                format!(
                    "The ladder's policies ran on {k} held-out seed(s) per task ({first}–{}), \
                     layouts that none of their demonstrations (the group's first {n} episodes \
                     of {policy}) had.",
                    first + k - 1
                ),
            );
        }
        (
            true,
            format!(
                "The ladder's policies ran on the batch's seeds, and the group's first {n} \
                 episodes of {policy}, which they imitate, are on the first of those seeds: part \
                 of their real success is on layouts they were shown. The ladder's \
                 held_out_seeds runs them on seeds no episode of the batch used."
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ladder_s_seeds_are_said_and_its_demonstrations_layouts_cautioned() {
        let plan = LadderPlan {
            episodes: vec![10, 40],
            train_episodes: vec![5],
            ..LadderPlan::default()
        };
        let (caution, text) = LadderSeeds::of(&plan).describe();
        assert!(caution);
        assert!(text.contains("first 40 episodes of oracle"), "{text}");
        let held_out = LadderPlan {
            held_out_seeds: 20,
            ..plan
        };
        let (caution, text) = LadderSeeds::of(&held_out).describe();
        assert!(!caution);
        assert!(
            text.contains("20 held-out seed(s) per task (1000000–1000019)"),
            "{text}"
        );
    }
}
