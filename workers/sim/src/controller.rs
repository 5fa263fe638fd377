//! The primitive controller: turns pick / place / push into commanded tool positions, step by
//! step, locating objects at the start of each primitive — from the live state (as a scripted
//! oracle would), or for a seeing oracle from what its camera last showed (`perception`).

use assay_spec::rng::Rng;
use assay_spec::spec::{EndEffector, PlaceTarget, Primitive, TaskSpec};
use rapier3d::prelude::*;

use crate::perception::Tracker;
use crate::placing;
use crate::scene::{GRIPPER_HALF_EXTENTS, SimScene};

/// Transit speed of the tool (m/s), descents and the push sweep.
const TRANSIT_SPEED: f32 = 0.8;
const DESCEND_SPEED: f32 = 0.25;
const PUSH_SPEED: f32 = 0.12;
/// Speed of a sweep's strokes (m/s).
const SWEEP_SPEED: f32 = 0.12;
/// The most strokes of one pass of a sweep.
const MAX_STROKES: u32 = 8;
const MIN_SEGMENT_STEPS: u32 = 20;
const DWELL_STEPS: u32 = 8;
/// How fast the tool turns what it holds (rad/s).
const TURN_SPEED: f32 = 2.0;
/// Gap left under a placed object before release (m).
const PLACE_CLEARANCE: f32 = 0.004;
/// How far the tool's face may be from an object's top and still grasp it (m).
const GRASP_REACH: f32 = 0.012;
/// How far inside a link's top edge the tool grasps it (m).
const HANDLE_INSET: f32 = 0.02;
/// Largest joint motion between two waypoints of an `actuate` (rad or m).
const ACTUATE_STEP: f64 = 0.05;
/// How far (m) inside what it grasps each finger pad of a friction gripper is driven: its motor
/// presses with `stiffness × SQUEEZE` (10 N), within its force limit.
const SQUEEZE: f32 = 0.005;

/// The yaw (rad) that closes a friction gripper's pads across object `i`'s narrower horizontal
/// side, and how wide the object is there between the pads held at `at` (the tool's position):
/// rays cast towards each other along the closing axis, across the pads' width and height, find
/// its widest part (a handle, not the ring it joins; the box when nothing is hit).
fn grip(scene: &SimScene, i: usize, at: Vec3) -> (f32, f32) {
    let o = &scene.objects[i];
    let x = scene.pose(o).rotation * Vec3::X;
    let yaw = x.y.atan2(x.x);
    let (yaw, boxed) = if o.half.y <= o.half.x {
        (yaw, 2.0 * o.half.y)
    } else {
        (yaw + std::f32::consts::FRAC_PI_2, 2.0 * o.half.x)
    };
    let turn = Rotation::from_rotation_z(yaw);
    let (across, along) = (turn * Vec3::Y, turn * Vec3::X);
    let reach = boxed / 2.0 + 0.05;
    let centre = scene.pose(o).translation;
    let h = (0.8 * o.half.z).min(0.02);
    let colliders = scene.world.bodies[o.body].colliders();
    let hit = |from: Vec3, dir: Vec3| placing::first_hit(scene, colliders, from, dir, 2.0 * reach);
    let mut width: Option<f32> = None;
    for dz in [-h, 0.0, h] {
        for dx in [-0.9, 0.0, 0.9].map(|k| k * crate::scene::FINGER_HALF_EXTENTS[0]) {
            let p = Vec3::new(at.x, at.y, centre.z + dz) + along * dx;
            if let (Some(a), Some(b)) = (
                hit(p - across * reach, across),
                hit(p + across * reach, -across),
            ) {
                let w = 2.0 * reach - a - b;
                width = Some(width.map_or(w, |v| v.max(w)));
            }
        }
    }
    (yaw, width.unwrap_or(boxed))
}

/// Steps to wait for the pads of a friction gripper to travel `gap` (m) and settle.
fn finger_steps(gap: f32, dt: f32) -> u32 {
    (gap.abs() / (crate::scene::FINGER_SPEED * dt)).ceil() as u32 + 24
}

/// One straight move of the tool, with ease-in/ease-out.
#[derive(Debug, Clone, Copy)]
struct Segment {
    from: Vec3,
    to: Vec3,
    steps: u32,
    /// How far the suction cup has turned what it holds about the tool's axis over the move
    /// (from, to; rad), where it turns it.
    yaw: Option<(f32, f32)>,
}

impl Segment {
    fn at(&self, k: u32) -> Vec3 {
        self.from.lerp(self.to, self.ease(k))
    }

    fn ease(&self, k: u32) -> f32 {
        let t = ((k + 1) as f32 / self.steps as f32).min(1.0);
        t * t * (3.0 - 2.0 * t)
    }

    fn yaw_at(&self, k: u32) -> Option<f32> {
        self.yaw.map(|(a, b)| a + (b - a) * self.ease(k))
    }
}

