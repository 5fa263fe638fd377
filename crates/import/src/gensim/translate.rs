//! From what a GenSim task's `reset()` recorded (`sandbox::SeedRecord`, several seeds) to a task
//! spec. Seed 0 gives the layout; the other seeds say which target poses are tied to an object
//! (its pose plus an offset that stays the same, in the world's or the object's axes, on every
//! seed): such targets become goals measured from that object, so the relation survives
//! Assay's own per-seed variation. A target tied to nothing is a place on the table.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use super::repair::{PoseGoal, declutter, supersede};
use super::sandbox::{GoalRecord, ObjectRecord, RecordedPose, SeedRecord};
use super::{EXTRA_COLORS, Notes};
use crate::{JITTER, r6};
use assay_spec::spec::{
    Color, Goal, Object, Pile, PlaceTarget, Pose, Primitive, Region, Shape, Zone,
};

/// How closely a target's offset from an object must repeat over the seeds to tie it (m).
const TIED: f64 = 1e-4;
/// An offset shorter than this (m, in x and y) puts the target on the object's spot.
const ON_SPOT: f64 = 0.005;
/// The most objects, goals, and targets of one goal a recording may hold (GenSim tasks place a
/// few dozen; a pile is 50).
const MAX_RECORDED: usize = 500;

pub(crate) struct Translated {
    pub objects: Vec<Object>,
    pub zones: Vec<Zone>,
    pub piles: Vec<Pile>,
    pub goals: Vec<Goal>,
    pub oracle: Vec<Primitive>,
    pub jitter: f64,
}

/// One recorded object as the spec will have it.
struct Made {
    /// Its id in the spec (an object's, a zone's or the pile's).
    id: String,
    kind: Kind,
    /// Spec centre minus GenSim's base position, in the world.
    shift: [f64; 3],
    /// GenSim's yaw (rad).
    yaw: f64,
    /// A goal moves it: a target tied to it would move with it, where GenSim's stays put.
    moved: bool,
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Object { container: bool },
    Zone,
    Pile,
}

