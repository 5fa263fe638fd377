//! Where the oracle sets what it carries: how high a carried object lands over a spot, how it
//! keeps clear of its neighbours, and which move of the plan goes first when a place is covered
//! by an object the plan moves later. Reads the sim's shapes and poses (the state-reading
//! oracle; a seeing oracle locates `relative_to` through its camera first).

use assay_spec::spec::{PlaceTarget, Primitive};
use rapier3d::prelude::*;

use crate::scene::SimScene;

/// The colliders of every scene object but `held`.
fn colliders_besides(scene: &SimScene, held: usize) -> Vec<ColliderHandle> {
    scene
        .objects
        .iter()
        .enumerate()
        .filter(|(k, _)| *k != held)
        .flat_map(|(_, other)| scene.world.bodies[other.body].colliders().iter().copied())
        .collect()
}

/// How far along a ray from `from` in direction `dir` (at most `max`) it first meets one of
/// `colliders`, if it does (a ray starting inside a shape meets it at 0).
pub(crate) fn first_hit(
    scene: &SimScene,
    colliders: &[ColliderHandle],
    from: Vec3,
    dir: Vec3,
    max: f32,
) -> Option<f32> {
    colliders
        .iter()
        .filter_map(|h| {
            let col = &scene.world.colliders[*h];
            col.shape()
                .cast_ray(col.position(), &Ray::new(from, dir), max, true)
        })
        .reduce(f32::min)
}

/// The height at which held object `held`, carried as it is and lowered straight down with its
/// centre over (`x`, `y`), first touches what lies below (another object, or the table at
/// z = 0): on a grid over its footprint, a ray up from under it finds its own bottom there and a
/// ray down finds the top of what is under that point; the highest meeting wins. A hollow, a
/// hole or a slot between two blocks is found as it is, whatever the shapes. The shapes are the
/// simulator's (a seeing oracle finds `relative_to` where its camera saw it, then lowers what
/// it carries onto what is there): `spot` is an oracle's place, not a policy's observation.
/// `inset` (0–1] keeps the grid to that share of the footprint about its centre: below 1 it
/// finds what the spot is meant to stand on, not a neighbour's edge under the rim.
fn resting_height(scene: &SimScene, held: usize, x: f32, y: f32, inset: f32) -> f32 {
    const GRID: usize = 9;
    const ABOVE: f32 = 3.0;
    let o = &scene.objects[held];
    let c = scene.pose(o).translation;
    let reach = o.half.x.max(o.half.y) * std::f32::consts::SQRT_2 * inset;
    let cast = |colliders: &[ColliderHandle], from: Vec3, dir: Vec3| {
        first_hit(scene, colliders, from, dir, 2.0 * ABOVE)
    };
    let own = scene.world.bodies[o.body].colliders();
    let others = colliders_besides(scene, held);
    let mut centre = o.half.z;
    for a in 0..GRID {
        for b in 0..GRID {
            let along = |k: usize| reach * (2.0 * k as f32 / (GRID - 1) as f32 - 1.0);
            let (dx, dy) = (along(a), along(b));
            let below = Vec3::new(c.x + dx, c.y + dy, c.z - ABOVE);
            let Some(up) = cast(own, below, Vec3::Z) else {
                continue;
            };
            let bottom = below.z + up - c.z;
            let top = cast(&others, Vec3::new(x + dx, y + dy, ABOVE), -Vec3::Z)
                .map_or(0.0, |down| (ABOVE - down).max(0.0));
            centre = centre.max(top - bottom);
        }
    }
    centre
}

/// Share of a carried object's footprint that finds what a `spot` is meant to stand on.
const CORE_INSET: f32 = 0.6;

/// Gap (m) a `spot` place keeps from what stands beside the spot at the height it lands.
const SIDE_CLEARANCE: f32 = 0.002;
/// The most (m) a `spot` place is shifted to keep that gap: well inside GenSim's 1 cm pose
/// tolerance.
const MAX_SIDE_SHIFT: f32 = 0.004;

