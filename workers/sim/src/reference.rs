//! The peer-benchmark reference scene (`shared/bench/peers/reference-scene.json`) rebuilt in
//! rapier3d: ten 5 cm boxes on a plane and a kinematic 4 × 4 × 10 cm tool, dt 1/240. Used by
//! `assay bench` to compare with MuJoCo and PyBullet running the same contract.

use assay_spec::scene::{SceneSnapshot, SnapshotObject};
use assay_spec::spec::{Camera, Shape, Surface};
use rapier3d::prelude::*;
use serde::Deserialize;

use crate::SimError;
use crate::record::contact_summary;
use crate::scene::{OBJECT_FRICTION, SimObject, SimScene, new_world};

/// The tool's path as the contract states it; the file is checked to say exactly this.
pub const PATH_PYTHON: &str = "x=0.5+0.2*sin(2*pi*t/3.3); y=0.17*sin(2*pi*t/5.0); z=0.06+0.025*(1+cos(2*pi*t/2.0)), t=step*dt";

#[derive(Debug, Clone, Deserialize)]
pub struct Contract {
    pub dt: f64,
    pub gravity: [f64; 3],
    pub boxes: Boxes,
    pub gripper: Gripper,
    pub measurement: Measurement,
    pub rollout: Rollout,
    pub camera: ContractCamera,
}

