//! Seed 0's goals, in GenSim's order, as goals, and the oracle's plan that follows them: a pose
//! goal's targets (tied to an object over the seeds, or places on the table) and the oracle's
//! assignment of objects to them; a zone goal's zones, and a pile swept or objects laid out on a
//! grid. Never makes objects (`objects` does).

use super::{Kind, Made, TIED, Translation, rot_z, yaw_of};
use crate::gensim::repair::PoseGoal;
use crate::gensim::sandbox::{GoalRecord, RecordedPose, SeedRecord};
use crate::r6;
use assay_spec::spec::{Color, Goal, PlaceTarget, Primitive, RewardStep, Zone};

/// An offset shorter than this (m, in x and y) puts the target on the object's spot.
const ON_SPOT: f64 = 0.005;

/// A target an object may go to: its index in the goal, its goal, the oracle's place, and its
/// height.
type Target = (usize, Goal, PlaceTarget, f64);

/// Where a target pose is tied: to made object `k` with a world offset, or nowhere.
#[derive(Clone, Copy)]
enum Tie {
    To(usize, [f64; 3]),
    Free,
}

/// The made object whose pose the target of goal `g`, index `j`, follows over the seeds.
fn tie(seeds: &[SeedRecord], made: &[Option<Made>], g: usize, j: usize, not: usize) -> Tie {
    let target = |s: &SeedRecord| s.goals.get(g).and_then(|gr| gr.targets.get(j)).copied();
    let Some(t0) = target(&seeds[0]) else {
        return Tie::Free;
    };
    let mut best: Option<(f64, usize, [f64; 3])> = None;
    for (k, m) in made.iter().enumerate() {
        let Some(m) = m else { continue };
        if k == not || m.kind == Kind::Pile || m.moved {
            continue;
        }
        let offsets = |local: bool| -> Option<[f64; 3]> {
            let mut first: Option<[f64; 3]> = None;
            for s in seeds {
                let (t, o) = (target(s)?, s.objects.get(k)?);
                let d = [
                    t.0[0] - o.pose.0[0],
                    t.0[1] - o.pose.0[1],
                    t.0[2] - o.pose.0[2],
                ];
                let d = if local {
                    let xy = rot_z(-yaw_of(&o.pose.1), [d[0], d[1]]);
                    [xy[0], xy[1], d[2]]
                } else {
                    d
                };
                match first {
                    None => first = Some(d),
                    Some(f) if (0..3).all(|a| (f[a] - d[a]).abs() <= TIED) => {}
                    Some(_) => return None,
                }
            }
            first
        };
        let found = if seeds.len() > 1 {
            offsets(false).or_else(|| offsets(true))
        } else {
            // One seed cannot show a tie: only a target on the object's very spot counts.
            offsets(false).filter(|d| d[0].hypot(d[1]) < 1e-6)
        };
        if found.is_some() {
            // The world offset on seed 0 (the layout the spec keeps).
            let o = &seeds[0].objects[k];
            let d = [
                t0.0[0] - o.pose.0[0],
                t0.0[1] - o.pose.0[1],
                t0.0[2] - o.pose.0[2],
            ];
            let len = d[0].hypot(d[1]);
            if best.is_none_or(|(l, _, _)| len < l) {
                best = Some((len, k, d));
            }
        }
    }
    match best {
        Some((_, k, d)) => Tie::To(k, d),
        None => Tie::Free,
    }
}

