//! TorchScript policies: a module saved with `torch.jit.save` (or traced from Rust with
//! `tch::CModule::create_by_tracing`), run with libtorch.
//!
//! Calling convention (also in `docs/policies.md`):
//!
//! ```text
//! forward(image: float32 [1, 3, H, W], proprio: float32 [1, 4]) -> float32 [1, K, 4]  (K ≥ 1)
//!                                                                 or       [1, 4]     (one action)
//! ```
//!
//! - `image`: the task camera's RGB frame (the batch's clip size, 64 × 64 by default), channels
//!   R, G, B, top row first, values in [0, 1] (the RGB8 bytes divided by 255).
//! - `proprio`: the tool's position x, y, z (m) and 1.0 while it holds an object, else 0.0.
//! - the answer: a chunk of K actions, each the tool's velocity x, y, z (m/s) until the next
//!   control step (10 Hz) and the hold command (≥ 0.5: hold). The simulator runs all K before it
//!   calls `forward` again.
//!
//! The module is called in eval mode without gradients and must be stateless between calls
//! (`reset` is a no-op): keep any history in the inputs. Inputs are on the module's device; the
//! answer may be on any device and of any floating kind. An answer of another shape, or with
//! non-finite values, is [`PolicyError::BadAnswer`] naming it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use assay_model::clip::{ACTION_DIMS, PROPRIO_DIMS};
use assay_model::policy::{Action, EpisodeContext, Policy, PolicyError, PolicyObservation};
use tch::{CModule, Device, IValue, Kind, Tensor};

/// A loaded TorchScript policy. Cloning shares the module (it is stateless), so one load serves
/// many episodes.
#[derive(Clone, Debug)]
pub struct TorchScriptPolicy {
    module: Arc<CModule>,
    device: Device,
    path: PathBuf,
}

impl TorchScriptPolicy {
    /// Loads the module at `path` onto `device`, in eval mode. A missing file or one that is not
    /// TorchScript is `Load` naming the path.
    pub fn load(path: impl AsRef<Path>, device: Device) -> Result<TorchScriptPolicy, PolicyError> {
        let path = path.as_ref();
        if !path.is_file() {
            return Err(PolicyError::Load(format!(
                "TorchScript policy {}: no such file",
                path.display()
            )));
        }
        let mut module = CModule::load_on_device(path, device).map_err(|e| {
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
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn forward(&self, obs: &PolicyObservation) -> Result<Tensor, PolicyError> {
        let (w, h) = (obs.width as i64, obs.height as i64);
        if obs.rgb.len() as i64 != w * h * 3 {
            return Err(PolicyError::Load(format!(
                "TorchScript policy {}: the observation has {} bytes of RGB, a {w}×{h} frame has {}",
                self.path.display(),
                obs.rgb.len(),
                w * h * 3
            )));
        }
        let failed = |e: tch::TchError| {
            PolicyError::BadAnswer(format!(
                "TorchScript policy {} failed at step {}: {}",
                self.path.display(),
                obs.step,
                first_line(&e.to_string())
            ))
        };
        let image = Tensor::from_slice(&obs.rgb)
            .view([1, h, w, 3])
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Float)
            .divide_scalar(255.0)
            .to_device(self.device);
        let proprio = Tensor::from_slice(&obs.proprio)
            .view([1, PROPRIO_DIMS as i64])
            .to_device(self.device);
        let out = tch::no_grad(|| {
            self.module
                .forward_is(&[IValue::Tensor(image), IValue::Tensor(proprio)])
        })
        .map_err(failed)?;
        match out {
            IValue::Tensor(t) => Ok(t),
            other => Err(PolicyError::BadAnswer(format!(
                "TorchScript policy {}: forward returned {}, expected a float32 tensor [1, K, {ACTION_DIMS}]",
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
        let out = self.forward(obs)?;
        let shape = out.size();
        let k = match shape.as_slice() {
            [1, k, a] if *k >= 1 && *a == ACTION_DIMS as i64 => *k as usize,
            [1, a] if *a == ACTION_DIMS as i64 => 1,
            _ => {
                return Err(PolicyError::BadAnswer(format!(
                    "TorchScript policy {}: forward returned a tensor of shape {shape:?}, expected \
                     [1, K, {ACTION_DIMS}] or [1, {ACTION_DIMS}]",
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
        debug_assert_eq!(values.len(), k * ACTION_DIMS);
        if let Some(i) = values.iter().position(|x| !x.is_finite()) {
            return Err(PolicyError::BadAnswer(format!(
                "TorchScript policy {}: action {} at step {} has the non-finite value {}",
                self.path.display(),
                i / ACTION_DIMS,
                obs.step,
                values[i]
            )));
        }
        Ok(values
            .chunks_exact(ACTION_DIMS)
            .map(|a| a.try_into().expect("chunks of ACTION_DIMS"))
            .collect())
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
