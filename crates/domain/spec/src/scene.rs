//! What a camera needs to draw one moment of an episode, as plain data: it is built by the sim
//! role and rendered by the render role, possibly in another process.

use serde::{Deserialize, Serialize};

use crate::spec::{Camera, Shape, Surface};

/// Half extents (m) of the kinematic tool, a 4 × 4 × 10 cm box.
pub const TOOL_HALF_EXTENTS: [f64; 3] = [0.02, 0.02, 0.05];

/// Segment ids in segmentation images: 0 is nothing, then the surface and the tool; object `i`
/// of the spec (in spec order) is `FIRST_OBJECT_SEGMENT + i`.
pub const SEGMENT_BACKGROUND: u32 = 0;
pub const SEGMENT_SURFACE: u32 = 1;
pub const SEGMENT_TOOL: u32 = 2;
pub const FIRST_OBJECT_SEGMENT: u32 = 3;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SnapshotObject {
    pub id: String,
    pub shape: Shape,
    pub color: [f32; 3],
    /// The task gave the object its colour (the spec's `color`): drawn over a URDF's base link
    /// materials, as PyBullet's `changeVisualShape(-1)`. False in episodes recorded before it
    /// was kept, drawn as they were.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub color_given: bool,
    pub position: [f32; 3],
    /// Unit quaternion (x, y, z, w).
    pub rotation: [f32; 4],
    /// Joint positions of an articulated URDF object at this moment (its shape's `joints` are
    /// the initial ones, which fix its frame); empty for everything else.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub joints: std::collections::BTreeMap<String, f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneSnapshot {
    pub surface: Surface,
    pub objects: Vec<SnapshotObject>,
    /// Tool centre, if the tool is drawn.
    pub tool: Option<[f32; 3]>,
    /// The tool's turn from pointing down (unit quaternion x, y, z, w); none: pointing down,
    /// not turned.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_rotation: Option<[f32; 4]>,
    /// The finger pads of a parallel gripper that grasps by friction (drawn as the tool).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fingers: Vec<SnapshotBox>,
    /// The links of the arm that carries the tool, if there is one (drawn as the tool).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub arm: Vec<SnapshotBox>,
}

/// A box: centre, unit quaternion (x, y, z, w) and half extents.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SnapshotBox {
    pub position: [f32; 3],
    pub rotation: [f32; 4],
    pub half_extents: [f32; 3],
}

impl SceneSnapshot {
    /// Segment id → what it shows, for the legend stored next to segmentation images.
    pub fn segment_legend(&self) -> Vec<(u32, String)> {
        let mut legend = vec![
            (SEGMENT_BACKGROUND, "background".to_owned()),
            (SEGMENT_SURFACE, "surface".to_owned()),
            (SEGMENT_TOOL, "tool".to_owned()),
        ];
        legend.extend(
            self.objects
                .iter()
                .enumerate()
                .map(|(i, o)| (FIRST_OBJECT_SEGMENT + i as u32, o.id.clone())),
        );
        legend
    }
}

fn camera(name: &str, eye: [f64; 3], target: [f64; 3]) -> Camera {
    Camera {
        name: name.into(),
        eye,
        target,
        fovy_deg: 50.0,
        width: 640,
        height: 480,
        up: None,
    }
}

/// The four fixed views of the initial scene used for scene alignment: top-down (as GenSim tasks
/// are seen), front, and two obliques.
pub fn scene_views() -> Vec<Camera> {
    vec![
        camera("top", [0.5, 0.0, 0.95], [0.5, 0.0, 0.0]),
        camera("front", [1.1, 0.0, 0.45], [0.5, 0.0, 0.05]),
        camera("oblique_left", [0.95, 0.5, 0.55], [0.5, 0.0, 0.05]),
        camera("oblique_right", [0.95, -0.5, 0.55], [0.5, 0.0, 0.05]),
    ]
}

/// The end-effector camera: 5 cm below the tool centre, looking straight down.
pub const EE_CAMERA: &str = "ee";

/// Cameras for a task: its own, or the defaults (top, front, oblique, end effector).
pub fn task_cameras(own: &[Camera]) -> Vec<Camera> {
    if !own.is_empty() {
        return own.to_vec();
    }
    let mut c = scene_views();
    c.truncate(3);
    c.push(Camera {
        fovy_deg: 70.0,
        ..camera(EE_CAMERA, [0.0; 3], [0.0; 3])
    });
    c
}

/// What a seeing policy gets from one camera at one moment: depth and segment ids, rows top to
/// bottom (the renderer's conventions).
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    pub camera: Camera,
    /// Distance (m) from the camera plane along its axis; infinity where nothing was drawn.
    pub depth: Vec<f32>,
    /// Segment ids, as in segmentation images.
    pub segments: Vec<u32>,
}

