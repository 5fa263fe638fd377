//! `assay-policy`: the policies a simulator shard calls through [`Policy`] — remote policy servers
//! over the `assay.v1.Policy` gRPC service ([`remote`]), the reference server for that service
//! ([`server`]), openpi policy servers over websocket + msgpack-numpy ([`openpi`]), TorchScript modules on libtorch ([`torchscript`], feature `torch`) — and
//! [`load`], which turns a [`PolicySpec`] into one of them. Also the client of world models served
//! over the `assay.v1.WorldModel` gRPC service ([`world_model`]), which the proxy imagines in.
//!
//! Owns: the policy client and server, the TorchScript calling convention (`docs/policies.md`),
//! the mapping between [`PolicyError`] and gRPC status codes. Never: physics, rendering, the job
//! store; never links libtorch without the `torch` feature (a sim-only node builds without it).
//!
//! Policies are called synchronously from the simulator's shard threads (plain threads, not
//! tokio tasks), once per control step; the remote client blocks on a runtime [`Handle`] it is
//! given, so it must never be called from inside that runtime.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use assay_model::policy::{Policy, PolicyError, PolicySpec};
use tokio::runtime::Handle;

mod grpc;
pub mod openpi;
pub mod random;
pub mod remote;
pub mod server;
mod status;
#[cfg(feature = "torch")]
pub mod torchscript;
pub mod wire;
pub mod world_model;

pub use remote::{Health, RemotePolicy};
pub use server::{PolicyFactory, ServerInfo, serve};

/// Builds a diffusion policy from its checkpoint's bytes.
///
/// HOOK(diffusion): this crate does not depend on the trainer crate (libtorch training code); the
/// binary wires `assay_trainer::diffusion::DiffusionPolicy` in with [`load_with`], e.g.
/// `Some(|bytes| Ok(Box::new(DiffusionPolicy::from_bytes(bytes, tch::Device::Cpu)?) as Box<dyn Policy>))`.
pub type DiffusionLoader = fn(&[u8]) -> Result<Box<dyn Policy>, PolicyError>;

/// The policy `spec` names, ready for its first [`Policy::reset`]. Diffusion policies need the
/// trainer crate: see [`load_with`].
///
/// - `torchscript:path=…` — a TorchScript module on this worker (feature `torch`; without it a
///   `Load` error), on the GPU when there is one.
/// - `remote:url=…` — connects and checks the server's Health (blocks on `rt` for at most the
///   spec's timeout: call it from a thread outside the runtime).
/// - `diffusion:model=…` — `Load` error here.
/// - `oracle…` — `Load` error: the scripted oracle runs inside the simulator.
pub fn load(
    spec: &PolicySpec,
    artifact_root: &Path,
    rt: &Handle,
) -> Result<Box<dyn Policy>, PolicyError> {
    load_with(spec, artifact_root, rt, None)
}

/// [`load`], with the loader of diffusion checkpoints (HOOK(diffusion), see [`DiffusionLoader`]).
/// A diffusion model is an artifact key under `artifact_root` or a path on the worker.
pub fn load_with(
    spec: &PolicySpec,
    artifact_root: &Path,
    rt: &Handle,
    diffusion: Option<DiffusionLoader>,
) -> Result<Box<dyn Policy>, PolicyError> {
    match spec {
        PolicySpec::Oracle { .. } => Err(PolicyError::Load(
            "the oracle is not a learned policy: it runs inside the simulator".into(),
        )),
        PolicySpec::TorchScript { path, interface } => {
            load_torchscript(Path::new(path), interface.clone())
        }
        PolicySpec::Remote {
            url,
            timeout_ms,
            interface,
        } => {
            let mut remote = RemotePolicy::connect(
                url,
                std::time::Duration::from_millis(*timeout_ms),
                rt.clone(),
            )?;
            if let Some(i) = interface {
                remote = remote.with_interface(i.clone())?;
            }
            Ok(Box::new(remote))
        }
        PolicySpec::OpenPi {
            url,
            timeout_ms,
            api_key_env,
            interface,
        } => Ok(Box::new(openpi::OpenPiPolicy::new(
            url,
            std::time::Duration::from_millis(*timeout_ms),
            api_key_env.as_deref(),
            interface.clone(),
        )?)),
        PolicySpec::Random { speed, hold } => {
            Ok(Box::new(random::RandomPolicy::new(*speed, *hold)))
        }
        PolicySpec::Diffusion { model } => match diffusion {
            Some(loader) => {
                let path = artifact_path(artifact_root, model);
                let bytes = std::fs::read(&path).map_err(|e| {
                    PolicyError::Load(format!(
                        "diffusion model '{model}': cannot read {}: {e}",
                        path.display()
                    ))
                })?;
                loader(&bytes)
            }
            None => Err(PolicyError::Load(
                "diffusion policies are loaded by the trainer crate".into(),
            )),
        },
    }
}

/// Makes one fresh policy per episode for [`serve`]: loads `spec` once now (so a bad spec fails
/// before anything listens), then TorchScript modules are shared between episodes (they are
/// stateless), other policies are loaded again for every episode (as [`load_with`] does).
pub fn factory(
    spec: &PolicySpec,
    artifact_root: &Path,
    rt: &Handle,
    diffusion: Option<DiffusionLoader>,
) -> Result<PolicyFactory, PolicyError> {
    #[cfg(feature = "torch")]
    if let PolicySpec::TorchScript { path, interface } = spec {
        let mut module =
            torchscript::TorchScriptPolicy::load(path, tch::Device::cuda_if_available())?;
        if let Some(i) = interface {
            module = module.with_interface(i.clone())?;
        }
        return Ok(Arc::new(move || {
            Ok(Box::new(module.clone()) as Box<dyn Policy>)
        }));
    }
    drop(load_with(spec, artifact_root, rt, diffusion)?);
    let (spec, root, rt) = (spec.clone(), artifact_root.to_owned(), rt.clone());
    Ok(Arc::new(move || load_with(&spec, &root, &rt, diffusion)))
}

/// Where an artifact key or a path names a file: absolute paths and paths that exist as given are
/// themselves, anything else is a key under the artifact root.
fn artifact_path(artifact_root: &Path, key: &str) -> PathBuf {
    let path = Path::new(key);
    if path.is_absolute() || path.exists() {
        path.to_owned()
    } else {
        artifact_root.join(path)
    }
}

#[cfg(feature = "torch")]
fn load_torchscript(
    path: &Path,
    interface: Option<assay_model::policy::Interface>,
) -> Result<Box<dyn Policy>, PolicyError> {
    let module = torchscript::TorchScriptPolicy::load(path, tch::Device::cuda_if_available())?;
    Ok(Box::new(match interface {
        Some(i) => module.with_interface(i)?,
        None => module,
    }))
}

#[cfg(not(feature = "torch"))]
fn load_torchscript(
    path: &Path,
    _: Option<assay_model::policy::Interface>,
) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError::Load(format!(
        "TorchScript policy {}: this binary was built without libtorch (assay-policy feature `torch`, \
         the assay binary's `trainer` feature)",
        path.display()
    )))
}