#[derive(Debug, Clone, Deserialize)]
pub struct ContractCamera {
    pub eye: [f64; 3],
    pub target: [f64; 3],
    pub fovy_deg: f64,
    pub width: u32,
    pub height: u32,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Boxes {
    pub half_extent_m: f64,
    pub mass_kg: f64,
    pub positions: Vec<[f64; 3]>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Gripper {
    pub half_extents_m: [f64; 3],
    pub park: [f64; 3],
    pub path_python: String,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Measurement {
    pub settle_steps: u32,
    pub timed_steps: u32,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Rollout {
    pub steps_per_action: u32,
    pub actions: u32,
    pub pick_order: Vec<usize>,
    pub targets: Vec<[f64; 3]>,
    pub z_safe: f64,
    pub reset_settle_steps: u32,
    pub attach_step: u32,
    pub release_step: u32,
    pub place_clearance_m: f64,
    pub success_tolerance_m: f64,
    pub render_after_actions: Vec<u32>,
    pub segments: Vec<(u32, u32, String, String)>,
}

impl Contract {
    pub fn parse(text: &str) -> Result<Self, SimError> {
        let c: Contract = serde_json::from_str(text)
            .map_err(|e| SimError::spec("reference-scene.json", e.to_string()))?;
        if c.gripper.path_python != PATH_PYTHON {
            return Err(SimError::spec(
                "gripper.path_python",
                format!("this build implements '{PATH_PYTHON}'"),
            ));
        }
        Ok(c)
    }

    /// The tool centre at time `t` on its Lissajous path.
    pub fn path(t: f64) -> Vec3 {
        use std::f64::consts::PI;
        let x = 0.5 + 0.2 * (2.0 * PI * t / 3.3).sin();
        let y = 0.17 * (2.0 * PI * t / 5.0).sin();
        let z = 0.06 + 0.025 * (1.0 + (2.0 * PI * t / 2.0).cos());
        Vec3::new(x as f32, y as f32, z as f32)
    }

    /// A fresh world in the contract's initial state.
    pub fn build(&self) -> SimScene {
        let mut world = new_world(self.dt as f32);
        world.gravity = Vec3::new(
            self.gravity[0] as f32,
            self.gravity[1] as f32,
            self.gravity[2] as f32,
        );
        world.insert(
            RigidBodyBuilder::fixed(),
            ColliderBuilder::halfspace(nalgebra::Unit::new_unchecked(Vector::Z))
                .friction(OBJECT_FRICTION),
        );
        let h = self.boxes.half_extent_m as f32;
        let objects = self
            .boxes
            .positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let (body, _) = world.insert(
                    RigidBodyBuilder::dynamic().translation(Vec3::new(
                        p[0] as f32,
                        p[1] as f32,
                        p[2] as f32,
                    )),
                    ColliderBuilder::cuboid(h, h, h)
                        .mass(self.boxes.mass_kg as f32)
                        .friction(OBJECT_FRICTION),
                );
                SimObject {
                    id: format!("box{i}"),
                    body,
                    half: Vec3::splat(h),
                    fixed: false,
                    container: None,
                    joints: Vec::new(),
                    rolling_friction: 0.0,
                }
            })
            .collect();
        let g = self.gripper.half_extents_m;
        let park = self.gripper.park;
        let (gripper, gripper_collider) = world.insert(
            RigidBodyBuilder::kinematic_position_based().translation(Vec3::new(
                park[0] as f32,
                park[1] as f32,
                park[2] as f32,
            )),
            ColliderBuilder::cuboid(g[0] as f32, g[1] as f32, g[2] as f32)
                .friction(OBJECT_FRICTION),
        );
        SimScene {
            world,
            objects,
            gripper,
            gripper_collider,
            fingers: None,
            arm: None,
            zones: Vec::new(),
            turn_goal: None,
            joint_goal: None,
        }
    }

    fn park(&self) -> Vec3 {
        let p = self.gripper.park;
        Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)
    }
}

fn drive(scene: &mut SimScene, at: Vec3) {
    scene.world.bodies[scene.gripper].set_next_kinematic_translation(at);
    scene.world.step();
}

/// Workload of a physics trial, to check that the scenes compare (peers see about 40 contact
/// points per step).
#[derive(Debug, Clone, Copy, Default)]
pub struct Workload {
    pub contact_points_per_step: f64,
    pub gripper_contact_fraction: f64,
}

/// Resets and settles the scene (untimed); returns the scene ready for the timed steps.
pub fn physics_setup(c: &Contract) -> SimScene {
    let mut scene = c.build();
    let park = c.park();
    for _ in 0..c.measurement.settle_steps {
        drive(&mut scene, park);
    }
    scene
}

/// The timed part of a physics trial: `steps` steps with the tool on its path.
pub fn physics_run(c: &Contract, scene: &mut SimScene, steps: u32, measure: Option<&mut Workload>) {
    let (mut points, mut touching) = (0u64, 0u64);
    for step in 0..steps {
        drive(scene, Contract::path(f64::from(step) * c.dt));
        if measure.is_some() {
            let (_, p, ee) = contact_summary(scene);
            points += u64::from(p);
            touching += u64::from(ee);
        }
    }
    if let Some(w) = measure {
        w.contact_points_per_step = points as f64 / f64::from(steps);
        w.gripper_contact_fraction = touching as f64 / f64::from(steps);
    }
}

/// The contract's camera as a task-spec camera (`width` × `height`).
pub fn camera(c: &Contract, width: u32, height: u32) -> Camera {
    Camera {
        name: "reference".into(),
        eye: c.camera.eye,
        target: c.camera.target,
        fovy_deg: c.camera.fovy_deg,
        width,
        height,
        up: None,
    }
}

/// The state every timed `render` frame draws: settled with the tool parked, then settled with
/// the tool held at the start of its path.
pub fn render_state(c: &Contract) -> SimScene {
    let mut scene = physics_setup(c);
    let start = Contract::path(0.0);
    for _ in 0..c.measurement.settle_steps {
        drive(&mut scene, start);
    }
    scene
}

const PALETTE: [[f32; 3]; 5] = [
    [0.84, 0.15, 0.16],
    [0.17, 0.63, 0.17],
    [0.12, 0.47, 0.71],
    [0.93, 0.79, 0.13],
    [0.58, 0.4, 0.74],
];

/// The scene as a camera sees it (boxes coloured in turn, the plane as ground, the tool).
pub fn snapshot(scene: &SimScene) -> SceneSnapshot {
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let p = scene.pose(o);
            let h = f64::from(o.half.x);
            SnapshotObject {
                id: o.id.clone(),
                shape: Shape::Box {
                    half_extents: [h; 3],
                },
                color: PALETTE[i % PALETTE.len()],
                color_given: true,
                position: p.translation.into(),
                rotation: [p.rotation.x, p.rotation.y, p.rotation.z, p.rotation.w],
                joints: Default::default(),
            }
        })
        .collect();
    SceneSnapshot {
        surface: Surface::Ground,
        objects,
        tool: Some(scene.gripper_position().into()),
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    }
}

