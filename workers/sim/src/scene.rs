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
    /// For articulated URDF objects: the moving joints (`body` is the root link's body).
    pub joints: Vec<SimJoint>,
}

/// A moving joint of an articulated object in the world.
#[derive(Debug, Clone)]
pub struct SimJoint {
    pub name: String,
    pub prismatic: bool,
    pub parent: RigidBodyHandle,
    /// The body of the joint's child link (and the links fixed to it).
    pub child: RigidBodyHandle,
    /// The joint frame at position 0 in the parent body's frame, turned so that its x axis is
    /// the joint axis; the child body's frame is this frame moved by the joint, then turned back
    /// by `align`.
    pub frame: Pose,
    pub align: Rotation,
    pub limit: Option<[f64; 2]>,
    pub handle: ImpulseJointHandle,
    /// `<dynamics friction>` (N or N m); 0 for none.
    pub friction: f64,
    /// Where the friction spring holds the joint (see [`SimScene::hold_joints`]).
    pub anchor: f64,
}

/// How far (rad or m) a joint with friction gives before it slips: its friction is a spring of
/// stiffness `friction / JOINT_SLIP` that holds it at an anchor, and the anchor follows the
/// joint when the spring's force would exceed the friction (stick-slip Coulomb friction). A
/// velocity motor bounded by the friction would let a lid creep down under gravity.
pub const JOINT_SLIP: f64 = 0.01;

impl SimJoint {
    fn axis(&self) -> JointAxis {
        if self.prismatic {
            JointAxis::LinX
        } else {
            JointAxis::AngX
        }
    }

    /// The joint's position (rad or m) in the current state.
    pub fn position(&self, world: &PhysicsWorld) -> f64 {
        let parent = world.bodies[self.parent].position();
        let child = world.bodies[self.child].position();
        // Child frame in the joint's zero frame, x axis along the joint axis.
        let rel = (*parent * self.frame).inverse() * (*child * Pose::from_rotation(self.align));
        if self.prismatic {
            f64::from(rel.translation.x)
        } else {
            let q = rel.rotation;
            f64::from(2.0 * q.x.atan2(q.w))
        }
    }
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

    /// Joint `name` of object `o`, if it is a moving joint of an articulated object.
    pub fn joint<'a>(&self, o: &'a SimObject, name: &str) -> Option<&'a SimJoint> {
        o.joints.iter().find(|j| j.name == name)
    }

    /// Joint friction, before each physics step: a joint pulled further than [`JOINT_SLIP`]
    /// from its anchor slips (the anchor follows it); otherwise its spring holds it.
    pub fn hold_joints(&mut self) {
        for o in &mut self.objects {
            for j in &mut o.joints {
                if j.friction <= 0.0 {
                    continue;
                }
                let q = j.position(&self.world);
                if (j.anchor - q).abs() <= JOINT_SLIP {
                    continue;
                }
                j.anchor = q + JOINT_SLIP * (j.anchor - q).signum();
                let axis = j.axis();
                if let Some(joint) = self.world.impulse_joints.get_mut(j.handle, true) {
                    let stiffness = (j.friction / JOINT_SLIP) as f32;
                    let damping = joint.data.motor(axis).map_or(0.0, |m| m.damping);
                    joint
                        .data
                        .set_motor_position(axis, j.anchor as f32, stiffness, damping);
                }
            }
        }
    }

    /// Every moving joint's position of object `o`, by name.
    pub fn joint_positions(&self, o: &SimObject) -> std::collections::BTreeMap<String, f64> {
        o.joints
            .iter()
            .map(|j| (j.name.clone(), j.position(&self.world)))
            .collect()
    }
}

fn to_pose(p: &assay_core::urdf::Pose) -> Pose {
    let [x, y, z] = p.translation.map(|c| c as f32);
    let [qx, qy, qz, qw] = p.rotation.map(|c| c as f32);
    Pose::from_parts(Vec3::new(x, y, z), Rotation::from_xyzw(qx, qy, qz, qw))
}

