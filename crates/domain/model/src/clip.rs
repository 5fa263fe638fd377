//! Dynamics clips: what a world model learns from. One clip per episode: small RGB frames at a
//! fixed rate from the task's camera, the robot's proprioception at each frame and the action
//! taken from each frame to the next. Written by the render role, read by the trainer role.
//!
//! A clip may be recorded at a policy's interface (`interface`, `Interface::to_args`): its
//! first camera is `rgb` at `width`×`height`, the cameras after it are `views` (each at its own
//! size), `proprio` is the interface's state vector and `actions` are in its action space. An
//! empty `interface` is the original one: the task camera, tool position + holding, tool
//! velocities ([`PROPRIO_DIMS`], [`ACTION_DIMS`]).
//!
//! File layout (little endian): the 8 bytes `ASYCLIP1`; a header of six `u32` — frames `T`,
//! height `H`, width `W`, proprioception dims `P`, action dims `A`, and the frame interval in
//! microseconds; then `T·H·W·3` bytes of RGB (row-major, top row first), `T·P` `f32` and `T·A`
//! `f32`. The action of the last frame is all zeros (nothing follows it). A clip with an
//! interface or views is `ASYCLIP2`: the same header, then the interface (a `u32` length and
//! UTF-8), the number of views (`u32`) and each view's name (a `u32` length and UTF-8), width
//! and height (`u32`); then the RGB of the first camera, of each view in order (`T·h·w·3`
//! each), the proprioception and the actions.
//!
//! Either may end with the objects' section: the 4 bytes `OBJS`, the object dims per frame `O`
//! (`u32`) and `T·O` `f32` — each scene object's position x, y, z (metres, world frame), in the
//! scene's order ([`Clip::objects`]). A reader that computes offsets from the header and stops
//! after the actions reads such a clip as before. Nothing a policy sees: what a world model may
//! learn to predict beside the frames, so that a task's outcome can be read off its imagination.

use thiserror::Error;

pub const CLIP_MAGIC: &[u8; 8] = b"ASYCLIP1";
/// A clip at a policy's interface (with an interface or views).
pub const CLIP_MAGIC_V2: &[u8; 8] = b"ASYCLIP2";
/// Most cameras after the first one clip holds.
pub const MAX_VIEWS: usize = 7;
/// The tag of the objects' section at a clip's end.
pub const OBJECTS_TAG: &[u8; 4] = b"OBJS";
/// Most object floats per frame a clip holds (3 per object).
pub const MAX_OBJECT_DIMS: usize = 3 * 64;
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
    /// The policy interface it was recorded at (`Interface::to_args`); empty: the original.
    pub interface: String,
    /// The interface's cameras after the first, in its order.
    pub views: Vec<ClipView>,
    /// Floats per frame in `objects` (0: none recorded).
    pub object_dims: u32,
    /// `len · object_dims`: each scene object's position x, y, z at each frame, in the scene's
    /// order — the simulator's, never shown to a policy.
    pub objects: Vec<f32>,
}

/// One camera of a clip after the first: `len` frames at its own size.
#[derive(Debug, Clone, PartialEq)]
pub struct ClipView {
    /// The interface's name for the camera.
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// `len · height · width · 3` bytes.
    pub rgb: Vec<u8>,
}

