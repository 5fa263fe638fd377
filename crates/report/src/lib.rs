//! `assay-report`: a batch's report — assembled from the rows the job store holds (`rows`,
//! `assemble`), each section aggregated by its module (`report` for success, `quality`,
//! `diversity`, `ranking`, `generalization`), the report's JSON Schema and provenance, and its
//! presentation: Markdown, `report.html` (`html`) and its SVG figures drawn with plotters
//! (`figures`).
//!
//! Owns: assembly, aggregation and presentation. Never does IO (the coordinator selects the rows;
//! artifacts reach the HTML through a callback), never calls a judge or a model, never links a
//! database, physics, rendering, torch or networking.

pub mod assemble;
pub mod diversity;
pub mod figures;
pub mod generalization;
pub mod html;
pub mod ladder_seeds;
pub mod markdown;
pub mod quality;
pub mod ranking;
pub mod report;
pub mod rows;
pub mod tables;
#[cfg(test)]
mod testing;
pub mod view;
