//! A robot arm from URDF that carries the tool: every step, damped-least-squares inverse
//! kinematics turns the commanded tool position into joint positions (the tool pointing straight
//! down, or turned as a policy commands: yaw, roll and pitch), the links follow as kinematic
//! bodies that collide with the scene, and the tool goes where the arm actually put it — a
//! command out of reach is not met.

use std::collections::BTreeMap;

use assay_spec::urdf::{Geometry, JointKind, Pose as UPose, Urdf};
use rapier3d::prelude::*;

use crate::tabletop::{GRIPPER_HALF_EXTENTS, OBJECT_FRICTION};

/// A built-in arm.
struct Model {
    name: &'static str,
    urdf: &'static str,
    /// The link the tool is mounted on.
    flange: &'static str,
    /// The axis of the flange's parent link the tool points along.
    tool_axis: [f32; 3],
    /// Joint positions the arm starts from, the tool pointing down over the table.
    home: &'static [f64],
}

const ARMS: &[Model] = &[
    Model {
        name: "ur5",
        urdf: include_str!("../robots/ur5.urdf"),
        flange: "flange",
        tool_axis: [0.0, 1.0, 0.0],
        home: &[0.0, -1.2, 1.9, -2.27, -std::f64::consts::FRAC_PI_2, 0.0],
    },
    Model {
        name: "panda",
        urdf: include_str!("../robots/panda.urdf"),
        flange: "flange",
        tool_axis: [0.0, 0.0, 1.0],
        home: &[0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785],
    },
];

/// The names of the built-in arms.
pub fn models() -> Vec<&'static str> {
    ARMS.iter().map(|a| a.name).collect()
}

/// Iterations of the solver per physics step (warm-started from the last step's solution).
const IK_ITERATIONS: usize = 12;
/// Damping of the least-squares step (m or rad).
const IK_DAMPING: f64 = 0.02;
/// Largest change of one joint per iteration (rad).
const IK_MAX_STEP: f64 = 0.15;

pub struct Arm {
    pub model: &'static str,
    urdf: Urdf,
    /// The moving joints from the root to the flange, in order (indices into `urdf.joints`).
    chain: Vec<usize>,
    flange: usize,
    /// The flange's parent link, and the axis in its frame the tool points along.
    wrist: usize,
    tool_axis: Vec3,
    /// The arm's base in the world.
    base: Pose,
    /// Joint positions along `chain`.
    pub q: Vec<f64>,
    /// One kinematic body per link with geometry, with its link index.
    bodies: Vec<(usize, RigidBodyHandle)>,
    pub colliders: Vec<ColliderHandle>,
    /// Each link's boxes: (link, pose in the link's frame, half extents).
    boxes: Vec<(usize, UPose, [f32; 3])>,
    /// The wrist's orientation where the episode's tool started (pointing down): the tool's
    /// turn is measured from it.
    wrist0: Rotation,
}

/// Fastest a joint follows a joint-position target (rad/s).
pub const MAX_JOINT_SPEED: f64 = 2.0;

