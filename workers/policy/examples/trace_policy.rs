//! Writes a small TorchScript policy that follows the calling convention of `docs/policies.md`,
//! traced from Rust (no Python): it moves the tool towards (0.1, 0.1, 0.1) at up to 0.1 m/s and
//! answers chunks of 4 actions.
//!
//! `cargo run -p assay-policy --features torch --example trace_policy -- OUT.pt`

use tch::{CModule, Device, Kind, Tensor};

fn policy(image: &Tensor, proprio: &Tensor) -> Tensor {
    // Only tensor operations are recorded: a tensor made from data inside the traced function
    // (`Tensor::from_slice`) is saved uninitialised (zeros), so constants enter as scalars.
    let xyz = proprio.narrow(1, 0, 3);
    let target = xyz.zeros_like() + 0.1; // (0.1, 0.1, 0.1)
    let velocity = (target - xyz).clamp(-0.1, 0.1);
    // The image enters the graph (so the module's signature is the convention's) with weight 0.
    let seen = image
        .mean_dim([1i64, 2, 3].as_slice(), true, Kind::Float)
        .view([1, 1])
        * 0.0;
    let hold = proprio.narrow(1, 3, 1) + seen;
    Tensor::cat(&[velocity, hold], 1)
        .unsqueeze(1)
        .repeat([1, 4, 1]) // [1, 4, 4]
}

fn main() {
    let out = std::env::args().nth(1).expect("usage: trace_policy OUT.pt");
    let image = Tensor::rand([1, 3, 64, 64], (Kind::Float, Device::Cpu));
    let proprio = Tensor::rand([1, 4], (Kind::Float, Device::Cpu));
    let module = CModule::create_by_tracing("Policy", "forward", &[image, proprio], &mut |xs| {
        vec![policy(&xs[0], &xs[1])]
    })
    .expect("trace");
    module.save(&out).expect("save");
    println!("{out}");
}
