//! Running one trainer shard: text diversity of a batch's texts, or one world-model fit with
//! checkpoints in the artifact store.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use assay_core::clip::Clip;
use assay_core::diversity::TextDiversityTable;
use assay_core::hash::sha256_hex;
use assay_core::trainer::{TrainerJob, TrainerOutcome};

use crate::embedders::Embedders;
use crate::world_model::{FitRequest, fit};

/// Why a trainer shard failed, and whether another attempt could succeed.
#[derive(Debug)]
pub struct JobError {
    pub message: String,
    pub retryable: bool,
}

impl JobError {
    fn permanent(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            retryable: false,
        }
    }
}

/// Where the checkpoints of `job` of `batch` live in the artifact store: one file per job,
/// named by a hash of the job itself, so any worker that gets the shard again finds it.
pub fn checkpoint_path(artifacts: &Path, batch: &str, job: &TrainerJob) -> PathBuf {
    let key = sha256_hex(serde_json::to_string(job).unwrap_or_default().as_bytes());
    artifacts
        .join("checkpoints")
        .join(batch)
        .join(format!("{}.ckpt", &key[..32]))
}

/// Runs `job`. `artifacts` is the artifact store's root (clips are read and checkpoints written
/// there). Text jobs hold `embedders` (the loaded models) while they run; world-model fits of
/// one worker run side by side.
pub fn run(
    job: &TrainerJob,
    batch: &str,
    artifacts: &Path,
    embedders: &Mutex<Embedders>,
    device: tch::Device,
) -> Result<TrainerOutcome, JobError> {
    match job {
        TrainerJob::Text { models, groups } => {
            let mut embedders = embedders.lock().unwrap_or_else(|e| e.into_inner());
            let mut described = Vec::with_capacity(models.len());
            let mut embeddings = Vec::with_capacity(models.len());
            let texts: Vec<&[String]> = groups.iter().map(|(_, t)| t.as_slice()).collect();
            for m in models {
                let (d, per_group) = embedders.column(m, &texts).map_err(|e| JobError {
                    message: e.message,
                    retryable: e.retryable,
                })?;
                described.push(d);
                embeddings.push(per_group);
            }
            Ok(TrainerOutcome::Text {
                table: TextDiversityTable::build(described, groups, &embeddings),
            })
        }
        TrainerJob::Dynamics {
            group,
            budget,
            clips,
            config,
        } => {
            let mut loaded = Vec::with_capacity(clips.len());
            for key in clips {
                let path = artifacts.join(key);
                let bytes = std::fs::read(&path).map_err(|e| JobError {
                    message: format!("dynamics clip {key}: {e}"),
                    retryable: true,
                })?;
                loaded.push(
                    Clip::decode(&bytes)
                        .map_err(|e| JobError::permanent(format!("dynamics clip {key}: {e}")))?,
                );
            }
            let train_n = (*budget as usize).min(loaded.len());
            let ckpt = checkpoint_path(artifacts, batch, job);
            let resume = std::fs::read(&ckpt).ok();
            if resume.is_some() {
                tracing::info!(group, budget, checkpoint = %ckpt.display(), "resuming a world model");
            }
            let mut save = |step: u64, bytes: &[u8]| -> Result<(), String> {
                write_atomically(&ckpt, bytes)
                    .map_err(|e| format!("checkpoint {}: {e}", ckpt.display()))?;
                tracing::debug!(group, budget, step, "world-model checkpoint written");
                Ok(())
            };
            let req = FitRequest {
                config,
                group,
                budget: *budget,
                train: &loaded[..train_n],
                eval: &loaded,
                eval_keys: clips,
                device,
            };
            let fit = fit(&req, resume.as_deref(), &mut save).map_err(|e| JobError {
                message: format!("world model of group {group:?} on {budget} episodes: {e}"),
                retryable: false,
            })?;
            Ok(TrainerOutcome::Dynamics { fit: Box::new(fit) })
        }
    }
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}
