//! Building a rapier3d world from a task spec and a seed.

use assay_spec::rng::Rng;
use assay_spec::spec::{
    MeshCollision, Object, Shape, Surface, TABLE_CENTER, TABLE_HALF_EXTENTS, TaskSpec,
};
use assay_spec::urdf::Geometry;
use rapier3d::prelude::*;

use crate::SimError;

pub use crate::tabletop::{
    DEFAULT_MASS, GRIPPER_HALF_EXTENTS, GRIPPER_PARK, OBJECT_FRICTION, yaw_of,
};

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
    /// The rolling friction its URDF's root link declares (m; Bullet's `rolling_friction`),
    /// 0 for every other shape: see [`SimScene::step`].
    pub rolling_friction: f32,
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

    /// The joint's position (rad or m) in the current state, within its limits (the solver lets
    /// a joint pass them by a hair, which a URDF reader would refuse to draw).
    pub fn position(&self, world: &PhysicsWorld) -> f64 {
        let q = self.unclamped(world);
        match self.limit {
            Some([lo, hi]) => q.clamp(lo, hi),
            None => q,
        }
    }

    fn unclamped(&self, world: &PhysicsWorld) -> f64 {
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

/// Half extents of a finger pad of a gripper that grasps by friction: 2 cm wide, 1 cm thick
/// (along the closing axis), 5 cm long, hanging below the tool's face.
pub const FINGER_HALF_EXTENTS: [f32; 3] = [0.01, 0.005, 0.025];
/// The most force (N) each pad's motor presses with (a Franka hand grips with up to 70 N for
/// both fingers). The controller drives the pads 5 mm inside what they close on, so they press
/// with about `PAD_STIFFNESS` × 5 mm = 10 N each, within this bound.
pub const GRIP_FORCE: f32 = 20.0;
/// Stiffness (N/m) and damping (N s/m) of each pad's position motor.
const PAD_STIFFNESS: f32 = 2000.0;
const PAD_DAMPING: f32 = 60.0;
/// Mass of a pad (kg).
const PAD_MASS: f32 = 0.05;
/// Friction of the finger pads (rubber).
pub const FINGER_FRICTION: f32 = 1.2;
/// How fast the pads' target gap closes or opens (m/s).
pub const FINGER_SPEED: f32 = 0.15;

/// The two finger pads of a parallel gripper that grasps by friction: dynamic boxes below the
/// tool, each on a prismatic joint along the closing axis (the tool's y axis turned by `yaw`),
/// driven towards a gap of `target` by a position motor whose force is bounded by
/// [`GRIP_FORCE`]. Closed on an object they stop against it and press it with that force; only
/// the pads' friction holds it.
#[derive(Debug, Clone)]
pub struct Fingers {
    pub bodies: [RigidBodyHandle; 2],
    pub colliders: [ColliderHandle; 2],
    pub joints: [ImpulseJointHandle; 2],
    /// The gap the pads are driven to now: it moves towards `goal` at [`FINGER_SPEED`], so
    /// that thin pads do not tunnel into what they close on.
    pub target: f32,
    pub goal: f32,
    pub yaw: f32,
    pub max_opening: f32,
    /// The tool the pads hang from.
    pub tool: RigidBodyHandle,
}

impl Fingers {
    /// The pads' poses for the tool at `tool` (centre), the gap `opening`, the pads turned by
    /// `turn` in the world (the tool's turn, then theirs about its axis).
    pub fn poses(tool: Vec3, opening: f32, turn: Rotation) -> [Pose; 2] {
        let [_, t, h] = FINGER_HALF_EXTENTS;
        let below = -(GRIPPER_HALF_EXTENTS[2] + h);
        [-1.0f32, 1.0].map(|s| {
            Pose::from_parts(
                tool + turn * Vec3::new(0.0, s * (opening / 2.0 + t), below),
                turn,
            )
        })
    }

    /// The gap between the pads' inner faces, measured along their closing axis (wherever the
    /// tool has turned them).
    pub fn opening(&self, world: &PhysicsWorld) -> f32 {
        let [a, b] = self.bodies.map(|h| world.bodies[h].translation());
        let axis = self.world_turn(world) * Vec3::Y;
        (b - a).dot(axis) - 2.0 * FINGER_HALF_EXTENTS[1]
    }

    /// The pads' turn about z in the world: the tool's turn plus theirs on it.
    pub fn world_yaw(&self, world: &PhysicsWorld) -> f32 {
        yaw_of(world.bodies[self.tool].rotation()) + self.yaw
    }

    /// The pads' turn in the world: the tool's, then theirs about its axis.
    pub fn world_turn(&self, world: &PhysicsWorld) -> Rotation {
        *world.bodies[self.tool].rotation() * Rotation::from_rotation_z(self.yaw)
    }

    /// Pads and joints for the tool `gripper` where it is, turned by `yaw` on it, `opening`
    /// apart.
    fn insert(
        world: &mut PhysicsWorld,
        gripper: RigidBodyHandle,
        yaw: f32,
        opening: f32,
        max_opening: f32,
        target: f32,
        colliders: Option<[ColliderHandle; 2]>,
    ) -> Self {
        let [fx, fy, fz] = FINGER_HALF_EXTENTS;
        let tool = world.bodies[gripper].translation();
        let poses = Self::poses(
            tool,
            opening,
            *world.bodies[gripper].rotation() * Rotation::from_rotation_z(yaw),
        );
        let mut bodies = Vec::new();
        let mut cols = Vec::new();
        let mut joints = Vec::new();
        for (k, (s, pose)) in [-1.0f32, 1.0].into_iter().zip(poses).enumerate() {
            let (b, c) = match colliders {
                // Turning: the same pads, moved.
                Some(cs) => {
                    let b = world.colliders[cs[k]].parent().expect("a pad has a body");
                    world.bodies[b].set_position(pose, true);
                    world.bodies[b].set_linvel(Vec3::ZERO, true);
                    world.bodies[b].set_angvel(Vec3::ZERO, true);
                    (b, cs[k])
                }
                None => world.insert(
                    RigidBodyBuilder::dynamic()
                        .pose(pose)
                        .can_sleep(false)
                        .ccd_enabled(true),
                    ColliderBuilder::cuboid(fx, fy, fz)
                        .mass(PAD_MASS)
                        .friction(FINGER_FRICTION)
                        .restitution(0.0),
                ),
            };
            let half_turn = Rotation::from_rotation_z(std::f32::consts::FRAC_PI_2);
            let below = -(GRIPPER_HALF_EXTENTS[2] + fz);
            let joint = GenericJointBuilder::new(JointAxesMask::LOCKED_PRISMATIC_AXES)
                .local_frame1(Pose::from_parts(
                    Vec3::new(0.0, 0.0, below),
                    Rotation::from_rotation_z(yaw) * half_turn,
                ))
                .local_frame2(Pose::from_rotation(half_turn))
                .limits(JointAxis::LinX, {
                    let (near, far) = (fy, max_opening / 2.0 + fy);
                    if s < 0.0 { [-far, -near] } else { [near, far] }
                })
                .motor_model(JointAxis::LinX, MotorModel::ForceBased)
                .motor_position(
                    JointAxis::LinX,
                    s * (target / 2.0 + fy),
                    PAD_STIFFNESS,
                    PAD_DAMPING,
                )
                .motor_max_force(JointAxis::LinX, GRIP_FORCE)
                .contacts_enabled(false);
            let j = world.insert_impulse_joint(gripper, b, joint);
            bodies.push(b);
            cols.push(c);
            joints.push(j);
        }
        Self {
            bodies: [bodies[0], bodies[1]],
            colliders: [cols[0], cols[1]],
            joints: [joints[0], joints[1]],
            target,
            goal: target,
            yaw,
            max_opening,
            tool: gripper,
        }
    }
}

pub struct SimScene {
    pub world: PhysicsWorld,
    pub objects: Vec<SimObject>,
    pub gripper: RigidBodyHandle,
    pub gripper_collider: ColliderHandle,
    /// Finger pads, for a parallel gripper that grasps by friction.
    pub fingers: Option<Fingers>,
    /// The arm that carries the tool, if the task has one.
    pub arm: Option<crate::arm::Arm>,
    /// The tool's commanded turn from pointing down (in the world frame: yaw, and roll and
    /// pitch that tilt it), for a policy that turns it; None: the tool keeps pointing down
    /// (the oracle, and policies of the original action space).
    pub turn_goal: Option<Rotation>,
    /// Joint targets of the arm (rad), for a policy that acts in joint space: the arm follows
    /// them instead of inverse kinematics.
    pub joint_goal: Option<Vec<f64>>,
    /// Zones: id, centre (z = 0), half extents (z = 0).
    pub zones: Vec<(String, Vec3, Vec3)>,
}

impl SimScene {
    /// One physics step, then each object's rolling friction ([`resist_rolling`]).
    pub fn step(&mut self) {
        self.world.step();
        resist_rolling(&mut self.world, &self.objects);
    }

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

    /// The tool's turn about z now (rad).
    pub fn tool_yaw(&self) -> f32 {
        yaw_of(self.world.bodies[self.gripper].rotation())
    }

    /// The tool's turn from pointing down now (world frame; the identity for a tool that has not
    /// turned).
    pub fn tool_turn(&self) -> Rotation {
        *self.world.bodies[self.gripper].rotation()
    }

    /// Where the tool goes for the command `cmd` (and [`SimScene::turn_goal`],
    /// [`SimScene::joint_goal`]): with an arm, where inverse kinematics (or the joint targets)
    /// put it, the links following at the next step; without, `cmd`. Returns its pose.
    pub fn drive_arm(&mut self, cmd: Vec3) -> Pose {
        let dt = self.world.integration_parameters.dt;
        let (at, turn) = match &mut self.arm {
            Some(arm) => {
                let at = match &self.joint_goal {
                    Some(goal) => arm.follow_joints(goal, f64::from(dt)),
                    None => arm.reach_turned(cmd, self.turn_goal),
                };
                arm.move_links(&mut self.world);
                // The tool turns with the arm's wrist only for a policy that turns it.
                let turn = (self.turn_goal.is_some() || self.joint_goal.is_some())
                    .then(|| arm.tool_turn());
                (at, turn)
            }
            None => (cmd, self.turn_goal),
        };
        Pose::from_parts(at, turn.unwrap_or(Rotation::IDENTITY))
    }

    /// Drives the finger pads towards a gap of `goal` (m); they stop against what lies
    /// between them.
    pub fn set_finger_target(&mut self, goal: f32) {
        if let Some(f) = &mut self.fingers {
            f.goal = goal;
        }
    }

    /// Before each physics step: the pads' motor target a step closer to their goal.
    pub fn drive_fingers(&mut self) {
        let dt = self.world.integration_parameters.dt;
        let Some(f) = &mut self.fingers else { return };
        if f.target == f.goal {
            return;
        }
        let step = FINGER_SPEED * dt;
        f.target += (f.goal - f.target).clamp(-step, step);
        let fy = FINGER_HALF_EXTENTS[1];
        for (s, j) in [-1.0f32, 1.0].into_iter().zip(f.joints) {
            if let Some(joint) = self.world.impulse_joints.get_mut(j, true) {
                joint.data.set_motor_position(
                    JointAxis::LinX,
                    s * (f.target / 2.0 + fy),
                    PAD_STIFFNESS,
                    PAD_DAMPING,
                );
            }
        }
    }

    /// Turns the open finger pads to `yaw` about the tool's axis (between grasps).
    pub fn turn_fingers(&mut self, yaw: f32) {
        let Some(f) = self.fingers.clone() else {
            return;
        };
        for j in f.joints {
            self.world.remove_impulse_joint(j);
        }
        let opening = f.opening(&self.world);
        let goal = f.goal;
        self.fingers = Some(Fingers::insert(
            &mut self.world,
            self.gripper,
            yaw,
            opening,
            f.max_opening,
            f.target,
            Some(f.colliders),
        ));
        self.set_finger_target(goal);
    }

    /// Every moving joint's position of object `o`, by name.
    pub fn joint_positions(&self, o: &SimObject) -> std::collections::BTreeMap<String, f64> {
        o.joints
            .iter()
            .map(|j| (j.name.clone(), j.position(&self.world)))
            .collect()
    }
}

fn to_pose(p: &assay_spec::urdf::Pose) -> Pose {
    let [x, y, z] = p.translation.map(|c| c as f32);
    let [qx, qy, qz, qw] = p.rotation.map(|c| c as f32);
    Pose::from_parts(Vec3::new(x, y, z), Rotation::from_xyzw(qx, qy, qz, qw))
}

/// A URDF collision part as rapier shapes and their poses in the frame the part is placed in
/// (a mesh: its convex hull, as PyBullet takes a mesh of a moving body, and the hull's
/// [`face_plates`]).
fn urdf_part(
    part: &assay_spec::urdf::PlacedPart,
    mesh: Option<&assay_spec::scene::TriangleMesh>,
    k: usize,
    path: &str,
) -> Result<Vec<(Pose, SharedShape)>, SimError> {
    let pose = to_pose(&part.pose);
    Ok(match &part.geometry {
        Geometry::Box { size } => {
            let h = v3(*size) / 2.0;
            vec![(pose, SharedShape::cuboid(h.x, h.y, h.z))]
        }
        Geometry::Sphere { radius } => vec![(pose, SharedShape::ball(*radius as f32))],
        // URDF cylinders stand on their local z; rapier's on y.
        Geometry::Cylinder { radius, length } => vec![(
            pose * Pose::new(Vec3::ZERO, Vec3::new(std::f32::consts::FRAC_PI_2, 0.0, 0.0)),
            SharedShape::cylinder(*length as f32 / 2.0, *radius as f32),
        )],
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
            let mut parts = face_plates(&hull);
            parts.insert(0, (Pose::IDENTITY, hull));
            parts.into_iter().map(|(p, s)| (pose * p, s)).collect()
        }
    })
}

