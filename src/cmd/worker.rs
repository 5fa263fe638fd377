use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{Context, bail};
use assay_core::report::{EpisodeImagery, Keyframe, NamedArtifact};
use assay_core::scene::{Observation, SceneSnapshot, task_cameras};
use assay_core::spec::{Camera, TaskSpec};
use assay_proto::v1 as pb;
use assay_render::Renderer;
use assay_render::imagery::Shot;
use assay_worker_runtime::artifacts;
use assay_worker_runtime::{ShardError, ShardHandler, WorkerConfig, default_worker_id, run_worker};

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Comma-separated roles: sim, render, judge (trainer comes with a later release). With sim
    /// and render, every episode gets its scene views, keyframes, scene caption and a contact
    /// sheet; judge scores rendered episodes with the judges a batch names.
    #[arg(long, default_value = "sim", value_delimiter = ',')]
    pub roles: Vec<String>,
    /// Configuration file (TOML) naming the judges this worker can run (`[judges.<name>]`);
    /// the built-in `offline` judge needs none.
    #[arg(long, env = "ASSAY_CONFIG")]
    pub config: Option<std::path::PathBuf>,
    /// Size of rendered views and keyframes, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub image_size: (u32, u32),
    /// Also render a video of every episode (half the image size, 12 frames/s): MP4 when
    /// ffmpeg is installed, else an animated GIF.
    #[arg(long)]
    pub video: bool,
    /// Shards run at once.
    #[arg(long, env = "ASSAY_CAPACITY", default_value_t = 1)]
    pub capacity: u32,
    /// Node id (defaults to the host name).
    #[arg(long, env = "ASSAY_NODE_ID")]
    pub node_id: Option<String>,
    /// Worker id (defaults to <node>/<pid>).
    #[arg(long)]
    pub worker_id: Option<String>,
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or("expected WIDTHxHEIGHT, e.g. 640x480")?;
    let (w, h): (u32, u32) = (
        w.parse().map_err(|_| "bad width")?,
        h.parse().map_err(|_| "bad height")?,
    );
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        return Err("width and height must lie in 1..=8192".into());
    }
    Ok((w, h))
}

/// The sim role, with the render role in the same process when asked for.
struct SimRole {
    render: Option<RenderRole>,
    counters: Arc<Counters>,
    /// The runtime remote policies' gRPC calls run on (shard threads block on it).
    runtime: tokio::runtime::Handle,
}

/// What the worker has done, for telemetry.
#[derive(Default)]
struct Counters {
    episodes: AtomicU64,
    failed: AtomicU64,
    running: AtomicU64,
    steps: AtomicU64,
    frames: AtomicU64,
    judged: AtomicU64,
    trained: AtomicU64,
}

/// The render role: one thread owns the device (a GPU, or lavapipe) and this worker's frame-bus
/// stream `<worker-id>/imagery`; shard threads send it episodes and wait for their pictures, and
/// a seeing policy's frames while its episode runs. Every
/// view and keyframe is read back straight into a shared-memory sample, encoded from there, and
/// published: a judge, a viewer or `assay frames relay` on the node reads it in place.
struct RenderRole {
    jobs: std::sync::mpsc::Sender<RenderJob>,
    adapter: String,
    /// Episodes come with video states (the sim role is asked for them).
    video: bool,
}

enum RenderJob {
    Episode(EpisodeJob),
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

struct EpisodeJob {
    shard: u64,
    initial: SceneSnapshot,
    initial_step: u64,
    keyframes: Vec<(u64, SceneSnapshot)>,
    /// Video states; empty when no video is wanted.
    video: Vec<(u64, SceneSnapshot)>,
    /// Dynamics clip states and the clip's frame size, when the shard asks for a clip.
    clip: Option<(assay_sim::ClipStates, u32)>,
    camera: Camera,
    reply: std::sync::mpsc::Sender<Result<Rendered, assay_render::RenderError>>,
}

struct Rendered {
    imagery: assay_render::imagery::Imagery,
    video: Option<assay_render::video::Video>,
    caption: assay_core::caption::SceneCaption,
    clip: Option<assay_core::clip::Clip>,
}

fn io_error(what: &str) -> impl Fn(std::io::Error) -> ShardError + '_ {
    move |e| ShardError::retryable(format!("artifact store: {what}: {e}"))
}

