//! What a shard of a batch does, and the states it moves through: the words the job store keeps
//! for them (`shards.kind`, `shards.state`).
//!
//! Owns: [`JobKind`], [`ShardState`] and a batch's [`Priority`], and the one conversion of each to and from its stored
//! text. Never decides which shards a batch has, never reads a store, never names a job for
//! people (the store's `job` column does: "ladder kitchen @ 10").

use std::fmt;
use std::str::FromStr;

/// What a shard does. Shards are told apart by this, never by their job's name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum JobKind {
    /// An episode of one of the batch's policies: those it was submitted with and a ranking
    /// ladder's learned ones (queued as the ladder trains; they count in the batch's success
    /// tables and are ranked like the others).
    Episode,
    /// An episode of a group's generalization policy on a variation it was trained on.
    GeneralizationTrainEpisode,
    /// An episode of a group's generalization policy on a held-out variation.
    GeneralizationHeldOutEpisode,
    /// A judge's verdict on an episode (quality).
    EpisodeJudging,
    /// A judge's verdict on a proxy's imagined rollout of a ranked episode.
    ImaginedJudging,
    /// Text diversity of the batch's task texts (one per batch).
    TextDiversity,
    /// One world-model fit of a group at one episode budget (dynamics diversity).
    DynamicsFit,
    /// A group's proxy world model, fitted ahead of its proxy while the ladder trains.
    ProxyWorldModel,
    /// A group's world-model proxy, which ranks its policies.
    Proxy,
    /// One training run of a group's ranking ladder (its policies kept at checkpoints).
    LadderTraining,
    /// A group's generalization diffusion policy.
    GeneralizationTraining,
}

impl JobKind {
    /// Every kind, in declaration order.
    pub const ALL: [JobKind; 11] = [
        JobKind::Episode,
        JobKind::GeneralizationTrainEpisode,
        JobKind::GeneralizationHeldOutEpisode,
        JobKind::EpisodeJudging,
        JobKind::ImaginedJudging,
        JobKind::TextDiversity,
        JobKind::DynamicsFit,
        JobKind::ProxyWorldModel,
        JobKind::Proxy,
        JobKind::LadderTraining,
        JobKind::GeneralizationTraining,
    ];

    /// The kind as the job store keeps it.
    pub const fn as_str(self) -> &'static str {
        match self {
            JobKind::Episode => "episode",
            JobKind::GeneralizationTrainEpisode => "generalization_train_episode",
            JobKind::GeneralizationHeldOutEpisode => "generalization_held_out_episode",
            JobKind::EpisodeJudging => "episode_judging",
            JobKind::ImaginedJudging => "imagined_judging",
            JobKind::TextDiversity => "text_diversity",
            JobKind::DynamicsFit => "dynamics_fit",
            JobKind::ProxyWorldModel => "proxy_world_model",
            JobKind::Proxy => "proxy",
            JobKind::LadderTraining => "ladder_training",
            JobKind::GeneralizationTraining => "generalization_training",
        }
    }

    /// Whether the shard runs an episode (its outcome is an `EpisodeOutcome`).
    pub const fn is_episode(self) -> bool {
        matches!(
            self,
            JobKind::Episode
                | JobKind::GeneralizationTrainEpisode
                | JobKind::GeneralizationHeldOutEpisode
        )
    }

    /// Whether the shard is a judge's (its outcome is a `JudgeOutcome`).
    pub const fn is_judging(self) -> bool {
        matches!(self, JobKind::EpisodeJudging | JobKind::ImaginedJudging)
    }

    /// Whether the shard is a trainer's (its outcome is a `TrainerOutcome`).
    pub const fn is_training(self) -> bool {
        !self.is_episode() && !self.is_judging()
    }
}

impl fmt::Display for JobKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A stored kind this version does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown job kind {0:?}")]
pub struct UnknownJobKind(pub String);

impl FromStr for JobKind {
    type Err = UnknownJobKind;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        JobKind::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or_else(|| UnknownJobKind(s.to_owned()))
    }
}

/// Where a shard is: queued → leased → done | failed | cancelled; an expired or returned lease
/// goes back to queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ShardState {
    Queued,
    Leased,
    Done,
    Failed,
    Cancelled,
}

impl ShardState {
    pub const ALL: [ShardState; 5] = [
        ShardState::Queued,
        ShardState::Leased,
        ShardState::Done,
        ShardState::Failed,
        ShardState::Cancelled,
    ];

    /// The state as the job store keeps it.
    pub const fn as_str(self) -> &'static str {
        match self {
            ShardState::Queued => "queued",
            ShardState::Leased => "leased",
            ShardState::Done => "done",
            ShardState::Failed => "failed",
            ShardState::Cancelled => "cancelled",
        }
    }

    /// Still to run or running.
    pub const fn is_open(self) -> bool {
        matches!(self, ShardState::Queued | ShardState::Leased)
    }
}

impl fmt::Display for ShardState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A stored state this version does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown shard state {0:?}")]
pub struct UnknownShardState(pub String);

impl FromStr for ShardState {
    type Err = UnknownShardState;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        ShardState::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or_else(|| UnknownShardState(s.to_owned()))
    }
}

/// How much of the cluster a batch asks for, beside the other running batches: workers are
/// shared between batches in proportion to their class's weight (a weighted fair share, not a
/// strict order: a low batch still moves while a high one runs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub enum Priority {
    /// Continuous evaluation (`assay watch`) by default: weight 1.
    Low,
    /// A person's batch by default: weight 4.
    #[default]
    Normal,
    /// Weight 16: a batch someone waits on.
    High,
}

impl Priority {
    pub const ALL: [Priority; 3] = [Priority::Low, Priority::Normal, Priority::High];

    /// The priority as the job store and the protocol keep it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Priority::Low => "low",
            Priority::Normal => "normal",
            Priority::High => "high",
        }
    }

    /// The class's weight in the fair share: one submitter's running batches of a class share
    /// it between them.
    pub const fn weight(self) -> f64 {
        match self {
            Priority::Low => 1.0,
            Priority::Normal => 4.0,
            Priority::High => 16.0,
        }
    }
}

impl fmt::Display for Priority {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A priority this version does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown priority {0:?} (low, normal or high)")]
pub struct UnknownPriority(pub String);

impl FromStr for Priority {
    type Err = UnknownPriority;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Priority::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or_else(|| UnknownPriority(s.to_owned()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_and_state_reads_back_from_its_stored_text() {
        for k in JobKind::ALL {
            assert_eq!(k.as_str().parse::<JobKind>(), Ok(k));
            assert_eq!(
                [k.is_episode(), k.is_judging(), k.is_training()]
                    .iter()
                    .filter(|b| **b)
                    .count(),
                1,
                "{k}"
            );
        }
        for s in ShardState::ALL {
            assert_eq!(s.as_str().parse::<ShardState>(), Ok(s));
        }
        assert_eq!(
            "ladder".parse::<JobKind>(),
            Err(UnknownJobKind("ladder".into()))
        );
        assert!("running".parse::<ShardState>().is_err());
        for p in Priority::ALL {
            assert_eq!(p.as_str().parse::<Priority>(), Ok(p));
        }
        assert!(
            "urgent"
                .parse::<Priority>()
                .unwrap_err()
                .to_string()
                .contains("low, normal or high")
        );
        assert!(Priority::Low.weight() < Priority::Normal.weight());
        assert!(Priority::Normal.weight() < Priority::High.weight());
    }
}
