//! `assay-worker`: what a worker process does — its roles as library code, so that each can be
//! run and tested in one process. The sim role (rapier3d episodes, `sim`), the render role
//! (wgpu, `render`: beside sim in the same process, or alone, drawing episodes other workers
//! simulated), the judge role (`judge`), the trainer role (libtorch,
//! `trainer`, with the `trainer` feature), the frames relay across nodes (`relay`), and the
//! statistics a worker publishes (`telemetry`). [`Worker`] puts the asked roles together behind
//! one [`assay_worker_runtime::ShardHandler`] and serves a coordinator with them.
//!
//! Owns: role logic. Never parses command lines or reads the environment beyond the cluster token
//! (the CLI's `assay worker` does that and builds [`Options`]); never touches the job store.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, bail};
use assay_proto::v1 as pb;
use assay_render::Renderer;
use assay_worker_runtime::{ShardError, ShardHandler, WorkerConfig, default_worker_id, run_worker};

pub mod judge;
mod kept;
pub mod relay;
pub mod render;
pub mod sim;
pub mod telemetry;
#[cfg(feature = "trainer")]
pub mod trainer;

use judge::JudgeRole;
use render::RenderRole;
pub use render::{POLICY_CAMERA_ID, imagery_stream};
use sim::SimRole;
use telemetry::Counters;

/// What a worker is asked to be: plain data, filled in by `assay worker`'s arguments.
#[derive(Debug, Clone)]
pub struct Options {
    /// The coordinator's address (`http://host:port`).
    pub coordinator: String,
    /// Role names: sim, render, judge, trainer.
    pub roles: Vec<String>,
    /// Configuration file (TOML) naming judges (`[judges.<name>]`) and embedders.
    pub config: Option<PathBuf>,
    /// Size of rendered views and keyframes.
    pub image_size: (u32, u32),
    /// Also render a video of every episode.
    pub video: bool,
    /// Shards run at once.
    pub capacity: u32,
    /// Node id (defaults to the host name).
    pub node_id: Option<String>,
    /// Worker id (defaults to `<node>/<pid>`).
    pub worker_id: Option<String>,
    /// MiB of drawn pictures the render role keeps in memory for the node's judges (0: none).
    pub keep_mib: usize,
    /// The folders the roles open asset files (URDF, meshes) from; none: the working folder.
    /// Never a folder a task names (`assay_spec::assets::set_roots`).
    pub asset_roots: Vec<PathBuf>,
    /// The environment variables an openpi policy's `api_key_env` may name (a key this worker
    /// may send to the server a policy string gives); none: no variable.
    pub policy_key_envs: Vec<String>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            coordinator: String::new(),
            roles: vec!["sim".into()],
            config: None,
            image_size: (640, 480),
            video: false,
            capacity: 1,
            node_id: None,
            worker_id: None,
            keep_mib: 256,
            asset_roots: Vec::new(),
            policy_key_envs: Vec::new(),
        }
    }
}

/// The loader of `diffusion:model=…` policies: libtorch's, in a build with the `trainer` feature.
pub fn diffusion_loader() -> Option<assay_policy::DiffusionLoader> {
    #[cfg(feature = "trainer")]
    {
        Some(|bytes| {
            // One libtorch thread per process: episodes run side by side on the shard threads,
            // and libtorch's intra-op threads collapse under that load on a small node.
            tch::set_num_threads(1);
            assay_trainer::diffusion::DiffusionPolicy::from_bytes(bytes, tch::Device::Cpu)
                .map(|p| Box::new(p) as Box<dyn assay_model::policy::Policy>)
                .map_err(|e| assay_model::policy::PolicyError::Load(e.to_string()))
        })
    }
    #[cfg(not(feature = "trainer"))]
    {
        None
    }
}

pub(crate) fn io_error(what: &str) -> impl Fn(std::io::Error) -> ShardError + '_ {
    move |e| ShardError::retryable(format!("artifact store: {what}: {e}"))
}

/// The roles of one worker process: shards go to the role they were leased for.
pub struct Roles {
    sim: Option<SimRole>,
    render: Option<Arc<RenderRole>>,
    judge: Option<JudgeRole>,
    #[cfg(feature = "trainer")]
    trainer: Option<trainer::TrainerRole>,
    counters: Arc<Counters>,
}

