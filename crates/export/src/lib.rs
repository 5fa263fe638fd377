//! `assay-export`: a run's results where researchers already look — the flat table of episodes
//! beside every report (`episodes.parquet`), a LeRobotDataset v3.0 of its episodes, and its
//! figures as TensorBoard scalars.
//!
//! Owns: those formats' encodings. Reads a run folder (report.json, the artifact store) and the
//! task specs its caller hands it; never writes into the run.

pub mod episodes_table;
pub mod lerobot;
pub mod tensorboard;