/// Thickness (m) of a [`face_plates`] plate.
const PLATE_THICKNESS: f32 = 0.0005;

/// Thin boxes flush inside the faces of convex hull `hull` that have more than four corners.
/// parry builds a contact between two faces from at most four corners of each, the first four
/// in order (`ConvexPolyhedron::local_support_feature`, a TODO there): a hull resting on a
/// many-sided face (a kit piece's 128-sided base) touches the table along one short stretch of
/// its rim and rocks for ever (2-6°, measured on GenSim's kit pieces), where PyBullet clips the
/// whole face and it rests. Each such face gets a plate, the largest rectangle about the
/// middle of the face that fits in it (8 orientations tried) and 0.5 mm thick, whose four
/// corners make the contact span the face. The plates lie inside the hull: the shape is
/// unchanged.
fn face_plates(hull: &SharedShape) -> Vec<(Pose, SharedShape)> {
    let Some(poly) = hull.as_convex_polyhedron() else {
        return Vec::new();
    };
    let mut plates = Vec::new();
    for face in poly.faces() {
        let (first, n) = (
            face.first_vertex_or_edge as usize,
            face.num_vertices_or_edges as usize,
        );
        if n <= 4 {
            continue;
        }
        let corners: Vec<Vec3> = poly.vertices_adj_to_face()[first..first + n]
            .iter()
            .map(|&v| poly.points()[v as usize])
            .collect();
        let normal = face.normal;
        // Which side of each edge the inside is.
        let mean = corners.iter().copied().sum::<Vec3>() / n as f32;
        let side = |q: Vec3, i: usize| {
            let (a, b) = (corners[i], corners[(i + 1) % n]);
            (b - a).cross(q - a).dot(normal)
        };
        let turn = (0..n).map(|i| side(mean, i)).sum::<f32>().signum();
        let inside = |q: Vec3| (0..n).all(|i| side(q, i) * turn >= -1e-9);
        let base = Rotation::from_rotation_arc(Vec3::Z, normal);
        let mut best: Option<(f32, Pose, Vec3)> = None;
        for k in 0..8 {
            let frame =
                base * Rotation::from_rotation_z(k as f32 * std::f32::consts::FRAC_PI_2 / 8.0);
            let (u, v) = (frame * Vec3::X, frame * Vec3::Y);
            let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
            for c in &corners {
                let d = [(*c - mean).dot(u), (*c - mean).dot(v)];
                for j in 0..2 {
                    lo[j] = lo[j].min(d[j]);
                    hi[j] = hi[j].max(d[j]);
                }
            }
            let centre = mean + u * (lo[0] + hi[0]) / 2.0 + v * (lo[1] + hi[1]) / 2.0;
            let half = [(hi[0] - lo[0]) / 2.0, (hi[1] - lo[1]) / 2.0];
            let fits = |s: f32| {
                [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)]
                    .iter()
                    .all(|(a, b)| inside(centre + u * (a * s * half[0]) + v * (b * s * half[1])))
            };
            let (mut s0, mut s1) = (0.0f32, 1.0f32);
            if fits(1.0) {
                s0 = 1.0;
            } else {
                for _ in 0..20 {
                    let m = (s0 + s1) / 2.0;
                    if fits(m) { s0 = m } else { s1 = m }
                }
            }
            let area = s0 * s0 * half[0] * half[1];
            if area > best.as_ref().map_or(0.0, |b| b.0) {
                let pose = Pose::from_parts(centre - normal * (PLATE_THICKNESS / 2.0), frame);
                best = Some((
                    area,
                    pose,
                    Vec3::new(s0 * half[0], s0 * half[1], PLATE_THICKNESS / 2.0),
                ));
            }
        }
        if let Some((_, pose, h)) = best
            && h.x > PLATE_THICKNESS
            && h.y > PLATE_THICKNESS
        {
            plates.push((pose, SharedShape::cuboid(h.x, h.y, h.z)));
        }
    }
    plates
}

