//! The RSSM as a [`WorldModelService`]: the embedded default of the proxy, behind the same
//! interface as any lab's world model (`assay.v1.WorldModel`). An episode starts from the
//! posterior of the real first frame and state (`h_0 = 0`, as in training); each action then
//! advances `h_{t+1} = GRU(h_t, [z_t, a_t])` with `z_{t+1}` the mode of the prior, never looking
//! at another real frame, and the frame and state are decoded from `[h, z]` (holding rounded to
//! 0 or 1). Deterministic: modes, no sampling.

use assay_model::clip::{ACTION_DIMS, PROPRIO_DIMS};
use assay_model::interface::Interface;
use assay_model::world::{ImaginedEpisode, WorldError, WorldFrame, WorldModelService, WorldStart};
use tch::{Device, Kind, Tensor};

use super::WorldModel;

/// [`WorldModel::service`].
pub struct Rssm<'a> {
    pub(super) model: &'a WorldModel,
}

struct Episode<'a> {
    model: &'a WorldModel,
    h: Tensor,
    z: Tensor,
}

impl WorldModelService for Rssm<'_> {
    fn name(&self) -> String {
        let c = &self.model.model;
        format!(
            "Assay RSSM ({s}x{s} frames, GRU {d}, {st}x{cl} latents)",
            s = self.model.size,
            d = c.deter,
            st = c.stoch,
            cl = c.classes,
        )
    }

    /// The interface of the clips it was trained on.
    fn interfaces(&self) -> Vec<Interface> {
        vec![Interface::legacy(self.model.size as u32)]
    }

    fn reset(&self, start: &WorldStart) -> Result<Box<dyn ImaginedEpisode + '_>, WorldError> {
        let size = self.model.size;
        if i64::from(start.width) != size || i64::from(start.height) != size {
            return Err(WorldError::Refused(format!(
                "frames of {}x{}: this RSSM was trained on {size}x{size}",
                start.width, start.height
            )));
        }
        if start.rgb.len() != (size * size * 3) as usize {
            return Err(WorldError::Refused(format!(
                "a first frame of {} bytes, {size}x{size} RGB is {}",
                start.rgb.len(),
                size * size * 3
            )));
        }
        if start.state.len() != PROPRIO_DIMS || start.state.iter().any(|v| !v.is_finite()) {
            return Err(WorldError::Refused(format!(
                "a first state of {} values: the RSSM takes {PROPRIO_DIMS} finite ones (tool x, y, z, holding)",
                start.state.len()
            )));
        }
        let m = &self.model.model;
        let device = self.model.device;
        let (h, z) = tch::no_grad(|| {
            let image = Tensor::from_slice(&start.rgb)
                .view([1, size, size, 3])
                .to_device(device)
                .permute([0, 3, 1, 2])
                .to_kind(Kind::Float)
                / 255.0
                - 0.5;
            let prop = Tensor::from_slice(&start.state)
                .view([1, -1])
                .to_device(device);
            let h = Tensor::zeros([1, m.deter], (Kind::Float, device));
            let z = m.mode(&m.posterior(&h, &m.post_e.forward(&m.encode(&image, &prop))));
            (h, z)
        });
        Ok(Box::new(Episode {
            model: self.model,
            h,
            z,
        }))
    }
}

/// Imagined frames as a service answers them, one per sample of a batch: each camera's image
/// `[B, 3, H, W]` in [0, 1] as RGB bytes (clamped, rounded; the first camera's as `rgb`, the
/// others' as `views`), and the state `[B, P]`, with holding (its last value, when
/// `holding_last`) rounded to 0 or 1; the state's last `objects` values are the objects'
/// positions (`WorldFrame::objects`), not the state. Each tensor is converted once for the
/// whole batch.
pub(crate) fn world_frames(
    cameras: &[Tensor],
    state: &Tensor,
    holding_last: bool,
    objects: usize,
) -> Result<Vec<WorldFrame>, tch::TchError> {
    let b = state.size()[0].max(1) as usize;
    let mut pictures = Vec::with_capacity(cameras.len());
    for image in cameras {
        let pixels = (image.clamp(0.0, 1.0) * 255.0)
            .round()
            .to_kind(Kind::Uint8)
            .permute([0, 2, 3, 1])
            .contiguous()
            .to_device(Device::Cpu);
        pictures.push(Vec::<u8>::try_from(pixels.flatten(0, -1))?);
    }
    let states = Vec::<f32>::try_from(state.to_device(Device::Cpu).flatten(0, -1))?;
    let p = states.len() / b;
    Ok((0..b)
        .map(|j| {
            let mut state = states[j * p..(j + 1) * p].to_vec();
            let objects = (objects > 0).then(|| state.split_off(p - objects));
            if let Some(holding) = state.last_mut().filter(|_| holding_last) {
                *holding = if *holding >= 0.5 { 1.0 } else { 0.0 };
            }
            let mut sample = pictures.iter().map(|c| {
                let n = c.len() / b;
                c[j * n..(j + 1) * n].to_vec()
            });
            WorldFrame {
                rgb: sample.next().unwrap_or_default(),
                views: sample.collect(),
                state: Some(state),
                objects,
            }
        })
        .collect())
}

impl ImaginedEpisode for Episode<'_> {
    fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<WorldFrame>, WorldError> {
        let device = self.model.device;
        let m = &self.model.model;
        let mut out = Vec::with_capacity(actions.len());
        for a in actions {
            if a.len() != ACTION_DIMS || a.iter().any(|v| !v.is_finite()) {
                return Err(WorldError::Refused(format!(
                    "an action of {} values: the RSSM takes {ACTION_DIMS} finite ones (tool velocity x, y, z, hold)",
                    a.len()
                )));
            }
            let frame = tch::no_grad(|| -> Result<WorldFrame, tch::TchError> {
                let a = Tensor::from_slice(a).view([1, -1]).to_device(device);
                self.h = m.step_h(&self.h, &self.z, &a);
                self.z = m.mode(&m.prior(&self.h));
                let (img, prop) = m.decode(&Tensor::cat(&[&self.h, &self.z], -1));
                let state = prop.narrow(1, 0, PROPRIO_DIMS as i64);
                Ok(world_frames(&[img + 0.5], &state, true, 0)?.remove(0))
            })
            .map_err(|e| WorldError::BadAnswer(format!("libtorch: {e}")))?;
            out.push(frame);
        }
        Ok(out)
    }
}