/// Where, near `at` (held object `held`'s centre where [`resting_height`] lands it), to lower it
/// so that it keeps [`SIDE_CLEARANCE`] from the objects beside it. Generated layouts put blocks
/// side by side with no gap (two 4 cm blocks 4 cm apart); lowered exactly there, the carried
/// block's bottom edge catches its neighbour's top edge and tips or shoves it out of tolerance.
/// Contacts whose normal is mostly vertical (what it lands on) do not move it; the shift is at
/// most [`MAX_SIDE_SHIFT`].
fn clear_of_neighbours(scene: &SimScene, held: usize, at: Vec3) -> Vec3 {
    use rapier3d::parry::query::contact;
    const LIFT: f32 = 0.001;
    let o = &scene.objects[held];
    let c = scene.pose(o).translation;
    let own = scene.world.bodies[o.body].colliders();
    let others = colliders_besides(scene, held);
    let mut shift = Vec3::ZERO;
    for _ in 0..4 {
        let delta = at + shift + Vec3::Z * LIFT - c;
        let mut push = Vec3::ZERO;
        for h1 in own {
            let c1 = &scene.world.colliders[*h1];
            let mut p1 = *c1.position();
            p1.translation += delta;
            for h2 in &others {
                let c2 = &scene.world.colliders[*h2];
                let Ok(Some(k)) =
                    contact(&p1, c1.shape(), c2.position(), c2.shape(), SIDE_CLEARANCE)
                else {
                    continue;
                };
                let n = k.normal1;
                let side = Vec3::new(n.x, n.y, 0.0);
                if n.z.abs() > 0.7 || side.length() < 1e-6 {
                    continue;
                }
                push -= side.normalize() * (SIDE_CLEARANCE - k.dist).min(MAX_SIDE_SHIFT);
            }
        }
        if push.length() < 1e-5 {
            break;
        }
        shift += push;
        if shift.length() > MAX_SIDE_SHIFT {
            shift = shift.normalize() * MAX_SIDE_SHIFT;
            break;
        }
    }
    at + shift
}

/// Where to lower held object `held` for a `spot` at (`x`, `y`): where [`resting_height`]
/// lands it, kept clear of its neighbours ([`clear_of_neighbours`]). Where only a neighbour's
/// edge under its rim holds it up above what the spot's middle stands on (two 4 cm blocks
/// asked 4 cm apart, the first set down a fraction of a millimetre off), the spot is cleared
/// at the lower height instead and kept if that frees it: lowered as it was, the block would
/// sit on that edge and tip.
pub(crate) fn edge_free_spot(scene: &SimScene, held: usize, x: f32, y: f32) -> Vec3 {
    const LOWER: f32 = 0.001;
    let full = resting_height(scene, held, x, y, 1.0);
    let core = resting_height(scene, held, x, y, CORE_INSET);
    if core < full - LOWER {
        let at = clear_of_neighbours(scene, held, Vec3::new(x, y, core));
        let z = resting_height(scene, held, at.x, at.y, 1.0);
        if z < full - LOWER {
            return Vec3::new(at.x, at.y, z);
        }
    }
    clear_of_neighbours(scene, held, Vec3::new(x, y, full))
}

/// A move of the plan: a pick of `object` at `pick`, its place at `place`, and the index after
/// it.
struct Move {
    object: String,
    pick: usize,
    place: usize,
    end: usize,
}

/// Where a place sets what it carries (its centre on the table), where that does not depend on
/// an object the plan still moves (`moved`).
fn place_xy(p: &Primitive, scene: &SimScene, moved: &[&str]) -> Option<Vec3> {
    let Primitive::Place { target } = p else {
        return None;
    };
    let centre_of = |id: &str| {
        if moved.contains(&id) {
            return None;
        }
        let i = scene.index_of(id)?;
        Some(scene.pose(&scene.objects[i]).translation)
    };
    let xy = match target {
        PlaceTarget::Spot { xy, relative_to } => {
            let origin = match relative_to {
                None => Vec3::ZERO,
                Some(id) => centre_of(id)?,
            };
            origin + Vec3::new(xy[0] as f32, xy[1] as f32, 0.0)
        }
        PlaceTarget::At(xy) => Vec3::new(xy[0] as f32, xy[1] as f32, 0.0),
        PlaceTarget::AtPoint(p) => Vec3::new(p[0] as f32, p[1] as f32, 0.0),
        PlaceTarget::Zone(id) => scene_zone(scene, id)?.0,
        PlaceTarget::On(id) | PlaceTarget::Into(id) => centre_of(id)?,
    };
    Some(Vec3::new(xy.x, xy.y, 0.0))
}

