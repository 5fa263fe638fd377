//! `assay-proto`: the gRPC contract between the coordinator, its clients and its workers.
//!
//! Owns: `assay/v1/*.proto`, the generated types and their conversions to and from the domain's
//! types (`convert`: task documents, batch settings, spec errors), the credentials (cluster
//! token, role keys, the coordinator's keyring: [`auth`]) and how a client opens a channel
//! ([`channel`]). Never holds logic beyond conversions and connection set-up; never links physics,
//! rendering or torch.

#[allow(clippy::all, clippy::pedantic, rust_2018_idioms)]
pub mod v1 {
    tonic::include_proto!("assay.v1");
}

pub use v1::*;

pub mod auth;
pub mod channel;
mod convert;

/// Message size limit for every Assay channel (frames and reports exceed tonic's 4 MiB default).
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024 * 1024;

/// The largest batch `Coordinator/SubmitBatchStream` takes, all its messages together.
pub const MAX_BATCH_BYTES: usize = 1024 * 1024 * 1024;

/// The size of each message a client streams a large batch in; a batch whose request is larger
/// goes by `SubmitBatchStream`, a smaller one by `SubmitBatch`.
pub const SUBMIT_CHUNK_BYTES: usize = 32 * 1024 * 1024;

impl Role {
    /// The lowercase role name used on the command line and in logs.
    pub fn name(self) -> &'static str {
        match self {
            Role::Unspecified => "unspecified",
            Role::Sim => "sim",
            Role::Render => "render",
            Role::Judge => "judge",
            Role::Trainer => "trainer",
        }
    }

    pub fn parse(s: &str) -> Option<Role> {
        match s {
            "sim" => Some(Role::Sim),
            "render" => Some(Role::Render),
            "judge" => Some(Role::Judge),
            "trainer" => Some(Role::Trainer),
            _ => None,
        }
    }
}

impl BatchState {
    pub fn is_final(self) -> bool {
        matches!(
            self,
            BatchState::Completed | BatchState::Cancelled | BatchState::Skipped
        )
    }
}
