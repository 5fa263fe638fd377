//! `assay-report`: a batch's report — each section aggregated from the records the job store
//! holds (`report` for success, `quality`, `diversity`, `ranking`, `generalization`), the
//! report's JSON Schema and provenance, and its presentation: Markdown, `report.html` (`html`) and
//! its SVG figures drawn with plotters (`figures`).
//!
//! Owns: aggregation and presentation. Never does IO (artifacts reach the HTML through a
//! callback), never calls a judge or a model, never links physics, rendering, torch or networking.

pub mod diversity;
pub mod figures;
pub mod generalization;
pub mod html;
pub mod markdown;
pub mod quality;
pub mod ranking;
pub mod report;
pub mod tables;
#[cfg(test)]
mod testing;
pub mod view;
