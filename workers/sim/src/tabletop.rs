//! The fixed sizes and materials of Assay's tabletop world, and its angle helpers (a rotation's
//! heading, an angle wrapped to (−π, π]), which the scene, the arm, the controller and the
//! policy driver share.

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
