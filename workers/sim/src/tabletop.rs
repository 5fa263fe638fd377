//! The fixed sizes and materials of Assay's tabletop world, and its angle helpers (a rotation's
//! heading, an angle wrapped to (−π, π], the tool's turn as a quaternion or as roll, pitch and
//! yaw), which the scene, the arm, the controller, the recorder and the policy driver share.

use rapier3d::glamx::EulerRot;
use rapier3d::prelude::Rotation;

/// The kinematic tool: a 4 × 4 × 10 cm box, as in the reference scene.
pub const GRIPPER_HALF_EXTENTS: [f32; 3] = [0.02, 0.02, 0.05];
/// Where the tool waits when nothing else is said.
pub const GRIPPER_PARK: [f32; 3] = [0.5, 0.0, 0.5];
pub const OBJECT_FRICTION: f32 = 0.8;
pub const DEFAULT_MASS: f64 = 0.1;

/// The turn about z of a rotation that keeps z up (or down): the heading of its x axis.
pub fn yaw_of(r: &rapier3d::prelude::Rotation) -> f32 {
    let x = *r * rapier3d::prelude::Vec3::X;
    x.y.atan2(x.x)
}

/// An angle (rad) in (−π, π].
pub fn wrap_angle(a: f32) -> f32 {
    let t = std::f32::consts::TAU;
    a - t * ((a + std::f32::consts::PI) / t).floor()
}

/// The tool's orientation (`ee_quat`, and the quaternion of an `ee_pose` action) when it is
/// turned by `turn` from pointing down: x, y, z, w. Pointing down, its z axis points down.
pub fn tool_quaternion(turn: Rotation) -> [f32; 4] {
    let q = (turn * Rotation::from_rotation_x(std::f32::consts::PI)).normalize();
    [q.x, q.y, q.z, q.w]
}

/// The turn from pointing down of a tool whose orientation is the unit quaternion `q` (x, y,
/// z, w): [`tool_quaternion`]'s inverse.
pub fn turn_of_quaternion(q: [f32; 4]) -> Rotation {
    let [x, y, z, w] = q;
    (Rotation::from_xyzw(x, y, z, w) * Rotation::from_rotation_x(std::f32::consts::PI).inverse())
        .normalize()
}

/// The turn `Rz(yaw) · Ry(pitch) · Rx(roll)`: roll about the world's x, then pitch about its y,
/// then yaw about its z (`ee_delta`'s droll, dpitch, dyaw; the recorded `ee_roll`, `ee_pitch`,
/// `ee_yaw`).
pub fn turn_of_rpy([roll, pitch, yaw]: [f32; 3]) -> Rotation {
    Rotation::from_euler(EulerRot::ZYX, yaw, pitch, roll)
}

/// [`turn_of_rpy`]'s inverse: roll, pitch, yaw (rad; pitch in [−π/2, π/2]).
pub fn rpy_of_turn(turn: Rotation) -> [f32; 3] {
    let (yaw, pitch, roll) = turn.to_euler(EulerRot::ZYX);
    [roll, pitch, yaw]
}