/// What the controller asks of the world at a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    None,
    /// Try to grasp this object (index into `SimScene::objects`).
    Grasp(usize),
    /// Try to grasp the moving link of joint `joint` of articulated object `object` at the
    /// tool's face (a ball joint: the link turns under the tool).
    GraspLink {
        object: usize,
        joint: usize,
    },
    /// Turn the (open) finger pads of a friction gripper about z to this yaw (rad).
    Turn(f32),
    Release,
}

/// Something the oracle noticed (recorded with the episode).
#[derive(Debug, Clone, PartialEq)]
pub struct Note {
    pub step: u64,
    pub text: String,
}

pub struct Controller {
    plan: Vec<Primitive>,
    next: usize,
    /// Moves of the current primitive, with an event after each.
    queue: std::collections::VecDeque<(Segment, Event)>,
    k: u32,
    /// Commanded tool position.
    pub command: Vec3,
    pub held: Option<Held>,
    /// Uniform noise (± m) added to every target in x and y.
    noise: f32,
    rng: Rng,
    pub notes: Vec<Note>,
    max_opening: Option<f32>,
    /// A seeing oracle's estimates from its camera; `None` for one that reads the sim's state.
    pub tracker: Option<Tracker>,
    /// Where a seeing oracle believed the object it last went to pick was (its centre).
    pick_belief: Option<Vec3>,
    /// The primitive for which a seeing oracle last moved the tool aside to look again.
    looked_aside: Option<usize>,
    /// The `sweep` whose first pass has been planned.
    swept: Option<usize>,
    /// This episode's grasps do not close (`oracle:grasp=P` drew it open): the tool goes through
    /// the plan's motions holding nothing.
    open_handed: bool,
    /// In an open-handed episode, what the tool would hold had the grasp closed: the plan's
    /// later moves are planned from it, as they would be from [`Controller::held`].
    feigned: Option<Held>,
}

/// An object as the policy believes it to be.
struct Belief {
    /// Centre of its box.
    centre: Vec3,
    /// Height of its top.
    top: f32,
}

#[derive(Debug, Clone, Copy)]
pub struct Held {
    pub object: usize,
    /// Object centre minus tool centre at the grasp (world frame).
    pub offset: Vec3,
    /// The joint that welds it to the tool (`None`: finger pads hold it by friction).
    pub joint: Option<ImpulseJointHandle>,
    /// Its pose in the tool's frame at the grasp (the weld's frame on the tool).
    pub grasped: Pose,
    /// How far the tool has turned it about its axis since the grasp (rad).
    pub turned: f32,
}

impl Held {
    /// Turns the weld to [`Held::turned`] (a suction grasp; nothing for one by friction or a
    /// link's ball joint).
    pub fn spin(&self, scene: &mut SimScene) {
        let Some(j) = self.joint else { return };
        if self.turned == 0.0 {
            return;
        }
        if let Some(joint) = scene.world.impulse_joints.get_mut(j, true) {
            joint.data.set_local_frame1(
                Pose::from_rotation(Rotation::from_rotation_z(self.turned)) * self.grasped,
            );
        }
    }
}

impl Controller {
    /// An oracle for `spec`; with a `tracker` it locates objects only through it (its camera).
    pub fn new(
        spec: &TaskSpec,
        start: Vec3,
        noise: f64,
        grasp: f64,
        seed: u64,
        tracker: Option<Tracker>,
    ) -> Self {
        // One draw per episode, from its own stream: the noise's draws stay as they were.
        let open_handed =
            grasp < 1.0 && Rng::new(seed, &format!("{}/policy-grasp", spec.id)).unit() >= grasp;
        Self {
            plan: spec.oracle.clone(),
            next: 0,
            queue: Default::default(),
            k: 0,
            command: start,
            held: None,
            noise: noise as f32,
            rng: Rng::new(seed, &format!("{}/policy-noise", spec.id)),
            notes: Vec::new(),
            max_opening: match spec.end_effector {
                EndEffector::Suction => None,
                EndEffector::ParallelGripper { max_opening, .. } => Some(max_opening as f32),
            },
            tracker,
            pick_belief: None,
            looked_aside: None,
            swept: None,
            open_handed,
            feigned: None,
        }
    }

    /// Forgets the plan: a policy object drives the tool (grasps and releases still go through
    /// [`Controller::apply`]).
    pub fn clear_plan(&mut self) {
        self.plan.clear();
        self.queue.clear();
    }

    pub fn done(&self) -> bool {
        self.queue.is_empty() && self.next >= self.plan.len()
    }