impl Roles {
    /// What this worker has done so far.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }
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
            (Ok(pb::Role::Render), _, _) if self.render.is_some() => {
                let render = self.render.as_ref().expect("checked");
                render.run(a, artifact_root, &self.counters)
            }
            #[cfg(feature = "trainer")]
            (Ok(pb::Role::Trainer), _, _) if self.trainer.is_some() => {
                let trainer = self.trainer.as_ref().expect("checked");
                self.counters.running.fetch_add(1, Ordering::Relaxed);
                let result = trainer.run(a, artifact_root, &self.counters);
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

/// A worker whose roles are ready (the renderer found its adapter, the configuration read, the
/// trainer's device chosen), before it joins a coordinator.
pub struct Worker {
    coordinator: String,
    /// The roles shards are leased for.
    roles: Vec<pb::Role>,
    role_names: Vec<String>,
    /// What this worker offers beyond its roles (`judge:<name>`, `gpu`, `libtorch`).
    capabilities: Vec<String>,
    capacity: u32,
    node_id: String,
    worker_id: String,
    judge_config: Option<(assay_judge::Config, String)>,
    render: Option<Arc<RenderRole>>,
    video: bool,
    simulating: bool,
    #[cfg(feature = "trainer")]
    trainer: Option<trainer::TrainerRole>,
}

impl Worker {
    /// Checks the roles and readies each: an unknown role, a role this build lacks, a bad
    /// configuration or no graphics adapter for the render role fail here, before any
    /// connection.
    pub fn new(o: Options) -> anyhow::Result<Self> {
        let roots = assay_spec::assets::set_roots(&o.asset_roots).map_err(anyhow::Error::msg)?;
        tracing::info!(roots = ?roots, "asset files are opened below these folders only");
        assay_policy::openpi::allow_key_vars(&o.policy_key_envs).map_err(anyhow::Error::msg)?;
        let mut roles = Vec::new();
        for r in &o.roles {
            match pb::Role::parse(r) {
                Some(role @ (pb::Role::Sim | pb::Role::Render | pb::Role::Judge)) => {
                    roles.push(role)
                }
                #[cfg(feature = "trainer")]
                Some(pb::Role::Trainer) => roles.push(pb::Role::Trainer),
                Some(other) => bail!(
                    "role '{}' is not available in this build (built without the `trainer` feature)",
                    other.name()
                ),
                None => bail!("unknown role '{r}' (sim, render, judge, trainer)"),
            }
        }
        let judge_config = match &o.config {
            Some(path) => (
                assay_judge::Config::load(path).map_err(anyhow::Error::msg)?,
                path.display().to_string(),
            ),
            None => (
                assay_judge::Config::default(),
                "no configuration file".to_owned(),
            ),
        };
        let node_id = o.node_id.unwrap_or_else(|| {
            std::fs::read_to_string("/etc/hostname")
                .map(|s| s.trim().to_owned())
                .unwrap_or_else(|_| "local".into())
        });
        let worker_id = o.worker_id.unwrap_or_else(|| default_worker_id(&node_id));
        let mut capabilities = Vec::new();
        let render = if roles.contains(&pb::Role::Render) {
            let renderer = Renderer::new().context("starting the render role")?;
            tracing::info!(adapter = %renderer.adapter(), "render role ready");
            if renderer.adapter().device_type != "Cpu" {
                capabilities.push("gpu".to_owned());
            }
            Some(Arc::new(RenderRole::start(
                renderer,
                imagery_stream(&worker_id),
                o.image_size,
                o.keep_mib << 20,
            )?))
        } else {
            None
        };
        let judging = roles.contains(&pb::Role::Judge);
        if judging {
            capabilities.extend(judge_config.0.names().iter().map(|n| format!("judge:{n}")));
        }
        if cfg!(feature = "trainer") && roles.contains(&pb::Role::Trainer) {
            capabilities.push("libtorch".to_owned());
        }
        #[cfg(feature = "trainer")]
        let trainer = if roles.contains(&pb::Role::Trainer) {
            let text = match &o.config {
                Some(p) => Some(
                    std::fs::read_to_string(p)
                        .with_context(|| format!("reading {}", p.display()))?,
                ),
                None => None,
            };
            Some(
                trainer::TrainerRole::new(text.as_deref())
                    .map_err(|e| anyhow::anyhow!("trainer role: {e}"))?,
            )
        } else {
            None
        };
        let simulating = roles.contains(&pb::Role::Sim);
        Ok(Self {
            coordinator: o.coordinator,
            roles,
            role_names: o.roles,
            capabilities,
            capacity: o.capacity.max(1),
            node_id,
            worker_id,
            judge_config: judging.then_some(judge_config),
            render,
            video: o.video,
            simulating,
            #[cfg(feature = "trainer")]
            trainer,
        })
    }

    /// The worker's id (`<node>/<pid>` unless one was given).
    pub fn id(&self) -> &str {
        &self.worker_id
    }

    /// The shard handler of these roles; their blocking calls (remote policies, judges, the
    /// trainer's policies) run on `runtime`.
    pub fn into_roles(self, runtime: tokio::runtime::Handle) -> Roles {
        self.split(runtime).1
    }

    fn split(self, runtime: tokio::runtime::Handle) -> (WorkerConfigParts, Roles) {
        let counters = Arc::new(Counters::default());
        let judge = self.judge_config.map(|(config, origin)| JudgeRole {
            config,
            origin,
            judges: Default::default(),
            runtime: runtime.clone(),
            worker_id: self.worker_id.clone(),
            counters: counters.clone(),
        });
        let sim = self.simulating.then(|| SimRole {
            render: self.render.clone(),
            video: self.video,
            counters: counters.clone(),
            runtime: runtime.clone(),
        });
        let roles = Roles {
            sim,
            render: self.render,
            judge,
            // Made before the runtime (a bad configuration fails first); runs on it.
            #[cfg(feature = "trainer")]
            trainer: self.trainer.map(|t| t.on(runtime)),
            counters,
        };
        let parts = WorkerConfigParts {
            coordinator: self.coordinator,
            roles: self.roles,
            role_names: self.role_names,
            capabilities: self.capabilities,
            capacity: self.capacity,
            node_id: self.node_id,
            worker_id: self.worker_id,
        };
        (parts, roles)
    }

    /// Joins the coordinator and runs shards until `shutdown` resolves (then hands back what it
    /// has not finished) or the session fails for good. Runs on the current tokio runtime.
    pub async fn serve(
        self,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let (parts, roles) = self.split(tokio::runtime::Handle::current());
        let (announce, announced) = tokio::sync::watch::channel(None::<(String, String)>);
        let mut versions = assay_sim::versions();
        versions.insert("assay".into(), env!("CARGO_PKG_VERSION").into());
        let credential =
            assay_proto::auth::Credential::from_env(&[assay_proto::auth::Access::Worker])
                .map_err(anyhow::Error::msg)?;
        let config = WorkerConfig {
            coordinator: parts.coordinator,
            worker_id: parts.worker_id,
            node_id: parts.node_id,
            roles: parts.roles,
            capabilities: parts.capabilities,
            capacity: parts.capacity,
            versions,
            max_backoff: Duration::from_secs(2),
            give_up_after: None,
            token: credential.as_ref().map(|c| c.token.clone()),
            on_registered: Some(Arc::new(move |r: &pb::Registered| {
                let _ = announce.send(Some((r.telemetry_endpoint.clone(), r.cluster.clone())));
            })),
        };
        let stats = tokio::spawn(telemetry::publish_stats(
            announced,
            credential.map(|c| c.zenoh_login()),
            roles.counters.clone(),
            config.worker_id.clone(),
            config.node_id.clone(),
            parts.role_names,
            u64::from(config.capacity),
        ));
        let result = run_worker(config, Arc::new(roles), shutdown).await;
        stats.abort();
        let _ = stats.await;
        result?;
        Ok(())
    }
}

/// What [`Worker::serve`] needs of a worker besides its roles.
struct WorkerConfigParts {
    coordinator: String,
    roles: Vec<pb::Role>,
    role_names: Vec<String>,
    capabilities: Vec<String>,
    capacity: u32,
    node_id: String,
    worker_id: String,
}
