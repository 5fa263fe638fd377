//! `assay-export`: a run's results where researchers already look — the flat table of episodes
//! beside every report (`episodes.parquet`), a LeRobotDataset v3.0 of its episodes, and its
//! figures as TensorBoard scalars and as a W&B offline run.
//!
//! Owns: those formats' encodings. Reads a run folder (report.json, the artifact store) and the
//! task specs its caller hands it; never writes into the run.

mod crc;
pub mod episodes_table;
pub mod lerobot;
pub mod scalars;
pub mod tensorboard;
pub mod wandb;

use std::path::Path;

use anyhow::Context;

/// The report of `run`, an `assay eval` output folder.
pub fn read_report(run: &Path) -> anyhow::Result<assay_report::report::Report> {
    let path = run.join("report.json");
    serde_json::from_slice(&std::fs::read(&path).with_context(|| {
        format!(
            "{} is not an `assay eval` output folder (no report.json)",
            run.display()
        )
    })?)
    .with_context(|| format!("reading {}", path.display()))
}
