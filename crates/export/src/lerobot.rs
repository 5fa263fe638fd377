//! `assay export lerobot RUN OUT`: a run's episodes as a LeRobotDataset v3.0 — what LeRobot's
//! `LeRobotDataset(repo_id, root=OUT)` loads and its training scripts read.
//!
//! Per frame (`fps` frames a second of the episode, from the policy's first step to the end):
//! - `observation.images.scene`: the task's first camera (the keyframes' and dynamics clips'
//!   camera) drawn at `size` × `size`, stored in one H.264 MP4 for all episodes, back to back;
//! - `observation.state` (4 float32): the tool centre x, y, z (m) and 1 while it holds an object;
//! - `action` (4 float32): the tool's commanded velocity until the next frame (m/s) and the hold
//!   command — a dynamics clip's action (docs/episode-format.md), zeros on the last frame;
//! - the task's instruction (its `description`) as the frame's task.
//!
//! At a policy's interface ([`Options::interface`], `assay export lerobot --interface`), the
//! frames are at its control rate (one every `CLIP_STRIDE_STEPS` physics steps, 10 a second at
//! the default time step) and each of its cameras is `observation.images.<name>` at its own size
//! (a wrist camera moving with the tool), `observation.state` its state parts and `action` its
//! action space, as a policy of that interface would have seen and commanded them
//! (`assay_sim::at_interface`); `meta/info.json` names every value, `meta/assay.json` keeps the
//! interface.
//!
//! Nothing is simulated again: the states are the episode file's recorded rows, drawn by the
//! same renderer as the run's pictures — a [`Drawing`] the caller hands in (the `assay-run`
//! layer implements it with `assay-sim`'s recorded states and `assay-render`; this crate links
//! neither). An episode that cannot be exported (its file missing or altered, its task's time
//! step not a whole number of recorded rows per frame) is left out with its reason; the rest are
//! written.
//!
//! Owns: the dataset's files. Reads the run's report and artifact store; never writes into the
//! run, never simulates or renders.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, bail};
use arrow_array::builder::{ListBuilder, StringBuilder};
use arrow_array::{
    ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array,
    StringArray, UInt64Array,
};
use arrow_schema::{DataType, Field};
use serde_json::json;

use assay_model::clip::{ACTION_DIMS, CLIP_STRIDE_STEPS, PROPRIO_DIMS};
use assay_model::policy::Interface;
use assay_spec::spec::TaskSpec;

use crate::episodes_table::to_parquet;

/// The dataset format this writes (LeRobot's `CODEBASE_VERSION`).
pub const CODEBASE_VERSION: &str = "v3.0";
/// The feature key of the original interface's one camera.
pub const VIDEO_KEY: &str = "observation.images.scene";
/// What a camera's feature key starts with.
pub const IMAGE_PREFIX: &str = "observation.images.";
const STATE_NAMES: [&str; PROPRIO_DIMS] = ["ee_x", "ee_y", "ee_z", "holding"];
const ACTION_NAMES: [&str; ACTION_DIMS] = ["ee_vx", "ee_vy", "ee_vz", "hold"];

/// What to export and how.
#[derive(Debug, Clone)]
pub struct Options {
    /// Frames are `size` × `size` pixels (even).
    pub size: u32,
    /// Frames a second of the episode's time.
    pub fps: u32,
    /// Only these policies' episodes (all when empty).
    pub policies: Vec<String>,
    /// Only episodes that succeeded.
    pub successful_only: bool,
    /// The policy interface to export at, its cameras without a size at `size`; `None`: the
    /// original one (the task's first camera, tool position + holding, tool velocity).
    pub interface: Option<Interface>,
}

/// One episode's recorded states drawn again: `len` frames of each camera, with the state and
/// the commanded action per frame (the original interface: `PROPRIO_DIMS` and `ACTION_DIMS`
/// floats each; a policy's: its state vector and action space).
pub struct Drawn {
    pub len: usize,
    /// Per camera, in the interface's order (the original: one, "scene").
    pub views: Vec<DrawnView>,
    pub state: Vec<f32>,
    pub action: Vec<f32>,
}