/// One rigid body of an articulated object: its frame in the object's frame and its parts.
struct LinkBody {
    frame: Pose,
    parts: Vec<(Pose, SharedShape)>,
}

/// The bodies and joints of an articulated URDF object whose root body is `root`: links joined by fixed
/// joints share a body; every revolute, continuous or prismatic joint joins two bodies with a
/// rapier joint that has the URDF's limits and resists motion with its `<dynamics friction>`.
fn insert_articulated(
    world: &mut PhysicsWorld,
    a: &assay_spec::urdf::Assembled,
    root: RigidBodyHandle,
    mass: f32,
    sleeping: bool,
    joints: &std::collections::BTreeMap<String, f64>,
    path: &str,
) -> Result<Vec<SimJoint>, SimError> {
    use assay_spec::urdf::JointKind;
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
        let b = &mut bodies[body_of[part.link]];
        for (p, shape) in urdf_part(part, mesh.as_ref(), k, path)? {
            b.parts.push((b.frame.inverse() * p, shape));
        }
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
            * to_pose(&assay_spec::urdf::Pose::from_origin(&joint.origin));
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
    world.integration_parameters.normalized_prediction_distance = PREDICTION_DISTANCE;
    // rapier recycles a touching pair's contacts (keeps its points and normal, frozen in the
    // world) until the pair has moved 5 cm or turned 11° since it was last computed: a default
    // for metre-sized game objects. On a tabletop of 4 cm blocks and balls that freezes every
    // contact that matters — a ball rolling off a rim kept the normal of where it was, a
    // container tilted on stale points stayed tilted. Every contact is computed every step.
    world.integration_parameters.contact_recycling = false;
    world
}