/// A camera's axes in the world, as the renderer builds its view: right, up and forward. World z
/// is up; a camera looking straight down takes +x as the image's up.
pub fn camera_axes(eye: [f64; 3], target: [f64; 3]) -> [[f64; 3]; 3] {
    let norm = |a: [f64; 3]| {
        let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        [a[0] / l, a[1] / l, a[2] / l]
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let f = norm([target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]]);
    let up = if cross(f, [0.0, 0.0, 1.0]).iter().all(|c| c.abs() < 1e-4) {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    let s = norm(cross(f, up));
    [s, cross(s, f), f]
}

impl Observation {
    pub fn width(&self) -> u32 {
        self.camera.width.max(1)
    }

    pub fn height(&self) -> u32 {
        self.camera.height.max(1)
    }

    /// The world point drawn at the centre of pixel (`x`, `y`), or `None` where nothing was.
    pub fn point(&self, x: u32, y: u32) -> Option<[f64; 3]> {
        let d = *self.depth.get((y * self.width() + x) as usize)?;
        self.unprojection().point(x, y, d)
    }

    /// The camera's pixel-to-world mapping, computed once for a whole image.
    pub fn unprojection(&self) -> Unprojection {
        let c = &self.camera;
        let t = (c.fovy_deg.to_radians() / 2.0).tan();
        let (w, h) = (f64::from(self.width()), f64::from(self.height()));
        Unprojection {
            eye: c.eye,
            axes: camera_axes(c.eye, c.target),
            half: [t * w / h, t],
            size: [w, h],
        }
    }
}

/// Pixels of one camera image back to world points.
#[derive(Debug, Clone, Copy)]
pub struct Unprojection {
    eye: [f64; 3],
    /// Right, up, forward.
    axes: [[f64; 3]; 3],
    /// Half the view's width and height at unit depth.
    half: [f64; 2],
    size: [f64; 2],
}

impl Unprojection {
    /// The world point at the centre of pixel (`x`, `y`) drawn at `depth` (m along the camera
    /// axis), or `None` where nothing was drawn.
    pub fn point(&self, x: u32, y: u32, depth: f32) -> Option<[f64; 3]> {
        let d = f64::from(depth);
        if !d.is_finite() {
            return None;
        }
        let nx = (f64::from(x) + 0.5) / self.size[0] * 2.0 - 1.0;
        let ny = 1.0 - (f64::from(y) + 0.5) / self.size[1] * 2.0;
        let (right, up) = (nx * self.half[0] * d, ny * self.half[1] * d);
        let [s, u, f] = self.axes;
        Some(std::array::from_fn(|k| {
            self.eye[k] + s[k] * right + u[k] * up + f[k] * d
        }))
    }
}

/// A triangle mesh: vertex positions and triangles indexing them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriangleMesh {
    pub vertices: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Reads Wavefront OBJ text with `tobj`: every object and group in one mesh, polygons fanned
/// from their first corner, `v/vt/vn` and negative indices resolved, points and lines skipped.
/// A `mtllib` is never opened (a mesh reaches no file but itself). Refuses a mesh without
/// triangles and non-finite coordinates.
pub fn parse_obj(text: &str) -> Result<TriangleMesh, String> {
    let options = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let (models, _materials) = tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| format!("OBJ: {e}"))?;
    let mut mesh = TriangleMesh::default();
    for m in models {
        let base = u32::try_from(mesh.vertices.len()).map_err(|_| "OBJ: too many vertices")?;
        let positions = &m.mesh.positions;
        mesh.vertices
            .extend(positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        mesh.triangles.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]]),
        );
    }
    if mesh.triangles.is_empty() {
        return Err("OBJ: no faces".into());
    }
    if mesh.vertices.iter().flatten().any(|c| !c.is_finite()) {
        return Err("OBJ: non-finite vertex coordinates".into());
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_faces_are_fanned_and_indices_resolved() {
        let m = parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1/1 2/2/2 3/3/3 4/4/4\nf -1 -2 -3\n",
        )
        .unwrap();
        assert_eq!(m.vertices.len(), 4);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [3, 2, 1]]);
        assert!(parse_obj("f 1 2 3\n").is_err());
        assert!(
            parse_obj("v 0 0 0\nf 1 2 3\n")
                .unwrap_err()
                .contains("out of bounds")
        );
        assert!(
            parse_obj("v 0 0 0\nv 1 0 0\n")
                .unwrap_err()
                .contains("no faces")
        );
        assert!(
            parse_obj("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
                .unwrap_err()
                .contains("non-finite")
        );
        // Objects and groups join one mesh; a material library is not opened.
        let two = parse_obj(
            "mtllib /etc/passwd\no a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\
             o b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 4 5 6\n",
        )
        .unwrap();
        assert_eq!(two.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        assert_eq!(two.vertices[3], [0.0, 0.0, 1.0]);
    }
}
