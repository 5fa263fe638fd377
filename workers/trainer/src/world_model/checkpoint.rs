//! World-model checkpoints (the module docs of [`super`], "Checkpoints"): the header
//! `ASYWM001`, the hashes of the training-relevant settings and of the training clips, the step,
//! Adam's step count and the epoch's running loss, then every parameter and Adam moment.

use std::collections::HashMap;
use std::io::Cursor;

use assay_model::clip::Clip;
use assay_model::dynamics::DynamicsConfig;
use tch::{Device, Tensor};

use super::{Model, WorldModelError};
use crate::adam::Adam;

const CHECKPOINT_MAGIC: &[u8; 8] = b"ASYWM001";
const HEADER_LEN: usize = 8 + 8 * 6;

fn fnv1a(h: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *h ^= u64::from(*b);
        *h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
}

/// Hash of the settings that change what training computes (not `checkpoint_every`, `threads`).
pub(super) fn config_hash(cfg: &DynamicsConfig) -> u64 {
    let mut c = cfg.clone();
    c.checkpoint_every = 0;
    c.threads = 0;
    let json = serde_json::to_vec(&c).unwrap_or_default();
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    fnv1a(&mut h, b"world-model v1 ");
    fnv1a(&mut h, &json);
    h
}

/// A fast fingerprint of the training clips (their shapes and contents).
pub(super) fn data_hash(clips: &[Clip]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mix = |h: &mut u64, v: u64| {
        *h = (*h ^ v).wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(29);
    };
    mix(&mut h, clips.len() as u64);
    for c in clips {
        for v in [c.len(), c.width as usize, c.height as usize] {
            mix(&mut h, v as u64);
        }
        for w in c.rgb.chunks(8) {
            let mut b = [0u8; 8];
            b[..w.len()].copy_from_slice(w);
            mix(&mut h, u64::from_le_bytes(b));
        }
        for v in c.proprio.iter().chain(&c.actions) {
            mix(&mut h, u64::from(v.to_bits()));
        }
        // A clip at a policy's interface: its interface and its other cameras too.
        if !c.interface.is_empty() || !c.views.is_empty() {
            for b in c.interface.bytes() {
                mix(&mut h, u64::from(b));
            }
            for v in &c.views {
                mix(&mut h, (u64::from(v.width) << 32) | u64::from(v.height));
                for w in v.rgb.chunks(8) {
                    let mut b = [0u8; 8];
                    b[..w.len()].copy_from_slice(w);
                    mix(&mut h, u64::from_le_bytes(b));
                }
            }
        }
        // The objects' section, when the clip has one.
        if c.object_dims > 0 {
            mix(&mut h, u64::from(c.object_dims));
            for v in &c.objects {
                mix(&mut h, u64::from(v.to_bits()));
            }
        }
    }
    h
}

pub(super) fn save_checkpoint(
    model: &Model,
    adam: &Adam,
    config_hash: u64,
    data_hash: u64,
    step: u64,
    epoch_loss: (f64, u64),
) -> Result<Vec<u8>, WorldModelError> {
    let mut out = Vec::new();
    out.extend_from_slice(CHECKPOINT_MAGIC);
    for v in [
        config_hash,
        data_hash,
        step,
        adam.t,
        epoch_loss.0.to_bits(),
        epoch_loss.1,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let mut named: Vec<(String, &Tensor)> = Vec::new();
    for (prefix, tensors) in [("p", &model.params), ("m", &adam.m), ("v", &adam.v)] {
        for (name, t) in model.names.iter().zip(tensors.iter()) {
            named.push((format!("{prefix}/{name}"), t));
        }
    }
    let mut blob = Vec::new();
    Tensor::save_multi_to_stream(&named, &mut blob)?;
    out.extend_from_slice(&blob);
    Ok(out)
}

pub(super) struct Saved {
    pub(super) step: u64,
    pub(super) adam_t: u64,
    pub(super) loss_sum: f64,
    pub(super) loss_count: u64,
    pub(super) tensors: HashMap<String, Tensor>,
}

pub(super) fn load_checkpoint(
    bytes: &[u8],
    config_hash: u64,
    data_hash: u64,
    total_steps: u64,
    device: Device,
) -> Result<Saved, WorldModelError> {
    let refuse = |s: String| Err(WorldModelError::CheckpointRefused(s));
    if bytes.len() < HEADER_LEN || &bytes[..8] != CHECKPOINT_MAGIC {
        return refuse("not a world-model checkpoint (no ASYWM001 header)".into());
    }
    let word = |k: usize| {
        let at = 8 + 8 * k;
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[at..at + 8]);
        u64::from_le_bytes(b)
    };
    if word(0) != config_hash {
        return refuse(format!(
            "it was written for another world-model config (hash {:016x}, this fit's {config_hash:016x})",
            word(0)
        ));
    }
    if word(1) != data_hash {
        return refuse("it was written for other training clips".into());
    }
    let step = word(2);
    if step > total_steps {
        return refuse(format!(
            "it is at step {step}, beyond this fit's {total_steps} steps"
        ));
    }
    let tensors =
        Tensor::load_multi_from_stream_with_device(Cursor::new(&bytes[HEADER_LEN..]), device)
            .map_err(|e| WorldModelError::CheckpointRefused(format!("unreadable tensors: {e}")))?;
    Ok(Saved {
        step,
        adam_t: word(3),
        loss_sum: f64::from_bits(word(4)),
        loss_count: word(5),
        tensors: tensors
            .into_iter()
            .map(|(k, v)| (k.replace('|', "."), v))
            .collect(),
    })
}
