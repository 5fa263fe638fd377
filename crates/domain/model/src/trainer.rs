//! The jobs of the trainer role and what they report: plain data, so the coordinator queues them
//! and builds reports without linking torch.

use serde::{Deserialize, Serialize};

use assay_stats::diversity::TextDiversityTable;

use crate::diffusion::{DiffusionConfig, DiffusionFit};
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
}
