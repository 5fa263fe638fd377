//! What a seeing policy knows of the scene: where each object is, estimated from the depth and
//! segmentation images of its camera, and tracked over the episode so that an object hidden for a
//! while (under the tool, behind what it carries) keeps its last well-seen estimate.
//!
//! Each frame, the pixels of an object are back-projected to world points. Its top surface is
//! the points within [`TOP_BAND`] of the highest one; their centroid gives the object's x, y and
//! the top's height, and their spread its footprint (how far it reaches in any direction). A
//! frame updates an object only if the object shows at least [`VISIBLE_SHARE`] of the largest
//! apparent area (pixels weighted by depth², so distance does not change it) seen of it so far.

use assay_spec::scene::{FIRST_OBJECT_SEGMENT, Observation};
use rapier3d::prelude::Vec3;

/// How far below an object's highest seen point a pixel still counts as its top surface (m).
const TOP_BAND: f64 = 0.006;
/// A frame updates an object's estimate only when this share of it is visible.
const VISIBLE_SHARE: f64 = 0.6;
/// Footprint points kept per object (evenly thinned).
const OUTLINE_POINTS: usize = 256;

/// One object as last seen well.
#[derive(Debug, Clone, PartialEq)]
pub struct Seen {
    /// Centroid of the top surface in x and y, and the top's height in z.
    pub top: Vec3,
    /// Top-surface points relative to `top`, in x and y.
    pub outline: Vec<[f32; 2]>,
    /// The physics step of the frame it comes from.
    pub step: u64,
}

impl Seen {
    /// How far the top surface reaches from its centre along the unit direction `dir` (x, y).
    pub fn extent_along(&self, dir: Vec3) -> f32 {
        self.outline
            .iter()
            .map(|p| p[0] * dir.x + p[1] * dir.y)
            .fold(0.0, f32::max)
    }
}

/// Estimates for every object of a scene, from the frames seen so far.
#[derive(Debug, Clone)]
pub struct Tracker {
    seen: Vec<Option<Seen>>,
    best_area: Vec<f64>,
    /// Frames looked at.
    pub frames: u64,
}

impl Tracker {
    pub fn new(objects: usize) -> Self {
        Self {
            seen: vec![None; objects],
            best_area: vec![0.0; objects],
            frames: 0,
        }
    }

    /// Object `i` as last seen well, if ever.
    pub fn get(&self, i: usize) -> Option<&Seen> {
        self.seen.get(i).and_then(Option::as_ref)
    }

    /// Takes in one frame taken at physics step `step`.
    pub fn update(&mut self, obs: &Observation, step: u64) {
        self.frames += 1;
        let n = self.seen.len();
        let mut points: Vec<Vec<[f64; 3]>> = vec![Vec::new(); n];
        let mut area = vec![0.0f64; n];
        let (w, h) = (obs.width(), obs.height());
        let unproject = obs.unprojection();
        for y in 0..h {
            for x in 0..w {
                let k = (y * w + x) as usize;
                let Some(i) = obs.segments[k].checked_sub(FIRST_OBJECT_SEGMENT) else {
                    continue;
                };
                let i = i as usize;
                if i >= n {
                    continue;
                }
                if let Some(p) = unproject.point(x, y, obs.depth[k]) {
                    let d = f64::from(obs.depth[k]);
                    area[i] += d * d;
                    points[i].push(p);
                }
            }
        }
        for (i, pts) in points.into_iter().enumerate() {
            if pts.is_empty() {
                continue;
            }
            self.best_area[i] = self.best_area[i].max(area[i]);
            if area[i] < VISIBLE_SHARE * self.best_area[i] {
                continue;
            }
            let top_z = pts.iter().map(|p| p[2]).fold(f64::MIN, f64::max);
            let top: Vec<&[f64; 3]> = pts.iter().filter(|p| p[2] >= top_z - TOP_BAND).collect();
            let k = top.len() as f64;
            let cx = top.iter().map(|p| p[0]).sum::<f64>() / k;
            let cy = top.iter().map(|p| p[1]).sum::<f64>() / k;
            let stride = top.len().div_ceil(OUTLINE_POINTS).max(1);
            self.seen[i] = Some(Seen {
                top: Vec3::new(cx as f32, cy as f32, top_z as f32),
                outline: top
                    .iter()
                    .step_by(stride)
                    .map(|p| [(p[0] - cx) as f32, (p[1] - cy) as f32])
                    .collect(),
                step,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_spec::spec::Camera;

    /// A straight-down camera over a flat scene at `depth`, with a square of segment `seg`.
    fn square(seg: u32, half_px: u32, depth: f32) -> Observation {
        let camera = Camera {
            name: "top".into(),
            eye: [0.0, 0.0, 1.0],
            target: [0.0, 0.0, 0.0],
            fovy_deg: 50.0,
            width: 64,
            height: 64,
            up: None,
        };
        let mut segments = vec![1; 64 * 64];
        let mut depths = vec![1.0f32; 64 * 64];
        for y in 32 - half_px..32 + half_px {
            for x in 32 - half_px..32 + half_px {
                segments[y as usize * 64 + x as usize] = seg;
                depths[y as usize * 64 + x as usize] = depth;
            }
        }
        Observation {
            camera,
            depth: depths,
            segments,
        }
    }

    #[test]
    fn a_centred_square_is_seen_at_the_centre_with_its_height_and_extent() {
        let mut t = Tracker::new(1);
        t.update(&square(FIRST_OBJECT_SEGMENT, 4, 0.9), 8);
        let s = t.get(0).expect("seen");
        assert!(s.top.x.abs() < 1e-6 && s.top.y.abs() < 1e-6, "{:?}", s.top);
        assert!((s.top.z - 0.1).abs() < 1e-5, "{:?}", s.top);
        // 8 pixels wide at 0.9 m with a 50° field over 64 pixels: 8 · 2 · 0.9 · tan 25° / 64.
        let side = 8.0 * 2.0 * 0.9 * 25f32.to_radians().tan() / 64.0;
        let e = s.extent_along(Vec3::X);
        assert!(
            (e - (side / 2.0 - side / 16.0)).abs() < 1e-4,
            "{e} vs {side}"
        );
        assert_eq!(s.step, 8);
    }

    #[test]
    fn a_mostly_hidden_object_keeps_its_last_good_estimate() {
        let mut t = Tracker::new(1);
        t.update(&square(FIRST_OBJECT_SEGMENT, 6, 0.9), 8);
        let before = t.get(0).cloned();
        // Only a sliver left (a quarter of the area): not trusted.
        t.update(&square(FIRST_OBJECT_SEGMENT, 3, 0.9), 16);
        assert_eq!(t.get(0).cloned(), before);
        assert_eq!(t.frames, 2);
        // Unknown segments and other objects are ignored.
        let mut t = Tracker::new(1);
        t.update(&square(FIRST_OBJECT_SEGMENT + 1, 4, 0.9), 8);
        assert!(t.get(0).is_none());
    }
}
