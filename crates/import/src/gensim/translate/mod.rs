//! From what a GenSim task's `reset()` recorded (`sandbox::SeedRecord`, several seeds) to a task
//! spec. Seed 0 gives the layout; the other seeds say which target poses are tied to an object
//! (its pose plus an offset that stays the same, in the world's or the object's axes, on every
//! seed): such targets become goals measured from that object, so the relation survives
//! Assay's own per-seed variation. A target tied to nothing is a place on the table.
//!
//! Owns: the checks on the recording as a whole, and the order of the phases. Seed 0's objects
//! become objects, zones and piles in `objects`; its goals become goals and the oracle's plan in
//! `goals`; `repair` then settles what the code says but a spec cannot take as written.

mod goals;
mod objects;
pub(crate) use objects::fill_text;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use super::Notes;
use super::repair::{PoseGoal, declutter, supersede};
use super::sandbox::SeedRecord;
use crate::JITTER;
use assay_spec::spec::{Goal, Object, Pile, Primitive, RewardStep, Zone};

/// How closely a target's offset from an object must repeat over the seeds to tie it (m).
const TIED: f64 = 1e-4;
/// The most objects, goals, and targets of one goal a recording may hold (GenSim tasks place a
/// few dozen; a pile is 50).
const MAX_RECORDED: usize = 500;

pub(crate) struct Translated {
    pub reward_steps: Vec<RewardStep>,
    pub objects: Vec<Object>,
    pub zones: Vec<Zone>,
    pub piles: Vec<Pile>,
    pub goals: Vec<Goal>,
    pub oracle: Vec<Primitive>,
    pub jitter: f64,
}

/// One recorded object as the spec will have it.
#[derive(Clone)]
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

fn rot_z(a: f64, v: [f64; 2]) -> [f64; 2] {
    let (s, c) = a.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

/// The first of `seeds` as a spec's scene, goals and plan (the others tell ties apart). `laid`:
/// for a per-seed layout, which no jitter moves (objects are kept clear of each other by no
/// more than they are drawn).
pub(crate) fn translate(
    seeds: &[SeedRecord],
    asset_root: &Path,
    notes: &mut Notes,
    laid: bool,
) -> Option<Translated> {
    within_bounds(seeds, notes)?;
    let same = same_scene(seeds, notes);
    let s0 = &seeds[0];
    if let Some(o) = s0.objects.iter().position(|o| o.category == "deformable") {
        notes.error(
            &format!("env.add_object[{o}]"),
            "a deformable object: Assay simulates rigid bodies only",
        );
        return None;
    }
    let mut t = Translation {
        seeds,
        same,
        asset_root,
        notes,
        fatal: false,
        made: Vec::new(),
        objects: Vec::new(),
        zones: Vec::new(),
        piles: Vec::new(),
        halves: BTreeMap::new(),
        jitter: if laid { 0.0 } else { JITTER },
        tied_pairs: BTreeSet::new(),
        goals: Vec::new(),
        oracle: Vec::new(),
        reward_steps: Vec::new(),
        pose_goals: Vec::new(),
        pose_steps: Vec::new(),
    };
    t.objects()?;
    t.tied_objects();
    t.mark_moved();
    t.goals()?;
    t.finish()
}

/// Refuses a recording larger than a task may be (noted).
fn within_bounds(seeds: &[SeedRecord], notes: &mut Notes) -> Option<()> {
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
    Some(())
}

/// The seeds that built the same scene as seed 0 (same objects, same goals): they tell ties
/// apart.
fn same_scene(seeds: &[SeedRecord], notes: &mut Notes) -> Vec<SeedRecord> {
    let s0 = &seeds[0];
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
                "the task builds a different scene on some seeds ({} of {} seeds match seed {}): the spec's scene is seed {}'s (a laid-out seed has its own)",
                same.len(),
                seeds.len(),
                s0.seed,
                s0.seed
            ),
        );
    }
    same
}

/// One recording on its way to a spec: what each phase made of it so far.
struct Translation<'a> {
    seeds: &'a [SeedRecord],
    /// The seeds that built the same scene as seed 0.
    same: Vec<SeedRecord>,
    asset_root: &'a Path,
    notes: &'a mut Notes,
    /// An object could not be imported.
    fatal: bool,
    /// Each object seed 0 recorded as the spec has it (`None`: not imported).
    made: Vec<Option<Made>>,
    objects: Vec<Object>,
    zones: Vec<Zone>,
    piles: Vec<Pile>,
    /// Each object's half extents (its asset's, not the size the code declared).
    halves: BTreeMap<String, [f64; 3]>,
    jitter: f64,
    /// Objects placed from another's pose: (object, the other).
    tied_pairs: BTreeSet<(String, String)>,
    goals: Vec<Goal>,
    oracle: Vec<Primitive>,
    /// GenSim's reward: each `add_goal`'s goals as they were made (before any is superseded).
    reward_steps: Vec<RewardStep>,
    pose_goals: Vec<PoseGoal>,
    /// (index of the pick in `oracle`, its steps to the place, object, add_goal) of each
    /// pick-and-place of a pose goal.
    pose_steps: Vec<(usize, usize, String, usize)>,
}

impl Translation<'_> {
    /// An error at `field` that rules the spec out.
    fn fail(&mut self, field: &str, reason: impl Into<String>) {
        self.notes.error(field, reason);
        self.fatal = true;
    }

    /// The repairs (`repair`) and the spec's parts; `None` without a goal.
    fn finish(self) -> Option<Translated> {
        let Translation {
            seeds,
            notes,
            mut objects,
            zones,
            piles,
            halves,
            jitter,
            tied_pairs,
            mut goals,
            mut oracle,
            reward_steps,
            pose_goals,
            pose_steps,
            ..
        } = self;
        supersede(
            &pose_goals,
            &pose_steps,
            seeds[0].pos_eps,
            &mut goals,
            &mut oracle,
            notes,
        );
        declutter(&mut objects, &zones, &halves, &tied_pairs, jitter, notes);
        if goals.is_empty() {
            notes.error("add_goal", "the task adds no goal");
            return None;
        }
        Some(Translated {
            reward_steps,
            objects,
            zones,
            piles,
            goals,
            oracle,
            jitter,
        })
    }
}