/// Whether object `i`, set down with its centre at `at` as it is turned now, would cover part
/// of where object `k` stands (their boxes seen from above).
fn footprints_overlap(scene: &SimScene, i: usize, at: Vec3, k: usize) -> bool {
    let corners = |half: Vec3, pose: Pose, centre: Vec3| -> [[f32; 2]; 4] {
        let ax = pose.rotation * Vec3::X * half.x;
        let ay = pose.rotation * Vec3::Y * half.y;
        [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)].map(|(u, v)| {
            [
                centre.x + u * ax.x + v * ay.x,
                centre.y + u * ax.y + v * ay.y,
            ]
        })
    };
    let (a, b) = (&scene.objects[i], &scene.objects[k]);
    let (pa, pb) = (scene.pose(a), scene.pose(b));
    let ca = corners(a.half, pa, at);
    let cb = corners(b.half, pb, pb.translation);
    let edge =
        |c: &[[f32; 2]; 4], from: usize, to: usize| [c[to][0] - c[from][0], c[to][1] - c[from][1]];
    // Separating axes: the normals of both rectangles' edges.
    let axes = [
        edge(&ca, 0, 1),
        edge(&ca, 0, 3),
        edge(&cb, 0, 1),
        edge(&cb, 0, 3),
    ];
    !axes.iter().any(|e| {
        let n = [-e[1], e[0]];
        if n[0] * n[0] + n[1] * n[1] < 1e-12 {
            return false;
        }
        let span = |c: &[[f32; 2]; 4]| {
            c.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
                let d = p[0] * n[0] + p[1] * n[1];
                (lo.min(d), hi.max(d))
            })
        };
        let (a0, a1) = span(&ca);
        let (b0, b1) = span(&cb);
        a1 <= b0 || b1 <= a0
    })
}

/// Where the move starting at plan index `next` (pick, turns, place) would set its object
/// where another object stands that a later move of the plan carries away, that later move is
/// brought forward to `next` (as a person clears a spot before using it), and the note for the
/// episode is returned: generated layouts draw objects onto targets the code computed but never
/// occupied, and set there, the object is knocked off or lands on the other one. Only a later
/// move that does not depend on the moves it jumps (its target is not on or beside what they
/// carry) and does not land where the first move's object stands is brought forward; one
/// reordering at most each time a move starts.
pub(crate) fn clear_first(
    plan: &mut Vec<Primitive>,
    next: usize,
    scene: &SimScene,
) -> Option<String> {
    let first = move_at(plan, next)?;
    let picked = |range: std::ops::Range<usize>| -> Vec<String> {
        plan[range]
            .iter()
            .filter_map(|p| match p {
                Primitive::Pick { object } => Some(object.clone()),
                _ => None,
            })
            .collect()
    };
    let moved = picked(next..plan.len());
    let moved: Vec<&str> = moved.iter().map(String::as_str).collect();
    let i = scene.index_of(&first.object)?;
    let at = place_xy(&plan[first.place], scene, &moved)?;
    let mut start = first.end;
    while let Some(later) = move_at(plan, start) {
        let blocking = scene
            .index_of(&later.object)
            .filter(|&k| !scene.objects[k].fixed && footprints_overlap(scene, i, at, k));
        let jumped = picked(next..later.pick);
        let jumped: Vec<&str> = jumped.iter().map(String::as_str).collect();
        let independent = match &plan[later.place] {
            Primitive::Place { target } => match target {
                PlaceTarget::Spot { relative_to, .. } => {
                    relative_to.as_deref().is_none_or(|r| !jumped.contains(&r))
                }
                PlaceTarget::On(r) | PlaceTarget::Into(r) => !jumped.contains(&r.as_str()),
                _ => true,
            },
            _ => false,
        };
        // Brought forward, it must not land where the first move's object stands now.
        let clear = |k: usize| {
            place_xy(&plan[later.place], scene, &jumped)
                .is_some_and(|to| !footprints_overlap(scene, k, to, i))
        };
        if let (Some(k), true) = (blocking, independent)
            && clear(k)
        {
            let lifted = plan.drain(later.pick..later.end).collect::<Vec<_>>();
            plan.splice(next..next, lifted);
            return Some(format!(
                "moved '{}' first: it stood where '{}' goes",
                scene.objects[k].id, first.object
            ));
        }
        start = later.end;
    }
    None
}

/// The move (a pick, any turns, a place) that starts at plan index `at`, if one does.
fn move_at(plan: &[Primitive], at: usize) -> Option<Move> {
    let Some(Primitive::Pick { object }) = plan.get(at) else {
        return None;
    };
    let mut k = at + 1;
    while let Some(Primitive::Turn { .. }) = plan.get(k) {
        k += 1;
    }
    matches!(plan.get(k), Some(Primitive::Place { .. })).then(|| Move {
        object: object.clone(),
        pick: at,
        place: k,
        end: k + 1,
    })
}

/// Centre and half extents of zone `id`.
pub(crate) fn scene_zone(scene: &SimScene, id: &str) -> Option<(Vec3, Vec3)> {
    scene.zones.iter().find(|z| z.0 == id).map(|z| (z.1, z.2))
}