impl ClipView {
    /// Frame `t`'s RGB bytes.
    pub fn frame(&self, t: usize) -> &[u8] {
        let n = (self.width * self.height * 3) as usize;
        &self.rgb[t * n..(t + 1) * n]
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum ClipError {
    #[error("not a dynamics clip (no ASYCLIP1 or ASYCLIP2 magic)")]
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
        if self.views.len() > MAX_VIEWS {
            return Err(ClipError::Shape(format!(
                "{} views (at most {MAX_VIEWS})",
                self.views.len()
            )));
        }
        for v in &self.views {
            let n = (v.width * v.height * 3) as usize;
            if n == 0 || v.rgb.len() != t * n {
                return Err(ClipError::Shape(format!(
                    "view '{}': {} RGB bytes, not {t} frames of {}x{}",
                    v.name,
                    v.rgb.len(),
                    v.width,
                    v.height
                )));
            }
        }
        if self.actions.len() != t * self.action_dims as usize {
            return Err(ClipError::Shape(format!(
                "{} action values for {t} frames of {}",
                self.actions.len(),
                self.action_dims
            )));
        }
        if self.object_dims as usize > MAX_OBJECT_DIMS
            || self.objects.len() != t * self.object_dims as usize
        {
            return Err(ClipError::Shape(format!(
                "{} object values for {t} frames of {} (at most {MAX_OBJECT_DIMS})",
                self.objects.len(),
                self.object_dims
            )));
        }
        Ok(())
    }

    /// Frame `t` of the first camera.
    pub fn frame(&self, t: usize) -> &[u8] {
        let n = (self.width * self.height * 3) as usize;
        &self.rgb[t * n..(t + 1) * n]
    }

    pub fn encode(&self) -> Vec<u8> {
        let v2 = !self.interface.is_empty() || !self.views.is_empty();
        let views: usize = self.views.iter().map(|v| v.rgb.len()).sum();
        let mut out = Vec::with_capacity(
            64 + self.rgb.len() + views + 4 * (self.proprio.len() + self.actions.len()),
        );
        out.extend_from_slice(if v2 { CLIP_MAGIC_V2 } else { CLIP_MAGIC });
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
        let text = |out: &mut Vec<u8>, s: &str| {
            out.extend_from_slice(&(s.len() as u32).to_le_bytes());
            out.extend_from_slice(s.as_bytes());
        };
        if v2 {
            text(&mut out, &self.interface);
            out.extend_from_slice(&(self.views.len() as u32).to_le_bytes());
            for v in &self.views {
                text(&mut out, &v.name);
                out.extend_from_slice(&v.width.to_le_bytes());
                out.extend_from_slice(&v.height.to_le_bytes());
            }
        }
        out.extend_from_slice(&self.rgb);
        for v in &self.views {
            out.extend_from_slice(&v.rgb);
        }
        for v in self.proprio.iter().chain(&self.actions) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        if self.object_dims > 0 {
            out.extend_from_slice(OBJECTS_TAG);
            out.extend_from_slice(&self.object_dims.to_le_bytes());
            for v in &self.objects {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Frame `t`'s object floats (empty when none were recorded).
    pub fn objects_at(&self, t: usize) -> &[f32] {
        let o = self.object_dims as usize;
        &self.objects[t * o..(t + 1) * o]
    }

    pub fn decode(bytes: &[u8]) -> Result<Clip, ClipError> {
        let v2 = match bytes.get(..8) {
            Some(m) if m == CLIP_MAGIC => false,
            Some(m) if m == CLIP_MAGIC_V2 => true,
            _ => return Err(ClipError::Magic),
        };
        let truncated = |want: usize| ClipError::Truncated {
            have: bytes.len(),
            want,
        };
        let word = |at: usize| -> Result<usize, ClipError> {
            let b = bytes.get(at..at + 4).ok_or(truncated(at + 4))?;
            Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        };
        let (t, h, w, p, a, us) = (
            word(8)?,
            word(12)?,
            word(16)?,
            word(20)?,
            word(24)?,
            word(28)?,
        );
        let mut at = 32;
        let text = |at: &mut usize| -> Result<String, ClipError> {
            let n = word(*at)?;
            if n > 4096 {
                return Err(ClipError::Shape(format!("a name of {n} bytes")));
            }
            let b = bytes
                .get(*at + 4..*at + 4 + n)
                .ok_or(truncated(*at + 4 + n))?;
            *at += 4 + n;
            String::from_utf8(b.to_vec())
                .map_err(|_| ClipError::Shape("a name that is not UTF-8".into()))
        };
        let (mut interface, mut views) = (String::new(), Vec::new());
        if v2 {
            interface = text(&mut at)?;
            let n = word(at)?;
            at += 4;
            if n > MAX_VIEWS {
                return Err(ClipError::Shape(format!("{n} views (at most {MAX_VIEWS})")));
            }
            for _ in 0..n {
                let name = text(&mut at)?;
                let (vw, vh) = (word(at)?, word(at + 4)?);
                at += 8;
                views.push(ClipView {
                    name,
                    width: vw as u32,
                    height: vh as u32,
                    rgb: Vec::new(),
                });
            }
        }
        let rgb_len = t * h * w * 3;
        let view_len: usize = views
            .iter()
            .map(|v| t * (v.width * v.height * 3) as usize)
            .sum();
        let mut want = at + rgb_len + view_len + 4 * t * (p + a);
        // The objects' section, when the clip goes on after its actions.
        let mut o = 0;
        if bytes.len() > want {
            if bytes.get(want..want + 4) != Some(&OBJECTS_TAG[..]) {
                return Err(ClipError::Shape(format!(
                    "{} bytes after the actions that are not an objects' section",
                    bytes.len() - want
                )));
            }
            o = word(want + 4)?;
            if o > MAX_OBJECT_DIMS {
                return Err(ClipError::Shape(format!(
                    "{o} object values per frame (at most {MAX_OBJECT_DIMS})"
                )));
            }
            want += 8 + 4 * t * o;
        }
        if bytes.len() != want {
            return Err(truncated(want));
        }
        let rgb = bytes[at..at + rgb_len].to_vec();
        at += rgb_len;
        for v in &mut views {
            let n = t * (v.width * v.height * 3) as usize;
            v.rgb = bytes[at..at + n].to_vec();
            at += n;
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
            rgb,
            proprio: floats(at, t * p),
            actions: floats(at + 4 * t * p, t * a),
            interface,
            views,
            object_dims: o as u32,
            objects: if o > 0 {
                floats(at + 4 * t * (p + a) + 8, t * o)
            } else {
                Vec::new()
            },
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
            interface: String::new(),
            views: Vec::new(),
            object_dims: 0,
            objects: Vec::new(),
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
    fn a_clip_at_an_interface_round_trips_with_its_views() {
        let mut c = clip(4);
        c.interface = "space=ee_delta,cameras=image:scene@3x2+wrist_image:wrist@2x2".into();
        c.views.push(ClipView {
            name: "wrist_image".into(),
            width: 2,
            height: 2,
            rgb: (0..4 * 12).map(|i| (i * 3) as u8).collect(),
        });
        let bytes = c.encode();
        assert_eq!(&bytes[..8], CLIP_MAGIC_V2);
        assert_eq!(Clip::decode(&bytes).unwrap(), c);
        assert_eq!(c.views[0].frame(1), &c.views[0].rgb[12..24]);
        assert!(matches!(
            Clip::decode(&bytes[..bytes.len() - 1]),
            Err(ClipError::Truncated { .. })
        ));
        c.views[0].rgb.pop();
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("view 'wrist_image'")
        );
        // A clip at the original interface is written as before.
        assert_eq!(&clip(2).encode()[..8], CLIP_MAGIC);
    }

    #[test]
    fn objects_ride_at_the_end_where_a_reader_of_the_header_s_offsets_does_not_look() {
        let plain = clip(3);
        let mut c = plain.clone();
        c.object_dims = 6;
        c.objects = (0..18).map(|i| i as f32 * 0.25 - 1.0).collect();
        let bytes = c.encode();
        // Every byte up to the actions is the clip's without objects; the section follows.
        let head = plain.encode();
        assert_eq!(&bytes[..head.len()], &head[..]);
        assert_eq!(&bytes[head.len()..head.len() + 4], OBJECTS_TAG);
        assert_eq!(bytes.len(), head.len() + 8 + 4 * 18);
        let back = Clip::decode(&bytes).unwrap();
        assert_eq!(back, c);
        assert_eq!(back.objects_at(2), &c.objects[12..18]);
        assert!(plain.objects_at(1).is_empty());
        // At an interface too.
        c.interface = "space=ee_delta".into();
        assert_eq!(Clip::decode(&c.encode()).unwrap(), c);
        // Damage: a cut section, a section of another tag, a count that does not fit.
        assert!(matches!(
            Clip::decode(&bytes[..bytes.len() - 4]),
            Err(ClipError::Truncated { .. })
        ));
        let mut other = bytes.clone();
        other[head.len()] = b'X';
        assert!(
            Clip::decode(&other)
                .unwrap_err()
                .to_string()
                .contains("not an objects' section")
        );
        let mut bad = c.clone();
        bad.objects.pop();
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("object values")
        );
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
