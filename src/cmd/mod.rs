//! One module per subcommand: its arguments, one call into the libraries, what it prints. No
//! command imports another (`tests/it/layout.rs` checks); what several share is `crate::args`,
//! `crate::print` and `crate::progress`.

pub mod agreement;
pub mod bench;
pub mod coordinator;
#[cfg(feature = "trainer")]
pub mod diversity;
pub mod doctor;
pub mod eval;
pub mod export;
pub mod frames;
pub mod import;
pub mod policy;
pub mod rank;
pub mod report;
pub mod status;
pub mod submit;
pub mod token;
pub mod top;
pub mod validate;
#[cfg(feature = "trainer")]
pub mod watch;
pub mod worker;
