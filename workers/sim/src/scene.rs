//! Building a rapier3d world from a task spec and a seed.

use assay_core::rng::Rng;
use assay_core::spec::{Object, Shape, Surface, TABLE_CENTER, TABLE_HALF_EXTENTS, TaskSpec};
use assay_core::urdf::Geometry;
use rapier3d::prelude::*;

use crate::SimError;

/// The kinematic tool: a 4 × 4 × 10 cm box, as in the reference scene.
pub const GRIPPER_HALF_EXTENTS: [f32; 3] = [0.02, 0.02, 0.05];
/// Where the tool waits when nothing else is said.
pub const GRIPPER_PARK: [f32; 3] = [0.5, 0.0, 0.5];
pub const OBJECT_FRICTION: f32 = 0.8;
pub const DEFAULT_MASS: f64 = 0.1;

/// One object of the task in the world.
#[derive(Debug, Clone)]
pub struct SimObject {
    pub id: String,
    pub body: RigidBodyHandle,
    /// Half extents of the object's box in its own frame (upright).
    pub half: Vec3,
    pub fixed: bool,
    /// For containers: inner half extents and wall thickness.
    pub container: Option<(Vec3, f32)>,
}

pub struct SimScene {
    pub world: PhysicsWorld,
    pub objects: Vec<SimObject>,
    pub gripper: RigidBodyHandle,
    pub gripper_collider: ColliderHandle,
    /// Zones: id, centre (z = 0), half extents (z = 0).
    pub zones: Vec<(String, Vec3, Vec3)>,
}

impl SimScene {
    pub fn object(&self, id: &str) -> Option<&SimObject> {
        self.objects.iter().find(|o| o.id == id)
    }

    pub fn index_of(&self, id: &str) -> Option<usize> {
        self.objects.iter().position(|o| o.id == id)
    }

    pub fn pose(&self, o: &SimObject) -> Pose {
        *self.world.bodies[o.body].position()
    }

    pub fn gripper_position(&self) -> Vec3 {
        self.world.bodies[self.gripper].translation()
    }
}

