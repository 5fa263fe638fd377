//! The render role: one thread owns the device (a GPU, or lavapipe) and this worker's frame-bus
//! stream `<worker-id>/imagery`; shard threads send it episodes and wait for their pictures, and a
//! seeing policy's frames while its episode runs. Alone in a worker it runs render shards: the
//! pictures of episodes sim-only workers simulated, from their scene states. What it stores it
//! also keeps in memory for the node's judges (`assay_framebus::cache`).
//!
//! Owns: the render thread, the frame-bus samples it draws into, storing pictures, captions,
//! videos and clips in the artifact store. Never runs physics or talks to the coordinator.

use std::path::Path;
use std::sync::atomic::Ordering;

use assay_model::episode::{ClipScenes, EpisodeImagery, EpisodeScenes, Keyframe, NamedArtifact};
use assay_proto::v1 as pb;
use assay_render::Renderer;
use assay_render::imagery::Shot;
use assay_spec::scene::{Observation, SceneSnapshot, task_cameras};
use assay_spec::spec::{Camera, TaskSpec};
use assay_worker_runtime::{ShardError, artifacts};

use crate::io_error;
use crate::telemetry::Counters;

/// The render role: one thread owns the device (a GPU, or lavapipe) and this worker's frame-bus
/// stream `<worker-id>/imagery`; shard threads send it episodes and wait for their pictures, and
/// a seeing policy's frames while its episode runs. Every
/// view and keyframe is read back straight into a shared-memory sample, encoded from there, and
/// published: a judge, a viewer or `assay frames relay` on the node reads it in place.
pub(crate) struct RenderRole {
    pub(crate) jobs: std::sync::mpsc::Sender<RenderJob>,
    pub(crate) adapter: String,
    /// Keeps this worker's pictures and captions in memory for the node's judges (None: no
    /// shared memory on this node).
    keeper: Option<assay_framebus::cache::ArtifactKeeper>,
}

pub(crate) enum RenderJob {
    Episode(Box<EpisodeJob>),
    /// The RGB frame a policy object sees (the task camera at the policy's frame size).
    Frame {
        scene: SceneSnapshot,
        camera: Camera,
        reply: std::sync::mpsc::Sender<Result<Vec<u8>, assay_render::RenderError>>,
    },
    /// What a seeing policy's camera sees now: RGB into a frame-bus sample (camera
    /// [`POLICY_CAMERA_ID`]), depth and segments back to the policy.
    Look {
        shard: u64,
        step: u64,
        scene: SceneSnapshot,
        camera: Camera,
        reply: std::sync::mpsc::Sender<Result<Observation, assay_render::RenderError>>,
    },
}

/// Frame-bus camera id of a seeing policy's frames (keyframes are 0, scene views 1000 + i).
pub const POLICY_CAMERA_ID: u32 = 2000;

pub(crate) struct EpisodeJob {
    pub(crate) shard: u64,
    pub(crate) initial: SceneSnapshot,
    pub(crate) initial_step: u64,
    pub(crate) keyframes: Vec<(u64, SceneSnapshot)>,
    /// Video states; empty when no video is wanted.
    pub(crate) video: Vec<(u64, SceneSnapshot)>,
    /// Dynamics clip states and the clip's frame size, when the shard asks for a clip.
    pub(crate) clip: Option<(ClipScenes, u32)>,
    pub(crate) camera: Camera,
    pub(crate) reply: std::sync::mpsc::Sender<Result<Rendered, assay_render::RenderError>>,
}

pub(crate) struct Rendered {
    pub(crate) imagery: assay_render::imagery::Imagery,
    pub(crate) video: Option<assay_render::video::Video>,
    pub(crate) caption: assay_model::caption::SceneCaption,
    pub(crate) clip: Option<assay_model::clip::Clip>,
}

