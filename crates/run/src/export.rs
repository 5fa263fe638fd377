//! What `assay export` needs of a run folder beyond its report: the task specs as its job store
//! holds them, and the drawing of its episodes for a LeRobot dataset — the episode files'
//! recorded states (`assay-sim`) drawn by the run's renderer (`assay-render`) and encoded by
//! ffmpeg, handed to `assay-export` as its [`Drawing`].
//!
//! Owns: those two bridges. Never writes into the run, never simulates (the states are the
//! episode file's rows).

use std::path::Path;

use anyhow::Context;
use assay_export::lerobot::{Drawing, Drawn, DrawnView, Specs, VideoSink};
use assay_model::policy::Interface;
use assay_spec::spec::TaskSpec;

use crate::outdir;

/// The task specs of `run` (an `assay eval` folder) as its job store holds them, by task id; a
/// spec that no longer parses carries its reason.
pub fn task_specs(run: &Path) -> anyhow::Result<Specs> {
    let marker = run.join(outdir::MARKER);
    let batch_id = serde_json::from_slice::<outdir::Marker>(
        &std::fs::read(&marker)
            .with_context(|| format!("{} is not an `assay eval` output folder", run.display()))?,
    )
    .with_context(|| format!("reading {}", marker.display()))?
    .batch_id
    .with_context(|| format!("{}: the run never submitted its batch", run.display()))?;
    let db = run.join("run").join("jobs.db");
    if !db.is_file() {
        anyhow::bail!(
            "{} has no job store (run/jobs.db): the task specs come from there",
            run.display()
        );
    }
    let store = assay_coordinator::store::Store::open(&db)
        .map_err(|e| anyhow::anyhow!("{}: {e}", db.display()))?;
    let rows = store
        .task_specs(&batch_id)
        .map_err(|e| anyhow::anyhow!("{}: {e}", db.display()))?;
    Ok(rows
        .into_iter()
        .map(|(id, json)| {
            let spec = serde_json::from_str(&json)
                .map_err(|e| format!("its stored spec does not parse: {e}"));
            (id, spec)
        })
        .collect())
}

/// The run's renderer (any wgpu adapter; lavapipe without a GPU), started when the export
/// starts drawing, and ffmpeg.
#[derive(Default)]
pub struct RunDrawing {
    renderer: Option<assay_render::Renderer>,
}

impl Drawing for RunDrawing {
    fn max_size(&self) -> u32 {
        assay_render::imagery::MAX_CLIP_SIZE
    }

    fn start(&mut self) -> anyhow::Result<()> {
        if self.renderer.is_none() {
            self.renderer = Some(assay_render::Renderer::new().context("starting the renderer")?);
        }
        Ok(())
    }

    fn draw(
        &mut self,
        spec: &TaskSpec,
        seed: u64,
        episode: &[u8],
        steps: u64,
        size: u32,
        interface: Option<&Interface>,
    ) -> Result<Drawn, String> {
        let states = match interface {
            None => assay_sim::recorded_states(spec, seed, episode, steps),
            Some(i) => assay_sim::recorded_states_at(spec, seed, episode, i),
        }
        .map_err(|e| format!("episode file: {e}"))?;
        let renderer = self
            .renderer
            .as_mut()
            .ok_or("the renderer was not started")?;
        let len = states.steps.len();
        let rendering = |e: assay_render::RenderError| format!("rendering: {e}");
        let Some(i) = interface else {
            let camera = assay_spec::scene::task_cameras(&spec.cameras).remove(0);
            let clip = assay_render::imagery::render_clip(
                renderer,
                &states.scenes,
                &camera,
                size,
                states.interval_s,
                states.proprio,
                states.actions,
            )
            .map_err(rendering)?;
            return Ok(Drawn {
                len,
                views: vec![DrawnView {
                    name: "scene".into(),
                    width: size,
                    height: size,
                    rgb: clip.rgb,
                }],
                state: clip.proprio,
                action: clip.actions,
            });
        };
        let clip = assay_render::imagery::render_clip_at(
            renderer,
            &states.scenes,
            &states.cameras,
            states.interval_s,
            states.proprio,
            states.actions,
            &i.to_args(),
        )
        .map_err(rendering)?;
        let mut views = vec![DrawnView {
            name: states.cameras[0].name.clone(),
            width: clip.width,
            height: clip.height,
            rgb: clip.rgb,
        }];
        views.extend(clip.views.into_iter().map(|v| DrawnView {
            name: v.name,
            width: v.width,
            height: v.height,
            rgb: v.rgb,
        }));
        Ok(Drawn {
            len,
            views,
            state: clip.proprio,
            action: clip.actions,
        })
    }

    fn video(
        &mut self,
        path: &Path,
        width: u32,
        height: u32,
        fps: u32,
    ) -> Result<Box<dyn VideoSink>, String> {
        let writer = assay_render::video::Mp4Writer::create(path, width, height, fps)?;
        Ok(Box::new(Mp4(writer)))
    }
}

struct Mp4(assay_render::video::Mp4Writer);

impl VideoSink for Mp4 {
    fn push(&mut self, rgb: &[u8]) -> Result<(), String> {
        self.0.push(rgb)
    }

    fn finish(self: Box<Self>) -> Result<u64, String> {
        self.0.finish()
    }
}
