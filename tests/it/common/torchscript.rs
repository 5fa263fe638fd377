//! A TorchScript policy made without Python, for tests that run policy objects.

use std::path::{Path, PathBuf};

use tch::{CModule, Device, Kind, Tensor};

/// A proportional controller to a point over the block's nominal position that commands a hold
/// once the tool is within 5 mm of it: [1, 3, H, W] image and [1, 4] proprio → [1, 2, 4].
pub fn controller(_image: &Tensor, proprio: &Tensor) -> Tensor {
    // Constants are built from the inputs: tracing records tensor operations only (a tensor
    // made from data inside the closure would be saved as zeros).
    let zero = proprio.narrow(1, 0, 1).zeros_like();
    let target = Tensor::cat(&[&zero + 0.5, &zero + 0.1, &zero + 0.09], 1);
    let error = target - proprio.narrow(1, 0, 3);
    let velocity = (&error * 5.0).clamp(-0.5, 0.5);
    let near = error
        .square()
        .sum_dim_intlist([1i64].as_slice(), true, Kind::Float)
        .sqrt()
        .lt(0.005)
        .to_kind(Kind::Float);
    let action = Tensor::cat(&[velocity, near], 1);
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
