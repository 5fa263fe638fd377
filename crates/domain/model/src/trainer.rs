//! The jobs of the trainer role and what they report: plain data, so the coordinator queues them
//! and builds reports without linking torch.

use serde::{Deserialize, Serialize};

use assay_stats::diversity::TextDiversityTable;

use crate::diffusion::{Backbone, DiffusionConfig, DiffusionFit};
use crate::dynamics::{DynamicsConfig, DynamicsFit};
use crate::proxy::{LadderPlan, ProxyConfig, ProxyEpisode, ProxyResult};

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
        /// Training steps at which the policy is also kept (a ladder's checkpoints; the final
        /// policy is always kept).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        checkpoints: Vec<u64>,
    },
    /// The world-model proxy of one group's ranked episodes (see [`crate::proxy`]).
    Proxy {
        group: String,
        /// Episodes of the training policies, with their real outcomes.
        train: Vec<ProxyEpisode>,
        /// Episodes of the ranked policies, without them.
        eval: Vec<ProxyEpisode>,
        config: ProxyConfig,
        /// The artifact key of the world model a [`TrainerJob::ProxyWorld`] job fitted on these
        /// `train` episodes with these settings: the proxy starts from it instead of fitting
        /// its own (absent: it fits its own).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        world_model: Option<String>,
    },
    /// The proxy's world model of one group, fitted ahead of the proxy on the training
    /// policies' episodes: a ranking with a ladder queues it as soon as the group's episodes are
    /// done, so it trains while the ladder's policies train and run, not after them.
    ProxyWorld {
        group: String,
        /// Episodes of the training policies, as the proxy will get them.
        train: Vec<ProxyEpisode>,
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
    /// A proxy's world model, fitted: its final checkpoint's key in the artifact store.
    ProxyWorld {
        group: String,
        checkpoint: String,
        fit: Box<DynamicsFit>,
    },
    /// A trained diffusion policy: its checkpoint's key in the artifact store and its fit.
    Diffusion {
        group: String,
        model: String,
        fit: Box<DiffusionFit>,
        /// The policies kept at the job's `checkpoints`: (step, key in the artifact store).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        checkpoints: Vec<(u64, String)>,
    },
}

impl TrainerOutcome {
    /// The policies a diffusion training kept: (step, key in the artifact store) for each
    /// checkpoint and the final model, by step, each key once (the final model's step is the
    /// fit's length). Empty for any other outcome.
    pub fn kept_policies(&self) -> Vec<(u64, &str)> {
        let TrainerOutcome::Diffusion {
            model,
            fit,
            checkpoints,
            ..
        } = self
        else {
            return Vec::new();
        };
        let mut kept: Vec<(u64, &str)> = Vec::with_capacity(checkpoints.len() + 1);
        for (step, key) in checkpoints
            .iter()
            .map(|(s, k)| (*s, k.as_str()))
            .chain([(fit.steps, model.as_str())])
        {
            if !kept.iter().any(|(_, k)| *k == key) {
                kept.push((step, key));
            }
        }
        kept.sort_by_key(|(step, _)| *step);
        kept
    }

    /// The policies a finished training of `ladder` kept ([`Self::kept_policies`]), by step,
    /// each with what the planner and the report read of it; empty for any other outcome.
    pub fn ladder_policies(&self, ladder: &LadderPlan) -> Vec<KeptPolicy> {
        let TrainerOutcome::Diffusion { group, fit, .. } = self else {
            return Vec::new();
        };
        self.kept_policies()
            .into_iter()
            .map(|(step, key)| KeptPolicy {
                name: ladder.policy_name(key),
                group: group.clone(),
                family: fit.config.backbone,
                clips: fit.clips,
                step,
                trains_only: ladder.trains_only(fit.clips, step),
            })
            .collect()
    }
}

/// A policy a ladder training kept ([`TrainerOutcome::ladder_policies`]).
#[derive(Debug, Clone, PartialEq)]
pub struct KeptPolicy {
    /// Its episodes' policy name ([`LadderPlan::policy_name`]).
    pub name: String,
    pub group: String,
    /// The run's denoiser.
    pub family: Backbone,
    /// The run's training episodes (fewer than asked when its group has fewer).
    pub clips: u32,
    /// The training step it was kept at.
    pub step: u64,
    /// Kept at one of `train_checkpoints` or by a run of `train_episodes`: it trains the proxy
    /// and is never ranked.
    pub trains_only: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ladder training's policies carry their run, read from the fit (a transformer run on 5
    /// clips, a `train_episodes` run), and are named as the ladder's episodes are.
    #[test]
    fn ladder_policies_carry_their_run_and_role() {
        let plan = LadderPlan {
            episodes: vec![10],
            train_episodes: vec![5],
            checkpoints: vec![300, 1000],
            ..LadderPlan::default()
        };
        let outcome = |clips| TrainerOutcome::Diffusion {
            group: "placement".into(),
            model: "final".into(),
            fit: Box::new(DiffusionFit {
                steps: 1000,
                final_loss: 0.0,
                mean_last_100_loss: 0.0,
                train_seconds: 0.0,
                parameters: 0,
                clips,
                samples: 0,
                device: "cpu".into(),
                libtorch: String::new(),
                config: DiffusionConfig {
                    backbone: Backbone::Transformer,
                    ..DiffusionConfig::default()
                },
            }),
            checkpoints: vec![(300, "early".into()), (1000, "final".into())],
        };
        let kept = outcome(5).ladder_policies(&plan);
        let view: Vec<_> = kept
            .iter()
            .map(|p| (p.name.as_str(), p.step, p.clips, p.trains_only))
            .collect();
        assert_eq!(
            view,
            [
                ("diffusion:model=early,max_steps=6000", 300, 5, true),
                ("diffusion:model=final,max_steps=6000", 1000, 5, true)
            ]
        );
        assert!(
            kept.iter()
                .all(|p| p.group == "placement" && p.family == Backbone::Transformer)
        );
        assert!(
            outcome(10)
                .ladder_policies(&plan)
                .iter()
                .all(|p| !p.trains_only)
        );
    }
}