pub fn v3(a: [f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// A world with the integration parameters Assay uses everywhere (the task's `dt`).
pub fn new_world(dt: f32) -> PhysicsWorld {
    let mut world = PhysicsWorld::new();
    world.gravity = Vec3::new(0.0, 0.0, -9.81);
    world.integration_parameters.dt = dt;
    world
}

/// A collider, the half extents of its box, and (containers) inner half extents and wall.
type BuiltShape = (ColliderBuilder, Vec3, Option<(Vec3, f32)>);

fn collider_for(shape: &Shape, spec: &TaskSpec, path: &str) -> Result<BuiltShape, SimError> {
    Ok(match shape {
        Shape::Box { half_extents } => {
            let h = v3(*half_extents);
            (ColliderBuilder::cuboid(h.x, h.y, h.z), h, None)
        }
        Shape::Sphere { radius } => {
            let r = *radius as f32;
            (ColliderBuilder::ball(r), Vec3::splat(r), None)
        }
        Shape::Cylinder {
            radius,
            half_height,
        } => {
            let (r, hh) = (*radius as f32, *half_height as f32);
            // rapier's cylinders stand on y; ours stand on z.
            let c = ColliderBuilder::cylinder(hh, r).rotation(Vec3::new(
                std::f32::consts::FRAC_PI_2,
                0.0,
                0.0,
            ));
            (c, Vec3::new(r, r, hh), None)
        }
        Shape::Container {
            inner_half_extents,
            wall,
        } => {
            let inner = v3(*inner_half_extents);
            let w = *wall as f32;
            let big_h = inner.z + w / 2.0;
            let mut parts: Vec<(Pose, SharedShape)> = Vec::new();
            // Bottom plate, then walls on ±x (full depth) and ±y (between the x walls).
            parts.push((
                Pose::from_translation(Vec3::new(0.0, 0.0, -big_h + w / 2.0)),
                SharedShape::cuboid(inner.x + w, inner.y + w, w / 2.0),
            ));
            let wall_z = -big_h + w + inner.z;
            for s in [-1.0f32, 1.0] {
                parts.push((
                    Pose::from_translation(Vec3::new(s * (inner.x + w / 2.0), 0.0, wall_z)),
                    SharedShape::cuboid(w / 2.0, inner.y + w, inner.z),
                ));
                parts.push((
                    Pose::from_translation(Vec3::new(0.0, s * (inner.y + w / 2.0), wall_z)),
                    SharedShape::cuboid(inner.x, w / 2.0, inner.z),
                ));
            }
            (
                ColliderBuilder::compound(parts),
                Vec3::new(inner.x + w, inner.y + w, big_h),
                Some((inner, w)),
            )
        }
        Shape::Urdf { path: file, joints } => {
            let full = spec.asset_path(file);
            let a = assay_core::urdf::assemble(&full, joints)
                .map_err(|e| SimError::spec(format!("{path}.urdf"), e))?;
            let mut parts: Vec<(Pose, SharedShape)> = Vec::new();
            for (k, (part, mesh)) in a.collisions.iter().enumerate() {
                let [x, y, z] = part.pose.translation.map(|c| c as f32);
                let [qx, qy, qz, qw] = part.pose.rotation.map(|c| c as f32);
                let pose =
                    Pose::from_parts(Vec3::new(x, y, z), Rotation::from_xyzw(qx, qy, qz, qw));
                let (pose, shape) = match &part.geometry {
                    Geometry::Box { size } => {
                        let h = v3(*size) / 2.0;
                        (pose, SharedShape::cuboid(h.x, h.y, h.z))
                    }
                    Geometry::Sphere { radius } => (pose, SharedShape::ball(*radius as f32)),
                    // URDF cylinders stand on their local z; rapier's on y.
                    Geometry::Cylinder { radius, length } => (
                        pose * Pose::new(
                            Vec3::ZERO,
                            Vec3::new(std::f32::consts::FRAC_PI_2, 0.0, 0.0),
                        ),
                        SharedShape::cylinder(*length as f32 / 2.0, *radius as f32),
                    ),
                    Geometry::Mesh { scale, .. } => {
                        let s = v3(*scale);
                        let points: Vec<Vec3> = mesh
                            .iter()
                            .flat_map(|m| m.vertices.iter())
                            .map(|v| Vec3::new(v[0], v[1], v[2]) * s)
                            .collect();
                        let hull = SharedShape::convex_hull(&points).ok_or_else(|| {
                            SimError::spec(
                                format!("{path}.urdf"),
                                format!("collision part {k}: the mesh has no usable hull"),
                            )
                        })?;
                        (pose, hull)
                    }
                };
                parts.push((pose, shape));
            }
            (ColliderBuilder::compound(parts), v3(a.half), None)
        }
        Shape::Mesh { path: file, scale } => {
            let full = spec.asset_path(file);
            let text = std::fs::read_to_string(&full).map_err(|e| {
                SimError::spec(
                    format!("{path}.mesh.path"),
                    format!("cannot read {}: {e}", full.display()),
                )
            })?;
            let s = *scale as f32;
            let points: Vec<Vec3> = text
                .lines()
                .filter_map(|l| l.strip_prefix("v "))
                .filter_map(|l| {
                    let c: Vec<f32> = l
                        .split_whitespace()
                        .take(3)
                        .filter_map(|x| x.parse().ok())
                        .collect();
                    (c.len() == 3).then(|| Vec3::new(c[0], c[1], c[2]) * s)
                })
                .collect();
            let collider = ColliderBuilder::convex_hull(&points).ok_or_else(|| {
                SimError::spec(
                    format!("{path}.mesh.path"),
                    format!("{} has no usable vertices", full.display()),
                )
            })?;
            let (lo, hi) = points.iter().fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            );
            (collider, (hi - lo) / 2.0, None)
        }
    })
}

/// Samples the initial state for `seed` and builds the world. Every random draw comes from one
/// stream per (seed, task id), in spec order.
pub fn build_scene(spec: &TaskSpec, seed: u64) -> Result<SimScene, SimError> {
    let mut rng = Rng::new(seed, &spec.id);
    let mut world = new_world(spec.physics.dt as f32);

    match spec.scene.surface {
        Surface::Table => {
            let [hx, hy] = TABLE_HALF_EXTENTS;
            world.insert(
                RigidBodyBuilder::fixed().translation(Vec3::new(
                    TABLE_CENTER[0] as f32,
                    TABLE_CENTER[1] as f32,
                    -0.05,
                )),
                ColliderBuilder::cuboid(hx as f32, hy as f32, 0.05).friction(OBJECT_FRICTION),
            );
        }
        Surface::Ground => {
            world.insert(
                RigidBodyBuilder::fixed(),
                ColliderBuilder::halfspace(nalgebra::Unit::new_unchecked(Vector::Z))
                    .friction(OBJECT_FRICTION),
            );
        }
    }

    let jitter = spec.variations.position_jitter;
    let yaw_jitter = spec.variations.yaw_jitter_deg;
    let mut objects = Vec::with_capacity(spec.scene.objects.len());
    for (i, o) in spec.scene.objects.iter().enumerate() {
        let (position, yaw_deg) = initial_pose(o, &mut rng);
        let (position, yaw_deg) = if o.is_fixed {
            (position, yaw_deg)
        } else {
            (
                [
                    position[0] + rng.uniform(-jitter, jitter),
                    position[1] + rng.uniform(-jitter, jitter),
                    position[2],
                ],
                yaw_deg + rng.uniform(-yaw_jitter, yaw_jitter),
            )
        };
        let path = format!("scene.objects[{i}].shape");
        let (collider, half, container) = collider_for(&o.shape, spec, &path)?;
        let body = if o.is_fixed {
            RigidBodyBuilder::fixed()
        } else {
            RigidBodyBuilder::dynamic()
        };
        let body = body
            .pose(Pose::new(
                v3(position),
                Vec3::new(0.0, 0.0, (yaw_deg as f32).to_radians()),
            ))
            .can_sleep(spec.physics.sleeping);
        let collider = collider
            .mass(o.mass.unwrap_or(DEFAULT_MASS) as f32)
            .friction(OBJECT_FRICTION)
            .restitution(0.0);
        let (handle, _) = world.insert(body, collider);
        objects.push(SimObject {
            id: o.id.clone(),
            body: handle,
            half,
            fixed: o.is_fixed,
            container,
        });
    }

    let start = match &spec.variations.ee_start {
        Some(r) => Vec3::new(
            rng.uniform(r.min[0], r.max[0]) as f32,
            rng.uniform(r.min[1], r.max[1]) as f32,
            rng.uniform(r.min[2], r.max[2]) as f32,
        ),
        None => Vec3::from(GRIPPER_PARK),
    };
    let [gx, gy, gz] = GRIPPER_HALF_EXTENTS;
    let (gripper, gripper_collider) = world.insert(
        RigidBodyBuilder::kinematic_position_based().translation(start),
        ColliderBuilder::cuboid(gx, gy, gz).friction(OBJECT_FRICTION),
    );
    let zones = spec
        .scene
        .zones
        .iter()
        .map(|z| {
            (
                z.id.clone(),
                Vec3::new(z.center[0] as f32, z.center[1] as f32, 0.0),
                Vec3::new(z.half_extents[0] as f32, z.half_extents[1] as f32, 0.0),
            )
        })
        .collect();
    Ok(SimScene {
        world,
        objects,
        gripper,
        gripper_collider,
        zones,
    })
}

fn initial_pose(o: &Object, rng: &mut Rng) -> ([f64; 3], f64) {
    match (&o.pose, &o.pose_range) {
        (Some(p), _) => (p.position, p.yaw_deg),
        (None, Some(r)) => (
            [
                rng.uniform(r.min[0], r.max[0]),
                rng.uniform(r.min[1], r.max[1]),
                rng.uniform(r.min[2], r.max[2]),
            ],
            rng.uniform(r.yaw_deg[0], r.yaw_deg[1]),
        ),
        (None, None) => ([0.0; 3], 0.0),
    }
}
