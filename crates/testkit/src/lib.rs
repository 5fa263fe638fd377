//! `assay-testkit`: what Assay's tests share — a local OpenAI-compatible server that speaks the
//! real protocol over real HTTP (`fixture`), standing in for a hosted vision-language model or
//! embedding endpoint that cannot run in a test; task documents several crates' tests share
//! (`tasks`); and GenSim libraries of a test's own task code (`gensim`).
//!
//! Owns: fixtures and shared test tasks. Never a normal dependency of a crate that ships: every
//! user names it under `[dev-dependencies]`.

pub mod fixture;
pub mod gensim;
pub mod tasks;