impl RenderRole {
    /// Starts the render thread; `keep_bytes` is how much of what it draws is kept in memory
    /// for the node's judges (0: nothing).
    pub(crate) fn start(
        renderer: Renderer,
        stream: String,
        size: (u32, u32),
        keep_bytes: usize,
    ) -> anyhow::Result<Self> {
        let adapter = renderer.adapter().to_string();
        let (jobs, rx) = std::sync::mpsc::channel::<RenderJob>();
        std::thread::Builder::new()
            .name("render".into())
            .spawn(move || render_loop(renderer, &stream, size, rx))?;
        let keeper = if keep_bytes == 0 {
            None
        } else {
            match assay_framebus::cache::ArtifactKeeper::start(
                &format!("assay-keeper-{}", std::process::id()),
                keep_bytes,
            ) {
                Ok(k) => Some(k),
                Err(e) => {
                    tracing::warn!(error = %e, "no shared memory: judges on this node read pictures from the artifact store");
                    None
                }
            }
        };
        Ok(RenderRole {
            jobs,
            adapter,
            keeper,
        })
    }

    /// Draws an episode's pictures and counts them.
    pub(crate) fn draw(
        &self,
        spec: &TaskSpec,
        shard: u64,
        scenes: EpisodeScenes,
        clip_size: u32,
        root: &Path,
        counters: &Counters,
    ) -> Result<EpisodeImagery, ShardError> {
        let video_frames = scenes.video.len();
        let clip_frames = scenes.clip.as_ref().map_or(0, |c| c.scenes.len());
        let imagery = self.imagery(spec, shard, scenes, clip_size, root)?;
        counters.frames.fetch_add(
            (imagery.views.len() + imagery.keyframes.len() + video_frames + clip_frames) as u64,
            Ordering::Relaxed,
        );
        Ok(imagery)
    }

    /// A render shard: the pictures of an episode a sim worker without a renderer simulated,
    /// drawn from the scenes it returned. Answers the episode's outcome with its pictures.
    pub(crate) fn run(
        &self,
        a: &pb::Assignment,
        root: &Path,
        counters: &Counters,
    ) -> Result<String, ShardError> {
        let spec: TaskSpec = serde_json::from_str(&a.task_spec_json).map_err(|e| {
            ShardError::permanent(format!(
                "task spec from the coordinator does not parse: {e}"
            ))
        })?;
        let mut outcome: assay_model::episode::EpisodeOutcome = serde_json::from_str(&a.input_json)
            .map_err(|e| {
                ShardError::permanent(format!(
                    "task {}: the episode to render does not parse: {e}",
                    spec.id
                ))
            })?;
        let scenes = outcome.scenes.take().ok_or_else(|| {
            ShardError::permanent(format!(
                "task {} seed {}: the episode to render carries no scenes",
                spec.id, a.seed
            ))
        })?;
        counters.running.fetch_add(1, Ordering::Relaxed);
        let drawn = self.draw(&spec, a.shard_id, scenes, a.clip_size, root, counters);
        counters.running.fetch_sub(1, Ordering::Relaxed);
        outcome.imagery = Some(drawn?);
        counters.rendered.fetch_add(1, Ordering::Relaxed);
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }

    /// Stores `bytes` in the artifact store and keeps them in memory for the node's readers.
    fn put(
        &self,
        root: &Path,
        kind: &str,
        ext: &str,
        bytes: Vec<u8>,
    ) -> Result<String, ShardError> {
        let key = artifacts::put(root, kind, ext, &bytes).map_err(io_error(kind))?;
        if let Some(k) = &self.keeper {
            k.keep(&key, bytes);
        }
        Ok(key)
    }

