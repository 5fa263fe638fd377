//! `assay policy`: serve a policy over the `assay.v1.Policy` gRPC service, or check one. The
//! service, the client and the loaders live in `assay-policy`; this file only parses flags.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use assay_model::policy::{
    DEFAULT_REMOTE_TIMEOUT_MS, EpisodeContext, NamedImage, Policy, PolicyError, PolicyObservation,
    PolicySpec,
};
use assay_policy::{PolicyFactory, RemotePolicy, ServerInfo};
use serde_json::json;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(clap::Subcommand)]
pub enum Cmd {
    /// Serve a policy Assay can load (e.g. torchscript:path=bc.pt) over gRPC. Prints
    /// `listening on http://ADDR` as its first line on stdout; stops on SIGTERM or Ctrl-C.
    Serve {
        /// The policy to serve (a policy spec: torchscript:path=…, diffusion:model=…, or
        /// remote:url=… to relay another server).
        #[arg(long)]
        policy: String,
        /// Address to listen on (port 0: any free port).
        #[arg(long, default_value = "127.0.0.1:0")]
        listen: SocketAddr,
        /// For tests of clients: delay every Act by this many milliseconds (a slow server).
        #[arg(long, default_value_t = 0)]
        delay_ms: u64,
        /// Where artifact keys of policies (diffusion:model=<key>) are found.
        #[arg(long, default_value = ".")]
        artifact_root: PathBuf,
    },
    /// Load a policy spec, or connect to a policy server (a spec remote:url=… or a bare
    /// http://HOST:PORT), and print what it says about itself as JSON. A loaded policy also acts
    /// once on a blank 64×64 frame.
    Check {
        spec: String,
        /// Where artifact keys of policies (diffusion:model=<key>) are found.
        #[arg(long, default_value = ".")]
        artifact_root: PathBuf,
    },
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let rt = assay_run::rt::runtime("assay-policy");
    match a.cmd {
        Cmd::Serve {
            policy,
            listen,
            delay_ms,
            artifact_root,
        } => serve(&rt, &policy, listen, delay_ms, &artifact_root),
        Cmd::Check {
            spec,
            artifact_root,
        } => check(&rt, spec, &artifact_root),
    }
}