impl Translation<'_> {
    /// Seed 0's goals in GenSim's order; the oracle follows them. `None` when one cannot be
    /// imported (the error is noted).
    pub(super) fn goals(&mut self) -> Option<()> {
        let seeds = self.seeds;
        let s0 = &seeds[0];
        self.notes.mapped(
            "add_goal.step_max_reward",
            "GenSim's reward, reported beside success: one reward step per add_goal, checked in order whenever nothing is held, a step met once counted for good, partial reward for the share of its objects that match (success still requires every goal at the end)",
        );
        for (gi, g) in s0.goals.iter().enumerate() {
            let start = self.goals.len();
            self.goal(gi, g)?;
            let max = g.step_max_reward;
            self.reward_steps.push(RewardStep {
                max_reward: if max.is_finite() {
                    r6(max.clamp(0.0, 1e6))
                } else {
                    1.0
                },
                goals: self.goals[start..].to_vec(),
            });
        }
        Some(())
    }

    /// Goal `gi` of seed 0.
    fn goal(&mut self, gi: usize, g: &GoalRecord) -> Option<()> {
        let field = format!("add_goal[{gi}]");
        if let Some(shape) = &g.matches_shape {
            self.notes.not_mapped(
                &format!("{field}.matches"),
                format!(
                    "{shape:?} for {} objects and {} targets: the rows and columns that exist are kept (GenSim fails when it reaches the others)",
                    g.objs.len(),
                    g.targets.len()
                ),
            );
        }
        let ids: Vec<(usize, Made)> = g
            .objs
            .iter()
            .filter_map(|&oid| {
                self.made
                    .get(oid.wrapping_sub(1))
                    .and_then(|m| m.as_ref())
                    .map(|m| (oid - 1, m.clone()))
            })
            .collect();
        if ids.len() != g.objs.len() {
            self.notes.error(
                &format!("{field}.objs"),
                "an object of this goal was not imported",
            );
            return None;
        }
        if g.metric == "zone" {
            return self.zone_goal(g, &field, &ids).then_some(());
        }
        if ids
            .iter()
            .any(|(_, m)| !matches!(m.kind, Kind::Object { .. }))
        {
            self.notes.error(
                &format!("{field}.objs"),
                "a pose goal on a zone or a pile: only objects can be placed",
            );
            return None;
        }
        self.pose_goal(gi, g, &field, &ids)
    }

    /// Pose goal `gi` on the objects `ids` (recorded index, made object): each object's
    /// allowed targets as its goal, and a pick and a place of each, lower targets first.
    fn pose_goal(
        &mut self,
        gi: usize,
        g: &GoalRecord,
        field: &str,
        ids: &[(usize, Made)],
    ) -> Option<()> {
        let seeds = self.seeds;
        let s0 = &seeds[0];
        let per_object = self.targets(gi, g, field, ids)?;
        let distance = |i: usize, j: usize| {
            let (p, t) = (&s0.objects[ids[i].0].pose.0, &g.targets[j].0);
            (p[0] - t[0]).hypot(p[1] - t[1])
        };
        let chosen = assign(g, &per_object, &distance);
        let mut plan: Vec<(f64, f64, String, Option<Primitive>, PlaceTarget)> = Vec::new();
        for (i, options) in per_object.iter().enumerate() {
            let (_, m) = &ids[i];
            let pick = &options[chosen[i].unwrap_or(0)];
            // GenSim's oracle turns what it carries to the target's yaw where the goal has
            // `rotations` (or the match tests yaw): so does Assay's, while it holds it up.
            let checks_yaw = matches!(
                &pick.1,
                Goal::PoseWithin {
                    yaw_deg: Some(_),
                    ..
                }
            );
            let turn = (g.rotations || checks_yaw).then(|| {
                let symmetry = g.symmetries.get(i).copied().unwrap_or(0.0);
                Primitive::Turn {
                    yaw_deg: r6(yaw_of(&g.targets[pick.0].1).to_degrees()),
                    symmetry_deg: (symmetry > 1e-3 && symmetry < 2.0 * std::f64::consts::PI - 1e-3)
                        .then(|| r6(symmetry.to_degrees())),
                }
            });
            plan.push((
                pick.3,
                distance(i, pick.0),
                m.id.clone(),
                turn,
                pick.2.clone(),
            ));
            let mut any: Vec<Goal> = options.iter().map(|(_, goal, ..)| goal.clone()).collect();
            self.pose_goals.push(PoseGoal {
                object: m.id.clone(),
                add_goal: gi,
                goal: self.goals.len(),
                targets: options
                    .iter()
                    .map(|(j, ..)| [g.targets[*j].0[0], g.targets[*j].0[1]])
                    .collect(),
            });
            self.goals.push(if any.len() == 1 {
                any.remove(0)
            } else {
                Goal::AnyOf { any }
            });
        }
        plan.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        for (_, _, object, turn, target) in plan {
            let at = self.oracle.len();
            self.oracle.push(Primitive::Pick {
                object: object.clone(),
            });
            self.oracle.extend(turn);
            self.oracle.push(Primitive::Place { target });
            self.pose_steps
                .push((at, self.oracle.len() - at, object, gi));
        }
        self.pose_goal_notes(g, field);
        Some(())
    }

    /// The targets each of the objects `ids` of pose goal `gi` may go to (its row of
    /// `matches`); `None` when one has none (noted).
    fn targets(
        &mut self,
        gi: usize,
        g: &GoalRecord,
        field: &str,
        ids: &[(usize, Made)],
    ) -> Option<Vec<Vec<Target>>> {
        let mut per_object: Vec<Vec<Target>> = Vec::new();
        for (i, (k, m)) in ids.iter().enumerate() {
            let row = g.matches.get(i).cloned().unwrap_or_default();
            let symmetry = g.symmetries.get(i).copied().unwrap_or(0.0);
            let mut options = Vec::new();
            for (j, t) in g.targets.iter().enumerate() {
                if row.get(j).copied().unwrap_or(0.0) <= 0.0 {
                    continue;
                }
                let (goal, place, tz) = self.pose_target(gi, j, *k, m, t, symmetry);
                options.push((j, goal, place, tz));
            }
            if options.is_empty() {
                self.notes.error(
                    &format!("{field}.matches[{i}]"),
                    format!("object '{}' has no target it may go to", m.id),
                );
                return None;
            }
            per_object.push(options);
        }
        Some(per_object)
    }

    /// The notes on how pose goal `g` (at `field`) was read.
    fn pose_goal_notes(&mut self, g: &GoalRecord, field: &str) {
        let s0 = &self.seeds[0];
        let pos_eps = s0.pos_eps;
        let rot_eps = s0.rot_eps.to_degrees();
        self.notes.mapped(
            &format!("{field}.targ_poses"),
            format!(
                "each object's targets (its row of matches) → pose_within, x and y within pos_eps {pos_eps} m (GenSim's match ignores height); several → any_of; a target tied to an object over the seeds is measured from it"
            ),
        );
        if g.rotations {
            self.notes.inferred(
                &format!("{field}.rotations"),
                "the oracle turns each object to its target's yaw while it holds it up, as GenSim's oracle turns what it places",
            );
        }
        if g.symmetries.iter().any(|s| *s > 0.0) {
            self.notes.mapped(
                &format!("{field}.symmetries"),
                format!("yaw within rot_eps {rot_eps:.0}° modulo the symmetry; the oracle turns the object to its target's yaw"),
            );
        }
    }

    /// Target `j` (`t`) of goal `gi` for object `k` (made `m`, symmetric under `symmetry`
    /// rad): its goal, the oracle's place, and its height.
    fn pose_target(
        &self,
        gi: usize,
        j: usize,
        k: usize,
        m: &Made,
        t: &RecordedPose,
        symmetry: f64,
    ) -> (Goal, PlaceTarget, f64) {
        let s0 = &self.seeds[0];
        let (pos_eps, rot_eps_deg) = (s0.pos_eps, s0.rot_eps.to_degrees());
        let basis = if self.same.is_empty() {
            &self.seeds[..1]
        } else {
            &self.same[..]
        };
        // The object's centre at the target: GenSim's base position moved by the object's shift
        // turned to the target's yaw.
        let ty = yaw_of(&t.1);
        let s = rot_z(ty - m.yaw, [m.shift[0], m.shift[1]]);
        let yaw = (symmetry > 0.0 && symmetry < 2.0 * std::f64::consts::PI - 1e-3)
            .then(|| r6(ty.to_degrees()));
        let (position, relative_to, place) =
            self.target_place(tie(basis, &self.made, gi, j, k), t, s, pos_eps);
        let goal = Goal::PoseWithin {
            object: m.id.clone(),
            position: [r6(position[0]), r6(position[1]), 0.0],
            tolerance: r6(pos_eps),
            yaw_deg: yaw,
            yaw_tolerance_deg: yaw.map(|_| r6(rot_eps_deg)),
            relative_to,
            planar: true,
            yaw_symmetry_deg: yaw.map(|_| r6(symmetry.to_degrees())),
        };
        (goal, place, t.0[2])
    }

    /// Where target `t` lies (with `s` the object's shift turned to the target's yaw): from the
    /// object it is tied to (`tie`), or on the table; the oracle's place there.
    fn target_place(
        &self,
        tie: Tie,
        t: &RecordedPose,
        s: [f64; 2],
        pos_eps: f64,
    ) -> ([f64; 2], Option<String>, PlaceTarget) {
        match tie {
            Tie::To(a, d) => {
                let anchor = self.made[a].as_ref().expect("tied to a made object");
                let off = [d[0] + s[0] - anchor.shift[0], d[1] + s[1] - anchor.shift[1]];
                match anchor.kind {
                    // Zones are fixed: the target is a place on the table.
                    Kind::Zone => {
                        let p = [t.0[0] + s[0], t.0[1] + s[1]];
                        (
                            p,
                            None,
                            PlaceTarget::Spot {
                                xy: p.map(r6),
                                relative_to: None,
                            },
                        )
                    }
                    Kind::Object { container: true }
                        if off[0].hypot(off[1]) < ON_SPOT.max(pos_eps / 2.0) =>
                    {
                        (
                            off,
                            Some(anchor.id.clone()),
                            PlaceTarget::Into(anchor.id.clone()),
                        )
                    }
                    _ => (
                        off,
                        Some(anchor.id.clone()),
                        PlaceTarget::Spot {
                            xy: off.map(r6),
                            relative_to: Some(anchor.id.clone()),
                        },
                    ),
                }
            }
            Tie::Free => {
                let p = [t.0[0] + s[0], t.0[1] + s[1]];
                (
                    p,
                    None,
                    PlaceTarget::Spot {
                        xy: p.map(r6),
                        relative_to: None,
                    },
                )
            }
        }
    }

    /// GenSim's zone metric: the objects `ids` (or a pile) into one of the zones in `params`.
    /// Whether it could be imported (else the error is noted).
    fn zone_goal(&mut self, g: &GoalRecord, field: &str, ids: &[(usize, Made)]) -> bool {
        if g.zones.is_empty() {
            self.notes
                .error(&format!("{field}.params"), "a zone goal without zones");
            return false;
        }
        let zone_ids = self.goal_zones(g);
        let pile = ids.iter().all(|(_, m)| m.kind == Kind::Pile);
        if pile {
            let pid = ids[0].1.id.clone();
            self.goals.push(Goal::PileInZone {
                pile: pid.clone(),
                zone: zone_ids[0].clone(),
                fraction: 0.9,
            });
            self.oracle.push(Primitive::Sweep {
                pile: pid,
                zone: zone_ids[0].clone(),
            });
            self.notes.mapped(
                &format!("{field}.metric"),
                "'zone' on a pile → pile_in_zone, 90 % of the copies' centres (GenSim pops the goal at 99 % of the copies' points inside)",
            );
            return true;
        }
        if ids
            .iter()
            .any(|(_, m)| !matches!(m.kind, Kind::Object { .. }))
        {
            self.notes.error(
                &format!("{field}.objs"),
                "a zone goal mixing a pile and objects",
            );
            return false;
        }
        self.lay_out_in_zone(ids, &zone_ids);
        self.notes.mapped(
            &format!("{field}.metric"),
            "'zone' → in_zone for each object (its centre over the zone; GenSim counts the share of its points inside)",
        );
        true
    }

    /// The ids of zone goal `g`'s zones: the zone object at each zone's pose (sized as the
    /// goal says), or a zone of its own.
    fn goal_zones(&mut self, g: &GoalRecord) -> Vec<String> {
        let s0 = &self.seeds[0];
        let mut zone_ids = Vec::new();
        for (zi, (pose, size)) in g.zones.iter().enumerate() {
            let (p, _) = pose;
            let half = [
                size.first().copied().unwrap_or(0.1) / 2.0,
                size.get(1).copied().unwrap_or(0.1) / 2.0,
            ];
            // The zone object at that pose, or a zone of its own.
            let at = self.made.iter().enumerate().find_map(|(k, m)| {
                let m = m.as_ref()?;
                let o = s0.objects.get(k)?;
                (m.kind == Kind::Zone
                    && (o.pose.0[0] - p[0]).abs() < 1e-6
                    && (o.pose.0[1] - p[1]).abs() < 1e-6)
                    .then(|| m.id.clone())
            });
            let id = match at {
                Some(id) => {
                    if let Some(z) = self.zones.iter_mut().find(|z| z.id == id) {
                        z.half_extents = half.map(r6);
                    }
                    id
                }
                None => {
                    let id = format!("zone_{}", self.zones.len() + zi);
                    self.zones.push(Zone {
                        id: id.clone(),
                        center: [r6(p[0]), r6(p[1])],
                        half_extents: half.map(r6),
                        color: Color::Named("gray".into()),
                    });
                    id
                }
            };
            zone_ids.push(id);
        }
        zone_ids
    }

    /// Each of the objects `ids` in one of the zones `zone_ids`; the oracle lays them out on a
    /// grid over the first zone (a zone may lie on a pallet: each is lowered onto what is
    /// there).
    fn lay_out_in_zone(&mut self, ids: &[(usize, Made)], zone_ids: &[String]) {
        let zone = self
            .zones
            .iter()
            .find(|z| z.id == zone_ids[0])
            .cloned()
            .expect("made above");
        let side = (ids.len() as f64).sqrt().ceil() as usize;
        for (n, (_, m)) in ids.iter().enumerate() {
            let mut any: Vec<Goal> = zone_ids
                .iter()
                .map(|z| Goal::InZone {
                    object: m.id.clone(),
                    zone: z.clone(),
                })
                .collect();
            self.goals.push(if any.len() == 1 {
                any.remove(0)
            } else {
                Goal::AnyOf { any }
            });
            let cell = |k: usize, half: f64| {
                let usable = (half - 0.02).max(0.0);
                if side == 1 {
                    0.0
                } else {
                    -usable + 2.0 * usable * k as f64 / (side - 1) as f64
                }
            };
            let xy = [
                r6(zone.center[0] + cell(n % side, zone.half_extents[0])),
                r6(zone.center[1] + cell(n / side, zone.half_extents[1])),
            ];
            self.oracle.push(Primitive::Pick {
                object: m.id.clone(),
            });
            self.oracle.push(Primitive::Place {
                target: PlaceTarget::Spot {
                    xy,
                    relative_to: None,
                },
            });
        }
    }
}

/// The oracle's assignment of the objects to their targets (`per_object`, `distance` between
/// object `i` and target `j`): the nearest object and target first, each target taken once
/// unless `replace` (as GenSim's oracle does). Then lower targets go first, so that a stack
/// grows from the bottom, and an object already at its target before the others.
fn assign(
    g: &GoalRecord,
    per_object: &[Vec<Target>],
    distance: &dyn Fn(usize, usize) -> f64,
) -> Vec<Option<usize>> {
    let mut used = vec![false; g.targets.len()];
    let mut chosen: Vec<Option<usize>> = vec![None; per_object.len()];
    for _ in 0..per_object.len() {
        let best = per_object
            .iter()
            .enumerate()
            .filter(|(i, _)| chosen[*i].is_none())
            .flat_map(|(i, options)| {
                options
                    .iter()
                    .enumerate()
                    .filter(|(_, o)| g.replace || !used[o.0])
                    .map(move |(n, o)| (i, n, o.0))
            })
            .min_by(|a, b| distance(a.0, a.2).total_cmp(&distance(b.0, b.2)));
        let Some((i, n, j)) = best else { break };
        chosen[i] = Some(n);
        used[j] = true;
    }
    chosen
}