/// A URDF collision part as a rapier shape and its pose in the frame the part is placed in.
fn urdf_part(
    part: &assay_core::urdf::PlacedPart,
    mesh: Option<&assay_core::scene::TriangleMesh>,
    k: usize,
    path: &str,
) -> Result<(Pose, SharedShape), SimError> {
    let pose = to_pose(&part.pose);
    Ok(match &part.geometry {
        Geometry::Box { size } => {
            let h = v3(*size) / 2.0;
            (pose, SharedShape::cuboid(h.x, h.y, h.z))
        }
        Geometry::Sphere { radius } => (pose, SharedShape::ball(*radius as f32)),
        // URDF cylinders stand on their local z; rapier's on y.
        Geometry::Cylinder { radius, length } => (
            pose * Pose::new(Vec3::ZERO, Vec3::new(std::f32::consts::FRAC_PI_2, 0.0, 0.0)),
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
    })
}

/// One rigid body of an articulated object: its frame in the object's frame and its parts.
struct LinkBody {
    frame: Pose,
    parts: Vec<(Pose, SharedShape)>,
}

/// The bodies and joints of an articulated URDF object posed at `pose`: links joined by fixed
/// joints share a body; every revolute, continuous or prismatic joint joins two bodies with a
/// rapier joint that has the URDF's limits and resists motion with its `<dynamics friction>`.
fn insert_articulated(
    world: &mut PhysicsWorld,
    a: &assay_core::urdf::Assembled,
    root: RigidBodyHandle,
    mass: f32,
    sleeping: bool,
    joints: &std::collections::BTreeMap<String, f64>,
    path: &str,
) -> Result<Vec<SimJoint>, SimError> {
    use assay_core::urdf::JointKind;
    let urdf = &a.urdf;
    let pose = *world.bodies[root].position();
    let err = |reason: String| SimError::spec(format!("{path}.urdf"), reason);
    let links = urdf.link_poses(joints).map_err(err)?;
    let centre = Vec3::new(a.centre[0] as f32, a.centre[1] as f32, a.centre[2] as f32);
    // Link frames in the object's frame.
    let in_object = |l: usize| Pose::from_translation(-centre) * to_pose(&links[l]);
    let mut body_of = vec![0usize; urdf.links.len()];
    let mut bodies = vec![LinkBody {
        frame: Pose::IDENTITY,
        parts: Vec::new(),
    }];
    for &j in urdf.joint_order() {
        let joint = &urdf.joints[j];
        if joint.kind == JointKind::Fixed {
            body_of[joint.child] = body_of[joint.parent];
        } else {
            body_of[joint.child] = bodies.len();
            bodies.push(LinkBody {
                frame: in_object(joint.child),
                parts: Vec::new(),
            });
        }
    }
    for (k, (part, mesh)) in a.collisions.iter().enumerate() {
        let (p, shape) = urdf_part(part, mesh.as_ref(), k, path)?;
        let b = &mut bodies[body_of[part.link]];
        b.parts.push((b.frame.inverse() * p, shape));
    }
    let mut handles = vec![root];
    for (b, body) in bodies.iter().enumerate().skip(1) {
        if body.parts.is_empty() {
            return Err(err(format!(
                "moving body {b} has no collision or visual geometry"
            )));
        }
        let (h, _) = world.insert(
            RigidBodyBuilder::dynamic()
                .pose(pose * body.frame)
                .can_sleep(sleeping),
            ColliderBuilder::compound(body.parts.clone())
                .mass(mass)
                .friction(OBJECT_FRICTION)
                .restitution(0.0),
        );
        handles.push(h);
    }
    let mut out = Vec::new();
    for &j in urdf.joint_order() {
        let joint = &urdf.joints[j];
        if joint.kind == JointKind::Fixed {
            continue;
        }
        let (pb, cb) = (body_of[joint.parent], body_of[joint.child]);
        // The joint frame at position 0, in the parent body's frame.
        let zero = Pose::from_translation(-centre)
            * to_pose(&links[joint.parent])
            * to_pose(&assay_core::urdf::Pose::from_origin(&joint.origin));
        let axis = v3(joint.axis).normalize();
        let align = Rotation::from_rotation_arc(Vec3::X, axis);
        let frame = bodies[pb].frame.inverse() * zero * Pose::from_rotation(align);
        let prismatic = joint.kind == JointKind::Prismatic;
        let (mask, axis_id) = if prismatic {
            (JointAxesMask::LOCKED_PRISMATIC_AXES, JointAxis::LinX)
        } else {
            (JointAxesMask::LOCKED_REVOLUTE_AXES, JointAxis::AngX)
        };
        let mut builder = GenericJointBuilder::new(mask)
            .local_frame1(frame)
            .local_frame2(Pose::from_rotation(align))
            .contacts_enabled(false);
        if let Some([lo, hi]) = joint.limit {
            builder = builder.limits(axis_id, [lo as f32, hi as f32]);
        }
        let q0 = joints
            .get(&joint.name)
            .copied()
            .unwrap_or_else(|| joint.default_position());
        if joint.friction > 0.0 || joint.damping > 0.0 {
            // Friction: a spring to an anchor that slips (`SimScene::hold_joints`), bounded by
            // the friction; damping: the motor's damping.
            let stiffness = (joint.friction / JOINT_SLIP) as f32;
            let max = if joint.friction > 0.0 {
                joint.friction as f32
            } else {
                f32::MAX
            };
            builder = builder
                .motor_model(axis_id, MotorModel::ForceBased)
                .motor_position(axis_id, q0 as f32, stiffness, joint.damping as f32)
                .motor_max_force(axis_id, max);
        }
        let handle = world.insert_impulse_joint(handles[pb], handles[cb], builder.build());
        out.push(SimJoint {
            name: joint.name.clone(),
            prismatic,
            parent: handles[pb],
            child: handles[cb],
            frame,
            align,
            limit: joint.limit,
            handle,
            friction: joint.friction,
            anchor: q0,
        });
    }
    Ok(out)
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

/// A collider, the half extents of its box, (containers) inner half extents and wall, and
/// (URDF objects) the assembled URDF.
type BuiltShape = (
    ColliderBuilder,
    Vec3,
    Option<(Vec3, f32)>,
    Option<assay_core::urdf::Assembled>,
);

/// Whether `link` is joined to `ancestor` by fixed joints only.
fn fixed_to(urdf: &assay_core::urdf::Urdf, link: usize, ancestor: usize) -> bool {
    let mut l = link;
    while l != ancestor {
        match urdf.joints.iter().find(|j| j.child == l) {
            Some(j) if j.kind == assay_core::urdf::JointKind::Fixed => l = j.parent,
            _ => return false,
        }
    }
    true
}

fn collider_for(shape: &Shape, spec: &TaskSpec, path: &str) -> Result<BuiltShape, SimError> {
    Ok(match shape {
        Shape::Box { half_extents } => {
            let h = v3(*half_extents);
            (ColliderBuilder::cuboid(h.x, h.y, h.z), h, None, None)
        }
        Shape::Sphere { radius } => {
            let r = *radius as f32;
            (ColliderBuilder::ball(r), Vec3::splat(r), None, None)
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
            (c, Vec3::new(r, r, hh), None, None)
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
                None,
            )
        }
        Shape::Urdf {
            path: file,
            joints,
            articulated,
        } => {
            let full = spec
                .resolve_asset(file)
                .map_err(|e| SimError::spec(format!("{path}.urdf.path"), e))?;
            // An articulated object's frame is fixed by its links at their default positions,
            // so that where it stands does not depend on how far it starts open.
            let frame_at = if *articulated {
                std::collections::BTreeMap::new()
            } else {
                joints.clone()
            };
            let a = assay_core::urdf::assemble_posed(&full, &frame_at, joints)
                .map_err(|e| SimError::spec(format!("{path}.urdf"), e))?;
            let root = a.urdf.root();
            let mut parts: Vec<(Pose, SharedShape)> = Vec::new();
            for (k, (part, mesh)) in a.collisions.iter().enumerate() {
                // An articulated object's root body holds the root link and what is fixed to
                // it; its moving links become bodies of their own (`insert_articulated`).
                if *articulated && !fixed_to(&a.urdf, part.link, root) {
                    continue;
                }
                parts.push(urdf_part(part, mesh.as_ref(), k, path)?);
            }
            if parts.is_empty() {
                return Err(SimError::spec(
                    format!("{path}.urdf"),
                    "the root link has no collision or visual geometry".to_string(),
                ));
            }
            let half = v3(a.half);
            (ColliderBuilder::compound(parts), half, None, Some(a))
        }
        Shape::Mesh { path: file, scale } => {
            let full = spec
                .resolve_asset(file)
                .map_err(|e| SimError::spec(format!("{path}.mesh.path"), e))?;
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
            (collider, (hi - lo) / 2.0, None, None)
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
        let (collider, half, container, urdf) = collider_for(&o.shape, spec, &path)?;
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
        let joints = match (&o.shape, &urdf) {
            (
                Shape::Urdf {
                    joints,
                    articulated: true,
                    ..
                },
                Some(a),
            ) => insert_articulated(
                &mut world,
                a,
                handle,
                o.mass.unwrap_or(DEFAULT_MASS) as f32,
                spec.physics.sleeping,
                joints,
                &path,
            )?,
            _ => Vec::new(),
        };
        objects.push(SimObject {
            id: o.id.clone(),
            body: handle,
            half,
            fixed: o.is_fixed,
            container,
            joints,
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