impl RenderRole {
    fn start(
        renderer: Renderer,
        stream: String,
        size: (u32, u32),
        video: bool,
    ) -> anyhow::Result<Self> {
        let adapter = renderer.adapter().to_string();
        let (jobs, rx) = std::sync::mpsc::channel::<RenderJob>();
        std::thread::Builder::new()
            .name("render".into())
            .spawn(move || render_loop(renderer, &stream, size, rx))?;
        Ok(RenderRole {
            jobs,
            adapter,
            video,
        })
    }

    /// Renders and stores `ep`'s pictures, and its dynamics clip at `clip_size` pixels square
    /// when it carries clip states.
    fn imagery(
        &self,
        spec: &TaskSpec,
        shard: u64,
        ep: assay_sim::Episode,
        clip_size: u32,
        root: &Path,
    ) -> Result<EpisodeImagery, ShardError> {
        let (reply, answer) = std::sync::mpsc::channel();
        let goals_met = ep.keyframe_goals;
        let job = RenderJob::Episode(EpisodeJob {
            shard,
            initial: ep.initial,
            initial_step: ep.initial_step,
            keyframes: ep.keyframes,
            video: ep.video,
            clip: ep.clip.map(|c| (c, clip_size)),
            camera: task_cameras(&spec.cameras).remove(0),
            reply,
        });
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
        let put = |bytes: Vec<u8>| {
            artifacts::put(root, "imagery", "png", &bytes).map_err(io_error("imagery"))
        };
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
            Some(c) => Some(
                artifacts::put(root, "clips", "clip", &c.encode()).map_err(io_error("clips"))?,
            ),
            None => None,
        };
        let caption = serde_json::to_vec_pretty(&rendered.caption)
            .map_err(|e| ShardError::permanent(format!("scene caption: {e}")))?;
        Ok(EpisodeImagery {
            adapter: self.adapter.clone(),
            views,
            keyframes,
            contact_sheet: put(img.sheet.png())?,
            video,
            caption: Some(
                artifacts::put(root, "captions", "json", &caption).map_err(io_error("captions"))?,
            ),
            clip,
        })
    }
}

