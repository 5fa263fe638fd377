//! Running one trainer shard: text diversity of a batch's texts, one world-model fit with
//! checkpoints in the artifact store, a proxy's world model fitted ahead of it, a proxy, or a
//! diffusion policy.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use assay_model::clip::Clip;
use assay_model::episode::Keyframe;
use assay_model::proxy::ProxyEpisode;
use assay_model::trainer::{TrainerJob, TrainerOutcome};
use assay_model::video::WorldModelKind;
use assay_spec::hash::sha256_hex;
use assay_stats::diversity::TextDiversityTable;

use crate::proxy::{PolicyLoader, WorldModelLoader};
use crate::world_model::{FitRequest, fit};
use assay_embed::Embedders;

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

/// Where a world-model fit of `group` stores its checkpoints: the file `ckpt`, written whole.
fn checkpoint_sink<'a>(
    ckpt: &'a Path,
    group: &'a str,
) -> impl FnMut(u64, &[u8]) -> Result<(), String> + 'a {
    move |step, bytes| {
        write_atomically(ckpt, bytes).map_err(|e| format!("checkpoint {}: {e}", ckpt.display()))?;
        tracing::debug!(group, step, checkpoint = %ckpt.display(), "world-model checkpoint written");
        Ok(())
    }
}

/// The jobs this process runs now (a worker runs up to its capacity side by side).
static RUNNING: AtomicUsize = AtomicUsize::new(0);

/// One running job, counted in [`RUNNING`] while it lives.
struct Running;

impl Running {
    fn start() -> Self {
        RUNNING.fetch_add(1, Ordering::SeqCst);
        Self
    }

