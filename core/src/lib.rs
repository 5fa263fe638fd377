//! `assay-core`: Assay's pure domain — task spec v1 and its validation, policy names,
//! deterministic random streams, scene snapshots that cameras draw, episode outcomes, batch
//! reports and the statistics they use.
//!
//! Owns: the data model every other crate agrees on. Never does IO beyond parsing strings and
//! reading the asset files a spec names (URDF and its meshes), never links physics, rendering,
//! torch or networking.

pub mod agreement;
pub mod assets;
pub mod caption;
pub mod clip;
pub mod diffusion;
pub mod diversity;
pub mod dynamics;
pub mod error;
pub mod figures;
pub mod generalization;
pub mod hash;
pub mod html;
pub mod import;
pub mod policy;
pub mod proxy;
pub mod quality;
pub mod quality_report;
pub mod ranking;
pub mod report;
pub mod rng;
pub mod scene;
pub mod spec;
pub mod stats;
pub mod trainer;
pub mod urdf;

pub use error::{SpecError, SpecErrors};
pub use spec::{TaskSpec, parse_task};