/// One camera's frames of an episode: `len` frames of `width` × `height` RGB, back to back.
pub struct DrawnView {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// An H.264 video the frames go into, one RGB frame at a time.
pub trait VideoSink {
    fn push(&mut self, rgb: &[u8]) -> Result<(), String>;
    /// Closes the file; returns the frames written.
    fn finish(self: Box<Self>) -> Result<u64, String>;
}

/// What draws an episode's recorded states and encodes video: the renderer and the episode
/// reader of the layer above.
pub trait Drawing {
    /// The largest frame side it draws, in pixels.
    fn max_size(&self) -> u32;
    /// Readies the renderer, once the dataset's folder is known to be writable.
    fn start(&mut self) -> anyhow::Result<()>;
    /// Draws the episode file `episode` of `spec` with `seed`, one frame every `steps` physics
    /// steps: from its task's first camera at `size` pixels square, or from the cameras of
    /// `interface` (sized) with its state and actions.
    fn draw(
        &mut self,
        spec: &TaskSpec,
        seed: u64,
        episode: &[u8],
        steps: u64,
        size: u32,
        interface: Option<&Interface>,
    ) -> Result<Drawn, String>;
    /// A video file at `path` of `width` × `height` frames at `fps`.
    fn video(
        &mut self,
        path: &Path,
        width: u32,
        height: u32,
        fps: u32,
    ) -> Result<Box<dyn VideoSink>, String>;
}

/// What was written.
#[derive(Debug, Default)]
pub struct Summary {
    pub episodes: usize,
    pub frames: usize,
    pub tasks: usize,
    /// Episodes left out: "task T seed S policy P: reason".
    pub skipped: Vec<String>,
}

/// One exported episode's rows and where they went.
struct EpisodeMeta {
    index: i64,
    task: String,
    task_id: String,
    seed: u64,
    policy: String,
    success: bool,
    file: String,
    from: i64,
    length: i64,
    video_from_s: f64,
}

/// The frame table, column by column.
#[derive(Default)]
struct Frames {
    state: Vec<f32>,
    action: Vec<f32>,
    timestamp: Vec<f32>,
    frame_index: Vec<i64>,
    episode_index: Vec<i64>,
    task_index: Vec<i64>,
}

/// Running per-dimension statistics (min, max, mean, std, count).
#[derive(Default, Clone)]
struct Moments {
    min: Vec<f64>,
    max: Vec<f64>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    count: u64,
}

impl Moments {
    fn new(dims: usize) -> Self {
        Self {
            min: vec![f64::INFINITY; dims],
            max: vec![f64::NEG_INFINITY; dims],
            sum: vec![0.0; dims],
            sum_sq: vec![0.0; dims],
            count: 0,
        }
    }

    /// Adds `values`, rows of `dims` values each.
    fn add_rows(&mut self, values: &[f32]) {
        let dims = self.min.len();
        for row in values.chunks_exact(dims) {
            for (d, &v) in row.iter().enumerate() {
                self.add(d, f64::from(v));
            }
            self.count += 1;
        }
    }

    fn add(&mut self, d: usize, v: f64) {
        self.min[d] = self.min[d].min(v);
        self.max[d] = self.max[d].max(v);
        self.sum[d] += v;
        self.sum_sq[d] += v * v;
    }

