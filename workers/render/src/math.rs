//! The little linear algebra the renderer needs: column-major 4 × 4 matrices (`m[col * 4 + row]`),
//! right-handed, z-up world, clip depth 0..1 (wgpu's convention).

pub type Mat4 = [f32; 16];

pub fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

/// View matrix of a camera at `eye` looking at `target`, `up` towards the image's top (a camera
/// that rides on the tool turns with it). Without one (or with one along the view) world z is
/// up; a camera looking straight down takes +x (away from the robot) as the image's up.
pub fn look_at(eye: [f32; 3], target: [f32; 3], up: Option<[f32; 3]>) -> Mat4 {
    let f = normalize(sub(target, eye));
    let along = |u: [f32; 3]| cross(f, normalize(u)).iter().all(|c| c.abs() < 1e-4);
    let up = match up {
        Some(u) if dot(u, u) > 0.0 && !along(u) => u,
        _ if along([0.0, 0.0, 1.0]) => [1.0, 0.0, 0.0],
        _ => [0.0, 0.0, 1.0],
    };
    let s = normalize(cross(f, up));
    let u = cross(s, f);
    [
        s[0],
        u[0],
        -f[0],
        0.0,
        s[1],
        u[1],
        -f[1],
        0.0,
        s[2],
        u[2],
        -f[2],
        0.0,
        -dot(s, eye),
        -dot(u, eye),
        dot(f, eye),
        1.0,
    ]
}

/// Perspective projection with clip depth 0 at `near` and 1 at `far`.
pub fn perspective(fovy_rad: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let f = 1.0 / (0.5 * fovy_rad).tan();
    let r = far / (near - far);
    [
        f / aspect,
        0.0,
        0.0,
        0.0,
        0.0,
        f,
        0.0,
        0.0,
        0.0,
        0.0,
        r,
        -1.0,
        0.0,
        0.0,
        r * near,
        0.0,
    ]
}

pub fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut o = [0.0f32; 16];
    for c in 0..4 {
        for r in 0..4 {
            o[c * 4 + r] = (0..4).map(|k| a[k * 4 + r] * b[c * 4 + k]).sum();
        }
    }
    o
}

/// Rotation matrix columns of a unit quaternion (x, y, z, w).
pub fn quat_columns(q: [f32; 4]) -> [[f32; 3]; 3] {
    let [x, y, z, w] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + z * w),
            2.0 * (x * z - y * w),
        ],
        [
            2.0 * (x * y - z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + x * w),
        ],
        [
            2.0 * (x * z + y * w),
            2.0 * (y * z - x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

pub fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
    let c = quat_columns(q);
    [
        c[0][0] * v[0] + c[1][0] * v[1] + c[2][0] * v[2],
        c[0][1] * v[0] + c[1][1] * v[1] + c[2][1] * v[2],
        c[0][2] * v[0] + c[1][2] * v[1] + c[2][2] * v[2],
    ]
}

/// Model matrix T · R · S.
pub fn trs(t: [f32; 3], q: [f32; 4], s: [f32; 3]) -> Mat4 {
    let r = quat_columns(q);
    let c = |i: usize| [r[i][0] * s[i], r[i][1] * s[i], r[i][2] * s[i]];
    let (c0, c1, c2) = (c(0), c(1), c(2));
    [
        c0[0], c0[1], c0[2], 0.0, c1[0], c1[1], c1[2], 0.0, c2[0], c2[1], c2[2], 0.0, t[0], t[1],
        t[2], 1.0,
    ]
}

/// Applies a matrix to a point, with the perspective divide.
pub fn project(m: &Mat4, p: [f32; 3]) -> [f32; 3] {
    let v = [p[0], p[1], p[2], 1.0];
    let r = |row: usize| (0..4).map(|k| m[k * 4 + row] * v[k]).sum::<f32>();
    let w = r(3);
    [r(0) / w, r(1) / w, r(2) / w]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_camera_target_projects_to_the_image_centre_at_the_right_depth() {
        let (near, far) = (0.01, 10.0);
        let vp = mul(
            &perspective(1.0, 4.0 / 3.0, near, far),
            &look_at([1.0, 0.0, 0.75], [0.5, 0.0, 0.0], None),
        );
        let c = project(&vp, [0.5, 0.0, 0.0]);
        assert!(c[0].abs() < 1e-5 && c[1].abs() < 1e-5, "{c:?}");
        // Window depth back to distance along the axis.
        let dist = near * far / (far - c[2] * (far - near));
        let expect = (0.5f32 * 0.5 + 0.75 * 0.75).sqrt();
        assert!((dist - expect).abs() < 1e-4, "{dist} vs {expect}");
        // Up in the world is up in the image.
        assert!(project(&vp, [0.5, 0.0, 0.1])[1] > 0.0);
        // Looking straight down works too (+x is image up).
        let top = mul(
            &perspective(1.0, 1.0, near, far),
            &look_at([0.5, 0.0, 1.0], [0.5, 0.0, 0.0], None),
        );
        assert!(project(&top, [0.6, 0.0, 0.0])[1] > 0.0);
    }

    #[test]
    fn quaternion_rotation_turns_x_into_y_about_z() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let v = rotate([0.0, 0.0, h, h], [1.0, 0.0, 0.0]);
        assert!((v[0]).abs() < 1e-6 && (v[1] - 1.0).abs() < 1e-6);
    }
}
