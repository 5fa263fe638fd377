//! `assay-policy`: the policies a simulator shard calls through [`Policy`] — remote policy servers
//! over the `assay.v1.Policy` gRPC service ([`remote`]), the reference server for that service
//! ([`server`]), openpi policy servers over websocket + msgpack-numpy ([`openpi`]), TorchScript modules on libtorch ([`torchscript`], feature `torch`) — and
//! [`load`], which turns a [`PolicySpec`] into one of them. Also the client of world models served
//! over the `assay.v1.WorldModel` gRPC service ([`world_model`]), which the proxy imagines in.
//!
//! Owns: the policy client and server, the TorchScript calling convention (`docs/policies.md`),
//! the mapping between [`PolicyError`] and gRPC status codes, where a model file a spec names may
//! be opened ([`open_model`]). Never: physics, rendering, the job store; never links libtorch
//! without the `torch` feature (a sim-only node builds without it); never hands libtorch a path
//! (models are read from a descriptor opened below the operator's folders, then loaded from
//! memory).
//!
//! Policies are called synchronously from the simulator's shard threads (plain threads, not
//! tokio tasks), once per control step; the remote client blocks on a runtime [`Handle`] it is
//! given, so it must never be called from inside that runtime.

use std::io::Read;
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
///   `Load` error), on the GPU when there is one; in a worker, only below its artifact store or
///   its asset roots ([`open_model`]).
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
/// A model (`diffusion:model=…`, `torchscript:path=…`) is an artifact key under
/// `artifact_root` or a path on the worker, which a worker opens only below its artifact store
/// or its asset roots ([`open_model`]).
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
            load_torchscript(artifact_root, path, interface.clone())
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
                let (path, mut file) = open_model(artifact_root, "model", model)
                    .map_err(|e| PolicyError::Load(format!("diffusion policy {e}")))?;
                let mut bytes = Vec::new();
                file.read_to_end(&mut bytes).map_err(|e| {
                    PolicyError::Load(format!(
                        "diffusion policy model={model}: cannot read {}: {e}",
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
        let mut module = open_torchscript(artifact_root, path)?;
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

/// Opens the model file a policy's spec names — `arg` is the spec's argument (`path`, `model`),
/// `value` its value — and says where it was found. A relative value is a path from the working
/// folder, else an artifact key under `artifact_root`.
///
/// In a worker (a process that set asset roots, `assay_spec::assets::set_roots`) the file must
/// lie below the artifact store or below the operator's asset roots, and is opened by
/// descriptor below the folder that holds it ([`assay_spec::assets::open_in`]): an absolute path
/// elsewhere, or one that climbs out with `..` or a link, is refused unopened — a batch's policy
/// names cannot make a worker read a file the operator did not put there. Elsewhere (`assay
/// policy serve` and `check`, whose operator names the policy) any path is opened.
///
/// The error names the argument and the value (`path=/etc/x: … is outside the folders the
/// operator allowed (…)`); callers name the policy's kind.
pub fn open_model(
    artifact_root: &Path,
    arg: &str,
    value: &str,
) -> Result<(PathBuf, std::fs::File), String> {
    let also = [artifact_root.to_owned()];
    let given = Path::new(value);
    let open = |p: &Path| assay_spec::assets::open_in(p, &also);
    if given.is_absolute() {
        return open(given)
            .map(|f| (given.to_owned(), f))
            .map_err(|e| format!("{arg}={value}: {e}"));
    }
    let as_path = match open(given) {
        Ok(f) => return Ok((given.to_owned(), f)),
        Err(e) => e,
    };
    let key = artifact_root.join(given);
    let as_key = match open(&key) {
        Ok(f) => return Ok((key, f)),
        Err(e) => e,
    };
    Err(format!(
        "{arg}={value}: from the working folder: {as_path}; as an artifact key under {}: {as_key}",
        artifact_root.display()
    ))
}

#[cfg(feature = "torch")]
fn open_torchscript(
    artifact_root: &Path,
    value: &str,
) -> Result<torchscript::TorchScriptPolicy, PolicyError> {
    let (path, mut file) = open_model(artifact_root, "path", value)
        .map_err(|e| PolicyError::Load(format!("TorchScript policy {e}")))?;
    torchscript::TorchScriptPolicy::from_reader(&path, &mut file, tch::Device::cuda_if_available())
}

#[cfg(feature = "torch")]
fn load_torchscript(
    artifact_root: &Path,
    path: &str,
    interface: Option<assay_model::policy::Interface>,
) -> Result<Box<dyn Policy>, PolicyError> {
    let module = open_torchscript(artifact_root, path)?;
    Ok(Box::new(match interface {
        Some(i) => module.with_interface(i)?,
        None => module,
    }))
}

#[cfg(not(feature = "torch"))]
fn load_torchscript(
    _: &Path,
    path: &str,
    _: Option<assay_model::policy::Interface>,
) -> Result<Box<dyn Policy>, PolicyError> {
    Err(PolicyError::Load(format!(
        "TorchScript policy {path}: this binary was built without libtorch (assay-policy feature `torch`, \
         the assay binary's `trainer` feature)"
    )))
}
