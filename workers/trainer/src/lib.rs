//! The trainer role on libtorch through tch: latent world models for dynamics diversity, the
//! world-model proxy that ranks policies (the video model, imagination, the frame judge),
//! diffusion policies trained on the dynamics clips, and the role's jobs — text diversity's
//! among them, with the sentence embeddings of `assay-embed`.
mod adam;
pub mod diffusion;
pub mod imagination;
pub mod jobs;
pub mod proxy;
pub mod video_eval;
pub mod video_model;
pub mod world_model;

/// The device trainer work runs on: the first CUDA device when libtorch sees one (a binary built
/// with CUDA support on a machine with a GPU), else the CPU.
pub fn default_device() -> tch::Device {
    tch::Device::cuda_if_available()
}

/// The libtorch this process runs with, for a report's provenance: the `build-version` file of
/// `$LIBTORCH` (`2.13.0`), or what is known without it.
pub fn libtorch_version() -> String {
    std::env::var_os("LIBTORCH")
        .map(std::path::PathBuf::from)
        .and_then(|dir| std::fs::read_to_string(dir.join("build-version")).ok())
        .map(|v| v.trim().to_owned())
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| "unknown (LIBTORCH is not set)".into())
}

/// What libtorch does on this machine (`assay doctor`): its version, the trainer's device, the
/// sum 1² + 2² + 3² computed there, and whether CUDA is available.
pub struct Probe {
    pub version: String,
    pub device: String,
    pub sum: f64,
    pub cuda: bool,
}

/// Runs one small computation on the trainer's device.
pub fn probe() -> Probe {
    let device = default_device();
    let t = tch::Tensor::from_slice(&[1.0f32, 2.0, 3.0]).to_device(device);
    let sum = f64::try_from((&t * &t).sum(tch::Kind::Float)).unwrap_or(f64::NAN);
    Probe {
        version: libtorch_version(),
        device: world_model::device_name(device),
        sum,
        cuda: tch::Cuda::is_available(),
    }
}

/// libtorch's intra-op threads for this process (at least 1).
pub fn set_threads(n: usize) {
    tch::set_num_threads(n.max(1) as i32);
}
