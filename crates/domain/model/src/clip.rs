//! Dynamics clips: what a world model learns from. One clip per episode: small RGB frames at a
//! fixed rate from the task's camera, the robot's proprioception at each frame and the action
//! taken from each frame to the next. Written by the render role, read by the trainer role.
//!
//! File layout (little endian): the 8 bytes `ASYCLIP1`; a header of six `u32` — frames `T`,
//! height `H`, width `W`, proprioception dims `P`, action dims `A`, and the frame interval in
//! microseconds; then `T·H·W·3` bytes of RGB (row-major, top row first), `T·P` `f32` and `T·A`
//! `f32`. The action of the last frame is all zeros (nothing follows it).

use thiserror::Error;

pub const CLIP_MAGIC: &[u8; 8] = b"ASYCLIP1";
/// Proprioception per frame: tool position x, y, z (metres) and whether it holds an object (0/1).
pub const PROPRIO_DIMS: usize = 4;
/// Action per frame: the tool's commanded velocity x, y, z (m/s) and the hold command (0/1: holding
/// at the next frame).
pub const ACTION_DIMS: usize = 4;
/// Physics steps between clip frames (10 Hz at the default 240 Hz).
pub const CLIP_STRIDE_STEPS: u64 = 24;

#[derive(Debug, Clone, PartialEq)]
pub struct Clip {
    pub height: u32,
    pub width: u32,
    /// Seconds between frames.
    pub interval_s: f32,
    pub proprio_dims: u32,
    pub action_dims: u32,
    /// `len · height · width · 3` bytes.
    pub rgb: Vec<u8>,
    /// `len · proprio_dims`.
    pub proprio: Vec<f32>,
    /// `len · action_dims`.
    pub actions: Vec<f32>,
}

#[derive(Debug, Error, PartialEq)]
pub enum ClipError {
    #[error("not a dynamics clip (no ASYCLIP1 magic)")]
    Magic,
    #[error("dynamics clip truncated: {have} bytes, the header promises {want}")]
    Truncated { have: usize, want: usize },
    #[error("dynamics clip has {0}")]
    Shape(String),
}

impl Clip {
    /// Frames in the clip.
    pub fn len(&self) -> usize {
        let frame = (self.height * self.width * 3) as usize;
        self.rgb.len().checked_div(frame).unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Checks that the arrays agree with the header.
    pub fn validate(&self) -> Result<(), ClipError> {
        let t = self.len();
        let frame = (self.height * self.width * 3) as usize;
        if frame == 0 {
            return Err(ClipError::Shape("an empty frame size".into()));
        }
        if self.rgb.len() != t * frame {
            return Err(ClipError::Shape(format!(
                "{} RGB bytes, not a whole number of {}x{} frames",
                self.rgb.len(),
                self.width,
                self.height
            )));
        }
        if self.proprio.len() != t * self.proprio_dims as usize {
            return Err(ClipError::Shape(format!(
                "{} proprioception values for {t} frames of {}",
                self.proprio.len(),
                self.proprio_dims
            )));
        }
        if self.actions.len() != t * self.action_dims as usize {
            return Err(ClipError::Shape(format!(
                "{} action values for {t} frames of {}",
                self.actions.len(),
                self.action_dims
            )));
        }
        Ok(())
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(
            8 + 24 + self.rgb.len() + 4 * (self.proprio.len() + self.actions.len()),
        );
        out.extend_from_slice(CLIP_MAGIC);
        let interval_us = (self.interval_s as f64 * 1e6).round() as u32;
        for v in [
            self.len() as u32,
            self.height,
            self.width,
            self.proprio_dims,
            self.action_dims,
            interval_us,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.rgb);
        for v in self.proprio.iter().chain(&self.actions) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    pub fn decode(bytes: &[u8]) -> Result<Clip, ClipError> {
        if bytes.len() < 8 || &bytes[..8] != CLIP_MAGIC {
            return Err(ClipError::Magic);
        }
        let header = |k: usize| -> Result<usize, ClipError> {
            let at = 8 + 4 * k;
            let b = bytes.get(at..at + 4).ok_or(ClipError::Truncated {
                have: bytes.len(),
                want: 32,
            })?;
            Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        };
        let (t, h, w, p, a, us) = (
            header(0)?,
            header(1)?,
            header(2)?,
            header(3)?,
            header(4)?,
            header(5)?,
        );
        let rgb_len = t * h * w * 3;
        let want = 32 + rgb_len + 4 * t * (p + a);
        if bytes.len() != want {
            return Err(ClipError::Truncated {
                have: bytes.len(),
                want,
            });
        }
        let floats = |from: usize, n: usize| -> Vec<f32> {
            bytes[from..from + 4 * n]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let clip = Clip {
            height: h as u32,
            width: w as u32,
            interval_s: (us as f64 / 1e6) as f32,
            proprio_dims: p as u32,
            action_dims: a as u32,
            rgb: bytes[32..32 + rgb_len].to_vec(),
            proprio: floats(32 + rgb_len, t * p),
            actions: floats(32 + rgb_len + 4 * t * p, t * a),
        };
        clip.validate()?;
        Ok(clip)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clip(t: usize) -> Clip {
        Clip {
            height: 2,
            width: 3,
            interval_s: 0.1,
            proprio_dims: PROPRIO_DIMS as u32,
            action_dims: ACTION_DIMS as u32,
            rgb: (0..t * 18).map(|i| i as u8).collect(),
            proprio: (0..t * PROPRIO_DIMS).map(|i| i as f32 * 0.5).collect(),
            actions: (0..t * ACTION_DIMS).map(|i| -(i as f32)).collect(),
        }
    }

    #[test]
    fn round_trips() {
        let c = clip(5);
        assert_eq!(c.len(), 5);
        let bytes = c.encode();
        assert_eq!(Clip::decode(&bytes).unwrap(), c);
    }

    #[test]
    fn rejects_damage() {
        let bytes = clip(3).encode();
        assert_eq!(Clip::decode(b"PNG....."), Err(ClipError::Magic));
        assert!(matches!(
            Clip::decode(&bytes[..bytes.len() - 1]),
            Err(ClipError::Truncated { .. })
        ));
        let mut bad = clip(3);
        bad.proprio.pop();
        assert!(bad.validate().is_err());
    }
}