/// Serves `policy` on `listen` until SIGTERM or Ctrl-C.
fn serve(
    rt: &tokio::runtime::Runtime,
    policy: &str,
    listen: SocketAddr,
    delay_ms: u64,
    artifact_root: &Path,
) -> anyhow::Result<ExitCode> {
    let spec = PolicySpec::parse(policy).map_err(anyhow::Error::msg)?;
    let factory = assay_policy::factory(
        &spec,
        artifact_root,
        rt.handle(),
        assay_worker::diffusion_loader(),
    )?;
    let factory = delayed(factory, Duration::from_millis(delay_ms));
    // The served policy's interface, declared in Health (one instance, made and dropped).
    let sample = factory()?;
    let info = ServerInfo {
        name: policy.to_owned(),
        version: env!("CARGO_PKG_VERSION").into(),
        interface: sample.interface(),
        ..ServerInfo::default()
    };
    drop(sample);
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(listen)
            .await
            .with_context(|| format!("cannot listen on {listen}"))?;
        let addr = listener.local_addr()?;
        {
            use std::io::Write;
            let mut out = std::io::stdout().lock();
            writeln!(out, "listening on http://{addr}")?;
            out.flush()?;
        }
        // With the cluster's policy token (ASSAY_POLICY_TOKEN[_FILE], or derived from the
        // cluster token), only callers that present it get in.
        let token =
            assay_proto::auth::Token::service_from_env("policy").map_err(anyhow::Error::msg)?;
        assay_policy::serve(listener, factory, info, token, assay_run::rt::terminated())
            .await
            .context("policy server")
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Loads a policy, or connects to a server, and prints what it says about itself.
fn check(
    rt: &tokio::runtime::Runtime,
    spec: String,
    artifact_root: &Path,
) -> anyhow::Result<ExitCode> {
    let name = spec;
    let spec = if name.starts_with("http://") || name.starts_with("https://") {
        PolicySpec::Remote {
            url: name.clone(),
            timeout_ms: DEFAULT_REMOTE_TIMEOUT_MS,
            interface: None,
        }
    } else {
        PolicySpec::parse(&name).map_err(anyhow::Error::msg)?
    };
    let report = match &spec {
        PolicySpec::Remote {
            url, timeout_ms, ..
        } => {
            let remote = RemotePolicy::connect(
                url,
                Duration::from_millis(*timeout_ms),
                rt.handle().clone(),
            )?;
            let h = remote.health()?;
            json!({
                "url": url,
                "name": h.info.name,
                "version": h.info.version,
                "image_width": h.info.image_width,
                "image_height": h.info.image_height,
                "chunk_size": h.info.chunk_size,
                "live_episodes": h.live_episodes,
                "interface": interface_json(&h.info.interface),
            })
        }
        _ => {
            let mut policy = assay_policy::load_with(
                &spec,
                artifact_root,
                rt.handle(),
                assay_worker::diffusion_loader(),
            )?;
            // f32 → JSON goes through f64: round so 0.1 prints as 0.1.
            let chunk: Vec<Vec<f64>> = trial_act(policy.as_mut())?
                .iter()
                .map(|a| a.iter().map(|x| (*x as f64 * 1e6).round() / 1e6).collect())
                .collect();
            json!({
                "policy": name,
                "trial_chunk": chunk,
            })
        }
    };
    outln!("{}", serde_json::to_string_pretty(&report)?);
    Ok(ExitCode::SUCCESS)
}

/// A policy interface as `assay policy check` prints it.
fn interface_json(i: &assay_model::policy::Interface) -> serde_json::Value {
    json!({
        "action_space": i.action.name(),
        "cameras": i.cameras.iter().map(|c| json!({
            "name": c.name,
            "source": c.source.name(),
            "width": c.width,
            "height": c.height,
            "depth": c.depth,
        })).collect::<Vec<_>>(),
        "state": i.state.iter().map(|s| s.name()).collect::<Vec<_>>(),
        "execute_horizon": i.execute,
    })
}

/// One episode step on a blank 64×64 frame with the tool at the origin.
fn trial_act(policy: &mut dyn Policy) -> Result<Vec<Vec<f32>>, PolicyError> {
    let interface = policy.interface();
    policy.reset(&EpisodeContext {
        task_id: "check".into(),
        seed: 0,
        instruction: "check the policy".into(),
        arm: None,
    })?;
    // Blank frames of the sizes the policy asked for (64 where it left it to the batch), a state
    // of zeros (`joints` as the Panda's 7).
    let images: Vec<NamedImage> = interface
        .cameras
        .iter()
        .map(|c| {
            let (w, h) = if c.width == 0 {
                (64, 64)
            } else {
                (c.width, c.height)
            };
            NamedImage {
                name: c.name.clone(),
                width: w,
                height: h,
                rgb: vec![0; (w * h * 3) as usize],
                depth: if c.depth {
                    vec![1.0; (w * h) as usize]
                } else {
                    Vec::new()
                },
            }
        })
        .collect();
    let first = &images[0];
    let mut obs =
        PolicyObservation::legacy(0, first.width, first.height, first.rgb.clone(), [0.0; 4]);
    obs.state = vec![0.0; interface.state_dims(Some("panda")).unwrap_or(4)];
    obs.images = images;
    policy.act_any(&obs)
}

/// Makes every policy of `factory` answer `delay` late (a slow server, for tests of clients).
fn delayed(factory: PolicyFactory, delay: Duration) -> PolicyFactory {
    if delay.is_zero() {
        return factory;
    }
    std::sync::Arc::new(move || {
        Ok(Box::new(Delayed {
            inner: factory()?,
            delay,
        }) as Box<dyn Policy>)
    })
}

struct Delayed {
    inner: Box<dyn Policy>,
    delay: Duration,
}

impl Policy for Delayed {
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError> {
        self.inner.reset(episode)
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        // Runs on the server's blocking pool: sleeping here holds no executor thread.
        std::thread::sleep(self.delay);
        self.inner.act_any(obs)
    }

    fn frame_size(&self) -> Option<u32> {
        self.inner.frame_size()
    }

    fn interface(&self) -> assay_model::policy::Interface {
        self.inner.interface()
    }
}
