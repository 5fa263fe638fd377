//! `assay-spec`: what a generated task is — task spec v1 with its strict parsing and validation
//! (every error names the task, the field and the reason), content hashes, Assay's versioned
//! random streams, the asset files a spec names (read with a size bound), URDF documents and their
//! forward kinematics, and the scene geometry a camera draws.
//!
//! Owns: the spec and everything needed to turn one into geometry. Never does IO beyond reading
//! the asset files a spec names; never links physics, rendering, reports, torch or networking.

pub mod assets;
pub mod error;
pub mod hash;
pub mod rng;
pub mod scene;
pub mod spec;
pub mod urdf;

pub use error::{SpecError, SpecErrors};
pub use spec::{TaskSpec, parse_task};