    /// Whether this is the process's only running job.
    fn alone(&self) -> bool {
        RUNNING.load(Ordering::SeqCst) == 1
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        RUNNING.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Reads an artifact by its key: where it is kept (the caller's choice), else the store.
pub type ArtifactReader<'a> = dyn Fn(&str) -> std::io::Result<Vec<u8>> + 'a;

/// Runs `job`. `artifacts` is the artifact store's root (checkpoints are written there); clips
/// are read with `read`. Text jobs hold `embedders` (the loaded models) while they run;
/// world-model fits of one worker run side by side.
#[allow(clippy::too_many_arguments)]
pub fn run(
    job: &TrainerJob,
    batch: &str,
    artifacts: &Path,
    read: &ArtifactReader<'_>,
    embedders: &Mutex<Embedders>,
    policies: &PolicyLoader<'_>,
    world_models: &WorldModelLoader<'_>,
    device: tch::Device,
) -> Result<TrainerOutcome, JobError> {
    let running = Running::start();
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
        TrainerJob::ProxyWorld {
            group,
            train,
            config,
        } => {
            let keys: Vec<String> = train.iter().map(|e| e.clip.clone()).collect();
            let clips = load_clips(read, &keys)?;
            let ckpt = checkpoint_path(artifacts, batch, job);
            let resume = std::fs::read(&ckpt).ok();
            let mut save = checkpoint_sink(&ckpt, group);
            // Exactly the fit the proxy would run (its settings, its training clips); the RSSM
            // evaluated on one clip only: the proxy evaluates on the ranked ones.
            let fitted = match config.model {
                WorldModelKind::Rssm => {
                    let req = FitRequest {
                        config: &config.world_model,
                        group,
                        budget: clips.len() as u32,
                        train: &clips,
                        eval: &clips[..clips.len().min(1)],
                        eval_keys: &keys[..keys.len().min(1)],
                        device,
                        normalize_actions: config.normalize_actions,
                    };
                    crate::world_model::fit_to_checkpoint(&req, resume.as_deref(), &mut save)
                }
                WorldModelKind::Video => crate::video_model::fit_to_checkpoint(
                    &config.video,
                    &clips,
                    device,
                    resume.as_deref(),
                    &mut save,
                )
                .map(|(vfit, last)| (crate::proxy::video_summary(group, &vfit, config), last)),
            };
            let (fit, last) = fitted.map_err(|e| {
                JobError::permanent(format!("the proxy's world model of group {group:?}: {e}"))
            })?;
            let key = format!(
                "checkpoints/{batch}/world-{}.ckpt",
                &sha256_hex(&last)[..32]
            );
            write_atomically(&artifacts.join(&key), &last).map_err(|e| JobError {
                message: format!("storing the proxy's world model of group {group:?}: {e}"),
                retryable: true,
            })?;
            Ok(TrainerOutcome::ProxyWorld {
                group: group.clone(),
                checkpoint: key,
                fit: Box::new(fit),
            })
        }
        TrainerJob::Proxy {
            group,
            train,
            eval,
            config,
            world_model,
        } => {
            let keys = |e: &[ProxyEpisode]| e.iter().map(|e| e.clip.clone()).collect::<Vec<_>>();
            let train_clips = load_clips(read, &keys(train))?;
            let eval_clips = load_clips(read, &keys(eval))?;
            let ckpt = checkpoint_path(artifacts, batch, job);
            // This job's own checkpoint (an earlier attempt's), else the world model fitted
            // ahead of it (trained to its last step: the proxy goes straight to imagining).
            let mut resume = std::fs::read(&ckpt).ok();
            let mut ahead = false;
            if resume.is_none()
                && let Some(key) = world_model
            {
                resume = Some(read(key).map_err(|e| JobError {
                    message: format!("the proxy's world model {key}: {e}"),
                    retryable: true,
                })?);
                ahead = true;
            }
            let mut save = checkpoint_sink(&ckpt, group);
            let req = crate::proxy::ProxyRequest {
                group,
                policies,
                world_models,
                train,
                train_clips: &train_clips,
                eval,
                eval_clips: &eval_clips,
                config,
                device,
                // Beside the ranking only when no other job of this worker shares the cores.
                diagnostics_beside: running.alone(),
            };
            let mut outcome = crate::proxy::run_proxy(&req, resume.as_deref(), &mut save);
            if ahead
                && let Err(crate::world_model::WorldModelError::CheckpointRefused(why)) = &outcome
            {
                // Not this fit's model (other clips or settings): fit from the start.
                tracing::warn!(group, why = %why, "the world model fitted ahead is refused; fitting the proxy's own");
                outcome = crate::proxy::run_proxy(&req, None, &mut save);
            }
            // A served world model that is down or late is retried, as a remote policy is.
            let mut result = outcome.map_err(|e| JobError {
                retryable: matches!(
                    e,
                    crate::world_model::WorldModelError::World(
                        assay_model::world::WorldError::Unavailable(_)
                    )
                ),
                message: format!("world-model proxy of group {group:?}: {e}"),
            })?;
            // The imagined keyframes go to the artifact store, for the judge role.
            let (width, height) = result.imagined_frame_size;
            let frames = std::mem::take(&mut result.imagined_frames);
            for (p, frames) in result.predictions.iter_mut().zip(frames) {
                for (index, rgb) in frames {
                    let png = crate::imagination::sheet_png(
                        &[vec![rgb.as_slice()]],
                        width as usize,
                        height as usize,
                    );
                    let key = format!("imagery/{}.png", sha256_hex(&png));
                    write_atomically(&artifacts.join(&key), &png).map_err(|e| JobError {
                        message: format!("storing an imagined keyframe of group {group:?}: {e}"),
                        retryable: true,
                    })?;
                    p.imagined_keyframes.push(Keyframe {
                        step: index,
                        camera: "imagined".into(),
                        artifact: key,
                        goals_met: 0,
                    });
                }
            }
            Ok(TrainerOutcome::Proxy {
                result: Box::new(result),
            })
        }
        TrainerJob::Diffusion {
            group,
            clips,
            config,
            checkpoints,
        } => {
            // The same training (same clips, same settings: the same bytes, as training is
            // deterministic) may have run in this batch already — a generalization policy that
            // is a ladder's final one. Without checkpoints to keep, its policy is taken as is.
            let memo = diffusion_memo(artifacts, batch, clips, config);
            if checkpoints.is_empty()
                && let Some((model, fit)) = read_memo(&memo, artifacts)
            {
                tracing::info!(group, model = %model, "diffusion policy: the same training ran in this batch; its policy is reused");
                return Ok(TrainerOutcome::Diffusion {
                    group: group.clone(),
                    model,
                    fit: Box::new(fit),
                    checkpoints: Vec::new(),
                });
            }
            let loaded = load_clips(read, clips)?;
            let mut last = std::time::Instant::now();
            let mut progress = |step: u64, loss: f64| {
                if last.elapsed().as_secs() >= 30 {
                    tracing::info!(group, step, loss, "diffusion policy training");
                    last = std::time::Instant::now();
                }
            };
            let (policy, fit, kept) = crate::diffusion::train_keeping(
                &loaded,
                config,
                checkpoints,
                device,
                &mut progress,
            )
            .map_err(|e| {
                JobError::permanent(format!("diffusion policy of group {group:?}: {e}"))
            })?;
            // Every kept policy is stored as the final one is, by the hash of its bytes.
            let store = |policy: &crate::diffusion::DiffusionPolicy| {
                let bytes = policy.to_bytes();
                let key = format!("policies/{}.diffusion", sha256_hex(&bytes));
                write_atomically(&artifacts.join(&key), &bytes).map_err(|e| JobError {
                    message: format!("storing the diffusion policy of group {group:?}: {e}"),
                    retryable: true,
                })?;
                Ok::<String, JobError>(key)
            };
            let mut stored = Vec::with_capacity(kept.len());
            for (step, p) in &kept {
                stored.push((*step, store(p)?));
            }
            let key = store(&policy)?;
            tracing::info!(group, model = %key, steps = fit.steps, kept = stored.len(), loss = fit.mean_last_100_loss, "diffusion policy trained");
            if let Ok(json) = serde_json::to_vec(&(&key, &fit)) {
                // Best effort: without it, the same training runs again.
                let _ = write_atomically(&memo, &json);
            }
            Ok(TrainerOutcome::Diffusion {
                group: group.clone(),
                model: key,
                fit: Box::new(fit),
                checkpoints: stored,
            })
        }
        TrainerJob::Dynamics {
            group,
            budget,
            clips,
            config,
        } => {
            let loaded = load_clips(read, clips)?;
            let train_n = (*budget as usize).min(loaded.len());
            let ckpt = checkpoint_path(artifacts, batch, job);
            let resume = std::fs::read(&ckpt).ok();
            if resume.is_some() {
                tracing::info!(group, budget, checkpoint = %ckpt.display(), "resuming a world model");
            }
            let mut save = checkpoint_sink(&ckpt, group);
            let req = FitRequest {
                config,
                group,
                budget: *budget,
                train: &loaded[..train_n],
                eval: &loaded,
                eval_keys: clips,
                device,
                normalize_actions: false,
            };
            let fit = fit(&req, resume.as_deref(), &mut save).map_err(|e| JobError {
                message: format!("world model of group {group:?} on {budget} episodes: {e}"),
                retryable: false,
            })?;
            Ok(TrainerOutcome::Dynamics { fit: Box::new(fit) })
        }
    }
}

/// Where a diffusion training of `batch` on `clips` with `config` records its policy's key and
/// fit, for [`read_memo`].
fn diffusion_memo(
    artifacts: &Path,
    batch: &str,
    clips: &[String],
    config: &assay_model::diffusion::DiffusionConfig,
) -> PathBuf {
    let what = serde_json::to_string(&(clips, config)).unwrap_or_default();
    artifacts.join("checkpoints").join(batch).join(format!(
        "diffusion-{}.json",
        &sha256_hex(what.as_bytes())[..32]
    ))
}

/// The policy key and fit a training recorded at `memo`, when its policy is in the store.
fn read_memo(
    memo: &Path,
    artifacts: &Path,
) -> Option<(String, assay_model::diffusion::DiffusionFit)> {
    let (model, fit): (String, assay_model::diffusion::DiffusionFit) =
        serde_json::from_slice(&std::fs::read(memo).ok()?).ok()?;
    artifacts.join(&model).is_file().then_some((model, fit))
}

/// Reads and decodes the clips at `keys`.
fn load_clips(read: &ArtifactReader<'_>, keys: &[String]) -> Result<Vec<Clip>, JobError> {
    let mut loaded = Vec::with_capacity(keys.len());
    for key in keys {
        let bytes = read(key).map_err(|e| JobError {
            message: format!("dynamics clip {key}: {e}"),
            retryable: true,
        })?;
        loaded.push(
            Clip::decode(&bytes)
                .map_err(|e| JobError::permanent(format!("dynamics clip {key}: {e}")))?,
        );
    }
    Ok(loaded)
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}
