//! Unit primitives (a [-1, 1]³ box, a unit sphere, a unit cylinder on z) with face normals.

use bytemuck::{Pod, Zeroable};

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Vertex {
    pub pos: [f32; 3],
    pub normal: [f32; 3],
}

#[derive(Debug, Clone, Default)]
pub struct MeshData {
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
}

impl MeshData {
    fn quad(&mut self, corners: [[f32; 3]; 4], normal: [f32; 3]) {
        let base = self.vertices.len() as u32;
        self.vertices
            .extend(corners.iter().map(|&pos| Vertex { pos, normal }));
        self.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }
}

pub fn unit_box() -> MeshData {
    let mut m = MeshData::default();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut n = [0.0; 3];
            n[axis] = sign;
            let corner = |a: f32, b: f32| {
                let mut p = [0.0; 3];
                p[axis] = sign;
                p[u] = a;
                p[v] = b;
                p
            };
            m.quad(
                [
                    corner(-1.0, -1.0),
                    corner(1.0, -1.0),
                    corner(1.0, 1.0),
                    corner(-1.0, 1.0),
                ],
                n,
            );
        }
    }
    m
}

pub fn unit_sphere(rings: u32, segments: u32) -> MeshData {
    let mut m = MeshData::default();
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..=segments {
            let phi = 2.0 * std::f32::consts::PI * s as f32 / segments as f32;
            let p = [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ];
            m.vertices.push(Vertex { pos: p, normal: p });
        }
    }
    let row = segments + 1;
    for r in 0..rings {
        for s in 0..segments {
            let (a, b) = (r * row + s, (r + 1) * row + s);
            m.indices.extend([a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    m
}

pub fn unit_cylinder(segments: u32) -> MeshData {
    let mut m = MeshData::default();
    let ring = |k: u32| {
        let a = 2.0 * std::f32::consts::PI * k as f32 / segments as f32;
        (a.cos(), a.sin())
    };
    for k in 0..segments {
        let (c0, s0) = ring(k);
        let (c1, s1) = ring(k + 1);
        let base = m.vertices.len() as u32;
        for (c, s, z) in [(c0, s0, -1.0), (c1, s1, -1.0), (c1, s1, 1.0), (c0, s0, 1.0)] {
            m.vertices.push(Vertex {
                pos: [c, s, z],
                normal: [c, s, 0.0],
            });
        }
        m.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        for z in [-1.0f32, 1.0] {
            let base = m.vertices.len() as u32;
            let n = [0.0, 0.0, z];
            m.vertices.push(Vertex {
                pos: [0.0, 0.0, z],
                normal: n,
            });
            m.vertices.push(Vertex {
                pos: [c0, s0, z],
                normal: n,
            });
            m.vertices.push(Vertex {
                pos: [c1, s1, z],
                normal: n,
            });
            m.indices.extend([base, base + 1, base + 2]);
        }
    }
    m
}

/// A triangle mesh with flat face normals (vertices are split per face).
pub fn from_triangles(vertices: &[[f32; 3]], triangles: &[[u32; 3]], scale: f32) -> MeshData {
    let mut m = MeshData::default();
    for t in triangles {
        let p = t.map(|i| vertices[i as usize].map(|c| c * scale));
        let e1 = crate::math::sub(p[1], p[0]);
        let e2 = crate::math::sub(p[2], p[0]);
        let n = crate::math::cross(e1, e2);
        let n = if crate::math::dot(n, n) > 0.0 {
            crate::math::normalize(n)
        } else {
            [0.0, 0.0, 1.0]
        };
        let base = m.vertices.len() as u32;
        m.vertices
            .extend(p.iter().map(|&pos| Vertex { pos, normal: n }));
        m.indices.extend([base, base + 1, base + 2]);
    }
    m
}
