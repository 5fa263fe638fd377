//! What GenSim code says that a spec checked on its final state cannot take as written: objects
//! drawn into the footprint of an asset larger than the code declared (`declutter`), and goals a
//! later goal of the same object contradicts (`supersede`). Each change is a mapping note.

use std::collections::{BTreeMap, BTreeSet};

use super::Notes;
use crate::r6;
use assay_spec::spec::{Goal, Object, Primitive, Zone};

/// GenSim's workspace (`Task.bounds`, x and y), where `get_random_pose` draws.
const WORKSPACE: [[f64; 2]; 2] = [[0.25, 0.75], [-0.5, 0.5]];
/// Step (m) of the search for a free spot.
const FREE_STEP: f64 = 0.005;
/// Footprint tests one task's search for free spots may make in all (well under a second): a
/// task of 500 objects drawn on top of each other is not searched without end.
const MAX_FOOTPRINT_TESTS: usize = 5_000_000;

/// An object's footprint on the table: centre, yaw (rad), half extents in x and y.
#[derive(Clone, Copy)]
struct Footprint {
    c: [f64; 2],
    yaw: f64,
    half: [f64; 2],
}

impl Footprint {
    /// Whether the two rectangles, each grown by `margin` on every side, overlap (separating
    /// axes: the four edge normals).
    fn overlaps(&self, other: &Footprint, margin: f64) -> bool {
        let d = [other.c[0] - self.c[0], other.c[1] - self.c[1]];
        let axes = |f: &Footprint| {
            let (s, c) = f.yaw.sin_cos();
            [[c, s], [-s, c]]
        };
        let reach = |f: &Footprint, a: [f64; 2]| {
            let [u, v] = axes(f);
            (f.half[0] + margin) * (u[0] * a[0] + u[1] * a[1]).abs()
                + (f.half[1] + margin) * (v[0] * a[0] + v[1] * a[1]).abs()
        };
        axes(self)
            .into_iter()
            .chain(axes(other))
            .all(|a| (d[0] * a[0] + d[1] * a[1]).abs() < reach(self, a) + reach(other, a) - 1e-4)
    }
}

/// Moves each movable object standing on the table that overlaps another one's footprint — its
/// asset's footprint, grown by the seeds' position jitter — to the nearest free spot in GenSim's
/// workspace. Generated code often declares a size smaller than the asset it loads (a pallet
/// "0.15 × 0.15" whose mesh is 0.30 × 0.25); the recorder keeps later objects clear of that
/// declared size only, where GenSim's own sampler masks the rendered asset. An object above the table (on another), or placed from another's pose by the
/// code (in a container it was drawn in), is left where the code put it.
pub(super) fn declutter(
    objects: &mut [Object],
    zones: &[Zone],
    halves: &BTreeMap<String, [f64; 3]>,
    tied: &BTreeSet<(String, String)>,
    jitter: f64,
    notes: &mut Notes,
) {
    let footprint = |o: &Object| {
        let p = o.pose.as_ref()?;
        let h = halves.get(&o.id)?;
        Some((
            Footprint {
                c: [p.position[0], p.position[1]],
                yaw: p.yaw_deg.to_radians(),
                half: [h[0], h[1]],
            },
            p.position[2] - h[2],
        ))
    };
    let zone_prints: Vec<Footprint> = zones
        .iter()
        .map(|z| Footprint {
            c: z.center,
            yaw: 0.0,
            half: z.half_extents,
        })
        .collect();
    let mut tests = 0usize;
    for k in 0..objects.len() {
        let o = &objects[k];
        if o.is_fixed {
            continue;
        }
        let Some((mine, bottom)) = footprint(o) else {
            continue;
        };
        // Above the table with something under it (on a pallet, in a container): where the
        // code put it. Above the table with nothing under it, it drops onto the table: so it is
        // kept clear as one standing there.
        let supported = objects.iter().enumerate().any(|(q, other)| {
            q != k
                && footprint(other).is_some_and(|(f, b)| {
                    let top = b + 2.0 * halves.get(&other.id).map_or(0.0, |h| h[2]);
                    top <= bottom + 0.01 && mine.overlaps(&f, 0.0)
                })
        });
        if bottom > 0.005 && supported {
            continue;
        }
        // What it must keep clear of: every fixed object, and the movable ones before it. Each
        // seed moves a movable object by up to `jitter` along x and y: a gap of √2 `jitter`
        // keeps it off a fixed one, twice that off another movable one.
        let others: Vec<(String, Footprint, f64)> = objects
            .iter()
            .enumerate()
            .filter(|(q, other)| *q != k && (other.is_fixed || *q < k))
            .filter_map(|(_, other)| {
                let margin = if other.is_fixed {
                    jitter / std::f64::consts::SQRT_2
                } else {
                    jitter * std::f64::consts::SQRT_2
                };
                footprint(other).map(|(f, ..)| (other.id.clone(), f, margin))
            })
            .collect();
        let clash = others.iter().find(|(id, f, margin)| {
            !tied.contains(&(o.id.clone(), id.clone())) && mine.overlaps(f, *margin)
        });
        let Some((with, ..)) = clash else { continue };
        let free = |c: [f64; 2]| {
            let f = Footprint { c, ..mine };
            c[0] - mine.half[0].max(mine.half[1]) >= WORKSPACE[0][0]
                && c[0] + mine.half[0].max(mine.half[1]) <= WORKSPACE[0][1]
                && c[1] - mine.half[0].max(mine.half[1]) >= WORKSPACE[1][0]
                && c[1] + mine.half[0].max(mine.half[1]) <= WORKSPACE[1][1]
                && others
                    .iter()
                    .all(|(_, g, margin)| !f.overlaps(g, margin + 0.0025))
                && zone_prints
                    .iter()
                    .all(|g| !f.overlaps(g, jitter / std::f64::consts::SQRT_2 + 0.0025))
        };
        // Rings of growing radius around where the code put it: the nearest free spot.
        let mut spot = None;
        'search: for ring in 1..200 {
            if tests > MAX_FOOTPRINT_TESTS {
                break;
            }
            let r = ring as f64 * FREE_STEP;
            let n = (2.0 * std::f64::consts::PI * r / FREE_STEP).ceil().max(8.0) as usize;
            for a in 0..n {
                let t = 2.0 * std::f64::consts::PI * a as f64 / n as f64;
                let c = [mine.c[0] + r * t.cos(), mine.c[1] + r * t.sin()];
                tests += others.len() + zone_prints.len() + 1;
                if free(c) {
                    spot = Some(c);
                    break 'search;
                }
            }
        }
        let id = objects[k].id.clone();
        let Some(c) = spot else {
            notes.not_mapped(
                &format!("scene.objects.{id}"),
                format!("overlaps '{with}' (the asset is larger than the size its code declared), and no free spot was found: it starts there"),
            );
            continue;
        };
        let p = objects[k].pose.as_mut().expect("has a footprint");
        let moved = (c[0] - p.position[0]).hypot(c[1] - p.position[1]);
        p.position[0] = r6(c[0]);
        p.position[1] = r6(c[1]);
        notes.inferred(
            &format!("scene.objects.{id}"),
            format!(
                "moved {:.0} mm to the nearest free spot: it overlapped '{with}' (its asset is larger than the size its code drew it with: GenSim's sampler keeps that size clear of what is drawn, and PyBullet pushes overlapping bodies apart at the first step)",
                moved * 1000.0
            ),
        );
    }
}