    /// Advances one step: returns the commanded tool position and the event to apply after it.
    pub fn step(&mut self, scene: &SimScene, step: u64) -> (Vec3, Event) {
        while self.queue.is_empty() && self.next < self.plan.len() {
            if self.tracker.is_none()
                && let Some(text) = placing::clear_first(&mut self.plan, self.next, scene)
            {
                self.notes.push(Note { step, text });
            }
            let p = self.plan[self.next].clone();
            self.next += 1;
            self.expand(&p, scene, step);
        }
        let Some((seg, ev)) = self.queue.front().copied() else {
            return (self.command, Event::None);
        };
        self.command = seg.at(self.k);
        if let (Some(yaw), Some(h)) = (seg.yaw_at(self.k), self.held.as_mut()) {
            h.turned = yaw;
        }
        self.k += 1;
        if self.k >= seg.steps {
            self.queue.pop_front();
            self.k = 0;
            return (self.command, ev);
        }
        (self.command, Event::None)
    }

    fn jitter(&mut self) -> Vec3 {
        if self.noise == 0.0 {
            return Vec3::ZERO;
        }
        let n = f64::from(self.noise);
        Vec3::new(
            self.rng.uniform(-n, n) as f32,
            self.rng.uniform(-n, n) as f32,
            0.0,
        )
    }

    fn push_move(&mut self, to: Vec3, speed: f32, ev: Event, dt: f32) {
        let from = self.queue.back().map(|(s, _)| s.to).unwrap_or(self.command);
        let dist = from.distance(to);
        let steps = ((dist / speed / dt).ceil() as u32).max(MIN_SEGMENT_STEPS);
        self.queue.push_back((
            Segment {
                from,
                to,
                steps,
                yaw: None,
            },
            ev,
        ));
    }

    /// Rises to `z_safe` where the tool is, then travels level to above `xy`.
    fn travel_over(&mut self, xy: Vec3, z_safe: f32, dt: f32) {
        self.push_move(
            Vec3::new(self.command.x, self.command.y, z_safe),
            DESCEND_SPEED * 2.0,
            Event::None,
            dt,
        );
        self.push_move(
            Vec3::new(xy.x, xy.y, z_safe),
            TRANSIT_SPEED,
            Event::None,
            dt,
        );
    }

    /// Turns a friction gripper's pads to `yaw` where the tool is, before it moves on.
    fn push_turn(&mut self, yaw: f32) {
        let at = self.queue.back().map(|(s, _)| s.to).unwrap_or(self.command);
        self.queue.push_back((
            Segment {
                from: at,
                to: at,
                steps: 1,
                yaw: None,
            },
            Event::Turn(yaw),
        ));
    }

    fn dwell(&mut self, ev: Event) {
        let at = self.queue.back().map(|(s, _)| s.to).unwrap_or(self.command);
        self.queue.push_back((
            Segment {
                from: at,
                to: at,
                steps: DWELL_STEPS,
                yaw: None,
            },
            ev,
        ));
    }

    /// Where object `i` is: the sim's state, or the camera's last good view of it (`None` if
    /// the camera has not seen it).
    fn belief(&self, scene: &SimScene, i: usize) -> Option<Belief> {
        let o = &scene.objects[i];
        match &self.tracker {
            None => {
                let p = scene.pose(o).translation;
                Some(Belief {
                    centre: p,
                    top: p.z + o.half.z,
                })
            }
            Some(t) => t.get(i).map(|s| Belief {
                centre: Vec3::new(s.top.x, s.top.y, s.top.z - o.half.z),
                top: s.top.z,
            }),
        }
    }

    /// An object the camera has not seen (the tool may be over it): the first time for this
    /// primitive, move the tool 15 cm aside, wait for fresh frames and try the primitive again;
    /// then give it up with a note.
    fn unseen(&mut self, scene: &SimScene, step: u64, id: &str) {
        let current = self.next - 1;
        if self.looked_aside != Some(current) {
            self.looked_aside = Some(current);
            let dt = scene.world.integration_parameters.dt;
            let dy = if self.command.y >= 0.0 { -0.15 } else { 0.15 };
            let aside = Vec3::new(self.command.x, self.command.y + dy, 0.0);
            self.travel_over(aside, self.safe_height(scene), dt);
            for _ in 0..3 {
                self.dwell(Event::None);
            }
            self.next = current;
            return;
        }
        self.notes.push(Note {
            step,
            text: format!("'{id}' has not been seen by the camera"),
        });
    }

    /// A height from which the tool, and what it holds, clears everything on the table.
    fn safe_height(&self, scene: &SimScene) -> f32 {
        let mut top = 0.0f32;
        for i in 0..scene.objects.len() {
            if self.held.is_some_and(|h| h.object == i) {
                continue;
            }
            if let Some(b) = self.belief(scene, i) {
                top = top.max(b.top);
            }
        }
        let held_height = self
            .held
            .map(|h| 2.0 * scene.objects[h.object].half.z)
            .unwrap_or(0.0);
        (top + held_height + GRIPPER_HALF_EXTENTS[2] + 0.04).max(0.25)
    }