    /// Renders and stores an episode's pictures from its scenes, and its dynamics clip at
    /// `clip_size` pixels square when it carries clip states. The pictures and the caption are
    /// also kept in this process's memory, where the node's judges read them.
    pub(crate) fn imagery(
        &self,
        spec: &TaskSpec,
        shard: u64,
        ep: EpisodeScenes,
        clip_size: u32,
        root: &Path,
    ) -> Result<EpisodeImagery, ShardError> {
        let (reply, answer) = std::sync::mpsc::channel();
        let goals_met = ep.keyframe_goals;
        let job = RenderJob::Episode(Box::new(EpisodeJob {
            shard,
            initial: ep.initial,
            initial_step: ep.initial_step,
            keyframes: ep.keyframes,
            video: ep.video,
            clip: ep.clip.map(|c| (c, clip_size)),
            camera: task_cameras(&spec.cameras).remove(0),
            reply,
        }));
        let gone = || ShardError::retryable("the render thread stopped");
        self.jobs.send(job).map_err(|_| gone())?;
        let rendered = answer.recv().map_err(|_| gone())?.map_err(|e| {
            let msg = format!("task {}: rendering: {e}", spec.id);
            match e {
                assay_render::RenderError::Scene { .. } => ShardError::permanent(msg),
                _ => ShardError::retryable(msg),
            }
        })?;
        let img = rendered.imagery;
        let put = |bytes: Vec<u8>| self.put(root, "imagery", "png", bytes);
        let mut views = Vec::new();
        for (name, i) in &img.views {
            views.push(NamedArtifact {
                name: name.clone(),
                artifact: put(i.png())?,
            });
        }
        let mut keyframes = Vec::new();
        for (k, (step, cam, i)) in img.keyframes.iter().enumerate() {
            keyframes.push(Keyframe {
                step: *step,
                camera: cam.clone(),
                artifact: put(i.png())?,
                goals_met: goals_met.get(k).copied().unwrap_or(0),
            });
        }
        let video = match rendered.video {
            Some(v) => Some(
                artifacts::put(root, "video", v.extension, &v.bytes).map_err(io_error("video"))?,
            ),
            None => None,
        };
        let clip = match rendered.clip {
            Some(c) => Some(self.put(root, "clips", "clip", c.encode())?),
            None => None,
        };
        let caption = serde_json::to_vec_pretty(&rendered.caption)
            .map_err(|e| ShardError::permanent(format!("scene caption: {e}")))?;
        Ok(EpisodeImagery {
            adapter: self.adapter.clone(),
            views,
            keyframes,
            contact_sheet: artifacts::put(root, "imagery", "png", &img.sheet.png())
                .map_err(io_error("imagery"))?,
            video,
            caption: Some(self.put(root, "captions", "json", caption)?),
            clip,
        })
    }
}

/// A seeing policy's camera, served by the render thread.
pub(crate) struct RoleObserver<'a> {
    pub(crate) role: &'a RenderRole,
    pub(crate) shard: u64,
}

impl assay_sim::Observer for RoleObserver<'_> {
    fn observe(
        &mut self,
        scene: SceneSnapshot,
        step: u64,
        camera: &Camera,
    ) -> Result<Observation, String> {
        let (reply, answer) = std::sync::mpsc::channel();
        let gone = || "the render thread stopped".to_owned();
        self.role
            .jobs
            .send(RenderJob::Look {
                shard: self.shard,
                step,
                scene,
                camera: camera.clone(),
                reply,
            })
            .map_err(|_| gone())?;
        answer
            .recv()
            .map_err(|_| gone())?
            .map_err(|e| e.to_string())
    }

    fn frame(
        &mut self,
        scene: SceneSnapshot,
        _step: u64,
        camera: &Camera,
    ) -> Result<Vec<u8>, String> {
        let (reply, answer) = std::sync::mpsc::channel();
        let gone = || "the render thread stopped".to_owned();
        self.role
            .jobs
            .send(RenderJob::Frame {
                scene,
                camera: camera.clone(),
                reply,
            })
            .map_err(|_| gone())?;
        answer
            .recv()
            .map_err(|_| gone())?
            .map_err(|e| e.to_string())
    }
}

/// The frame-bus stream a worker's render role publishes its views and keyframes on.
pub fn imagery_stream(worker_id: &str) -> String {
    format!("{worker_id}/imagery")
}