/// How far apart (m) two shapes start to be predicted to touch. rapier's default, 2 cm, is made
/// for metre-sized game objects: on a tabletop of 4 cm blocks, a carried block lowered 1 cm
/// beside another built "contacts" across the gap that shoved the standing block into the one
/// below it (GenSim's pyramids and bridges, issue 25). 5 mm keeps contacts ahead of a body moving
/// at the tool's 0.8 m/s over a 1/240 s step (3.3 mm).
const PREDICTION_DISTANCE: f32 = 0.005;

/// A collider, the half extents of its box, (containers) inner half extents and wall, and
/// (URDF objects) the assembled URDF.
type BuiltShape = (
    ColliderBuilder,
    Vec3,
    Option<(Vec3, f32)>,
    Option<assay_spec::urdf::Assembled>,
);

/// The V-HACD decomposition of a mesh, computed once per file and scale in a process (it takes
/// far longer than building a scene).
fn decomposition(
    file: &std::path::Path,
    scale: f32,
    points: &[Vec3],
    triangles: &[[u32; 3]],
) -> SharedShape {
    type Cache =
        std::sync::Mutex<std::collections::HashMap<(std::path::PathBuf, u32), SharedShape>>;
    static CACHE: std::sync::OnceLock<Cache> = std::sync::OnceLock::new();
    let key = (file.to_path_buf(), scale.to_bits());
    let cache = CACHE.get_or_init(Default::default);
    if let Some(shape) = cache.lock().expect("decomposition cache").get(&key) {
        return shape.clone();
    }
    let shape = SharedShape::convex_decomposition(points, triangles);
    cache
        .lock()
        .expect("decomposition cache")
        .insert(key, shape.clone());
    shape
}