    /// Turns what the tool holds about the tool's axis, where it is, until it comes to
    /// `yaw_deg` (modulo `symmetry_deg`) the shorter way round: the suction cup spins (the weld
    /// turns, [`Held::turned`]), the arm's wrist stays. The held object's offset from the tool
    /// turns with it. The object's yaw now is read from the world, also by a seeing oracle (its
    /// camera tracks positions, not turns).
    fn turn(&mut self, scene: &SimScene, step: u64, yaw_deg: f64, symmetry_deg: Option<f64>) {
        let Some(mut h) = self.held else {
            self.notes.push(Note {
                step,
                text: "turn with nothing held (the grasp failed)".into(),
            });
            return;
        };
        let now = crate::tabletop::yaw_of(&scene.pose(&scene.objects[h.object]).rotation);
        let period = symmetry_deg
            .map_or(std::f32::consts::TAU, |s| (s as f32).to_radians())
            .max(1e-3);
        let d = (yaw_deg as f32).to_radians() - now;
        let d = d - period * (d / period).round();
        if d.abs() < 1e-4 {
            return;
        }
        let from = h.turned;
        let at = self.queue.back().map(|(s, _)| s.to).unwrap_or(self.command);
        let dt = scene.world.integration_parameters.dt;
        let steps = ((d.abs() / TURN_SPEED / dt).ceil() as u32).max(MIN_SEGMENT_STEPS);
        self.queue.push_back((
            Segment {
                from: at,
                to: at,
                steps,
                yaw: Some((from, from + d)),
            },
            Event::None,
        ));
        let (sin, cos) = d.sin_cos();
        let o = h.offset;
        h.offset = Vec3::new(cos * o.x - sin * o.y, sin * o.x + cos * o.y, o.z);
        self.held = Some(h);
        self.dwell(Event::None);
    }

