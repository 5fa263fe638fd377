//! `assay-plan`: what a batch is before anything runs — its task documents parsed, validated and
//! confined to the operator's asset roots (`documents`), the texts text diversity embeds
//! (`texts`), the interfaces its policies declare checked against its tasks (`interfaces`), the
//! hash of its content (`hash`), and its settings checked against each other (`settings`).
//!
//! The coordinator plans every submitted batch with it, and a client (`assay eval`, `assay
//! validate`, `assay watch`) runs the same functions before it starts a process, so what the
//! coordinator would refuse never costs a cluster start. Errors are typed ([`PlanError`],
//! [`settings::SettingsError`]); the coordinator maps them to gRPC status codes in one place.
//!
//! Never: gRPC or any generated protocol type (the protocol crate converts at the edge), the job
//! store, files (documents arrive as text; asset roots are paths the operator gave), physics,
//! rendering or torch.

pub mod documents;
pub mod error;
pub mod hash;
pub mod interfaces;
pub mod settings;
pub mod texts;

pub use documents::{PlannedTask, TaskDocument, plan_tasks};
pub use error::PlanError;
pub use settings::{BatchSettings, DynamicsPlan, Settings, SettingsError};
