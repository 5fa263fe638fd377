//! The fixed sizes and materials of Assay's tabletop world, which the scene, the arm and the
//! controller share.

/// The kinematic tool: a 4 × 4 × 10 cm box, as in the reference scene.
pub const GRIPPER_HALF_EXTENTS: [f32; 3] = [0.02, 0.02, 0.05];
/// Where the tool waits when nothing else is said.
pub const GRIPPER_PARK: [f32; 3] = [0.5, 0.0, 0.5];
pub const OBJECT_FRICTION: f32 = 0.8;
pub const DEFAULT_MASS: f64 = 0.1;
