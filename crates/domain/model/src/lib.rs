//! `assay-model`: the records that cross process boundaries — episode outcomes, keyframes and
//! task info (`episode`), the policy interface and policy names (`policy`), dynamics clips
//! (`clip`), the judge protocol and scene captions (`quality`, `caption`), the plans and
//! results of the trainer role's jobs (`trainer`, `dynamics`, `diffusion`, `proxy`,
//! `generalization`), and what a batch's shard does and where it is (`job`).
//!
//! Owns: plain data every role and the coordinator agree on, with its validation and wire format.
//! Never aggregates a report, never draws, never does IO (a clip is encoded to and decoded from
//! bytes the caller holds); never links physics, rendering, torch or networking.

pub mod caption;
pub mod clip;
pub mod diffusion;
pub mod dynamics;
pub mod episode;
pub mod generalization;
pub mod interface;
pub mod job;
pub mod policy;
pub mod proxy;
pub mod quality;
pub mod trainer;
pub mod video;
pub mod world;
