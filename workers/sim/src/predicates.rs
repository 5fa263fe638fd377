//! Goal predicates, evaluated on the simulator's state: the ground truth of success.

use assay_model::episode::PredicateValue;
use assay_spec::spec::Goal;
use rapier3d::prelude::*;

use crate::scene::{SimObject, SimScene};

/// How far (m) a resting object's height may differ from the nominal stack height.
const REST_TOLERANCE: f32 = 0.02;

pub fn evaluate(goals: &[Goal], scene: &SimScene) -> Vec<PredicateValue> {
    goals
        .iter()
        .map(|g| {
            let (holds, detail) = holds(g, scene);
            PredicateValue {
                label: g.label(),
                holds,
                detail,
            }
        })
        .collect()
}

/// The objects that are copies of pile `pile` (`{pile}_0`, `{pile}_1`, ...).
pub fn pile_copies(scene: &SimScene, pile: &str) -> Vec<usize> {
    let prefix = format!("{pile}_");
    scene
        .objects
        .iter()
        .enumerate()
        .filter(|(_, o)| {
            o.id.strip_prefix(&prefix)
                .is_some_and(|k| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit()))
        })
        .map(|(i, _)| i)
        .collect()
}

fn obj<'a>(scene: &'a SimScene, id: &str) -> &'a SimObject {
    scene.object(id).expect("validated: goal objects exist")
}

fn on_top_of(scene: &SimScene, object: &str, support: &str) -> (bool, String) {
    let (o, s) = (obj(scene, object), obj(scene, support));
    let sp = scene.pose(s);
    let local = sp.inverse() * scene.pose(o).translation;
    let over = local.x.abs() <= s.half.x && local.y.abs() <= s.half.y;
    let rest = o.half.z + s.half.z;
    let dz = scene.pose(o).translation.z - sp.translation.z;
    let resting = (dz - rest).abs() <= REST_TOLERANCE;
    (
        over && resting,
        format!(
            "offset ({:.3}, {:.3}) m over a top of ±({:.3}, {:.3}); height above support {dz:.3} m (expected {rest:.3})",
            local.x, local.y, s.half.x, s.half.y
        ),
    )
}

fn holds(goal: &Goal, scene: &SimScene) -> (bool, String) {
    match goal {
        Goal::InZone { object, zone } => {
            let p = scene.pose(obj(scene, object)).translation;
            let (_, c, h) = scene
                .zones
                .iter()
                .find(|z| &z.0 == zone)
                .expect("validated: zone exists");
            let inside = (p.x - c.x).abs() <= h.x && (p.y - c.y).abs() <= h.y && p.z > -0.02;
            (
                inside,
                format!(
                    "centre ({:.3}, {:.3}, {:.3}); zone ({:.3}, {:.3}) ± ({:.3}, {:.3})",
                    p.x, p.y, p.z, c.x, c.y, h.x, h.y
                ),
            )
        }
        Goal::InContainer { object, container } => {
            let (o, c) = (obj(scene, object), obj(scene, container));
            let local = scene.pose(c).inverse() * scene.pose(o).translation;
            let (inner, w) = c.container.unwrap_or((c.half, 0.0));
            let big_h = inner.z + w / 2.0;
            let inside = local.x.abs() <= inner.x
                && local.y.abs() <= inner.y
                && local.z >= -big_h
                && local.z <= big_h + 0.5 * o.half.z;
            (
                inside,
                format!(
                    "centre at ({:.3}, {:.3}, {:.3}) in the container's frame; interior ±({:.3}, {:.3}), floor {:.3}",
                    local.x,
                    local.y,
                    local.z,
                    inner.x,
                    inner.y,
                    -big_h + w
                ),
            )
        }
        Goal::OnTopOf { object, support } => on_top_of(scene, object, support),
        Goal::Stacked { order } => {
            let mut details = Vec::new();
            let mut all = true;
            for pair in order.windows(2) {
                let (ok, d) = on_top_of(scene, &pair[1], &pair[0]);
                all &= ok;
                if !ok {
                    details.push(format!("{} on {}: {d}", pair[1], pair[0]));
                }
            }
            (
                all,
                if all {
                    "every level rests on the one below".into()
                } else {
                    details.join("; ")
                },
            )
        }
        Goal::WithinDistance {
            object,
            target,
            point,
            distance,
        } => {
            let p = scene.pose(obj(scene, object)).translation;
            let q = match (target, point) {
                (Some(t), _) => scene.pose(obj(scene, t)).translation,
                (None, Some(pt)) => Vec3::new(pt[0] as f32, pt[1] as f32, pt[2] as f32),
                (None, None) => unreachable!("validated: a target or a point"),
            };
            let d = p.distance(q);
            (
                d <= *distance as f32,
                format!("distance {d:.3} m (limit {distance})"),
            )
        }
        Goal::PoseWithin {
            object,
            position,
            tolerance,
            yaw_deg,
            yaw_tolerance_deg,
            relative_to,
            planar,
            yaw_symmetry_deg,
        } => {
            let pose = scene.pose(obj(scene, object));
            let origin = match relative_to {
                Some(anchor) => scene.pose(obj(scene, anchor)).translation,
                None => Vec3::ZERO,
            };
            let target =
                origin + Vec3::new(position[0] as f32, position[1] as f32, position[2] as f32);
            let mut err = pose.translation - target;
            if *planar {
                err.z = 0.0;
            }
            let d = err.length();
            let mut ok = d <= *tolerance as f32;
            let mut detail = format!("position error {d:.3} m (tolerance {tolerance})");
            if let (Some(want), Some(tol)) = (yaw_deg, yaw_tolerance_deg) {
                let fwd = pose.rotation * Vec3::X;
                let yaw = fwd.y.atan2(fwd.x).to_degrees() as f64;
                let period = yaw_symmetry_deg.unwrap_or(360.0);
                let e = (yaw - want).rem_euclid(period);
                let err = e.min(period - e);
                ok &= err <= *tol;
                detail.push_str(&format!("; yaw error {err:.1}° (tolerance {tol}°)"));
            }
            (ok, detail)
        }
        Goal::AnyOf { any } => {
            let mut details = Vec::new();
            for g in any {
                let (ok, d) = holds(g, scene);
                if ok {
                    return (true, format!("{}: {d}", g.label()));
                }
                details.push(format!("{}: {d}", g.label()));
            }
            (false, format!("none holds ({})", details.join("; ")))
        }
        Goal::JointPosition {
            object,
            joint,
            min,
            max,
        } => {
            let o = obj(scene, object);
            let Some(j) = scene.joint(o, joint) else {
                return (false, format!("'{object}' has no moving joint '{joint}'"));
            };
            let q = j.position(&scene.world);
            let ok = min.is_none_or(|lo| q >= lo) && max.is_none_or(|hi| q <= hi);
            let unit = if j.prismatic { "m" } else { "rad" };
            let bounds = match (min, max) {
                (Some(lo), Some(hi)) => format!("[{lo}, {hi}]"),
                (Some(lo), None) => format!(">= {lo}"),
                (None, Some(hi)) => format!("<= {hi}"),
                (None, None) => "anything".into(),
            };
            (ok, format!("'{joint}' at {q:.3} {unit} (wanted {bounds})"))
        }
        Goal::PileInZone {
            pile,
            zone,
            fraction,
        } => {
            let (inside, copies) = pile_over_zone(scene, pile, zone);
            let share = inside as f64 / copies.max(1) as f64;
            (
                copies > 0 && share >= *fraction,
                format!(
                    "{inside} of {copies} over the zone ({:.0} %, wanted {:.0} %)",
                    share * 100.0,
                    fraction * 100.0
                ),
            )
        }
        Goal::Lifted { object, height } => {
            let o = obj(scene, object);
            let bottom = scene.pose(o).translation.z - o.half.z;
            (
                f64::from(bottom) >= *height,
                format!("bottom at {bottom:.3} m (wanted at least {height} m)"),
            )
        }
    }
}

