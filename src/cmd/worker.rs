use std::path::Path;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, bail};
use assay_core::report::{EpisodeImagery, Keyframe, NamedArtifact};
use assay_core::scene::task_cameras;
use assay_core::spec::TaskSpec;
use assay_proto::v1 as pb;
use assay_render::Renderer;
use assay_worker_runtime::artifacts;
use assay_worker_runtime::{ShardError, ShardHandler, WorkerConfig, default_worker_id, run_worker};

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = super::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Comma-separated roles: sim, render (judge and trainer come with later releases). With both,
    /// every episode gets its scene views, keyframes and a contact sheet.
    #[arg(long, default_value = "sim", value_delimiter = ',')]
    pub roles: Vec<String>,
    /// Size of rendered views and keyframes, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub image_size: (u32, u32),
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
}

/// The render role: one GPU (or software) device per process, shared by the shard threads.
struct RenderRole {
    renderer: Mutex<Renderer>,
    size: (u32, u32),
}

fn io_error(what: &str) -> impl Fn(std::io::Error) -> ShardError + '_ {
    move |e| ShardError::retryable(format!("artifact store: {what}: {e}"))
}

impl RenderRole {
    fn imagery(
        &self,
        spec: &TaskSpec,
        ep: &assay_sim::Episode,
        root: &Path,
    ) -> Result<EpisodeImagery, ShardError> {
        let camera = task_cameras(&spec.cameras).remove(0);
        let mut r = self
            .renderer
            .lock()
            .map_err(|_| ShardError::retryable("the renderer panicked earlier"))?;
        let (w, h) = self.size;
        let img = assay_render::imagery::render_episode(
            &mut r,
            &ep.initial,
            &ep.keyframes,
            &camera,
            w,
            h,
        )
        .map_err(|e| {
            let msg = format!("task {}: rendering: {e}", spec.id);
            match e {
                assay_render::RenderError::Scene { .. } => ShardError::permanent(msg),
                _ => ShardError::retryable(msg),
            }
        })?;
        let adapter = r.adapter().to_string();
        drop(r);
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
        for (step, cam, i) in &img.keyframes {
            keyframes.push(Keyframe {
                step: *step,
                camera: cam.clone(),
                artifact: put(i.png())?,
            });
        }
        Ok(EpisodeImagery {
            adapter,
            views,
            keyframes,
            contact_sheet: put(img.sheet.png())?,
        })
    }
}

impl ShardHandler for SimRole {
    fn run(&self, a: &pb::Assignment, artifact_root: &Path) -> Result<String, ShardError> {
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
        let ep = assay_sim::simulate(&spec, a.seed, policy).map_err(|e| {
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
        if let Some(render) = &self.render {
            outcome.imagery = Some(render.imagery(&spec, &ep, artifact_root)?);
        }
        serde_json::to_string(&outcome).map_err(|e| ShardError::retryable(e.to_string()))
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut roles = Vec::new();
    for r in &a.roles {
        match pb::Role::parse(r) {
            Some(role @ (pb::Role::Sim | pb::Role::Render)) => roles.push(role),
            Some(other) => bail!(
                "role '{}' is not available in this build (sim, render)",
                other.name()
            ),
            None => bail!("unknown role '{r}' (sim, render, judge, trainer)"),
        }
    }
    if !roles.contains(&pb::Role::Sim) {
        bail!(
            "this build runs render together with sim (--roles sim,render); a render-only worker comes with the frame bus"
        );
    }
    let render = if roles.contains(&pb::Role::Render) {
        let renderer = Renderer::new().context("starting the render role")?;
        tracing::info!(adapter = %renderer.adapter(), "render role ready");
        Some(RenderRole {
            renderer: Mutex::new(renderer),
            size: a.image_size,
        })
    } else {
        None
    };
    // Shards are leased for the sim role; rendering rides along in the same process.
    roles.retain(|r| *r == pb::Role::Sim);
    let node_id = a.node_id.unwrap_or_else(|| {
        std::fs::read_to_string("/etc/hostname")
            .map(|s| s.trim().to_owned())
            .unwrap_or_else(|_| "local".into())
    });
    let mut versions = assay_sim::versions();
    versions.insert("assay".into(), env!("CARGO_PKG_VERSION").into());
    let config = WorkerConfig {
        coordinator: a.coordinator,
        worker_id: a.worker_id.unwrap_or_else(|| default_worker_id(&node_id)),
        node_id,
        roles,
        capacity: a.capacity.max(1),
        versions,
        max_backoff: Duration::from_secs(2),
        give_up_after: None,
    };
    super::block_on(async move {
        run_worker(config, Arc::new(SimRole { render }), super::terminated()).await?;
        Ok(ExitCode::SUCCESS)
    })
}
