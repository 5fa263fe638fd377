//! A TorchScript policy made without Python, for tests that run policy objects.

use std::path::{Path, PathBuf};

use tch::{CModule, Device, Kind, Tensor};

/// 1.0 where the position error [1, 3] is under 5 mm, else 0.0: [1, 1].
fn within_5_mm(error: &Tensor) -> Tensor {
    error
        .square()
        .sum_dim_intlist([1i64].as_slice(), true, Kind::Float)
        .sqrt()
        .lt(0.005)
        .to_kind(Kind::Float)
}

/// A proportional controller to a point over the block's nominal position that commands a hold
/// once the tool is within 5 mm of it: [1, 3, H, W] image and [1, 4] proprio → [1, 2, 4].
pub fn controller(_image: &Tensor, proprio: &Tensor) -> Tensor {
    // Constants are built from the inputs: tracing records tensor operations only (a tensor
    // made from data inside the closure would be saved as zeros).
    let zero = proprio.narrow(1, 0, 1).zeros_like();
    let target = Tensor::cat(&[&zero + 0.5, &zero + 0.1, &zero + 0.09], 1);
    let error = target - proprio.narrow(1, 0, 3);
    let velocity = (&error * 5.0).clamp(-0.5, 0.5);
    let action = Tensor::cat(&[velocity, within_5_mm(&error)], 1);
    Tensor::stack(&[&action, &action], 1)
}

pub fn torchscript(dir: &Path) -> PathBuf {
    let image = Tensor::rand([1, 3, 64, 64], (Kind::Float, Device::Cpu));
    let proprio = Tensor::rand([1, 4], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Policy", "forward", &[image, proprio], &mut |xs| {
        vec![controller(&xs[0], &xs[1])]
    })
    .expect("trace");
    let path = dir.join("controller.pt");
    module.save(&path).expect("save");
    path
}

/// The scripted policy of `tests/python/policies/scripted.py`, the same float32 arithmetic as
/// tensor operations (every constant a power of two or exactly representable, no reductions, so
/// the two agree bit for bit): image [1, 3, 32, 32] in [0, 1] and state [1, 5] (x, y, z, yaw,
/// holding) → [1, 2, 7] end-effector deltas.
pub fn scripted_twin(image: &Tensor, state: &Tensor) -> Tensor {
    let p = image.select(0, 0).select(1, 8).select(1, 24);
    let s = state.select(0, 0);
    let zero = s.select(0, 0).zeros_like();
    let target = [
        p.select(0, 0) * 0.125 + 0.5,
        p.select(0, 1) * 0.25 + -0.125,
        &zero + 0.125,
    ];
    let d: Vec<Tensor> = target
        .iter()
        .enumerate()
        .map(|(i, t)| ((t - s.select(0, i as i64)) * 0.25).clamp(-0.03125, 0.03125))
        .collect();
    let grip = s.select(0, 2).lt(0.0625).to_kind(Kind::Float);
    let action = Tensor::stack(
        &[
            d[0].shallow_clone(),
            d[1].shallow_clone(),
            d[2].shallow_clone(),
            zero.shallow_clone(),
            zero.shallow_clone(),
            &zero + 0.0625,
            grip,
        ],
        0,
    );
    action.view([1, 1, 7]).repeat([1, 2, 1])
}

/// [`scripted_twin`] traced and saved in `dir`.
pub fn scripted_torchscript(dir: &Path) -> PathBuf {
    let image = Tensor::rand([1, 3, 32, 32], (Kind::Float, Device::Cpu));
    let state = Tensor::rand([1, 5], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Policy", "forward", &[image, state], &mut |xs| {
        vec![scripted_twin(&xs[0], &xs[1])]
    })
    .expect("trace");
    let path = dir.join("scripted.pt");
    module.save(&path).expect("save");
    path
}

/// A policy at a 7-D, two-camera interface (`image` [1, 6, H, W]: two cameras stacked, `state`
/// [1, S ≥ 3] starting with the tool's position) traced and saved in `dir` as `name`.pt: end-
/// effector deltas of `gain` × the way to a point over the block's nominal position, at most
/// 3 cm a step, holding once within 5 mm; chunks of two. `gain` 0: it stands still.
pub fn seven_d_torchscript(dir: &Path, name: &str, gain: f64) -> PathBuf {
    let image = Tensor::rand([1, 6, 32, 32], (Kind::Float, Device::Cpu));
    let state = Tensor::rand([1, 8], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Policy", "forward", &[image, state], &mut |xs| {
        let s = &xs[1];
        let zero = s.narrow(1, 0, 1).zeros_like();
        let target = Tensor::cat(&[&zero + 0.5, &zero + 0.1, &zero + 0.09], 1);
        let error = target - s.narrow(1, 0, 3);
        let delta = (&error * gain).clamp(-0.03, 0.03);
        let near = within_5_mm(&error);
        let action = Tensor::cat(&[&delta, &zero, &zero, &zero, &near], 1);
        vec![Tensor::stack(&[&action, &action], 1)]
    })
    .expect("trace");
    let path = dir.join(format!("{name}.pt"));
    module.save(&path).expect("save");
    path
}