/// The render thread: draws each job's pictures into frame-bus samples (or plain memory when
/// the bus cannot be opened), then its video, and answers.
fn render_loop(
    mut r: Renderer,
    stream: &str,
    (w, h): (u32, u32),
    jobs: std::sync::mpsc::Receiver<RenderJob>,
) {
    use assay_framebus::{FrameBus, FrameHeader, format};
    use assay_render::image::Rgb;
    let len = (w * h * 4) as usize;
    // iceoryx2 ports belong to the thread that made them: open the bus here.
    let bus = FrameBus::open(&format!("assay-render-{}", std::process::id()))
        .and_then(|bus| Ok((bus.publisher(stream, len)?, bus)));
    let publisher = match bus {
        Ok((p, bus)) => {
            tracing::info!(stream, "publishing imagery on the frame bus");
            Some((p, bus))
        }
        Err(e) => {
            tracing::warn!(error = %e, "no frame bus: rendering into process memory");
            None
        }
    };
    for job in jobs {
        let job = match job {
            RenderJob::Episode(job) => *job,
            RenderJob::Frame {
                scene,
                camera,
                reply,
            } => {
                let mut rgba = vec![0u8; (camera.width * camera.height * 4) as usize];
                let rgb = r.render_rgba_into(&scene, &camera, &mut rgba).map(|()| {
                    rgba.chunks_exact(4)
                        .flat_map(|p| [p[0], p[1], p[2]])
                        .collect::<Vec<u8>>()
                });
                let _ = reply.send(rgb);
                continue;
            }
            RenderJob::Look {
                shard,
                step,
                scene,
                camera,
                reply,
            } => {
                let outputs = assay_render::Outputs::ALL;
                let frame = match &publisher {
                    None => r.render_with(&scene, &camera, outputs),
                    Some((p, _)) => {
                        let (cw, ch) = (camera.width.max(1), camera.height.max(1));
                        let header = FrameHeader {
                            episode: shard,
                            step,
                            camera: POLICY_CAMERA_ID,
                            format: format::RGBA8,
                            width: cw,
                            height: ch,
                            stride: cw * 4,
                            ..Default::default()
                        };
                        match p.try_publish(header, (cw * ch * 4) as usize, |sample| {
                            r.render_into(&scene, &camera, outputs, sample)
                        }) {
                            Ok(drawn) => drawn.map(|(frame, _reached)| frame),
                            Err(e) => Err(assay_render::RenderError::Device(e.to_string())),
                        }
                    }
                };
                let _ = reply.send(frame.map(|f| Observation {
                    camera,
                    depth: f.depth,
                    segments: f.segments,
                }));
                continue;
            }
        };
        // The scene views are drawn with depth and segments too: the scene caption is measured
        // on the very pictures a judge is shown.
        let mut views: Vec<(String, Camera, assay_render::Frame)> = Vec::new();
        let mut draw = |shot: Shot, scene: &SceneSnapshot, cam: &Camera| {
            let outputs = match shot {
                Shot::View(_) => assay_render::Outputs::ALL,
                Shot::Keyframe(_) => assay_render::Outputs::RGB,
            };
            let Some((p, _)) = &publisher else {
                let frame = r.render_with(scene, cam, outputs)?;
                let rgb = Rgb::from_frame(&frame);
                if let Shot::View(_) = shot {
                    views.push((cam.name.clone(), cam.clone(), frame));
                }
                return Ok(rgb);
            };
            let header = FrameHeader {
                episode: job.shard,
                step: shot.step(job.initial_step),
                camera: shot.camera(),
                format: format::RGBA8,
                width: w,
                height: h,
                stride: w * 4,
                ..Default::default()
            };
            match p.try_publish(header, len, |sample| {
                let mut frame = r.render_into(scene, cam, outputs, sample)?;
                if let Shot::View(_) = shot {
                    frame.rgba = sample.to_vec();
                    views.push((cam.name.clone(), cam.clone(), frame));
                }
                Ok(Rgb::from_rgba(w, h, sample))
            }) {
                Ok(drawn) => drawn.map(|(rgb, _reached)| rgb),
                Err(e) => Err(assay_render::RenderError::Device(e.to_string())),
            }
        };
        let result = assay_render::imagery::render_episode_with(
            &job.initial,
            &job.keyframes,
            &job.camera,
            w,
            h,
            &mut draw,
        )
        .and_then(|imagery| {
            let video = if job.video.is_empty() {
                None
            } else {
                let (vw, vh) = (w.div_ceil(2), h.div_ceil(2));
                Some(assay_render::imagery::render_video(
                    &mut r,
                    &job.video,
                    &job.camera,
                    vw,
                    vh,
                )?)
            };
            let caption = assay_render::caption::caption_frames(&job.initial, &views);
            let clip = match job.clip {
                Some((c, _)) if !c.cameras.is_empty() => {
                    Some(assay_render::imagery::render_clip_at(
                        &mut r,
                        &c.scenes,
                        &c.cameras,
                        c.interval_s,
                        c.proprio,
                        c.actions,
                        &c.interface,
                    )?)
                }
                Some((c, size)) => Some(assay_render::imagery::render_clip(
                    &mut r,
                    &c.scenes,
                    &job.camera,
                    size,
                    c.interval_s,
                    c.proprio,
                    c.actions,
                )?),
                None => None,
            };
            Ok(Rendered {
                imagery,
                video,
                caption,
                clip,
            })
        });
        let _ = job.reply.send(result);
    }
}
