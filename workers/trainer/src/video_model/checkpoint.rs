//! The video model's checkpoints: the header `ASYVM001`, the hashes of the training settings and
//! of the clips, the step and Adam's step count, then the parameters, Adam's moments, the
//! normalisation statistics and the clips' layout (libtorch's stream format).

use std::collections::HashMap;
use std::io::Cursor;

use assay_model::video::VideoModelConfig;
use tch::{Device, Tensor};

use super::{Layout, Net};
use crate::adam::Adam;
use crate::world_model::WorldModelError;

pub(super) const MAGIC: &[u8; 8] = b"ASYVM001";
const HEADER_LEN: usize = 8 + 8 * 4;

pub(super) fn config_hash(cfg: &VideoModelConfig) -> u64 {
    let mut c = cfg.clone();
    c.checkpoint_every = 0;
    c.threads = 0;
    let json = serde_json::to_vec(&c).unwrap_or_default();
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in b"video-model v1 ".iter().chain(&json) {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

pub(super) fn write_checkpoint(
    net: &Net,
    adam: &Adam,
    layout: &Layout,
    size: i64,
    config_hash: u64,
    data_hash: u64,
    step: u64,
) -> Result<Vec<u8>, WorldModelError> {
    let mut out = Vec::from(&MAGIC[..]);
    for v in [config_hash, data_hash, step, adam.t] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let mut named: Vec<(String, &Tensor)> = Vec::new();
    for (prefix, tensors) in [("p", &net.params), ("m", &adam.m), ("v", &adam.v)] {
        for (name, t) in net.names.iter().zip(tensors.iter()) {
            named.push((format!("{prefix}/{name}"), t));
        }
    }
    for (name, t) in net.stats.named() {
        named.push((name.to_string(), t));
    }
    // What the clips held, so that a checkpoint loads without them.
    // [state, action, size], then the objects' floats when the model predicts them.
    let mut dims = vec![layout.state as i64, layout.action as i64, size];
    if layout.objects > 0 {
        dims.push(layout.objects as i64);
    }
    let dims = Tensor::from_slice(&dims);
    let sizes: Vec<i64> = layout
        .cameras
        .iter()
        .flat_map(|(_, w, h)| [i64::from(*w), i64::from(*h)])
        .collect();
    let sizes = Tensor::from_slice(&sizes);
    let names: Vec<&str> = layout.cameras.iter().map(|(n, _, _)| n.as_str()).collect();
    // Texts lead with '#': libtorch cannot save an empty tensor to a stream.
    let names = Tensor::from_slice(format!("#{}", names.join("\n")).as_bytes());
    let interface = Tensor::from_slice(format!("#{}", layout.interface).as_bytes());
    for (name, t) in [
        ("layout/dims", &dims),
        ("layout/camera_sizes", &sizes),
        ("layout/camera_names", &names),
        ("layout/interface", &interface),
    ] {
        named.push((name.to_string(), t));
    }
    let mut blob = Vec::new();
    Tensor::save_multi_to_stream(&named, &mut blob)?;
    out.extend_from_slice(&blob);
    Ok(out)
}

/// The clips' layout and the model's frame size a checkpoint holds; one written before layouts
/// were saved is of the original interface at `size`.
pub(super) fn read_layout(
    saved: &HashMap<String, Tensor>,
    size: u32,
) -> Result<(Layout, u32), WorldModelError> {
    let Some(dims) = saved.get("layout/dims") else {
        return Ok((Layout::original(size), size));
    };
    let bad = |what: &str| WorldModelError::CheckpointRefused(format!("its layout: {what}"));
    let ints = |t: &Tensor| {
        Vec::<i64>::try_from(t.to_device(Device::Cpu)).map_err(|_| bad("not integers"))
    };
    let text = |k: &str| -> Result<String, WorldModelError> {
        let t = saved.get(k).ok_or_else(|| bad(k))?;
        let bytes = Vec::<u8>::try_from(t.to_device(Device::Cpu)).map_err(|_| bad(k))?;
        let text = String::from_utf8(bytes).map_err(|_| bad(k))?;
        text.strip_prefix('#')
            .map(str::to_owned)
            .ok_or_else(|| bad(k))
    };
    let dims = ints(dims)?;
    let sizes = ints(
        saved
            .get("layout/camera_sizes")
            .ok_or_else(|| bad("camera sizes"))?,
    )?;
    let names = text("layout/camera_names")?;
    let names: Vec<&str> = names.split('\n').collect();
    if !(3..=4).contains(&dims.len())
        || sizes.len() != 2 * names.len()
        || dims.iter().chain(&sizes).any(|v| *v < 1)
    {
        return Err(bad("inconsistent sizes"));
    }
    let layout = Layout {
        interface: text("layout/interface")?,
        cameras: names
            .iter()
            .zip(sizes.chunks(2))
            .map(|(n, s)| (n.to_string(), s[0] as u32, s[1] as u32))
            .collect(),
        state: dims[0] as usize,
        action: dims[1] as usize,
        objects: dims.get(3).map_or(0, |&o| o as usize),
    };
    Ok((layout, dims[2] as u32))
}

pub(super) struct Saved {
    pub(super) config_hash: u64,
    pub(super) step: u64,
    pub(super) adam_t: u64,
    pub(super) tensors: HashMap<String, Tensor>,
}

/// `expect`: the config and data hashes the checkpoint must carry (a resumed fit).
pub(super) fn read_checkpoint(
    bytes: &[u8],
    expect: Option<(u64, u64)>,
    device: Device,
) -> Result<Saved, WorldModelError> {
    let refuse = |s: &str| Err(WorldModelError::CheckpointRefused(s.to_string()));
    if bytes.len() < HEADER_LEN || &bytes[..8] != MAGIC {
        return refuse("not a video-model checkpoint (no ASYVM001 header)");
    }
    let word = |k: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[8 + 8 * k..16 + 8 * k]);
        u64::from_le_bytes(b)
    };
    if let Some((config, data)) = expect {
        if word(0) != config {
            return refuse("it was written for another video-model config");
        }
        if word(1) != data {
            return refuse("it was written for other training clips");
        }
    }
    let tensors =
        Tensor::load_multi_from_stream_with_device(Cursor::new(&bytes[HEADER_LEN..]), device)
            .map_err(|e| WorldModelError::CheckpointRefused(format!("unreadable tensors: {e}")))?;
    Ok(Saved {
        config_hash: word(0),
        step: word(2),
        adam_t: word(3),
        tensors: tensors
            .into_iter()
            .map(|(k, v)| (k.replace('|', "."), v))
            .collect(),
    })
}