/// Whether `link` is joined to `ancestor` by fixed joints only.
fn fixed_to(urdf: &assay_spec::urdf::Urdf, link: usize, ancestor: usize) -> bool {
    let mut l = link;
    while l != ancestor {
        match urdf.joints.iter().find(|j| j.child == l) {
            Some(j) if j.kind == assay_spec::urdf::JointKind::Fixed => l = j.parent,
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
            fill,
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
            let a = assay_spec::urdf::assemble_filled(&full, fill, &frame_at, joints)
                .map_err(|e| SimError::spec(format!("{path}.urdf"), e))?;
            let root = a.urdf.root();
            let mut parts: Vec<(Pose, SharedShape)> = Vec::new();
            for (k, (part, mesh)) in a.collisions.iter().enumerate() {
                // An articulated object's root body holds the root link and what is fixed to
                // it; its moving links become bodies of their own (`insert_articulated`).
                if *articulated && !fixed_to(&a.urdf, part.link, root) {
                    continue;
                }
                parts.extend(urdf_part(part, mesh.as_ref(), k, path)?);
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
        Shape::Mesh {
            path: file,
            scale,
            collision,
        } => {
            let full = spec
                .resolve_asset(file)
                .map_err(|e| SimError::spec(format!("{path}.mesh.path"), e))?;
            let text = assay_spec::assets::read_to_string(&full).map_err(|e| {
                SimError::spec(
                    format!("{path}.mesh.path"),
                    format!("cannot read {}: {e}", full.display()),
                )
            })?;
            let mesh = assay_spec::scene::parse_obj(&text).map_err(|e| {
                SimError::spec(
                    format!("{path}.mesh.path"),
                    format!("{}: {e}", full.display()),
                )
            })?;
            let s = *scale as f32;
            let points: Vec<Vec3> = mesh
                .vertices
                .iter()
                .map(|v| Vec3::new(v[0], v[1], v[2]) * s)
                .collect();
            let shape = match collision {
                MeshCollision::Hull => SharedShape::convex_hull(&points).map(|hull| {
                    let plates = face_plates(&hull);
                    if plates.is_empty() {
                        hull
                    } else {
                        SharedShape::compound(
                            std::iter::once((Pose::IDENTITY, hull))
                                .chain(plates)
                                .collect(),
                        )
                    }
                }),
                MeshCollision::Decomposition if !mesh.triangles.is_empty() => {
                    Some(decomposition(&full, s, &points, &mesh.triangles))
                }
                MeshCollision::Decomposition => {
                    return Err(SimError::spec(
                        format!("{path}.mesh.collision"),
                        format!("{} has no faces to decompose", full.display()),
                    ));
                }
            };
            let shape = shape.ok_or_else(|| {
                SimError::spec(
                    format!("{path}.mesh.path"),
                    format!("{} has no usable vertices", full.display()),
                )
            })?;
            let (lo, hi) = points.iter().fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            );
            (ColliderBuilder::new(shape), (hi - lo) / 2.0, None, None)
        }
    })
}

