//! TorchScript policies: a module saved with `torch.jit.save` (or traced from Rust with
//! `tch::CModule::create_by_tracing`), run with libtorch.
//!
//! Calling convention (also in `docs/policies.md`):
//!
//! ```text
//! forward(image: float32 [1, 3·N, H, W], state: float32 [1, S]) -> float32 [1, K, D]  (K ≥ 1)
//!                                                                or       [1, D]     (one action)
//! ```
//!
//! - `image`: the N cameras of the policy's interface, stacked along channels in its order (each
//!   R, G, B, top row first, values in [0, 1]: the RGB8 bytes divided by 255); all the same size.
//!   The original interface has one: the task camera at the batch's clip size (64 × 64 by default).
//! - `state`: the interface's state vector; the original one is the tool's position x, y, z (m)
//!   and 1.0 while it holds an object, else 0.0.
//! - the answer: a chunk of K actions of the interface's action space (D floats each; the
//!   original: the tool's velocity x, y, z in m/s and the hold command). The simulator runs them
//!   (or the first `horizon`) before it calls `forward` again.
//!
//! The module is called in eval mode without gradients and must be stateless between calls
//! (`reset` is a no-op): keep any history in the inputs. Inputs are on the module's device; the
//! answer may be on any device and of any floating kind. An answer of another shape, or with
//! non-finite values, is [`PolicyError::BadAnswer`] naming it. The interface comes from the
//! policy's spec (`torchscript:path=…,space=ee_delta,cameras=…`); depth is not passed to modules.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use assay_model::clip::ACTION_DIMS;
use assay_model::policy::{
    Action, EpisodeContext, Interface, Policy, PolicyError, PolicyObservation,
};
use tch::{CModule, Device, IValue, Kind, Tensor};

/// A loaded TorchScript policy. Cloning shares the module (it is stateless), so one load serves
/// many episodes.
#[derive(Clone, Debug)]
pub struct TorchScriptPolicy {
    module: Arc<CModule>,
    device: Device,
    path: PathBuf,
    interface: Interface,
}

impl TorchScriptPolicy {
    /// Loads the module at `path` onto `device`, in eval mode. A missing file or one that is not
    /// TorchScript is `Load` naming the path. Opens `path` as given: for a path the operator
    /// names; a worker opens the file a spec names with [`crate::open_model`] and loads it with
    /// [`TorchScriptPolicy::from_reader`].
    pub fn load(path: impl AsRef<Path>, device: Device) -> Result<TorchScriptPolicy, PolicyError> {
        let path = path.as_ref();
        let mut file = std::fs::File::open(path)
            .ok()
            .filter(|f| f.metadata().is_ok_and(|m| m.is_file()))
            .ok_or_else(|| {
                PolicyError::Load(format!(
                    "TorchScript policy {}: no such file",
                    path.display()
                ))
            })?;
        Self::from_reader(path, &mut file, device)
    }

    /// Loads the module whose bytes `reader` gives (the file at `path`, already open) onto
    /// `device`, in eval mode: libtorch never opens a path itself. One that is not TorchScript is
    /// `Load` naming `path`.
    pub fn from_reader(
        path: &Path,
        reader: &mut impl std::io::Read,
        device: Device,
    ) -> Result<TorchScriptPolicy, PolicyError> {
        let mut module = CModule::load_data_on_device(reader, device).map_err(|e| {
            PolicyError::Load(format!(
                "TorchScript policy {}: not a TorchScript module: {}",
                path.display(),
                first_line(&e.to_string())
            ))
        })?;
        module.f_set_eval().map_err(|e| {
            PolicyError::Load(format!("TorchScript policy {}: {e}", path.display()))
        })?;
        Ok(TorchScriptPolicy {
            module: Arc::new(module),
            device,
            path: path.to_owned(),
            interface: Interface::default(),
        })
    }

