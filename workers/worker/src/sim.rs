//! The sim role: one episode per shard on the shard's thread (rapier3d), with the render role of
//! the same process drawing its pictures and a seeing policy's frames when it has one. Without
//! one, an episode whose pictures are wanted returns its scenes, and a render worker draws them.
//!
//! Owns: building the episode's policy object, running it, storing the episode file. Never
//! renders by itself (it asks the render role) and never talks to the coordinator.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use assay_model::episode::{ClipScenes, EpisodeScenes};
use assay_proto::v1 as pb;
use assay_spec::spec::TaskSpec;
use assay_worker_runtime::{ShardError, ShardHandler, artifacts};

use crate::io_error;
use crate::render::{RenderRole, RoleObserver};
use crate::telemetry::Counters;

/// The sim role, with the render role in the same process when asked for.
pub(crate) struct SimRole {
    pub(crate) render: Option<Arc<RenderRole>>,
    /// Record video states for the episodes' videos (drawn here or by a render worker).
    pub(crate) video: bool,
    pub(crate) counters: Arc<Counters>,
    /// The runtime remote policies' gRPC calls run on (shard threads block on it).
    pub(crate) runtime: tokio::runtime::Handle,
}

impl ShardHandler for SimRole {
    fn run(&self, a: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError> {
        self.counters.running.fetch_add(1, Ordering::Relaxed);
        let result = self.episode(a, artifact_root);
        self.counters.running.fetch_sub(1, Ordering::Relaxed);
        match &result {
            Ok(_) => self.counters.episodes.fetch_add(1, Ordering::Relaxed),
            Err(_) => self.counters.failed.fetch_add(1, Ordering::Relaxed),
        };
        result
    }
}

impl SimRole {
    pub(crate) fn episode(
        &self,
        a: &pb::Assignment,
        artifact_root: &Path,
    ) -> Result<String, ShardError> {
        let spec: TaskSpec = serde_json::from_str(&a.task_spec_json).map_err(|e| {
            ShardError::permanent(format!(
                "task spec from the coordinator does not parse: {e}"
            ))
        })?;
        let policy = a
            .policy
            .as_ref()
            .map(|p| p.name.as_str())
            .unwrap_or("oracle");
        // The batch wants the episode's pictures (a clip is pictures too): drawn here when this
        // worker renders, else by a render worker from the scenes this returns.
        let pictures = a.render || a.clip_size > 0;
        let video_frames = if pictures && self.video {
            assay_sim::VIDEO_FRAMES
        } else {
            0
        };
        let mut observer = self.render.as_deref().map(|role| RoleObserver {
            role,
            shard: a.shard_id,
        });
        let clip_size = a.clip_size;
        // A clip at a policy's interface: its cameras without a size at the clip size.
        let clip_interface = match a.clip_interface.as_str() {
            "" => None,
            args => {
                let i = assay_model::policy::Interface::parse_args(args).map_err(|e| {
                    ShardError::permanent(format!("task {}: clip interface: {e}", spec.id))
                })?;
                Some(i.sized(clip_size))
            }
        };
        // Every policy but the built-in oracle is a policy object, made for this episode: a
        // remote server is health-checked here, a model is loaded from this worker or the
        // artifact store.
        let parsed = assay_model::policy::PolicySpec::parse(policy)
            .map_err(|e| ShardError::permanent(format!("task {}: {e}", spec.id)))?;
        let mut object = if parsed.is_oracle() {
            None
        } else {
            let loaded = assay_policy::load_with(
                &parsed,
                artifact_root,
                &self.runtime,
                crate::diffusion_loader(),
            )
            .map_err(|e| {
                let msg = format!("task {} seed {}: policy '{policy}': {e}", spec.id, a.seed);
                if e.retryable() {
                    ShardError::retryable(msg)
                } else {
                    ShardError::permanent(msg)
                }
            })?;
            Some(loaded)
        };
        let frame_size = object.as_ref().and_then(|p| p.frame_size()).unwrap_or(0);
        let options = assay_sim::SimOptions {
            video_frames,
            clip: clip_size > 0,
            clip_interface,
            observer: observer.as_mut().map(|o| o as &mut dyn assay_sim::Observer),
            policy: object
                .as_deref_mut()
                .map(|p| p as &mut dyn assay_model::policy::Policy),
            frame_size,
        };
        let ep = assay_sim::simulate_with(&spec, a.seed, policy, options).map_err(|e| {
            let msg = format!("task {}: {e}", spec.id);
            if e.retryable() {
                ShardError::retryable(msg)
            } else {
                ShardError::permanent(msg)
            }
        })?;
        let mut outcome = ep.outcome.clone();
        outcome.artifact = artifacts::put(artifact_root, "episodes", "arrow", &ep.file)
            .map_err(io_error("episodes"))?;
        self.counters
            .steps
            .fetch_add(outcome.steps, Ordering::Relaxed);
        self.counters
            .frames
            .fetch_add(ep.observations, Ordering::Relaxed);
        if pictures {
            let scenes = scenes_of(ep);
            match &self.render {
                Some(render) => {
                    outcome.imagery = Some(render.draw(
                        &spec,
                        a.shard_id,
                        scenes,
                        clip_size,
                        artifact_root,
                        &self.counters,
                    )?);
                }
                // The coordinator queues the episode for a render worker.
                None => outcome.scenes = Some(scenes),
            }
        }
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

/// What an episode's pictures are drawn from.
fn scenes_of(ep: assay_sim::Episode) -> EpisodeScenes {
    EpisodeScenes {
        initial: ep.initial,
        initial_step: ep.initial_step,
        keyframes: ep.keyframes,
        keyframe_goals: ep.keyframe_goals,
        video: ep.video,
        clip: ep.clip.map(|c| ClipScenes {
            interval_s: c.interval_s,
            steps: c.steps,
            scenes: c.scenes,
            proprio: c.proprio,
            actions: c.actions,
            interface: c.interface.map(|i| i.to_args()).unwrap_or_default(),
            cameras: c.cameras,
        }),
    }
}