    /// LeRobot's stats entry; `shape` wraps each per-dimension list (images: `[3, 1, 1]`).
    fn json(&self, image: bool) -> serde_json::Value {
        let n = self.count.max(1) as f64;
        let mean: Vec<f64> = self.sum.iter().map(|s| s / n).collect();
        let std: Vec<f64> = self
            .sum_sq
            .iter()
            .zip(&mean)
            .map(|(s, m)| (s / n - m * m).max(0.0).sqrt())
            .collect();
        let shape = |v: &[f64]| {
            if image {
                json!(v.iter().map(|x| json!([[x]])).collect::<Vec<_>>())
            } else {
                json!(v)
            }
        };
        json!({
            "min": shape(&self.min),
            "max": shape(&self.max),
            "mean": shape(&mean),
            "std": shape(&std),
            "count": [self.count],
        })
    }
}

/// The task specs of a run by task id: each parsed, or why it could not be.
pub type Specs = HashMap<String, Result<TaskSpec, String>>;

/// A camera of the dataset: its name, feature key and frame size.
struct Camera {
    name: String,
    key: String,
    width: u32,
    height: u32,
}

impl Camera {
    fn video_path(&self) -> String {
        format!("videos/{}/chunk-000/file-000.mp4", self.key)
    }
}

/// The dataset's cameras: the original interface's one (`scene`, `size` square) or the
/// interface's (sized), each at its own size. Every side must be even (H.264's 4:2:0) and at
/// most `max`.
fn cameras(o: &Options, max: u32) -> anyhow::Result<Vec<Camera>> {
    let cams: Vec<(String, u32, u32)> = match &o.interface {
        None => vec![("scene".to_owned(), o.size, o.size)],
        Some(i) => i
            .cameras
            .iter()
            .map(|c| (c.name.clone(), c.width, c.height))
            .collect(),
    };
    for (name, w, h) in &cams {
        if *w == 0 || w % 2 == 1 || h % 2 == 1 || (*w).max(*h) > max {
            bail!(
                "camera '{name}' of {w}x{h} pixels: frames are an even number of pixels a side, \
                 at most {max} (--size sets cameras without a size)"
            );
        }
    }
    Ok(cams
        .into_iter()
        .map(|(name, width, height)| Camera {
            key: format!("{IMAGE_PREFIX}{name}"),
            name,
            width,
            height,
        })
        .collect())
}

/// Exports `run` (an `assay eval` output folder: report.json and the artifact store) to `out`,
/// which must not exist or be empty; `specs` are the run's tasks as it ran them (its job store).
pub fn export(
    run: &Path,
    out: &Path,
    specs: &Specs,
    o: &Options,
    drawing: &mut dyn Drawing,
) -> anyhow::Result<Summary> {
    if o.size == 0 || o.size % 2 == 1 || o.size > drawing.max_size() {
        bail!(
            "--size {}: frames are an even number of pixels square, at most {}",
            o.size,
            drawing.max_size()
        );
    }
    if o.fps == 0 {
        bail!("--fps 0: a dataset needs a frame rate");
    }
    // The interface's cameras without a size are `size` square.
    let sized;
    let o = match &o.interface {
        None => o,
        Some(i) => {
            i.validate()
                .map_err(|e| anyhow::anyhow!("--interface: {e}"))?;
            sized = Options {
                interface: Some(i.clone().sized(o.size)),
                ..o.clone()
            };
            &sized
        }
    };
    let cameras = cameras(o, drawing.max_size())?;
    let report = crate::read_report(run)?;
    if out.exists()
        && std::fs::read_dir(out)
            .with_context(|| format!("reading {}", out.display()))?
            .next()
            .is_some()
    {
        bail!(
            "{} is not empty: the dataset goes into a new folder",
            out.display()
        );
    }
    for dir in ["meta/episodes/chunk-000", "data/chunk-000"] {
        std::fs::create_dir_all(out.join(dir))?;
    }
    drawing.start()?;
    let mut videos = Vec::with_capacity(cameras.len());
    for c in &cameras {
        let path = out.join(c.video_path());
        std::fs::create_dir_all(path.parent().expect("video folder"))?;
        videos.push(
            drawing
                .video(&path, c.width, c.height, o.fps)
                .map_err(anyhow::Error::msg)
                .with_context(|| format!("writing the dataset's video of camera '{}'", c.name))?,
        );
    }
    let mut summary = Summary::default();
    let mut frames = Frames::default();
    let mut episodes: Vec<EpisodeMeta> = Vec::new();
    let mut tasks: Vec<String> = Vec::new();
    // The state and action widths and names, from the first episode written (a joint state or
    // action space has the arm's width: episodes of an arm of another width are left out).
    let mut widths: Option<(usize, usize)> = None;
    let mut names: (Vec<String>, Vec<String>) = (Vec::new(), Vec::new());
    let mut state_stats = Moments::new(0);
    let mut action_stats = Moments::new(0);
    let mut image_stats = vec![Moments::new(3); cameras.len()];
    for t in &report.results.tasks {
        for e in &t.episodes {
            if (!o.policies.is_empty() && !o.policies.contains(&e.policy))
                || (o.successful_only && !e.success)
            {
                continue;
            }
            let skip =
                |why: String| format!("task {} seed {} policy {}: {why}", t.id, e.seed, e.policy);
            let spec = match specs.get(&t.id) {
                Some(Ok(s)) => s,
                Some(Err(why)) => {
                    summary.skipped.push(skip(why.clone()));
                    continue;
                }
                None => {
                    summary
                        .skipped
                        .push(skip("the run's job store has no spec for it".into()));
                    continue;
                }
            };
            let episode = match render_episode(run, spec, e.seed, &e.artifact, o, drawing) {
                Ok(ep) => ep,
                Err(why) => {
                    summary.skipped.push(skip(why));
                    continue;
                }
            };
            let n = episode.len;
            let shape = (
                episode.state.len() / n.max(1),
                episode.action.len() / n.max(1),
            );
            if episode.views.len() != cameras.len() {
                summary.skipped.push(skip(format!(
                    "{} cameras drawn, the dataset has {}",
                    episode.views.len(),
                    cameras.len()
                )));
                continue;
            }
            match widths {
                None => {
                    widths = Some(shape);
                    names = value_names(o.interface.as_ref(), spec, shape)?;
                    state_stats = Moments::new(shape.0);
                    action_stats = Moments::new(shape.1);
                }
                Some(w) if w != shape => {
                    summary.skipped.push(skip(format!(
                        "{} state and {} action values a frame; the dataset's first episode has \
                         {} and {} (an arm of another width)",
                        shape.0, shape.1, w.0, w.1
                    )));
                    continue;
                }
                Some(_) => {}
            }
            let instruction = instruction(spec);
            let task_index = match tasks.iter().position(|x| *x == instruction) {
                Some(i) => i,
                None => {
                    tasks.push(instruction.clone());
                    tasks.len() - 1
                }
            } as i64;
            let index = episodes.len() as i64;
            let from = frames.frame_index.len() as i64;
            for ((view, video), stats) in episode
                .views
                .iter()
                .zip(videos.iter_mut())
                .zip(image_stats.iter_mut())
            {
                let frame_bytes = (view.width * view.height * 3) as usize;
                for rgb in view.rgb.chunks_exact(frame_bytes) {
                    video.push(rgb).map_err(anyhow::Error::msg)?;
                    for px in rgb.chunks_exact(3) {
                        for (c, &v) in px.iter().enumerate() {
                            stats.add(c, f64::from(v) / 255.0);
                        }
                    }
                }
                stats.count += (n * frame_bytes / 3) as u64;
            }
            for k in 0..n {
                frames.timestamp.push(k as f32 / o.fps as f32);
                frames.frame_index.push(k as i64);
                frames.episode_index.push(index);
                frames.task_index.push(task_index);
            }
            state_stats.add_rows(&episode.state);
            action_stats.add_rows(&episode.action);
            frames.state.extend_from_slice(&episode.state);
            frames.action.extend_from_slice(&episode.action);
            let video_from_s = from as f64 / f64::from(o.fps);
            episodes.push(EpisodeMeta {
                index,
                task: instruction,
                task_id: t.id.clone(),
                seed: e.seed,
                policy: e.policy.clone(),
                success: e.success,
                file: format!("artifacts/{}", e.artifact),
                from,
                length: n as i64,
                video_from_s,
            });
        }
    }
    let Some((state_dims, action_dims)) = widths.filter(|_| !episodes.is_empty()) else {
        // Nothing to write: stop ffmpeg and take back the folders made above (`out` held
        // nothing before).
        drop(videos);
        for dir in ["videos", "meta", "data"] {
            let _ = std::fs::remove_dir_all(out.join(dir));
        }
        bail!(
            "no episode of {} could be exported{}",
            run.display(),
            if summary.skipped.is_empty() {
                " (none matches --policy / --successful)".to_owned()
            } else {
                format!(":\n  {}", summary.skipped.join("\n  "))
            }
        );
    };
    let mut video_bytes = 0;
    for (video, c) in videos.into_iter().zip(&cameras) {
        let written = video.finish().map_err(anyhow::Error::msg)?;
        debug_assert_eq!(written as usize, frames.frame_index.len());
        video_bytes = video_bytes.max(std::fs::metadata(out.join(c.video_path()))?.len());
    }
    summary.episodes = episodes.len();
    summary.frames = frames.frame_index.len();
    summary.tasks = tasks.len();

    let write = |rel: &str, bytes: &[u8]| -> anyhow::Result<()> {
        std::fs::write(out.join(rel), bytes).with_context(|| format!("writing {rel}"))
    };
    write(
        "data/chunk-000/file-000.parquet",
        &data_table(&frames, state_dims, action_dims).map_err(anyhow::Error::msg)?,
    )?;
    write(
        "meta/episodes/chunk-000/file-000.parquet",
        &episodes_table(&episodes, &cameras, o.fps).map_err(anyhow::Error::msg)?,
    )?;
    write(
        "meta/tasks.parquet",
        &tasks_table(&tasks).map_err(anyhow::Error::msg)?,
    )?;
    let info = info_json(o, &summary, &cameras, &names, video_bytes);
    write("meta/info.json", &serde_json::to_vec_pretty(&info)?)?;
    let mut stats = serde_json::Map::new();
    stats.insert("observation.state".into(), state_stats.json(false));
    stats.insert("action".into(), action_stats.json(false));
    for (c, m) in cameras.iter().zip(&image_stats) {
        stats.insert(c.key.clone(), m.json(true));
    }
    write("meta/stats.json", &serde_json::to_vec_pretty(&stats)?)?;
    let provenance = json!({
        "exported_by": format!("assay {}", env!("CARGO_PKG_VERSION")),
        "run": run.display().to_string(),
        "batch_id": report.run.batch_id,
        "size": o.size,
        "fps": o.fps,
        "policies": o.policies,
        "successful_only": o.successful_only,
        "interface": o.interface.as_ref().map(Interface::to_args),
        "skipped": summary.skipped,
    });
    write("meta/assay.json", &serde_json::to_vec_pretty(&provenance)?)?;
    Ok(summary)
}

/// The names of the state's and the action's values: the original interface's, or those of
/// `interface`'s parts and space on `spec`'s arm (which must give `widths`).
fn value_names(
    interface: Option<&Interface>,
    spec: &TaskSpec,
    widths: (usize, usize),
) -> anyhow::Result<(Vec<String>, Vec<String>)> {
    let owned = |n: &[&str]| n.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
    let names = match interface {
        None => (owned(&STATE_NAMES), owned(&ACTION_NAMES)),
        Some(i) => {
            let arm = spec.arm.as_ref().map(|a| a.model.as_str());
            (
                i.state_names(arm).map_err(anyhow::Error::msg)?,
                i.action.value_names(arm).map_err(anyhow::Error::msg)?,
            )
        }
    };
    if (names.0.len(), names.1.len()) != widths {
        bail!(
            "task {}: {} state and {} action values a frame, where the interface names {} and {}",
            spec.id,
            widths.0,
            widths.1,
            names.0.len(),
            names.1.len()
        );
    }
    Ok(names)
}

/// What a task asks for, in words: its description, else its name.
fn instruction(spec: &TaskSpec) -> String {
    let d = spec.description.trim();
    if d.is_empty() {
        spec.name.clone()
    } else {
        d.to_owned()
    }
}

/// Reads episode `artifact` of `spec` with `seed` from the run's artifact store and draws its
/// states `o.fps` times a second.
fn render_episode(
    run: &Path,
    spec: &TaskSpec,
    seed: u64,
    artifact: &str,
    o: &Options,
    drawing: &mut dyn Drawing,
) -> Result<Drawn, String> {
    let path = run.join("artifacts").join(artifact);
    let bytes =
        std::fs::read(&path).map_err(|e| format!("episode file {}: {e}", path.display()))?;
    let expected = artifact
        .rsplit('/')
        .next()
        .and_then(|f| f.split('.').next())
        .unwrap_or_default();
    if assay_spec::hash::sha256_hex(&bytes) != expected {
        return Err(format!(
            "episode file {} does not match its content address (changed since the run)",
            path.display()
        ));
    }
    let dt = spec.for_seed(seed).physics.dt;
    let stride = 1.0 / (f64::from(o.fps) * dt);
    let steps = stride.round();
    if (stride - steps).abs() > 1e-6 || steps < 1.0 {
        return Err(format!(
            "--fps {}: physics.dt = {dt} s gives {stride:.3} physics steps a frame, not a whole \
             number",
            o.fps
        ));
    }
    if o.interface.is_some() && steps as u64 != CLIP_STRIDE_STEPS {
        return Err(format!(
            "--fps {}: a dataset at a policy interface is at its control rate, one frame every \
             {CLIP_STRIDE_STEPS} physics steps ({} fps at this task's physics.dt = {dt} s)",
            o.fps,
            1.0 / (CLIP_STRIDE_STEPS as f64 * dt)
        ));
    }
    drawing.draw(
        spec,
        seed,
        &bytes,
        steps as u64,
        o.size,
        o.interface.as_ref(),
    )
}

/// A fixed-size list column of `dims` float32 values per row (a `datasets.Sequence` of a length).
fn vectors(values: Vec<f32>, dims: usize) -> ArrayRef {
    Arc::new(
        FixedSizeListArray::try_new(
            Arc::new(Field::new("item", DataType::Float32, true)),
            dims as i32,
            Arc::new(Float32Array::from(values)),
            None,
        )
        .expect("whole rows"),
    )
}

fn data_table(f: &Frames, state_dims: usize, action_dims: usize) -> Result<Vec<u8>, String> {
    let n = f.frame_index.len() as i64;
    to_parquet(
        vec![
            (
                "observation.state",
                true,
                vectors(f.state.clone(), state_dims),
            ),
            ("action", true, vectors(f.action.clone(), action_dims)),
            (
                "timestamp",
                true,
                Arc::new(Float32Array::from(f.timestamp.clone())),
            ),
            (
                "frame_index",
                true,
                Arc::new(Int64Array::from(f.frame_index.clone())),
            ),
            (
                "episode_index",
                true,
                Arc::new(Int64Array::from(f.episode_index.clone())),
            ),
            ("index", true, Arc::new(Int64Array::from_iter_values(0..n))),
            (
                "task_index",
                true,
                Arc::new(Int64Array::from(f.task_index.clone())),
            ),
        ],
        HashMap::new(),
    )
}

fn episodes_table(
    episodes: &[EpisodeMeta],
    cameras: &[Camera],
    fps: u32,
) -> Result<Vec<u8>, String> {
    let ints = |f: &dyn Fn(&EpisodeMeta) -> i64| -> ArrayRef {
        Arc::new(Int64Array::from_iter_values(episodes.iter().map(f)))
    };
    let floats = |f: &dyn Fn(&EpisodeMeta) -> f64| -> ArrayRef {
        Arc::new(Float64Array::from_iter_values(episodes.iter().map(f)))
    };
    let texts = |f: &dyn Fn(&EpisodeMeta) -> String| -> ArrayRef {
        Arc::new(StringArray::from_iter_values(episodes.iter().map(f)))
    };
    let mut task_lists = ListBuilder::new(StringBuilder::new());
    for e in episodes {
        task_lists.values().append_value(&e.task);
        task_lists.append(true);
    }
    let fps = f64::from(fps);
    // Per camera, where its frames of each episode are (every camera's video holds every
    // episode, back to back).
    let mut video_columns: Vec<(String, ArrayRef)> = Vec::new();
    for c in cameras {
        let column = |k: &str| format!("videos/{}/{k}", c.key);
        video_columns.extend([
            (column("chunk_index"), ints(&|_| 0)),
            (column("file_index"), ints(&|_| 0)),
            (column("from_timestamp"), floats(&|e| e.video_from_s)),
            (
                column("to_timestamp"),
                floats(&|e| e.video_from_s + e.length as f64 / fps),
            ),
        ]);
    }
    to_parquet(
        vec![
            ("episode_index", true, ints(&|e| e.index)),
            ("tasks", true, Arc::new(task_lists.finish())),
            ("length", true, ints(&|e| e.length)),
            ("data/chunk_index", true, ints(&|_| 0)),
            ("data/file_index", true, ints(&|_| 0)),
            ("dataset_from_index", true, ints(&|e| e.from)),
            ("dataset_to_index", true, ints(&|e| e.from + e.length)),
        ]
        .into_iter()
        .chain(
            video_columns
                .iter()
                .map(|(k, v)| (k.as_str(), true, v.clone())),
        )
        .chain([
            ("meta/episodes/chunk_index", true, ints(&|_| 0)),
            ("meta/episodes/file_index", true, ints(&|_| 0)),
            // Where each episode came from, for joining with the run's episodes.parquet.
            ("assay/task_id", true, texts(&|e| e.task_id.clone())),
            (
                "assay/seed",
                true,
                Arc::new(UInt64Array::from_iter_values(
                    episodes.iter().map(|e| e.seed),
                )),
            ),
            ("assay/policy", true, texts(&|e| e.policy.clone())),
            (
                "assay/success",
                true,
                Arc::new(BooleanArray::from(
                    episodes.iter().map(|e| e.success).collect::<Vec<_>>(),
                )),
            ),
            ("assay/episode_file", true, texts(&|e| e.file.clone())),
        ])
        .collect(),
        HashMap::new(),
    )
}

/// `meta/tasks.parquet`: a pandas frame indexed by the task's text with its `task_index` (the
/// pandas metadata makes the text the index again when pandas reads it, as LeRobot does).
fn tasks_table(tasks: &[String]) -> Result<Vec<u8>, String> {
    let pandas = json!({
        "index_columns": ["__index_level_0__"],
        "column_indexes": [{
            "name": null, "field_name": null, "pandas_type": "unicode",
            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}
        }],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": null},
            {"name": null, "field_name": "__index_level_0__", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": null}
        ],
        "creator": {"library": "assay", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.2.3"
    });
    to_parquet(
        vec![
            (
                "task_index",
                true,
                Arc::new(Int64Array::from_iter_values(0..tasks.len() as i64)),
            ),
            (
                "__index_level_0__",
                true,
                Arc::new(StringArray::from_iter_values(tasks)),
            ),
        ],
        HashMap::from([("pandas".to_owned(), pandas.to_string())]),
    )
}

fn info_json(
    o: &Options,
    s: &Summary,
    cameras: &[Camera],
    names: &(Vec<String>, Vec<String>),
    video_bytes: u64,
) -> serde_json::Value {
    let scalar = |dtype: &str| json!({"dtype": dtype, "shape": [1], "names": null});
    let mut features = BTreeMap::new();
    for c in cameras {
        features.insert(
            c.key.clone(),
            json!({
                "dtype": "video",
                "shape": [c.height, c.width, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": c.height,
                    "video.width": c.width,
                    "video.codec": "h264",
                    "video.pix_fmt": "yuv420p",
                    "video.is_depth_map": false,
                    "video.fps": o.fps,
                    "video.channels": 3,
                    "has_audio": false
                }
            }),
        );
    }
    features.insert(
        "observation.state".to_owned(),
        json!({"dtype": "float32", "shape": [names.0.len()], "names": names.0}),
    );
    features.insert(
        "action".to_owned(),
        json!({"dtype": "float32", "shape": [names.1.len()], "names": names.1}),
    );
    features.insert("timestamp".to_owned(), scalar("float32"));
    for k in ["frame_index", "episode_index", "index", "task_index"] {
        features.insert(k.to_owned(), scalar("int64"));
    }
    json!({
        "codebase_version": CODEBASE_VERSION,
        "robot_type": "assay_tool",
        "total_episodes": s.episodes,
        "total_frames": s.frames,
        "total_tasks": s.tasks,
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": (video_bytes / (1 << 20)).max(200),
        "fps": o.fps,
        "splits": {"train": format!("0:{}", s.episodes)},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": features,
    })
}
