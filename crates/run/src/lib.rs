//! `assay-run`: the library under the `assay` command line — what it takes to run batches and
//! read their results, as functions a test can call without a terminal.
//!
//! - a **local cluster** of real processes and its supervision (`local`), and following a batch
//!   to its end behind an [`follow::Observer`] the caller implements (`follow`: progress,
//!   telemetry rates, a coordinator that comes back);
//! - the **runs** themselves: `assay eval` (`eval`) and `assay watch` (`watch`), their batch
//!   settings (`batch`), the task files they read (`docs`), the output folder's rules
//!   (`outdir`), the import step (`imports`) and the report bundle (`bundle`);
//! - what the other commands do: `export` (a run's specs and episode drawing for
//!   `assay-export`), `doctor`, `diversity`, `frames`, `bench`, and the coordinator client
//!   (`client`) and runtime (`rt`) they share.
//!
//! Owns: the phases of a run and the files it leaves. Never: argument parsing beyond the shared
//! `clap::Args` groups, printing (observers and return values carry everything the command line
//! shows), the coordinator's or the workers' logic (it starts them as processes), or the
//! report's contents (the coordinator and `assay-report` build it).

pub mod batch;
pub mod bench;
pub mod bundle;
pub mod client;
pub mod corpus;
#[cfg(feature = "trainer")]
pub mod diversity;
pub mod docs;
pub mod doctor;
pub mod eval;
pub mod export;
pub mod follow;
pub mod frames;
pub mod imports;
pub mod local;
pub mod outdir;
pub mod rt;
#[cfg(feature = "trainer")]
pub mod watch;