/// Bullet's rolling friction, after the step: where an object that declares a rolling friction
/// (GenSim's URDFs: 0.0001 m) touches another body, its rolling (its turn relative to the other
/// body about axes in the contact plane) is resisted by an angular impulse about the contact
/// point of at most `μ_r · J_n`, J_n the contact's normal impulse over the step, with Bullet's
/// combined coefficient `μ_r = r_a · f_b + r_b · f_a` (r: rolling friction, f: sliding
/// friction; Assay's objects share one f). rapier has no rolling friction: without it a ball on a
/// top that its weight tilts by a tenth of a degree (rapier's contacts are springs) rolls off,
/// where PyBullet's holds still on slopes up to `μ_r / r` (0.19° for a 3 cm ball; measured with
/// PyBullet 3.2.7 on GenSim's plane: still at 0.15°, rolling at 0.25°).
///
/// Bullet solves the rolling constraint together with the sliding friction, so a body rolling
/// without slipping loses turn and speed together (inertia about the contact point, `I + m d²`,
/// d from its centre to the contact: half its height, a ball's radius). Done after rapier's step,
/// the turn and the speed it carries come off together, but never more speed than the body has
/// in the direction it rolls: a ball that spins without travelling loses spin only, as sliding
/// friction, not rolling friction, is what sets it travelling. Taking the turn alone would leave
/// the speed for the next step's friction to turn back into rolling, and a ball held by rolling
/// friction on a slight tilt would creep (about 2.5 g sin θ dt per step, 5 mm a minute at 0.1°).
pub fn resist_rolling(world: &mut PhysicsWorld, objects: &[SimObject]) {
    let rolling_of = |body: Option<RigidBodyHandle>| {
        body.and_then(|b| objects.iter().find(|o| o.body == b))
            .map_or(0.0, |o| o.rolling_friction)
    };
    for o in objects {
        if o.fixed || o.rolling_friction <= 0.0 {
            continue;
        }
        let Some(body) = world.bodies.get(o.body) else {
            continue;
        };
        if !body.is_dynamic() {
            continue;
        }
        let inertia = body.mass_properties().local_mprops.principal_inertia();
        let lever = o.half.z.max(1e-4);
        let rolling_inertia = (inertia.x + inertia.y) / 2.0 + body.mass() * lever * lever;
        if rolling_inertia <= 0.0 {
            continue;
        }
        let mut resist = Vec::new();
        for &collider in body.colliders() {
            for pair in world.narrow_phase.contact_pairs_with(collider) {
                if !pair.has_any_active_contact() {
                    continue;
                }
                let mine_first = pair.collider1 == collider;
                let other = if mine_first {
                    pair.collider2
                } else {
                    pair.collider1
                };
                let other_body = world.colliders.get(other).and_then(|c| c.parent());
                let mu = (o.rolling_friction + rolling_of(other_body)) * OBJECT_FRICTION;
                for m in pair.solver_manifolds() {
                    let impulse: f32 = m.points.iter().map(|p| p.data.impulse).sum();
                    if impulse <= 0.0 {
                        continue;
                    }
                    // rapier's normal points from the first collider to the second: the
                    // support's side, seen from the object, is the other way round.
                    let normal = if mine_first {
                        -m.data.normal
                    } else {
                        m.data.normal
                    };
                    resist.push((other_body, normal, mu * impulse));
                }
            }
        }
        for (other_body, normal, limit) in resist {
            let (support_turn, support_speed) = other_body
                .and_then(|b| world.bodies.get(b))
                .map_or((Vec3::ZERO, Vec3::ZERO), |b| (b.angvel(), b.linvel()));
            let body = &mut world.bodies[o.body];
            let relative = body.angvel() - support_turn;
            let rolling = relative - normal * relative.dot(normal);
            let turn = rolling.length();
            if turn <= 0.0 {
                continue;
            }
            let taken = (limit / rolling_inertia).min(turn);
            // The way the body travels when it rolls so, and how fast it does.
            let way = rolling.cross(normal) / turn;
            let travel = (body.linvel() - support_speed).dot(way).max(0.0);
            body.set_angvel(body.angvel() - rolling * (taken / turn), false);
            body.set_linvel(body.linvel() - way * (taken * lever).min(travel), false);
        }
    }
}