/// A generator's staged reward as the generator computes it (GenSim: Ravens' `Task.reward`),
/// followed over an episode: [`StagedReward::check`] on a state evaluates the current step;
/// a step whose goals all hold (its reward within 0.01 of its worth) is counted for good and
/// the next one is checked from then on, one step per check, as Ravens pops one goal per
/// `reward()` call.
#[derive(Debug, Clone, Default)]
pub struct StagedReward {
    /// Steps completed.
    pub met: usize,
    /// Their worth.
    pub progress: f64,
    /// The current step's reward at the last check.
    pub partial: f64,
}

impl StagedReward {
    /// Checks the current step of `steps` on `scene`.
    pub fn check(&mut self, steps: &[assay_spec::spec::RewardStep], scene: &SimScene) {
        let Some(step) = steps.get(self.met) else {
            self.partial = 0.0;
            return;
        };
        let n = step.goals.len().max(1) as f64;
        let share: f64 = step
            .goals
            .iter()
            .map(|g| match g {
                // GenSim's zone metric: the share of the pile's points over the zone.
                Goal::PileInZone { pile, zone, .. } => {
                    let (inside, copies) = pile_over_zone(scene, pile, zone);
                    inside as f64 / copies.max(1) as f64
                }
                g => f64::from(u8::from(holds(g, scene).0)),
            })
            .sum::<f64>()
            / n;
        let reward = step.max_reward * share;
        if (step.max_reward - reward).abs() < 0.01 {
            self.met += 1;
            self.progress += step.max_reward;
            self.partial = 0.0;
        } else {
            self.partial = reward;
        }
    }

    /// The reward so far.
    pub fn value(&self) -> f64 {
        self.progress + self.partial
    }
}

/// How many of pile `pile`'s copies lie over zone `zone` (their centres, not fallen off the
/// table), and how many copies there are.
fn pile_over_zone(scene: &SimScene, pile: &str, zone: &str) -> (usize, usize) {
    let (_, c, h) = scene
        .zones
        .iter()
        .find(|z| z.0 == zone)
        .expect("validated: zone exists");
    let copies = pile_copies(scene, pile);
    let inside = copies
        .iter()
        .filter(|&&i| {
            let p = scene.pose(&scene.objects[i]).translation;
            (p.x - c.x).abs() <= h.x && (p.y - c.y).abs() <= h.y && p.z > -0.02
        })
        .count();
    (inside, copies.len())
}