/// Solves `a x = b` for a 6 × 6 system by Gaussian elimination with partial pivoting.
fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    for c in 0..6 {
        let p = (c..6).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-12 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let pivot = a[c];
        for r in c + 1..6 {
            let f = a[r][c] / pivot[c];
            for (x, p) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * p;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 6];
    for r in (0..6).rev() {
        let s: f64 = (r + 1..6).map(|k| a[r][k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    Some(x)
}

fn to_pose(p: &UPose) -> Pose {
    let [x, y, z] = p.translation.map(|c| c as f32);
    let [qx, qy, qz, qw] = p.rotation.map(|c| c as f32);
    Pose::from_parts(Vec3::new(x, y, z), Rotation::from_xyzw(qx, qy, qz, qw))
}

impl Arm {
    /// The built-in arm `model` with its base at `base` (position, yaw in degrees), at its home
    /// configuration, not yet in a world.
    pub fn new(model: &str, base: [f64; 3], yaw_deg: f64) -> Result<Self, String> {
        let m = ARMS
            .iter()
            .find(|a| a.name == model)
            .ok_or_else(|| format!("unknown arm '{model}' (built in: {})", models().join(", ")))?;
        let (name, text, flange_name, home) = (&m.name, m.urdf, &m.flange, m.home);
        let urdf = assay_spec::urdf::parse(text).map_err(|e| format!("arm '{name}': {e}"))?;
        let flange = urdf
            .links
            .iter()
            .position(|l| l.name == *flange_name)
            .ok_or_else(|| format!("arm '{name}': no link '{flange_name}'"))?;
        // Walk from the flange up to the root.
        let mut chain = Vec::new();
        let mut link = flange;
        let mut wrist = flange;
        while let Some(j) = urdf.joints.iter().position(|j| j.child == link) {
            if link == flange {
                wrist = urdf.joints[j].parent;
            }
            if urdf.joints[j].kind != JointKind::Fixed {
                chain.push(j);
            }
            link = urdf.joints[j].parent;
        }
        chain.reverse();
        if chain.len() != home.len() {
            return Err(format!(
                "arm '{name}': home has {} joints, the chain {}",
                home.len(),
                chain.len()
            ));
        }
        let mut boxes = Vec::new();
        for (l, lk) in urdf.links.iter().enumerate() {
            for v in &lk.visuals {
                if let Geometry::Box { size } = v.geometry {
                    boxes.push((
                        l,
                        UPose::from_origin(&v.origin),
                        size.map(|s| s as f32 / 2.0),
                    ));
                }
            }
        }
        let base = Pose::new(
            Vec3::new(base[0] as f32, base[1] as f32, base[2] as f32),
            Vec3::new(0.0, 0.0, (yaw_deg as f32).to_radians()),
        );
        Ok(Self {
            model: name,
            urdf,
            chain,
            flange,
            wrist,
            tool_axis: Vec3::from(m.tool_axis),
            base,
            q: home.to_vec(),
            bodies: Vec::new(),
            colliders: Vec::new(),
            boxes,
            wrist0: Rotation::IDENTITY,
        })
    }

    /// Puts the links into `world` as kinematic bodies where the current joint positions put
    /// them.
    pub fn insert_links(&mut self, world: &mut PhysicsWorld) {
        let poses = self.link_poses();
        let links: std::collections::BTreeSet<usize> = self.boxes.iter().map(|b| b.0).collect();
        for l in links {
            let parts: Vec<(Pose, SharedShape)> = self
                .boxes
                .iter()
                .filter(|b| b.0 == l)
                .map(|(_, p, h)| (to_pose(p), SharedShape::cuboid(h[0], h[1], h[2])))
                .collect();
            let (b, c) = world.insert(
                RigidBodyBuilder::kinematic_position_based().pose(poses[l]),
                ColliderBuilder::compound(parts).friction(OBJECT_FRICTION),
            );
            self.bodies.push((l, b));
            self.colliders.push(c);
        }
    }

    /// Moves the tool's centre from where it is to `target` in small steps (for the start of an
    /// episode: from home to the tool's start); returns where it got.
    pub fn settle_at(&mut self, target: Vec3) -> Vec3 {
        let from = self.tool_position();
        let steps = (from.distance(target) / 0.005).ceil().max(1.0) as usize;
        for k in 1..=steps {
            self.reach(from.lerp(target, k as f32 / steps as f32));
        }
        for _ in 0..20 {
            self.reach(target);
        }
        self.wrist0 = self.link_poses()[self.wrist].rotation;
        self.tool_position()
    }

    /// The tool's turn from where the episode's tool started, in the world frame: the rotation
    /// that takes the starting wrist onto the wrist now (the tool's yaw is its turn about z).
    pub fn tool_turn(&self) -> Rotation {
        (self.link_poses()[self.wrist].rotation * self.wrist0.inverse()).normalize()
    }

    /// Moves every joint towards `goal` (rad, along the chain; clamped to its limits) by at most
    /// [`MAX_JOINT_SPEED`] · `dt`; returns the tool's centre there.
    pub fn follow_joints(&mut self, goal: &[f64], dt: f64) -> Vec3 {
        let step = MAX_JOINT_SPEED * dt;
        for (k, &j) in self.chain.iter().enumerate() {
            let Some(&g) = goal.get(k) else { break };
            let (lo, hi) = self.urdf.joints[j]
                .limit
                .map_or((f64::MIN, f64::MAX), |l| (l[0], l[1]));
            let g = g.clamp(lo, hi);
            self.q[k] += (g - self.q[k]).clamp(-step, step);
        }
        self.tool_position()
    }

    /// The joint positions, along the chain (rad).
    pub fn joints(&self) -> &[f64] {
        &self.q
    }

    /// [`Arm::reach`], also turning the tool by `turn` (from where it started, in the world
    /// frame; see [`Arm::tool_turn`]) when given.
    pub fn reach_turned(&mut self, target: Vec3, turn: Option<Rotation>) -> Vec3 {
        self.solve(target, turn)
    }

    fn positions(&self, q: &[f64]) -> BTreeMap<String, f64> {
        self.chain
            .iter()
            .zip(q)
            .map(|(&j, &x)| (self.urdf.joints[j].name.clone(), x))
            .collect()
    }

    /// Every link's pose in the world at the current joint positions.
    pub fn link_poses(&self) -> Vec<Pose> {
        self.world_poses(&self.q)
    }

    fn world_poses(&self, q: &[f64]) -> Vec<Pose> {
        self.urdf
            .link_poses(&self.positions(q))
            .expect("joint positions are kept within limits")
            .iter()
            .map(|p| self.base * to_pose(p))
            .collect()
    }

    /// Where the tool's centre is with the arm at its current joint positions.
    pub fn tool_position(&self) -> Vec3 {
        let poses = self.link_poses();
        let flange = poses[self.flange].translation;
        let down = poses[self.wrist].rotation * self.tool_axis;
        flange + down * GRIPPER_HALF_EXTENTS[2]
    }

    /// Solves for joint positions that put the tool's centre at `target`, pointing down, from the
    /// current ones; keeps the best it finds within the limits. Returns the tool's centre there.
    pub fn reach(&mut self, target: Vec3) -> Vec3 {
        self.solve(target, None)
    }

    fn solve(&mut self, target: Vec3, turn: Option<Rotation>) -> Vec3 {
        // The tool's axis and the wrist's heading axis (its x, across the tool) as wanted: down
        // and free about z without a turn; else the start's turned by it.
        let (axis, across) = match turn {
            Some(r) => (r * -Vec3::Z, Some(r * (self.wrist0 * Vec3::X))),
            None => (-Vec3::Z, None),
        };
        let flange_target = target - axis * GRIPPER_HALF_EXTENTS[2];
        let t = [flange_target.x, flange_target.y, flange_target.z].map(f64::from);
        let n = self.chain.len();
        let mut q = self.q.clone();
        for _ in 0..IK_ITERATIONS {
            let poses = self.world_poses(&q);
            let p = poses[self.flange].translation;
            let a = poses[self.wrist].rotation * self.tool_axis;
            // Position error, and the rotation that turns the tool's axis onto the wanted one.
            let ep = [
                t[0] - f64::from(p.x),
                t[1] - f64::from(p.y),
                t[2] - f64::from(p.z),
            ];
            let mut er = a.cross(axis);
            // Pointing down its part along the axis is 0: the turn about the axis goes there —
            // the signed angle from the wrist's heading axis (across the tool, laid into the
            // plane across the wanted axis) to the wanted one.
            if let Some(want) = across {
                let x = poses[self.wrist].rotation * Vec3::X;
                let x = (x - axis * x.dot(axis)).normalize_or_zero();
                let twist = x.cross(want).dot(axis).atan2(x.dot(want));
                er += axis * twist;
            }
            let e = [
                ep[0],
                ep[1],
                ep[2],
                f64::from(er.x),
                f64::from(er.y),
                f64::from(er.z),
            ];
            let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm(&e[..3]) < 1e-5 && norm(&e[3..]) < 1e-4 {
                break;
            }
            // Columns of the Jacobian: [w × (p − o); w] per revolute joint.
            let mut jac: Vec<[f64; 6]> = Vec::with_capacity(n);
            for &j in &self.chain {
                let joint = &self.urdf.joints[j];
                let frame = poses[joint.parent] * to_pose(&UPose::from_origin(&joint.origin));
                let w = frame.rotation
                    * Vec3::new(
                        joint.axis[0] as f32,
                        joint.axis[1] as f32,
                        joint.axis[2] as f32,
                    );
                let lin = w.cross(p - frame.translation);
                jac.push([lin.x, lin.y, lin.z, w.x, w.y, w.z].map(f64::from));
            }
            // Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ e
            let mut a = [[0.0f64; 6]; 6];
            for (r, row) in a.iter_mut().enumerate() {
                for (c, x) in row.iter_mut().enumerate() {
                    *x = jac.iter().map(|col| col[r] * col[c]).sum::<f64>()
                        + if r == c { IK_DAMPING * IK_DAMPING } else { 0.0 };
                }
            }
            let Some(y) = solve6(a, e) else { break };
            let dq: Vec<f64> = jac
                .iter()
                .map(|col| col.iter().zip(&y).map(|(c, y)| c * y).sum())
                .collect();
            for (k, &j) in self.chain.iter().enumerate() {
                let step = dq[k].clamp(-IK_MAX_STEP, IK_MAX_STEP);
                let (lo, hi) = self.urdf.joints[j]
                    .limit
                    .map_or((f64::MIN, f64::MAX), |l| (l[0], l[1]));
                q[k] = (q[k] + step).clamp(lo, hi);
            }
        }
        self.q = q;
        self.tool_position()
    }

    /// Sends every link's body to where the current joint positions put it (at the next step).
    pub fn move_links(&self, world: &mut PhysicsWorld) {
        let poses = self.link_poses();
        for (l, b) in &self.bodies {
            world.bodies[*b].set_next_kinematic_position(poses[*l]);
        }
    }

    /// The moving joints' names, along the chain.
    pub fn joint_names(&self) -> Vec<String> {
        self.chain
            .iter()
            .map(|&j| self.urdf.joints[j].name.clone())
            .collect()
    }

    /// The links' boxes in the world at joint positions `q` (for drawing).
    pub fn boxes_at(&self, q: &[f64]) -> Vec<assay_spec::scene::SnapshotBox> {
        let poses = self.world_poses(q);
        self.boxes
            .iter()
            .map(|(l, p, h)| {
                let w = poses[*l] * to_pose(p);
                assay_spec::scene::SnapshotBox {
                    position: w.translation.into(),
                    rotation: [w.rotation.x, w.rotation.y, w.rotation.z, w.rotation.w],
                    half_extents: *h,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_arm_reaches_the_workspace_pointing_down_and_not_beyond_its_reach() {
        assert_eq!(models(), assay_spec::spec::ARM_MODELS);
        for model in models() {
            let mut arm = Arm::new(model, [0.0; 3], 0.0).unwrap();
            // Home: the tool above the table.
            let home = arm.tool_position();
            assert!(
                home.z > 0.1 && home.x > 0.2,
                "{model}: home tool at {home:?}"
            );
            // GenSim's workspace, followed in small steps as the controller commands it.
            let mut at = home;
            for target in [
                Vec3::new(0.5, 0.0, 0.3),
                Vec3::new(0.3, -0.4, 0.1),
                Vec3::new(0.7, 0.35, 0.08),
                Vec3::new(0.5, 0.2, 0.5),
            ] {
                for k in 1..=200 {
                    let t = at.lerp(target, k as f32 / 200.0);
                    arm.reach(t);
                }
                at = target;
                let got = arm.tool_position();
                assert!(
                    got.distance(target) < 1e-3,
                    "{model} {target:?}: the tool at {got:?}"
                );
                let poses = arm.link_poses();
                let down = poses[arm.wrist].rotation * arm.tool_axis;
                assert!(
                    down.dot(-Vec3::Z) > 0.999,
                    "{model} {target:?}: tool axis {down:?}"
                );
            }
            // 1.5 m away is out of reach (0.85 m for both): the tool stops short.
            for k in 1..=200 {
                arm.reach(at.lerp(Vec3::new(1.5, 0.0, 0.1), k as f32 / 200.0));
            }
            let got = arm.tool_position();
            assert!(got.x < 1.0, "{model}: the tool reached {got:?}");
        }
    }
}
