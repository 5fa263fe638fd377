//! Assay's integration tests, one module per area, in one test binary (one link instead of one
//! per file on a 2-core CI). Most start the real `assay` binary: a coordinator and workers on
//! loopback, real iceoryx2, zenoh, rapier3d, wgpu (lavapipe without a GPU) and libtorch.

mod common;

mod agreement;
mod boundary;
mod cluster;
mod deploy;
mod diversity;
mod eval;
mod export;
mod forbidden_dependencies;
mod framebus;
mod generalization;
mod gensim;
mod gensim_seeds;
mod import;
mod judge;
mod large_batch;
mod layout;
mod library;
mod netns;
mod operations;
mod policies;
mod rank;
mod ranking;
mod real_policies;
mod report;
mod roles;
mod scripts;
mod security;
mod telemetry;
mod watch;
