//! A worker opens the model a policy's spec names (`torchscript:path=…`, `diffusion:model=…`)
//! only below its artifact store or the asset roots its operator gave: an absolute path
//! elsewhere, a `..` climb and a link out are refused as a load error naming the argument and
//! the reason, while files inside load. The files outside are valid models that would load and
//! act: the refusals are the confinement's, not the files'.
//!
//! The asset roots are the process's (`assay_spec::assets::set_roots`, set once): every test
//! here shares one layout.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

use assay_model::policy::{Policy, PolicyError, PolicySpec};
use assay_policy::DiffusionLoader;

/// `assets/` (the asset root), `artifacts/` (the artifact store) and `outside/`, each holding a
/// model; `assets/link.pt` points at the one outside.
struct Layout {
    _dir: tempfile::TempDir,
    root: PathBuf,
}

impl Layout {
    fn assets(&self) -> PathBuf {
        self.root.join("assets")
    }
    fn artifacts(&self) -> PathBuf {
        self.root.join("artifacts")
    }
    fn outside(&self) -> PathBuf {
        self.root.join("outside")
    }
}

fn layout() -> &'static Layout {
    static LAYOUT: OnceLock<Layout> = OnceLock::new();
    LAYOUT.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().canonicalize().unwrap();
        let l = Layout { _dir: dir, root };
        for d in [l.assets(), l.artifacts().join("policies"), l.outside()] {
            std::fs::create_dir_all(d).unwrap();
        }
        for path in [
            l.assets().join("policy.pt"),
            l.artifacts().join("policies/key.pt"),
            l.outside().join("policy.pt"),
        ] {
            write_model(&path);
        }
        std::os::unix::fs::symlink(l.outside().join("policy.pt"), l.assets().join("link.pt"))
            .unwrap();
        assay_spec::assets::set_roots(&[l.assets()]).unwrap();
        l
    })
}

/// A valid model at `path`: a traced TorchScript module with the feature `torch`, else bytes the
/// diffusion loader of these tests takes.
fn write_model(path: &Path) {
    #[cfg(feature = "torch")]
    {
        use tch::{CModule, Device, Kind, Tensor};
        let image = Tensor::rand([1, 3, 8, 8], (Kind::Float, Device::Cpu));
        let proprio = Tensor::rand([1, 4], (Kind::Float, Device::Cpu));
        let module =
            CModule::create_by_tracing("Policy", "forward", &[image, proprio], &mut |xs| {
                vec![&xs[1] * 2.0]
            })
            .unwrap();
        module.save(path).unwrap();
    }
    #[cfg(not(feature = "torch"))]
    std::fs::write(path, MODEL).unwrap();
}

#[cfg(not(feature = "torch"))]
const MODEL: &[u8] = b"a diffusion checkpoint";

fn runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| tokio::runtime::Runtime::new().unwrap())
}

/// Times [`any_bytes`] was given bytes (only the test of models inside calls it).
static LOADED: AtomicUsize = AtomicUsize::new(0);

/// A diffusion loader that takes any bytes: what it is given was opened and read.
fn any_bytes(bytes: &[u8]) -> Result<Box<dyn Policy>, PolicyError> {
    assert!(!bytes.is_empty());
    LOADED.fetch_add(1, Ordering::SeqCst);
    Ok(Box::new(assay_policy::random::RandomPolicy::new(0.1, 0.1)))
}

/// A diffusion loader for specs that must be refused: bytes given to it were read.
fn never(_: &[u8]) -> Result<Box<dyn Policy>, PolicyError> {
    panic!("the diffusion loader was given the bytes of a model outside the operator's folders")
}

fn load_with(spec: &str, diffusion: DiffusionLoader) -> Result<Box<dyn Policy>, PolicyError> {
    let l = layout();
    let spec = PolicySpec::parse(spec).unwrap();
    assay_policy::load_with(&spec, &l.artifacts(), runtime().handle(), Some(diffusion))
}

fn load(spec: &str) -> Result<Box<dyn Policy>, PolicyError> {
    load_with(spec, any_bytes)
}

/// The load error of `spec`, which must be a refusal naming `arg`.
fn refused(spec: &str, arg: &str) -> String {
    match load_with(spec, never) {
        Err(PolicyError::Load(m)) => {
            assert!(
                m.contains(&format!("{arg}="))
                    && m.contains("outside the folders the operator allowed"),
                "{spec}: {m}"
            );
            m
        }
        Err(other) => panic!("{spec}: expected a load error, got {other}"),
        Ok(_) => panic!("{spec}: loaded a model outside the operator's folders"),
    }
}