/// One scripted pick-and-place episode of the contract (physics only). Returns the boxes that
/// ended within the success tolerance of their targets.
pub fn rollout_episode(c: &Contract) -> usize {
    rollout_episode_with(c, &mut |_| {})
}

/// The scripted episode, calling `frame` where the contract renders: after the reset settle and
/// after each action in `render_after_actions`.
pub fn rollout_episode_with(c: &Contract, frame: &mut dyn FnMut(&SimScene)) -> usize {
    let r = &c.rollout;
    let mut scene = c.build();
    let gh = c.gripper.half_extents_m[2] as f32;
    let bh = c.boxes.half_extent_m as f32;
    let mut last = c.park();
    for _ in 0..r.reset_settle_steps {
        drive(&mut scene, last);
    }
    frame(&scene);
    for a in 0..r.actions as usize {
        let b = r.pick_order[a];
        let body = scene.objects[b].body;
        let bp = scene.world.bodies[body].translation();
        let t = r.targets[a];
        let target = Vec3::new(t[0] as f32, t[1] as f32, t[2] as f32);
        let start = last;
        let point = |name: &str| -> Vec3 {
            match name {
                "start" => start,
                "above_box" => Vec3::new(bp.x, bp.y, r.z_safe as f32),
                "grasp" => bp + Vec3::new(0.0, 0.0, gh + bh),
                "above_target" => Vec3::new(target.x, target.y, r.z_safe as f32),
                "place" => target + Vec3::new(0.0, 0.0, gh + bh + r.place_clearance_m as f32),
                other => panic!("unknown segment point '{other}' in the contract"),
            }
        };
        let mut joint = None;
        for k in 0..r.steps_per_action {
            if k == r.attach_step {
                let j = FixedJointBuilder::new()
                    .local_anchor1(Vec3::new(0.0, 0.0, -(gh + bh)))
                    .local_anchor2(Vec3::ZERO)
                    .contacts_enabled(false);
                joint = Some(scene.world.insert_impulse_joint(scene.gripper, body, j));
            }
            if k == r.release_step
                && let Some(j) = joint.take()
            {
                scene.world.remove_impulse_joint(j);
            }
            let (from, to, a_name, b_name) = r
                .segments
                .iter()
                .find(|s| k >= s.0 && k < s.1)
                .expect("segments cover the action");
            let s = (k - from + 1) as f32 / (to - from) as f32;
            let at = point(a_name).lerp(point(b_name), s);
            drive(&mut scene, at);
            last = at;
        }
        if r.render_after_actions.contains(&(a as u32)) {
            frame(&scene);
        }
    }
    r.pick_order
        .iter()
        .take(r.actions as usize)
        .zip(&r.targets)
        .filter(|(b, t)| {
            let p = scene.world.bodies[scene.objects[**b].body].translation();
            p.distance(Vec3::new(t[0] as f32, t[1] as f32, t[2] as f32))
                <= r.success_tolerance_m as f32
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONTRACT: &str = include_str!("../../../bench/reference-scene.json");

    #[test]
    fn scripted_rollout_places_every_box_and_offers_eight_frames() {
        let c = Contract::parse(CONTRACT).unwrap();
        let mut frames = 0;
        assert_eq!(rollout_episode_with(&c, &mut |_| frames += 1), 10);
        assert_eq!(frames, 8);
    }

    #[test]
    fn physics_workload_is_comparable_with_the_peers() {
        let c = Contract::parse(CONTRACT).unwrap();
        let mut scene = physics_setup(&c);
        let mut w = Workload::default();
        physics_run(&c, &mut scene, 600, Some(&mut w));
        // MuJoCo and PyBullet report about 40 contact points per step on this scene.
        assert!(w.contact_points_per_step > 15.0, "{w:?}");
        assert!(w.gripper_contact_fraction > 0.0, "{w:?}");
    }
}