/// Samples the initial state for `seed` and builds the world. Every random draw comes from one
/// stream per (seed, task id), in spec order.
pub fn build_scene(spec: &TaskSpec, seed: u64) -> Result<SimScene, SimError> {
    // A task laid out per seed by its generator's code, on a seed it has no layout for (a
    // spec from `for_seed` keeps its layouts only then).
    if let Some(why) = spec.seed_unavailable(seed) {
        return Err(SimError::spec("layouts", why));
    }
    // In a worker, the operator's folders bound where asset files come from: a task whose own
    // asset root lies outside them fails here, naming the field, before any file is opened.
    if let Some(roots) = assay_spec::assets::roots() {
        spec.check_asset_roots(&roots)
            .map_err(|(field, reason)| SimError::spec(field, reason))?;
    }
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
            rolling_friction: urdf
                .as_ref()
                .and_then(|a| a.urdf.links.get(a.urdf.root()))
                .map_or(0.0, |l| l.rolling_friction as f32),
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
    // With an arm, the tool starts where the arm can put it, moved there from its home.
    let mut arm = match &spec.arm {
        Some(a) => Some(
            crate::arm::Arm::new(&a.model, a.base, a.base_yaw_deg)
                .map_err(|e| SimError::spec("arm.model", e))?,
        ),
        None => None,
    };
    let start = match &mut arm {
        Some(a) => {
            let at = a.settle_at(start);
            a.insert_links(&mut world);
            at
        }
        None => start,
    };
    let [gx, gy, gz] = GRIPPER_HALF_EXTENTS;
    let (gripper, gripper_collider) = world.insert(
        RigidBodyBuilder::kinematic_position_based().translation(start),
        ColliderBuilder::cuboid(gx, gy, gz).friction(OBJECT_FRICTION),
    );
    let fingers = match spec.end_effector {
        assay_spec::spec::EndEffector::ParallelGripper {
            max_opening,
            grasp: assay_spec::spec::Grasp::Friction,
        } => {
            let max = max_opening as f32;
            Some(Fingers::insert(
                &mut world, gripper, 0.0, max, max, max, None,
            ))
        }
        _ => None,
    };
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
        fingers,
        arm,
        zones,
        turn_goal: None,
        joint_goal: None,
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