#[test]
fn a_diffusion_model_outside_the_operators_folders_is_refused_unread() {
    let l = layout();
    let outside = l.outside().join("policy.pt");
    let m = refused(&format!("diffusion:model={}", outside.display()), "model");
    assert!(m.starts_with("diffusion policy model="), "{m}");
    // A file that does not exist is refused in the same words: the refusal comes before any open.
    let missing = refused(
        &format!(
            "diffusion:model={}",
            l.outside().join("missing.pt").display()
        ),
        "model",
    );
    assert_eq!(
        m.replace("policy.pt", "missing.pt"),
        missing,
        "an existing and a missing file outside are refused alike"
    );
    // Climbing out of the artifact store, and a link out of the asset root.
    refused("diffusion:model=../outside/policy.pt", "model");
    refused(
        &format!(
            "diffusion:model={}/../outside/policy.pt",
            l.assets().display()
        ),
        "model",
    );
    refused(
        &format!("diffusion:model={}", l.assets().join("link.pt").display()),
        "model",
    );
}

#[test]
fn a_diffusion_model_in_the_artifact_store_or_an_asset_root_loads() {
    let l = layout();
    for spec in [
        "diffusion:model=policies/key.pt".to_owned(),
        format!(
            "diffusion:model={}",
            l.artifacts().join("policies/key.pt").display()
        ),
        format!("diffusion:model={}", l.assets().join("policy.pt").display()),
        // `..` that stays inside is no climb out.
        "diffusion:model=policies/../policies/key.pt".to_owned(),
    ] {
        let before = LOADED.load(Ordering::SeqCst);
        load(&spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
        assert_eq!(LOADED.load(Ordering::SeqCst), before + 1, "{spec}");
    }
}

#[cfg(feature = "torch")]
mod torchscript {
    use super::*;
    use assay_model::policy::{EpisodeContext, PolicyObservation};

    fn acts(mut policy: Box<dyn Policy>) {
        policy
            .reset(&EpisodeContext {
                task_id: "t".into(),
                seed: 1,
                instruction: String::new(),
                arm: None,
            })
            .unwrap();
        let obs = PolicyObservation::legacy(0, 8, 8, vec![0; 8 * 8 * 3], [0.25, 0.5, 0.0, 1.0]);
        assert_eq!(policy.act(&obs).unwrap(), vec![[0.5, 1.0, 0.0, 2.0]]);
    }

    #[test]
    fn a_module_outside_the_operators_folders_is_refused() {
        let l = layout();
        let outside = l.outside().join("policy.pt");
        // The module outside is a valid one: given the operator's own path, it loads and acts.
        acts(Box::new(
            assay_policy::torchscript::TorchScriptPolicy::load(&outside, tch::Device::Cpu).unwrap(),
        ));
        let m = refused(&format!("torchscript:path={}", outside.display()), "path");
        assert!(m.starts_with("TorchScript policy path="), "{m}");
        refused("torchscript:path=../outside/policy.pt", "path");
        refused(
            &format!(
                "torchscript:path={}/../outside/policy.pt",
                l.assets().display()
            ),
            "path",
        );
        refused(
            &format!("torchscript:path={}", l.assets().join("link.pt").display()),
            "path",
        );
        // A policy server's factory refuses it too.
        let spec = PolicySpec::parse(&format!("torchscript:path={}", outside.display())).unwrap();
        match assay_policy::factory(&spec, &l.artifacts(), runtime().handle(), None) {
            Err(PolicyError::Load(m)) => {
                assert!(
                    m.contains("outside the folders the operator allowed"),
                    "{m}"
                )
            }
            Err(e) => panic!("expected a load error, got {e}"),
            Ok(_) => panic!("the factory loaded a module outside"),
        }
    }

    #[test]
    fn a_module_in_an_asset_root_or_the_artifact_store_loads_and_acts() {
        let l = layout();
        for spec in [
            format!(
                "torchscript:path={}",
                l.assets().join("policy.pt").display()
            ),
            "torchscript:path=policies/key.pt".to_owned(),
        ] {
            acts(load(&spec).unwrap_or_else(|e| panic!("{spec}: {e}")));
        }
    }
}