    /// The module fed through `interface` (its cameras all of one size, no depth).
    pub fn with_interface(mut self, interface: Interface) -> Result<Self, PolicyError> {
        let bad = |e: String| {
            PolicyError::Load(format!("TorchScript policy {}: {e}", self.path.display()))
        };
        interface.validate().map_err(bad)?;
        let first = &interface.cameras[0];
        if let Some((i, _)) = interface
            .cameras
            .iter()
            .enumerate()
            .find(|(_, c)| (c.width, c.height) != (first.width, first.height))
        {
            return Err(bad(format!(
                "interface.cameras[{i}]: every camera of a module has the first one's size (they \
                 are stacked along channels)"
            )));
        }
        if let Some(i) = interface.cameras.iter().position(|c| c.depth) {
            return Err(bad(format!(
                "interface.cameras[{i}].depth: modules get RGB only"
            )));
        }
        self.interface = interface;
        Ok(self)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn forward(&self, obs: &PolicyObservation) -> Result<Tensor, PolicyError> {
        let failed = |e: tch::TchError| {
            PolicyError::BadAnswer(format!(
                "TorchScript policy {} failed at step {}: {}",
                self.path.display(),
                obs.step,
                first_line(&e.to_string())
            ))
        };
        let mut planes = Vec::with_capacity(obs.images.len().max(1));
        let legacy;
        let images = if obs.images.is_empty() {
            legacy = [assay_model::policy::NamedImage {
                name: "image".into(),
                width: obs.width,
                height: obs.height,
                rgb: obs.rgb.clone(),
                depth: Vec::new(),
            }];
            &legacy[..]
        } else {
            &obs.images[..]
        };
        for im in images {
            let (w, h) = (im.width as i64, im.height as i64);
            if im.rgb.len() as i64 != w * h * 3
                || (im.width, im.height) != (images[0].width, images[0].height)
            {
                return Err(PolicyError::BadAnswer(format!(
                    "TorchScript policy {}: camera '{}' is {w}×{h} with {} bytes of RGB (the \
                     cameras of a module are all {}×{}, 3 bytes a pixel)",
                    self.path.display(),
                    im.name,
                    im.rgb.len(),
                    images[0].width,
                    images[0].height
                )));
            }
            planes.push(
                Tensor::from_slice(&im.rgb)
                    .view([1, h, w, 3])
                    .permute([0, 3, 1, 2])
                    .to_kind(Kind::Float)
                    .divide_scalar(255.0),
            );
        }
        let image = Tensor::cat(&planes, 1).to_device(self.device);
        let state = if obs.state.is_empty() {
            &obs.proprio[..]
        } else {
            &obs.state[..]
        };
        let state = Tensor::from_slice(state)
            .view([1, state.len() as i64])
            .to_device(self.device);
        let out = tch::no_grad(|| {
            self.module
                .forward_is(&[IValue::Tensor(image), IValue::Tensor(state)])
        })
        .map_err(failed)?;
        match out {
            IValue::Tensor(t) => Ok(t),
            other => Err(PolicyError::BadAnswer(format!(
                "TorchScript policy {}: forward returned {}, expected a float32 tensor [1, K, D]",
                self.path.display(),
                ivalue_kind(&other)
            ))),
        }
    }
}

impl Policy for TorchScriptPolicy {
    fn reset(&mut self, _: &EpisodeContext) -> Result<(), PolicyError> {
        Ok(())
    }

    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        self.act_any(obs)?
            .into_iter()
            .map(|a| {
                a.try_into().map_err(|a: Vec<f32>| {
                    PolicyError::BadAnswer(format!(
                        "TorchScript policy {}: actions of {} floats, expected {ACTION_DIMS}",
                        self.path.display(),
                        a.len()
                    ))
                })
            })
            .collect()
    }

    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        let out = self.forward(obs)?;
        let shape = out.size();
        // The original interface's answers are checked here; others by the simulator, which
        // knows the task's arm.
        let want = self.interface.is_legacy().then_some(ACTION_DIMS as i64);
        let fits = |a: i64| a >= 1 && want.is_none_or(|d| d == a);
        let (k, d) = match shape.as_slice() {
            [1, k, a] if *k >= 1 && fits(*a) => (*k as usize, *a as usize),
            [1, a] if fits(*a) => (1, *a as usize),
            _ => {
                let d = want.map_or("D".to_string(), |d| d.to_string());
                return Err(PolicyError::BadAnswer(format!(
                    "TorchScript policy {}: forward returned a tensor of shape {shape:?}, expected \
                     [1, K, {d}] or [1, {d}]",
                    self.path.display()
                )));
            }
        };
        if !out.is_floating_point() {
            return Err(PolicyError::BadAnswer(format!(
                "TorchScript policy {}: forward returned {:?} values, expected float32",
                self.path.display(),
                out.kind()
            )));
        }
        let values: Vec<f32> = out
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .contiguous()
            .view([-1])
            .try_into()
            .map_err(|e: tch::TchError| {
                PolicyError::BadAnswer(format!(
                    "TorchScript policy {}: {}",
                    self.path.display(),
                    first_line(&e.to_string())
                ))
            })?;
        debug_assert_eq!(values.len(), k * d);
        if let Some(i) = values.iter().position(|x| !x.is_finite()) {
            return Err(PolicyError::BadAnswer(format!(
                "TorchScript policy {}: action {} at step {} has the non-finite value {}",
                self.path.display(),
                i / d,
                obs.step,
                values[i]
            )));
        }
        Ok(values.chunks_exact(d).map(<[f32]>::to_vec).collect())
    }

    fn interface(&self) -> Interface {
        self.interface.clone()
    }
}

/// libtorch's errors carry a C++ backtrace after the first line.
fn first_line(s: &str) -> &str {
    s.lines().next().unwrap_or(s)
}

fn ivalue_kind(v: &IValue) -> &'static str {
    match v {
        IValue::None => "None",
        IValue::Tensor(_) => "a tensor",
        IValue::Double(_) | IValue::Int(_) | IValue::Bool(_) => "a number",
        IValue::Tuple(_) => "a tuple",
        IValue::GenericList(_)
        | IValue::DoubleList(_)
        | IValue::IntList(_)
        | IValue::BoolList(_)
        | IValue::TensorList(_) => "a list",
        IValue::String(_) | IValue::StringList(_) => "a string",
        IValue::GenericDict(_) => "a dict",
        IValue::Object(_) => "an object",
        _ => "a value of another kind",
    }
}