/// A seeing policy's camera, served by the render thread.
struct RoleObserver<'a> {
    role: &'a RenderRole,
    shard: u64,
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
            RenderJob::Episode(job) => job,
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
    fn episode(&self, a: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError> {
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
        let video_frames = match &self.render {
            Some(r) if r.video => assay_sim::VIDEO_FRAMES,
            _ => 0,
        };
        let mut observer = self.render.as_ref().map(|role| RoleObserver {
            role,
            shard: a.shard_id,
        });
        // A dynamics clip is drawn by the render role; a worker without it has no imagery.
        let clip_size = if self.render.is_some() {
            a.clip_size
        } else {
            0
        };
        // Every policy but the built-in oracle is a policy object, made for this episode: a
        // remote server is health-checked here, a model is loaded from this worker or the
        // artifact store.
        let parsed = assay_core::policy::PolicySpec::parse(policy)
            .map_err(|e| ShardError::permanent(format!("task {}: {e}", spec.id)))?;
        let mut object = if parsed.is_oracle() {
            None
        } else {
            let loaded = assay_policy::load_with(
                &parsed,
                artifact_root,
                &self.runtime,
                super::policy::diffusion_loader(),
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
            observer: observer.as_mut().map(|o| o as &mut dyn assay_sim::Observer),
            policy: object
                .as_deref_mut()
                .map(|p| p as &mut dyn assay_core::policy::Policy),
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
        if let Some(render) = &self.render {
            let video_frames = ep.video.len();
            let clip_frames = ep.clip.as_ref().map_or(0, |c| c.len());
            let imagery = render.imagery(&spec, a.shard_id, ep, clip_size, artifact_root)?;
            self.counters.frames.fetch_add(
                (imagery.views.len() + imagery.keyframes.len() + video_frames + clip_frames) as u64,
                Ordering::Relaxed,
            );
            outcome.imagery = Some(imagery);
        }
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

/// The judge role: scores judge shards with the judges of the configuration.
struct JudgeRole {
    config: assay_judge::Config,
    /// Where the configuration came from, for errors.
    origin: String,
    /// Judges are built on first use and shared by the shards (their endpoints hold the
    /// concurrency and rate limits).
    judges: std::sync::Mutex<std::collections::HashMap<String, Arc<assay_judge::Judge>>>,
    runtime: tokio::runtime::Handle,
    worker_id: String,
    counters: Arc<Counters>,
}

impl JudgeRole {
    fn judge(&self, name: &str) -> Result<Arc<assay_judge::Judge>, ShardError> {
        let mut judges = self.judges.lock().expect("judges");
        if let Some(j) = judges.get(name) {
            return Ok(j.clone());
        }
        let cfg = self.config.judge(name).ok_or_else(|| {
            ShardError::permanent(format!(
                "judge '{name}' is not configured on worker {} ({}; configured: {})",
                self.worker_id,
                self.origin,
                self.config.names().join(", ")
            ))
        })?;
        let judge = Arc::new(
            assay_judge::Judge::new(name, &cfg)
                .map_err(|e| ShardError::permanent(e.to_string()))?,
        );
        judges.insert(name.to_owned(), judge.clone());
        Ok(judge)
    }

    fn run(&self, a: &pb::Assignment, root: &Path) -> Result<String, ShardError> {
        let spec: TaskSpec = serde_json::from_str(&a.task_spec_json).map_err(|e| {
            ShardError::permanent(format!(
                "task spec from the coordinator does not parse: {e}"
            ))
        })?;
        let episode: assay_core::report::EpisodeOutcome = serde_json::from_str(&a.input_json)
            .map_err(|e| {
                ShardError::permanent(format!(
                    "task {}: the episode to judge does not parse: {e}",
                    spec.id
                ))
            })?;
        let judge = self.judge(&a.judge)?;
        let judged = self
            .runtime
            .block_on(judge.judge(
                &episode,
                &spec.description,
                a.judge_repeats,
                a.budget_left_usd,
                root,
            ))
            .map_err(|e| {
                let msg = format!("task {} seed {}: judge '{}': {e}", spec.id, a.seed, a.judge);
                match e {
                    assay_judge::JudgeError::Permanent(_) => ShardError::permanent(msg),
                    assay_judge::JudgeError::Retryable(_) => ShardError::retryable(msg),
                }
            })?;
        let mut outcome = judged.outcome;
        outcome.transcript = Some(
            artifacts::put(root, "judge", "json", &judged.transcript).map_err(io_error("judge"))?,
        );
        self.counters.judged.fetch_add(1, Ordering::Relaxed);
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

/// The roles of one worker process: shards go to the role they were leased for.
struct Roles {
    sim: Option<SimRole>,
    judge: Option<JudgeRole>,
    #[cfg(feature = "trainer")]
    trainer: Option<super::trainer_role::TrainerRole>,
    counters: Arc<Counters>,
}

impl ShardHandler for Roles {
    fn run(&self, a: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError> {
        match (pb::Role::try_from(a.role), &self.sim, &self.judge) {
            (Ok(pb::Role::Judge), _, Some(judge)) => {
                judge.counters.running.fetch_add(1, Ordering::Relaxed);
                let result = judge.run(a, artifact_root);
                judge.counters.running.fetch_sub(1, Ordering::Relaxed);
                result
            }
            (Ok(pb::Role::Sim), Some(sim), _) => sim.run(a, artifact_root),
            #[cfg(feature = "trainer")]
            (Ok(pb::Role::Trainer), _, _) if self.trainer.is_some() => {
                let trainer = self.trainer.as_ref().expect("checked");
                self.counters.running.fetch_add(1, Ordering::Relaxed);
                let result = trainer.run(a, artifact_root);
                self.counters.running.fetch_sub(1, Ordering::Relaxed);
                if result.is_ok() {
                    self.counters.trained.fetch_add(1, Ordering::Relaxed);
                }
                result
            }
            (role, _, _) => Err(ShardError::permanent(format!(
                "this worker does not hold the role of shard {} ({role:?})",
                a.shard_id
            ))),
        }
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut roles = Vec::new();
    for r in &a.roles {
        match pb::Role::parse(r) {
            Some(role @ (pb::Role::Sim | pb::Role::Render | pb::Role::Judge)) => roles.push(role),
            #[cfg(feature = "trainer")]
            Some(pb::Role::Trainer) => roles.push(pb::Role::Trainer),
            Some(other) => bail!(
                "role '{}' is not available in this build (built without the `trainer` feature)",
                other.name()
            ),
            None => bail!("unknown role '{r}' (sim, render, judge, trainer)"),
        }
    }
    if roles.contains(&pb::Role::Render) && !roles.contains(&pb::Role::Sim) {
        bail!(
            "this build runs render together with sim (--roles sim,render): a render-only worker, fed scene states over the frame bus, comes with the policy role"
        );
    }
    let judge_config = match &a.config {
        Some(path) => (
            assay_judge::Config::load(path).map_err(anyhow::Error::msg)?,
            path.display().to_string(),
        ),
        None => (
            assay_judge::Config::default(),
            "no configuration file".to_owned(),
        ),
    };
    let node_id = a.node_id.unwrap_or_else(|| {
        std::fs::read_to_string("/etc/hostname")
            .map(|s| s.trim().to_owned())
            .unwrap_or_else(|_| "local".into())
    });
    let worker_id = a.worker_id.unwrap_or_else(|| default_worker_id(&node_id));
    let render = if roles.contains(&pb::Role::Render) {
        let renderer = Renderer::new().context("starting the render role")?;
        tracing::info!(adapter = %renderer.adapter(), "render role ready");
        Some(RenderRole::start(
            renderer,
            imagery_stream(&worker_id),
            a.image_size,
            a.video,
        )?)
    } else {
        None
    };
    // Shards are leased for the sim and judge roles; rendering rides along with sim.
    roles.retain(|r| *r != pb::Role::Render);
    let judging = roles.contains(&pb::Role::Judge);
    #[cfg(feature = "trainer")]
    let trainer = if roles.contains(&pb::Role::Trainer) {
        let text = match &a.config {
            Some(p) => Some(
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            ),
            None => None,
        };
        Some(
            super::trainer_role::TrainerRole::new(text.as_deref())
                .map_err(|e| anyhow::anyhow!("trainer role: {e}"))?,
        )
    } else {
        None
    };
    let simulating = roles.contains(&pb::Role::Sim);
    let (announce, announced) = tokio::sync::watch::channel(None::<(String, String)>);
    let counters = Arc::new(Counters::default());
    let role_names: Vec<String> = a.roles.clone();
    let mut versions = assay_sim::versions();
    versions.insert("assay".into(), env!("CARGO_PKG_VERSION").into());
    let config = WorkerConfig {
        coordinator: a.coordinator,
        worker_id,
        node_id,
        roles,
        capacity: a.capacity.max(1),
        versions,
        max_backoff: Duration::from_secs(2),
        give_up_after: None,
        token: assay_proto::auth::Token::from_env().map_err(anyhow::Error::msg)?,
        on_registered: Some(Arc::new(move |r: &pb::Registered| {
            let _ = announce.send(Some((r.telemetry_endpoint.clone(), r.cluster.clone())));
        })),
    };
    super::block_on(async move {
        let stats = tokio::spawn(publish_stats(
            announced,
            config.token.as_ref().map(|t| t.derive("zenoh")),
            counters.clone(),
            config.worker_id.clone(),
            config.node_id.clone(),
            role_names,
            u64::from(config.capacity),
        ));
        let judge = judging.then(|| JudgeRole {
            config: judge_config.0,
            origin: judge_config.1,
            judges: Default::default(),
            runtime: tokio::runtime::Handle::current(),
            worker_id: config.worker_id.clone(),
            counters: counters.clone(),
        });
        let sim = simulating.then(|| SimRole {
            render,
            counters: counters.clone(),
            runtime: tokio::runtime::Handle::current(),
        });
        let handler = Arc::new(Roles {
            sim,
            judge,
            // Made before the runtime (a bad configuration fails first); runs on it.
            #[cfg(feature = "trainer")]
            trainer: trainer.map(|t| t.on(tokio::runtime::Handle::current())),
            counters,
        });
        let result = run_worker(config, handler, super::terminated()).await;
        stats.abort();
        let _ = stats.await;
        result?;
        Ok(ExitCode::SUCCESS)
    })
}

/// Publishes this worker's statistics every second on `assay/<cluster>/workers/<worker>/stats`,
/// once the coordinator has announced where its telemetry router is.
async fn publish_stats(
    mut announced: tokio::sync::watch::Receiver<Option<(String, String)>>,
    password: Option<String>,
    counters: Arc<Counters>,
    worker: String,
    node: String,
    roles: Vec<String>,
    capacity: u64,
) {
    let (endpoint, cluster) = loop {
        if let Some((e, c)) = announced.borrow_and_update().clone()
            && !e.is_empty()
        {
            break (e, c);
        }
        if announced.changed().await.is_err() {
            return;
        }
    };
    let session = match assay_telemetry::open_client(&endpoint, password.as_deref()).await {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!(%endpoint, error = %e, "telemetry is off for this worker");
            return;
        }
    };
    let publisher = match assay_telemetry::JsonPublisher::new(
        &session,
        assay_telemetry::worker_key(&cluster, &worker),
    )
    .await
    {
        Ok(p) => p,
        Err(e) => {
            tracing::warn!(error = %e, "telemetry publisher");
            return;
        }
    };
    tracing::info!(%endpoint, "publishing telemetry");
    let start = std::time::Instant::now();
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let (mut last, mut last_steps, mut last_frames) = (std::time::Instant::now(), 0u64, 0u64);
    loop {
        tick.tick().await;
        let (steps, frames) = (
            counters.steps.load(Ordering::Relaxed),
            counters.frames.load(Ordering::Relaxed),
        );
        let dt = last.elapsed().as_secs_f64().max(1e-3);
        let stats = assay_telemetry::WorkerStats {
            worker: worker.clone(),
            node: node.clone(),
            roles: roles.clone(),
            episodes_done: counters.episodes.load(Ordering::Relaxed),
            episodes_failed: counters.failed.load(Ordering::Relaxed),
            judged: counters.judged.load(Ordering::Relaxed),
            trained: counters.trained.load(Ordering::Relaxed),
            leases_held: counters.running.load(Ordering::Relaxed),
            lease_capacity: capacity,
            physics_steps_per_s: (steps - last_steps) as f64 / dt,
            frames_per_s: (frames - last_frames) as f64 / dt,
            uptime_s: start.elapsed().as_secs_f64(),
            unix_ms: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_millis() as i64)
                .unwrap_or(0),
        };
        (last, last_steps, last_frames) = (std::time::Instant::now(), steps, frames);
        if let Err(e) = publisher.put(&stats).await {
            tracing::warn!(error = %e, "telemetry put");
        }
    }
}