fn yaw_of(q: &[f64; 4]) -> f64 {
    let [x, y, z, w] = *q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

fn tilt_of(q: &[f64; 4]) -> f64 {
    let [x, y, z, w] = *q;
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    roll.abs().max(pitch.abs())
}

fn rot_z(a: f64, v: [f64; 2]) -> [f64; 2] {
    let (s, c) = a.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

fn color_of(o: &ObjectRecord) -> Color {
    if let Some(name) = &o.color_name {
        if let Some((_, rgb)) = EXTRA_COLORS.iter().find(|(k, _)| k == name) {
            return Color::Rgb(*rgb);
        }
        if assay_spec::spec::COLORS.iter().any(|(k, _)| k == name) {
            return Color::Named(name.clone());
        }
    }
    match o.color {
        Some(rgb) => Color::Rgb(rgb.map(r6)),
        None => Color::default(),
    }
}

fn fill_text(v: &serde_json::Value) -> Option<String> {
    match v {
        serde_json::Value::Number(n) => n.as_f64().map(|x| format!("{}", r6(x))),
        serde_json::Value::String(s) => Some(s.clone()),
        _ => None,
    }
}

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

pub(crate) fn translate(
    seeds: &[SeedRecord],
    asset_root: &Path,
    notes: &mut Notes,
) -> Option<Translated> {
    let s0 = &seeds[0];
    for s in seeds {
        let most = s
            .goals
            .iter()
            .map(|g| g.targets.len().max(g.objs.len()))
            .max();
        if s.objects.len() > MAX_RECORDED
            || s.goals.len() > MAX_RECORDED
            || most.is_some_and(|n| n > MAX_RECORDED)
        {
            notes.error(
                "reset",
                format!(
                    "builds {} objects and {} goals: more than the {MAX_RECORDED} a task may have",
                    s.objects.len(),
                    s.goals.len()
                ),
            );
            return None;
        }
    }
    // Seeds that built the same scene as seed 0 (same objects, same goals) tell ties apart.
    let same: Vec<SeedRecord> = seeds
        .iter()
        .filter(|s| {
            s.objects.len() == s0.objects.len()
                && s.objects
                    .iter()
                    .zip(&s0.objects)
                    .all(|(a, b)| a.urdf == b.urdf)
                && s.goals.len() == s0.goals.len()
                && s.goals
                    .iter()
                    .zip(&s0.goals)
                    .all(|(a, b)| a.objs == b.objs && a.targets.len() == b.targets.len())
        })
        .cloned()
        .collect();
    if same.len() < seeds.len() {
        notes.not_mapped(
            "reset",
            format!(
                "the task builds a different scene on some seeds ({} of {} seeds match seed 0): seed 0's scene is imported",
                same.len(),
                seeds.len()
            ),
        );
    }
    if let Some(o) = s0.objects.iter().position(|o| o.category == "deformable") {
        notes.error(
            &format!("env.add_object[{o}]"),
            "a deformable object: Assay simulates rigid bodies only",
        );
        return None;
    }

    // Objects.
    let mut made: Vec<Option<Made>> = Vec::new();
    let mut objects = Vec::new();
    let mut zones = Vec::new();
    let mut piles: Vec<Pile> = Vec::new();
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    // Each object's half extents (its asset's, not the size the code declared).
    let mut halves: BTreeMap<String, [f64; 3]> = BTreeMap::new();
    let mut fatal = false;
    for (k, o) in s0.objects.iter().enumerate() {
        let field = format!("env.add_object[{k}]");
        if let Err(e) = crate::check_asset(asset_root, &o.urdf) {
            notes.error(&field, format!("URDF {e}"));
            fatal = true;
            made.push(None);
            continue;
        }
        let mut fill = BTreeMap::new();
        for (key, v) in &o.fill {
            match fill_text(v) {
                Some(t) => {
                    fill.insert(key.clone(), t);
                }
                None => {
                    notes.error(
                        &format!("{field}.fill.{key}"),
                        format!("not a number or a file name: {v}"),
                    );
                    fatal = true;
                }
            }
        }
        let full = asset_root.join(&o.urdf);
        let assembled = match assay_spec::urdf::assemble_filled(
            &full,
            &fill,
            &BTreeMap::new(),
            &BTreeMap::new(),
        ) {
            Ok(a) => a,
            Err(e) => {
                notes.error(&field, format!("URDF '{}': {e}", o.urdf));
                fatal = true;
                made.push(None);
                continue;
            }
        };
        let (pos, rot) = o.pose;
        if tilt_of(&rot) > 1f64.to_radians() {
            notes.not_mapped(
                &format!("{field}.pose"),
                "a tilted pose (roll or pitch): spec v1 poses turn about z only; the object stands upright",
            );
        }
        let yaw = yaw_of(&rot);
        // The spec's frame is the centre of the visual box; GenSim's is the URDF's base link.
        let c = {
            let xy = rot_z(yaw, [assembled.centre[0], assembled.centre[1]]);
            [xy[0], xy[1], assembled.centre[2]]
        };
        let half = assembled.half;
        let stem = Path::new(&o.urdf)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("object")
            .trim_end_matches("-template")
            .replace('-', "_");
        let stem = crate::slug(&stem, '_');
        let base = match &o.color_name {
            Some(c) => format!("{}_{stem}", crate::slug(c, '_')),
            None => stem,
        };
        let marker = assembled.urdf.links.iter().all(|l| l.collisions.is_empty());
        if o.pile {
            let pid = format!("{base}_pile");
            if let Some(p) = piles.iter_mut().find(|p| p.id == pid) {
                p.count += 1;
                p.region.min = [p.region.min[0].min(pos[0]), p.region.min[1].min(pos[1])];
                p.region.max = [p.region.max[0].max(pos[0]), p.region.max[1].max(pos[1])];
            } else {
                piles.push(Pile {
                    id: pid.clone(),
                    count: 1,
                    shape: Shape::Urdf {
                        path: o.urdf.clone(),
                        joints: BTreeMap::new(),
                        articulated: false,
                        fill,
                    },
                    color: color_of(o),
                    mass: None,
                    region: Region {
                        min: [pos[0], pos[1]],
                        max: [pos[0], pos[1]],
                    },
                });
            }
            made.push(Some(Made {
                id: pid,
                kind: Kind::Pile,
                shift: [0.0; 3],
                yaw,
                moved: false,
            }));
            continue;
        }
        let n = counts.entry(base.clone()).or_insert(0);
        let id = if *n == 0 {
            base.clone()
        } else {
            format!("{base}_{n}")
        };
        *n += 1;
        if marker {
            // A flat marker with nothing to collide (a zone, a line): drawn, not simulated.
            zones.push(Zone {
                id: id.clone(),
                center: [r6(pos[0] + c[0]), r6(pos[1] + c[1])],
                half_extents: [r6(half[0].max(0.005)), r6(half[1].max(0.005))],
                color: color_of(o),
            });
            notes.mapped(
                &field,
                format!(
                    "zone '{id}' from '{}' (visual only: a flat marker, axis-aligned in spec v1)",
                    o.urdf
                ),
            );
            made.push(Some(Made {
                id,
                kind: Kind::Zone,
                shift: [c[0], c[1], 0.0],
                yaw,
                moved: false,
            }));
            continue;
        }
        let container = o.urdf.ends_with("bowl/bowl.urdf");
        let shape = if container {
            Shape::Container {
                inner_half_extents: [0.05, 0.05, 0.015],
                wall: 0.01,
            }
        } else {
            Shape::Urdf {
                path: o.urdf.clone(),
                joints: BTreeMap::new(),
                articulated: false,
                fill: fill.clone(),
            }
        };
        let half_z = if container { 0.02 } else { half[2] };
        let centre = [pos[0] + c[0], pos[1] + c[1], (pos[2] + c[2]).max(half_z)];
        notes.mapped(
            &field,
            if fill.is_empty() {
                format!("object '{id}' from '{}'", o.urdf)
            } else {
                format!(
                    "object '{id}' from template '{}' filled with {:?}",
                    o.urdf, fill
                )
            },
        );
        // What it occupies: its visual box, or its collision shapes where they reach further.
        let reach = assembled.collision_half();
        halves.insert(
            id.clone(),
            [half[0].max(reach[0]), half[1].max(reach[1]), half_z],
        );
        objects.push(Object {
            id: id.clone(),
            shape,
            color: color_of(o),
            mass: None,
            is_fixed: o.category == "fixed",
            pose: Some(Pose {
                position: centre.map(r6),
                yaw_deg: r6(yaw.to_degrees()),
            }),
            pose_range: None,
        });
        made.push(Some(Made {
            id,
            kind: Kind::Object { container },
            shift: [c[0], c[1], centre[2] - pos[2]],
            yaw,
            moved: false,
        }));
    }
    if fatal {
        return None;
    }
    for p in &mut piles {
        p.region.min = p.region.min.map(|x| r6(x - 0.01));
        p.region.max = p.region.max.map(|x| r6(x + 0.01));
    }

    // Objects placed from another's pose (a part on a base, a block in a bowl) keep their
    // relation only when nothing moves them apart.
    let mut jitter = JITTER;
    let mut tied_pairs: BTreeSet<(String, String)> = BTreeSet::new();
    for (k, m) in made.iter().enumerate() {
        let Some(m) = m else { continue };
        if !matches!(m.kind, Kind::Object { .. }) || same.len() < 2 {
            continue;
        }
        for (q, other) in made.iter().enumerate() {
            let Some(other) = other else { continue };
            if q == k || !matches!(other.kind, Kind::Object { .. }) {
                continue;
            }
            let d: Vec<[f64; 3]> = same
                .iter()
                .map(|s| {
                    let (a, b) = (&s.objects[k].pose.0, &s.objects[q].pose.0);
                    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
                })
                .collect();
            let tied = d
                .windows(2)
                .all(|w| (0..3).all(|a| (w[0][a] - w[1][a]).abs() <= TIED));
            if tied {
                tied_pairs.insert((m.id.clone(), other.id.clone()));
            }
            if tied && d[0][0].hypot(d[0][1]) < 0.2 && jitter > 0.0 {
                jitter = 0.0;
                notes.inferred(
                    "variations.position_jitter",
                    format!(
                        "0: '{}' is placed from the pose of '{}', and independent jitter would move them apart",
                        m.id, other.id
                    ),
                );
            }
        }
    }

    for g in &s0.goals {
        for &oid in &g.objs {
            if let Some(Some(m)) = made.get_mut(oid.wrapping_sub(1)) {
                m.moved = true;
            }
        }
    }

    if s0.goals.len() > 1 {
        notes.not_mapped(
            "add_goal.step_max_reward",
            "goal order and partial reward: GenSim checks goals one after another (a goal met once stays counted), Assay requires all of them at the end",
        );
    }

    // Goals, in GenSim's order; the oracle follows them.
    let mut goals = Vec::new();
    let mut oracle = Vec::new();
    let pos_eps = s0.pos_eps;
    let rot_eps = s0.rot_eps.to_degrees();
    let mut start_yaw: BTreeMap<String, f64> = BTreeMap::new();
    let mut pose_goals: Vec<PoseGoal> = Vec::new();
    // (index of the pick in `oracle`, object, add_goal) of each pick-and-place of a pose goal.
    let mut pose_steps: Vec<(usize, String, usize)> = Vec::new();
    for (gi, g) in s0.goals.iter().enumerate() {
        let field = format!("add_goal[{gi}]");
        if let Some(shape) = &g.matches_shape {
            notes.not_mapped(
                &format!("{field}.matches"),
                format!(
                    "{shape:?} for {} objects and {} targets: the rows and columns that exist are kept (GenSim fails when it reaches the others)",
                    g.objs.len(),
                    g.targets.len()
                ),
            );
        }
        let ids: Vec<(usize, &Made)> = g
            .objs
            .iter()
            .filter_map(|&oid| {
                made.get(oid.wrapping_sub(1))
                    .and_then(|m| m.as_ref())
                    .map(|m| (oid - 1, m))
            })
            .collect();
        if ids.len() != g.objs.len() {
            notes.error(
                &format!("{field}.objs"),
                "an object of this goal was not imported",
            );
            return None;
        }
        if g.metric == "zone" {
            if !zone_goal(
                g,
                &field,
                &ids,
                &made,
                s0,
                &mut zones,
                &mut goals,
                &mut oracle,
                notes,
            ) {
                return None;
            }
            continue;
        }
        if ids
            .iter()
            .any(|(_, m)| !matches!(m.kind, Kind::Object { .. }))
        {
            notes.error(
                &format!("{field}.objs"),
                "a pose goal on a zone or a pile: only objects can be placed",
            );
            return None;
        }
        // Each object's allowed targets, as goals.
        let mut per_object: Vec<Vec<(usize, Goal, PlaceTarget, f64)>> = Vec::new();
        for (i, (k, m)) in ids.iter().enumerate() {
            let row = g.matches.get(i).cloned().unwrap_or_default();
            let symmetry = g.symmetries.get(i).copied().unwrap_or(0.0);
            let mut options = Vec::new();
            for (j, t) in g.targets.iter().enumerate() {
                if row.get(j).copied().unwrap_or(0.0) <= 0.0 {
                    continue;
                }
                let (goal, place, tz) = pose_target(
                    g, gi, j, *k, m, t, symmetry, pos_eps, rot_eps, &same, seeds, &made,
                );
                options.push((j, goal, place, tz));
            }
            if options.is_empty() {
                notes.error(
                    &format!("{field}.matches[{i}]"),
                    format!("object '{}' has no target it may go to", m.id),
                );
                return None;
            }
            per_object.push(options);
        }
        // The oracle's assignment: the nearest object and target first, each target taken
        // once unless `replace` (as GenSim's oracle does); then lower targets first, so that a
        // stack grows from the bottom, and an object already at its target before the others.
        let distance = |i: usize, j: usize| {
            let (p, t) = (&s0.objects[ids[i].0].pose.0, &g.targets[j].0);
            (p[0] - t[0]).hypot(p[1] - t[1])
        };
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
        let mut plan: Vec<(f64, f64, String, PlaceTarget)> = Vec::new();
        for (i, options) in per_object.iter().enumerate() {
            let (_, m) = ids[i];
            let pick = &options[chosen[i].unwrap_or(0)];
            // GenSim's oracle turns what it carries to the target's yaw where the goal has
            // `rotations` (or the match tests yaw); Assay's does not turn it, so the object
            // starts turned as its target.
            let checks_yaw = matches!(
                &pick.1,
                Goal::PoseWithin {
                    yaw_deg: Some(_),
                    ..
                }
            );
            if g.rotations || checks_yaw {
                start_yaw.insert(m.id.clone(), yaw_of(&g.targets[pick.0].1).to_degrees());
            }
            plan.push((pick.3, distance(i, pick.0), m.id.clone(), pick.2.clone()));
            let mut any: Vec<Goal> = options.iter().map(|(_, goal, ..)| goal.clone()).collect();
            pose_goals.push(PoseGoal {
                object: m.id.clone(),
                add_goal: gi,
                goal: goals.len(),
                targets: options
                    .iter()
                    .map(|(j, ..)| [g.targets[*j].0[0], g.targets[*j].0[1]])
                    .collect(),
            });
            goals.push(if any.len() == 1 {
                any.remove(0)
            } else {
                Goal::AnyOf { any }
            });
        }
        plan.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        for (_, _, object, target) in plan {
            pose_steps.push((oracle.len(), object.clone(), gi));
            oracle.push(Primitive::Pick { object });
            oracle.push(Primitive::Place { target });
        }
        notes.mapped(
            &format!("{field}.targ_poses"),
            format!(
                "each object's targets (its row of matches) → pose_within, x and y within pos_eps {pos_eps} m (GenSim's match ignores height); several → any_of; a target tied to an object over the seeds is measured from it"
            ),
        );
        if g.rotations {
            notes.inferred(
                &format!("{field}.rotations"),
                "the objects start turned as their targets: GenSim's oracle turns what it places, Assay's carries it as it lies",
            );
        }
        if g.symmetries.iter().any(|s| *s > 0.0) {
            notes.mapped(
                &format!("{field}.symmetries"),
                format!("yaw within rot_eps {rot_eps:.0}° modulo the symmetry; the object starts turned as its target (Assay's oracle does not turn what it carries)"),
            );
        }
    }
    supersede(
        &pose_goals,
        &pose_steps,
        pos_eps,
        &mut goals,
        &mut oracle,
        notes,
    );
    // Objects with a yaw to match start at it (mod nothing: the same yaw).
    for o in &mut objects {
        if let (Some(y), Some(p)) = (start_yaw.get(&o.id), o.pose.as_mut()) {
            p.yaw_deg = r6(*y);
        }
    }
    declutter(&mut objects, &zones, &halves, &tied_pairs, jitter, notes);
    if goals.is_empty() {
        notes.error("add_goal", "the task adds no goal");
        return None;
    }
    Some(Translated {
        objects,
        zones,
        piles,
        goals,
        oracle,
        jitter,
    })
}

/// A pose target of object `k` (made `m`): its goal, the oracle's place, and its height.
#[allow(clippy::too_many_arguments)]
fn pose_target(
    _g: &GoalRecord,
    gi: usize,
    j: usize,
    k: usize,
    m: &Made,
    t: &RecordedPose,
    symmetry: f64,
    pos_eps: f64,
    rot_eps_deg: f64,
    same: &[SeedRecord],
    seeds: &[SeedRecord],
    made: &[Option<Made>],
) -> (Goal, PlaceTarget, f64) {
    let basis = if same.is_empty() { &seeds[..1] } else { same };
    // The object's centre at the target: GenSim's base position moved by the object's shift
    // turned to the target's yaw.
    let ty = yaw_of(&t.1);
    let s = rot_z(ty - m.yaw, [m.shift[0], m.shift[1]]);
    let yaw = (symmetry > 0.0 && symmetry < 2.0 * std::f64::consts::PI - 1e-3)
        .then(|| r6(ty.to_degrees()));
    let (position, relative_to, place) = match tie(basis, made, gi, j, k) {
        Tie::To(a, d) => {
            let anchor = made[a].as_ref().expect("tied to a made object");
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
    };
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

/// GenSim's zone metric: the objects (or a pile) into one of the zones in `params`.
#[allow(clippy::too_many_arguments)]
fn zone_goal(
    g: &GoalRecord,
    field: &str,
    ids: &[(usize, &Made)],
    made: &[Option<Made>],
    s0: &SeedRecord,
    zones: &mut Vec<Zone>,
    goals: &mut Vec<Goal>,
    oracle: &mut Vec<Primitive>,
    notes: &mut Notes,
) -> bool {
    if g.zones.is_empty() {
        notes.error(&format!("{field}.params"), "a zone goal without zones");
        return false;
    }
    let mut zone_ids = Vec::new();
    for (zi, (pose, size)) in g.zones.iter().enumerate() {
        let (p, _) = pose;
        let half = [
            size.first().copied().unwrap_or(0.1) / 2.0,
            size.get(1).copied().unwrap_or(0.1) / 2.0,
        ];
        // The zone object at that pose, or a zone of its own.
        let at = made.iter().enumerate().find_map(|(k, m)| {
            let m = m.as_ref()?;
            let o = s0.objects.get(k)?;
            (m.kind == Kind::Zone
                && (o.pose.0[0] - p[0]).abs() < 1e-6
                && (o.pose.0[1] - p[1]).abs() < 1e-6)
                .then(|| m.id.clone())
        });
        let id = match at {
            Some(id) => {
                if let Some(z) = zones.iter_mut().find(|z| z.id == id) {
                    z.half_extents = half.map(r6);
                }
                id
            }
            None => {
                let id = format!("zone_{}", zones.len() + zi);
                zones.push(Zone {
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
    let pile = ids.iter().all(|(_, m)| m.kind == Kind::Pile);
    if pile {
        let pid = ids[0].1.id.clone();
        goals.push(Goal::PileInZone {
            pile: pid.clone(),
            zone: zone_ids[0].clone(),
            fraction: 0.9,
        });
        oracle.push(Primitive::Sweep {
            pile: pid,
            zone: zone_ids[0].clone(),
        });
        notes.mapped(
            &format!("{field}.metric"),
            "'zone' on a pile → pile_in_zone, 90 % of the copies' centres (GenSim pops the goal at 99 % of the copies' points inside)",
        );
        return true;
    }
    if ids
        .iter()
        .any(|(_, m)| !matches!(m.kind, Kind::Object { .. }))
    {
        notes.error(
            &format!("{field}.objs"),
            "a zone goal mixing a pile and objects",
        );
        return false;
    }
    // The oracle lays the objects out on a grid over the first zone (a zone may lie on a
    // pallet: each is lowered onto what is there).
    let zone = zones
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
        goals.push(if any.len() == 1 {
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
        oracle.push(Primitive::Pick {
            object: m.id.clone(),
        });
        oracle.push(Primitive::Place {
            target: PlaceTarget::Spot {
                xy,
                relative_to: None,
            },
        });
    }
    notes.mapped(
        &format!("{field}.metric"),
        "'zone' → in_zone for each object (its centre over the zone; GenSim counts the share of its points inside)",
    );
    true
}