    fn expand(&mut self, p: &Primitive, scene: &SimScene, step: u64) {
        let dt = scene.world.integration_parameters.dt;
        let gh = GRIPPER_HALF_EXTENTS[2];
        match p {
            Primitive::Pick { object } => {
                let Some(i) = scene.index_of(object) else {
                    return;
                };
                let o = &scene.objects[i];
                if let Some(max) = self.max_opening
                    && 2.0 * o.half.x.min(o.half.y) > max
                {
                    self.notes.push(Note {
                        step,
                        text: format!("'{object}' is wider than the gripper opens ({max} m)"),
                    });
                }
                let half = o.half;
                let Some(seen) = self.belief(scene, i) else {
                    self.unseen(scene, step, object);
                    return;
                };
                self.pick_belief = Some(seen.centre);
                let pos = seen.centre + self.jitter();
                let z_safe = self.safe_height(scene);
                let top = seen.top;
                // Finger pads hang below the tool: its face stops just over the object's top, or
                // higher for a flat object, so that the pads' tips clear the table.
                let (face, fingers) = match &scene.fingers {
                    Some(f) => {
                        let (yaw, width) = grip(scene, i, pos);
                        self.push_turn(yaw);
                        let pad = 2.0 * crate::scene::FINGER_HALF_EXTENTS[2];
                        let bottom = top - 2.0 * half.z;
                        // An object wider than the pads open: they stop on its top.
                        let face = if width > f.max_opening {
                            top + pad + 0.002
                        } else {
                            (top + 0.002).max(bottom + pad + 0.004)
                        };
                        (face, Some(finger_steps(f.max_opening - width, dt)))
                    }
                    None => (top, None),
                };
                self.travel_over(pos, z_safe, dt);
                self.push_move(
                    Vec3::new(pos.x, pos.y, face + gh),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
                self.dwell(Event::Grasp(i));
                for _ in 0..fingers.unwrap_or(0).div_ceil(DWELL_STEPS) {
                    self.dwell(Event::None);
                }
                let lift = z_safe.max(face + gh + 0.02 + 2.0 * half.z);
                self.push_move(
                    Vec3::new(pos.x, pos.y, lift),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
            }
            Primitive::Place { target } => {
                let Some(h) = self.held.or(self.feigned) else {
                    self.notes.push(Note {
                        step,
                        text: "place with nothing held (the grasp failed)".into(),
                    });
                    return;
                };
                let held_half = scene.objects[h.object].half;
                let believed = |id: &str| {
                    let i = scene.index_of(id)?;
                    Some((&scene.objects[i], self.belief(scene, i)))
                };
                let centre = match target {
                    PlaceTarget::On(id) | PlaceTarget::Into(id) => match believed(id) {
                        None => None,
                        Some((_, None)) => {
                            self.unseen(scene, step, id);
                            return;
                        }
                        Some((c, Some(b))) => Some(match target {
                            PlaceTarget::On(_) => {
                                Vec3::new(b.centre.x, b.centre.y, b.top + held_half.z)
                            }
                            _ => {
                                let (inner, w) = c.container.unwrap_or((c.half, 0.0));
                                let floor = b.centre.z - (inner.z + w / 2.0) + w;
                                Vec3::new(b.centre.x, b.centre.y, floor + held_half.z)
                            }
                        }),
                    },
                    PlaceTarget::Zone(id) => placing::scene_zone(scene, id)
                        .map(|(c, _)| Vec3::new(c.x, c.y, held_half.z)),
                    PlaceTarget::At(xy) => Some(Vec3::new(xy[0] as f32, xy[1] as f32, held_half.z)),
                    PlaceTarget::AtPoint(p) => {
                        Some(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
                    }
                    PlaceTarget::Spot { xy, relative_to } => {
                        let origin = match relative_to {
                            None => Some(Vec3::ZERO),
                            Some(id) => match believed(id) {
                                None => None,
                                Some((_, None)) => {
                                    self.unseen(scene, step, id);
                                    return;
                                }
                                Some((_, Some(b))) => Some(b.centre),
                            },
                        };
                        origin.map(|o| {
                            let (x, y) = (o.x + xy[0] as f32, o.y + xy[1] as f32);
                            placing::edge_free_spot(scene, h.object, x, y)
                        })
                    }
                };
                let Some(centre) = centre else { return };
                let centre = centre + self.jitter();
                let z_safe = self.safe_height(scene);
                let tool = centre - h.offset;
                self.travel_over(tool, z_safe, dt);
                self.push_move(
                    Vec3::new(tool.x, tool.y, tool.z + PLACE_CLEARANCE),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
                self.dwell(Event::Release);
                self.dwell(Event::None);
                if let Some(f) = &scene.fingers {
                    let n = finger_steps(f.max_opening - 2.0 * held_half.x.min(held_half.y), dt);
                    for _ in 0..n.div_ceil(DWELL_STEPS) {
                        self.dwell(Event::None);
                    }
                }
                self.push_move(
                    Vec3::new(tool.x, tool.y, z_safe),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
            }
            Primitive::Actuate { object, joint, to } => {
                self.actuate(scene, object, joint, *to);
            }
            Primitive::Turn {
                yaw_deg,
                symmetry_deg,
            } => self.turn(scene, step, *yaw_deg, *symmetry_deg),
            Primitive::Sweep { pile, zone } => {
                // Two passes: the second is planned from where the first left the pile.
                let current = self.next - 1;
                let first = self.swept != Some(current);
                self.sweep(scene, pile, zone);
                if first {
                    self.swept = Some(current);
                    self.next = current;
                }
            }
            Primitive::Push { object, to } => {
                let Some(i) = scene.index_of(object) else {
                    return;
                };
                let Some(seen) = self.belief(scene, i) else {
                    self.unseen(scene, step, object);
                    return;
                };
                let p = seen.centre;
                let goal = Vec3::new(to[0] as f32, to[1] as f32, 0.0) + self.jitter();
                let d = Vec3::new(goal.x - p.x, goal.y - p.y, 0.0);
                if d.length() < 1e-4 {
                    return;
                }
                let dir = d.normalize();
                // Extent of the object along the push direction: from its (yawed) box, or from the
                // footprint the camera saw.
                let e = match &self.tracker {
                    None => {
                        let o = &scene.objects[i];
                        let rotation = scene.pose(o).rotation;
                        let ax = rotation * Vec3::X;
                        let ay = rotation * Vec3::Y;
                        o.half.x * dir.dot(ax).abs() + o.half.y * dir.dot(ay).abs()
                    }
                    Some(t) => t.get(i).map_or(0.0, |s| s.extent_along(dir)),
                };
                let g = GRIPPER_HALF_EXTENTS[0] * (dir.x.abs() + dir.y.abs());
                let z_low = gh + 0.004;
                let z_safe = self.safe_height(scene);
                let start = Vec3::new(p.x, p.y, 0.0) - dir * (e + g + 0.03);
                let end = Vec3::new(goal.x, goal.y, 0.0) - dir * (e + g);
                self.travel_over(start, z_safe, dt);
                self.push_move(
                    Vec3::new(start.x, start.y, z_low),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
                self.push_move(Vec3::new(end.x, end.y, z_low), PUSH_SPEED, Event::None, dt);
                let back = end - dir * 0.02;
                self.push_move(
                    Vec3::new(back.x, back.y, z_low),
                    PUSH_SPEED,
                    Event::None,
                    dt,
                );
                self.push_move(
                    Vec3::new(back.x, back.y, z_safe),
                    DESCEND_SPEED,
                    Event::None,
                    dt,
                );
            }
        }
    }

    /// One pass of a sweep: strokes 3 cm apart across the part of the pile still outside the
    /// zone, each from 3 cm behind it along the table to the zone's centre line, the tool's face
    /// 4 mm over the table. Reads the sim's state (a seeing oracle too: its camera tracks
    /// objects one by one, not heaps of them).
    fn sweep(&mut self, scene: &SimScene, pile: &str, zone: &str) {
        let dt = scene.world.integration_parameters.dt;
        let gh = GRIPPER_HALF_EXTENTS[2];
        let g = GRIPPER_HALF_EXTENTS[0];
        let Some((zc, zh)) = placing::scene_zone(scene, zone) else {
            return;
        };
        let outside: Vec<Vec3> = crate::predicates::pile_copies(scene, pile)
            .into_iter()
            .map(|i| scene.pose(&scene.objects[i]).translation)
            .filter(|p| (p.x - zc.x).abs() > zh.x * 0.8 || (p.y - zc.y).abs() > zh.y * 0.8)
            // Not what fell off the table.
            .filter(|p| p.z > -0.01)
            .collect();
        if outside.is_empty() {
            return;
        }
        // The heap, not the strays far from it: what lies within 15 cm of its median.
        let median = |f: fn(&Vec3) -> f32| {
            let mut v: Vec<f32> = outside.iter().map(f).collect();
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let heart = Vec3::new(median(|p| p.x), median(|p| p.y), 0.0);
        let outside: Vec<Vec3> = outside
            .into_iter()
            .filter(|p| Vec3::new(p.x - heart.x, p.y - heart.y, 0.0).length() < 0.15)
            .collect();
        let extent = crate::predicates::pile_copies(scene, pile)
            .first()
            .map_or(0.01, |&i| {
                scene.objects[i].half.x.max(scene.objects[i].half.y)
            });
        let centroid = outside.iter().copied().sum::<Vec3>() / outside.len() as f32;
        let d = Vec3::new(zc.x - centroid.x, zc.y - centroid.y, 0.0).normalize_or_zero();
        if d == Vec3::ZERO {
            return;
        }
        let n = Vec3::new(-d.y, d.x, 0.0);
        let along = |p: Vec3| (p - zc).dot(d);
        let across = |p: Vec3| (p - zc).dot(n);
        let back = outside.iter().map(|p| along(*p)).fold(f32::MAX, f32::min);
        let (lo, hi) = outside
            .iter()
            .map(|p| across(*p))
            .fold((f32::MAX, f32::MIN), |(a, b), x| (a.min(x), b.max(x)));
        // How far across the zone a stroke may end and still leave what it pushes inside.
        let room = (zh.x * n.x.abs() + zh.y * n.y.abs() - extent - g).max(0.0);
        let strokes = (((hi - lo) / 0.03).ceil() as u32).clamp(1, MAX_STROKES);
        let z_low = gh + 0.004;
        let z_safe = self.safe_height(scene);
        // Between strokes the tool hops just over the table (3 cm over anything that is not the
        // pile), not up to the safe height.
        let copies = crate::predicates::pile_copies(scene, pile);
        let top = (0..scene.objects.len())
            .filter(|i| !copies.contains(i))
            .filter_map(|i| self.belief(scene, i).map(|b| b.top))
            .fold(0.0f32, f32::max);
        let hop = (top + gh + 0.03).max(gh + 0.03);
        for k in 0..=strokes {
            let o = lo + (hi - lo) * k as f32 / strokes as f32;
            let start = zc + d * (back - extent - g - 0.03) + n * o;
            let end = zc + n * o.clamp(-room, room);
            if k == 0 {
                self.travel_over(start, z_safe, dt);
            } else {
                // Up from the last stroke: over to the next one at the hop height.
                self.push_move(
                    Vec3::new(start.x, start.y, hop),
                    TRANSIT_SPEED,
                    Event::None,
                    dt,
                );
            }
            self.push_move(
                Vec3::new(start.x, start.y, z_low),
                DESCEND_SPEED,
                Event::None,
                dt,
            );
            self.push_move(Vec3::new(end.x, end.y, z_low), SWEEP_SPEED, Event::None, dt);
            self.push_move(Vec3::new(end.x, end.y, hop), DESCEND_SPEED, Event::None, dt);
        }
    }

    /// Grasp the moving link of a joint at the top point farthest from the joint (along the axis
    /// for a prismatic joint), carry it along the joint's motion to `to`, release, retreat.
    /// Joint positions are read from the sim's state, also by a seeing oracle (its camera
    /// tracks objects, not joints).
    fn actuate(&mut self, scene: &SimScene, object: &str, joint: &str, to: f64) {
        let dt = scene.world.integration_parameters.dt;
        let gh = GRIPPER_HALF_EXTENTS[2];
        let Some(i) = scene.index_of(object) else {
            return;
        };
        let o = &scene.objects[i];
        let Some(k) = o.joints.iter().position(|j| j.name == joint) else {
            return;
        };
        let j = &o.joints[k];
        let q = j.position(&scene.world);
        let to = match j.limit {
            Some([lo, hi]) => to.clamp(lo, hi),
            None => to,
        };
        let zero = *scene.world.bodies[j.parent].position() * j.frame;
        let (origin, axis) = (zero.translation, zero.rotation * Vec3::X);
        // Candidate points: the corners, edge midpoints and face centres of every part of the
        // moving link's shape, with the centre of the part each belongs to.
        let mut points: Vec<(Vec3, Vec3)> = Vec::new();
        for h in scene.world.bodies[j.child].colliders() {
            let c = &scene.world.colliders[*h];
            let parts: Vec<(Pose, rapier3d::parry::shape::SharedShape)> =
                match c.shape().as_compound() {
                    Some(compound) => compound.shapes().to_vec(),
                    None => vec![(Pose::IDENTITY, c.shared_shape().clone())],
                };
            for (local, shape) in parts {
                let pose = *c.position() * local;
                let b = shape.compute_local_aabb();
                let (lo, hi) = (b.mins, b.maxs);
                let mid = (lo + hi) / 2.0;
                let centre = pose.transform_point(mid);
                for fx in [lo.x, mid.x, hi.x] {
                    for fy in [lo.y, mid.y, hi.y] {
                        for fz in [lo.z, mid.z, hi.z] {
                            points.push((pose.transform_point(Vec3::new(fx, fy, fz)), centre));
                        }
                    }
                }
            }
        }
        let Some(top) = points.iter().map(|(p, _)| p.z).reduce(f32::max) else {
            return;
        };
        let reach = |p: Vec3| {
            if j.prismatic {
                p.dot(axis)
            } else {
                let d = p - origin;
                (d - axis * d.dot(axis)).length()
            }
        };
        // On the top, as far from the joint as it goes, and as near the middle of its part as
        // that allows (an edge's midpoint rather than its corner).
        let score =
            |(p, c): &(Vec3, Vec3)| reach(*p) - 0.5 * Vec3::new(p.x - c.x, p.y - c.y, 0.0).length();
        let Some((mut grasp, centre)) = points
            .iter()
            .filter(|(p, _)| p.z >= top - 0.005)
            .copied()
            .max_by(|a, b| score(a).total_cmp(&score(b)))
        else {
            return;
        };
        // Inside the edge, so that the tool's face rests on the part.
        let inward = Vec3::new(centre.x - grasp.x, centre.y - grasp.y, 0.0);
        grasp += inward.normalize_or_zero() * inward.length().min(HANDLE_INSET);
        let grasp = grasp + self.jitter();
        let z_safe = self.safe_height(scene).max(grasp.z + gh + 0.05);
        self.travel_over(grasp, z_safe, dt);
        self.push_move(
            Vec3::new(grasp.x, grasp.y, grasp.z + gh),
            DESCEND_SPEED,
            Event::None,
            dt,
        );
        self.dwell(Event::GraspLink {
            object: i,
            joint: k,
        });
        let n = ((to - q).abs() / ACTUATE_STEP).ceil().max(10.0) as u32;
        let mut last = grasp;
        for s in 1..=n {
            let dq = ((to - q) * f64::from(s) / f64::from(n)) as f32;
            let p = if j.prismatic {
                grasp + axis * dq
            } else {
                origin + Rotation::from_axis_angle(axis, dq) * (grasp - origin)
            };
            self.push_move(
                Vec3::new(p.x, p.y, p.z + gh),
                DESCEND_SPEED,
                Event::None,
                dt,
            );
            last = p;
        }
        self.dwell(Event::Release);
        self.push_move(
            Vec3::new(last.x, last.y, last.z + gh + 0.08),
            DESCEND_SPEED,
            Event::None,
            dt,
        );
    }

    /// A friction gripper's grasp: the pads close across the object's narrower side to press
    /// [`SQUEEZE`] into it, and only their friction holds it. Refused, with a note, when the tool
    /// is not over the object, the object is fixed or wider than the gripper opens.
    fn close_fingers(&mut self, i: usize, scene: &mut SimScene, step: u64) {
        let o = &scene.objects[i];
        let tool = scene.gripper_position();
        let pose = scene.pose(o);
        let horizontal = Vec3::new(
            pose.translation.x - tool.x,
            pose.translation.y - tool.y,
            0.0,
        )
        .length();
        let (yaw, width) = grip(scene, i, tool);
        let Some(f) = &scene.fingers else { return };
        let reason = if o.fixed {
            Some("it is fixed".to_string())
        } else if width > f.max_opening {
            Some(format!(
                "{width:.3} m wide, the gripper opens {:.3} m",
                f.max_opening
            ))
        } else if horizontal > o.half.x.max(o.half.y) {
            Some(format!("the tool is {horizontal:.3} m off its centre"))
        } else {
            None
        };
        if let Some(reason) = reason {
            self.notes.push(Note {
                step,
                text: format!("grasp of '{}' failed: {reason}", o.id),
            });
            return;
        }
        let believed = match (&self.tracker, self.pick_belief) {
            (Some(_), Some(b)) => b,
            _ => pose.translation,
        };
        self.held = Some(Held {
            object: i,
            offset: believed - tool,
            joint: None,
            grasped: Pose::IDENTITY,
            turned: 0.0,
        });
        // A policy that grasps without turning the pads first: turn them (they are open). The
        // pads' yaw is on the tool, which a policy may have turned.
        let yaw = {
            let r = yaw - scene.tool_yaw();
            r - std::f32::consts::PI * (r / std::f32::consts::PI).round()
        };
        if scene
            .fingers
            .as_ref()
            .is_some_and(|f| (f.yaw - yaw).abs() > 1e-3)
        {
            scene.turn_fingers(yaw);
        }
        scene.set_finger_target((width - 2.0 * SQUEEZE).max(0.0));
    }

    /// Applies a grasp or release to the world.
    pub fn apply(&mut self, ev: Event, scene: &mut SimScene, step: u64) {
        match ev {
            Event::None => {}
            Event::Turn(yaw) => scene.turn_fingers(yaw),
            Event::Grasp(i) | Event::GraspLink { object: i, .. } if self.open_handed => {
                // The tool stays open; the plan goes on as if it held the object.
                let o = scene.objects[i].clone();
                let offset = match ev {
                    Event::Grasp(_) => scene.pose(&o).translation - scene.gripper_position(),
                    _ => Vec3::ZERO,
                };
                self.notes.push(Note {
                    step,
                    text: format!(
                        "grasp of '{}' left open (this episode was drawn not to grasp)",
                        o.id
                    ),
                });
                self.feigned = Some(Held {
                    object: i,
                    offset,
                    joint: None,
                    grasped: Pose::IDENTITY,
                    turned: 0.0,
                });
            }
            Event::Grasp(i) if scene.fingers.is_some() => self.close_fingers(i, scene, step),
            Event::Grasp(i) => {
                let o = scene.objects[i].clone();
                let tool = scene.gripper_position();
                let pose = scene.pose(&o);
                let top = pose.translation.z + o.half.z;
                let face = tool.z - GRIPPER_HALF_EXTENTS[2];
                let horizontal = Vec3::new(
                    pose.translation.x - tool.x,
                    pose.translation.y - tool.y,
                    0.0,
                )
                .length();
                let fits = self
                    .max_opening
                    .is_none_or(|m| 2.0 * o.half.x.min(o.half.y) <= m);
                if o.fixed
                    || (face - top).abs() > GRASP_REACH
                    || horizontal > o.half.x.max(o.half.y)
                    || !fits
                {
                    self.notes.push(Note {
                        step,
                        text: format!(
                            "grasp of '{}' failed: tool face {:.3} m from its top, {:.3} m off centre{}",
                            o.id,
                            (face - top).abs(),
                            horizontal,
                            if fits { "" } else { ", too wide for the gripper" }
                        ),
                    });
                    return;
                }
                let tool_pose = *scene.world.bodies[scene.gripper].position();
                let rel = tool_pose.inverse() * pose;
                let joint = FixedJointBuilder::new()
                    .local_frame1(rel)
                    .local_frame2(Pose::IDENTITY)
                    .contacts_enabled(false);
                let handle = scene
                    .world
                    .insert_impulse_joint(scene.gripper, o.body, joint);
                // A seeing oracle knows where it grasped only from what it saw.
                let believed = match (&self.tracker, self.pick_belief) {
                    (Some(_), Some(b)) => b,
                    _ => pose.translation,
                };
                self.held = Some(Held {
                    object: i,
                    offset: believed - tool,
                    joint: Some(handle),
                    grasped: rel,
                    turned: 0.0,
                });
            }
            Event::GraspLink { object, joint } => {
                let o = &scene.objects[object];
                let j = &o.joints[joint];
                let face = scene.gripper_position() - Vec3::new(0.0, 0.0, GRIPPER_HALF_EXTENTS[2]);
                let distance = scene.world.bodies[j.child]
                    .colliders()
                    .iter()
                    .map(|h| {
                        let c = &scene.world.colliders[*h];
                        c.shape().distance_to_point(c.position(), face, true)
                    })
                    .fold(f32::MAX, f32::min);
                if distance > GRASP_REACH {
                    self.notes.push(Note {
                        step,
                        text: format!(
                            "grasp of '{}' (the link of joint '{}') failed: tool face {distance:.3} m from it",
                            o.id, j.name
                        ),
                    });
                    return;
                }
                let child = j.child;
                let link = *scene.world.bodies[child].position();
                let ball = SphericalJointBuilder::new()
                    .local_anchor1(Vec3::new(0.0, 0.0, -GRIPPER_HALF_EXTENTS[2]))
                    .local_anchor2(link.inverse_transform_point(face))
                    .contacts_enabled(false);
                let handle = scene.world.insert_impulse_joint(scene.gripper, child, ball);
                self.held = Some(Held {
                    object,
                    offset: Vec3::ZERO,
                    joint: Some(handle),
                    grasped: Pose::IDENTITY,
                    turned: 0.0,
                });
            }
            Event::Release => {
                self.feigned = None;
                if let Some(max) = scene.fingers.as_ref().map(|f| f.max_opening) {
                    scene.set_finger_target(max);
                }
                if let Some(h) = self.held.take() {
                    if let Some(j) = h.joint {
                        scene.world.remove_impulse_joint(j);
                    }
                    let body = scene.objects[h.object].body;
                    scene.world.wake_up(body, true);
                }
            }
        }
    }
}