/// One object's pose goal of one `add_goal`: where it went in the spec's goals, and GenSim's
/// target positions (x, y) it may meet it at.
pub(super) struct PoseGoal {
    pub object: String,
    pub add_goal: usize,
    pub goal: usize,
    pub targets: Vec<[f64; 2]>,
}

/// Drops an object's pose goal that a later `add_goal` of the same object supersedes: none of
/// its targets lies within `pos_eps` of any of the later one's. GenSim checks its goals one
/// after another, and a goal met once stays counted ("sort the blocks into the zones, then
/// stack them"); spec v1 checks every goal in the final state, where no state meets both. The
/// final state GenSim's oracle leaves is the later goal's, so that one is kept. The oracle
/// carries an object with several pose goals once, to its last goal's target.
pub(super) fn supersede(
    pose_goals: &[PoseGoal],
    pose_steps: &[(usize, usize, String, usize)],
    pos_eps: f64,
    goals: &mut Vec<Goal>,
    oracle: &mut Vec<Primitive>,
    notes: &mut Notes,
) {
    let disjoint = |a: &PoseGoal, b: &PoseGoal| {
        a.targets.iter().all(|p| {
            b.targets
                .iter()
                .all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) > pos_eps)
        })
    };
    let mut dropped: BTreeSet<usize> = BTreeSet::new();
    for a in pose_goals {
        let later = pose_goals
            .iter()
            .find(|b| b.object == a.object && b.add_goal > a.add_goal && disjoint(a, b));
        if let Some(b) = later {
            dropped.insert(a.goal);
            notes.inferred(
                &format!("add_goal[{}].objs", a.add_goal),
                format!(
                    "'{}': superseded by add_goal[{}], which puts it elsewhere (no target of the two within pos_eps): GenSim counts a goal met once, spec v1 checks the final state, so the later goal is kept",
                    a.object, b.add_goal
                ),
            );
        }
    }
    let mut k = 0;
    goals.retain(|_| {
        k += 1;
        !dropped.contains(&(k - 1))
    });
    // The oracle carries each object once, to its last goal's target: an earlier placement of
    // it would only stand in the way of what is built later.
    let skip: BTreeSet<usize> = pose_steps
        .iter()
        .filter(|(_, _, object, gi)| {
            pose_steps
                .iter()
                .any(|(_, _, other, later)| other == object && later > gi)
        })
        .flat_map(|(at, n, ..)| *at..*at + n)
        .collect();
    let mut k = 0;
    oracle.retain(|_| {
        k += 1;
        !skip.contains(&(k - 1))
    });
}
