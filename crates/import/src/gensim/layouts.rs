//! Per-seed layouts: each seed's scene, goals and plan as the task's own `reset()` built them on
//! that seed, translated as seed 0's are (`translate`, with that seed first and no jitter), so
//! that a seed of an imported task is the scene GenSim draws on it, not seed 0's shaken.
//!
//! A seed whose `reset()` raised, or built what a spec cannot take, gets a layout that is an
//! error: its episode fails naming the seed and the reason; the other seeds run.

use std::path::Path;

use super::Notes;
use super::sandbox::{SeedOutcome, SeedRecord};
use super::translate;
use assay_spec::spec::{Layout, Scene, Surface, TaskSpec, seed_ranges};

/// The most characters of one seed's reasons kept in its layout.
const MAX_REASON: usize = 600;

/// The layouts of `seeds` (each one asked of the recorder: `outcomes`; `built`, the seeds it
/// built, seed 0 first), for the spec built from seed 0. A summary goes to `notes`.
pub(super) fn lay_out(
    spec: &TaskSpec,
    outcomes: &[SeedOutcome],
    built: &[SeedRecord],
    seeds: &[u64],
    asset_root: &Path,
    notes: &mut Notes,
) -> Vec<Layout> {
    if seeds.is_empty() {
        notes.not_mapped(
            "layouts",
            "none asked: every seed starts from seed 0's scene, its objects jittered (variations.position_jitter)",
        );
        return Vec::new();
    }
    let mut layouts = Vec::with_capacity(seeds.len());
    let mut failed: Vec<(u64, String)> = Vec::new();
    let (mut moved, mut moved_on) = (0usize, 0usize);
    for &seed in seeds {
        let Some(outcome) = outcomes.iter().find(|o| o.seed() == seed) else {
            continue;
        };
        let laid = match outcome {
            SeedOutcome::Failed { refused, .. } => Err(format!(
                "the task's reset() on this seed: {}: {}",
                refused.field, refused.reason
            )),
            SeedOutcome::Built(record) => {
                one(spec, record, built, asset_root, notes).map(|(layout, m)| {
                    moved += m;
                    moved_on += usize::from(m > 0);
                    layout
                })
            }
        };
        layouts.push(match laid {
            Ok(layout) => layout,
            Err(why) => {
                let why = cut(&why);
                failed.push((seed, why.clone()));
                Layout {
                    seed,
                    error: Some(why),
                    scene: None,
                    goals: Vec::new(),
                    oracle: Vec::new(),
                    reward_steps: Vec::new(),
                }
            }
        });
    }
    let mut note = format!(
        "{} seeds ({}) laid out as the task's reset() built each: its objects where the code put them (no jitter), its goals and the oracle's plan for them",
        layouts.len() - failed.len(),
        seed_ranges(layouts.iter().filter(|l| l.error.is_none()).map(|l| l.seed))
    );
    if moved > 0 {
        note.push_str(&format!(
            "; {moved} objects on {moved_on} seeds moved clear of another they were drawn into (the asset larger than the size its code declared)"
        ));
    }
    notes.mapped("layouts", note);
    if let Some((seed, why)) = failed.first() {
        notes.not_mapped(
            "layouts",
            format!(
                "{} seeds ({}) have no layout, their episodes fail: seed {seed}: {why}",
                failed.len(),
                seed_ranges(failed.iter().map(|(s, _)| *s))
            ),
        );
    }
    layouts
}

/// Seed `record.seed`'s layout and how many objects were moved clear; or why it has none.
fn one(
    spec: &TaskSpec,
    record: &SeedRecord,
    built: &[SeedRecord],
    asset_root: &Path,
    notes: &Notes,
) -> Result<(Layout, usize), String> {
    // This seed first (its scene is translated), the others to tell ties apart.
    let order: Vec<SeedRecord> = std::iter::once(record.clone())
        .chain(built.iter().filter(|b| b.seed != record.seed).cloned())
        .collect();
    let mut scratch = Notes::new(&notes.task, &notes.origin);
    let t = translate::translate(&order, asset_root, &mut scratch, true);
    let reasons = |errors: &[assay_spec::error::SpecError]| {
        errors
            .iter()
            .map(|e| format!("{}: {}", e.path, e.reason))
            .collect::<Vec<_>>()
            .join("; ")
    };
    let t = match t {
        Some(t) if scratch.errors.is_empty() => t,
        _ => {
            return Err(format!(
                "the scene the task's reset() built on this seed cannot be imported: {}",
                reasons(&scratch.errors)
            ));
        }
    };
    let moved = scratch
        .mapping
        .iter()
        .filter(|m| m.note.contains("to the nearest free spot"))
        .count();
    // Goals, plan and reward measured from objects are the same on every seed: a layout leaves
    // out what is the spec's own.
    let layout = Layout {
        seed: record.seed,
        error: None,
        scene: Some(Scene {
            surface: Surface::Table,
            objects: t.objects,
            zones: t.zones,
            piles: t.piles,
        }),
        goals: unless_same(t.goals, &spec.goals),
        oracle: unless_same(t.oracle, &spec.oracle),
        reward_steps: unless_same(t.reward_steps, &spec.reward_steps),
    };
    // It must validate as the spec's own scene does.
    let alone = TaskSpec {
        layouts: vec![layout.clone()],
        ..spec.clone()
    };
    let laid = alone
        .with_layout(record.seed)
        .expect("a layout with a scene");
    let errors = assay_spec::spec::validate(&laid, &notes.origin);
    if !errors.is_empty() {
        return Err(format!(
            "the scene the task's reset() built on this seed does not validate: {}",
            reasons(&errors)
        ));
    }
    Ok((layout, moved))
}

/// `mine`, or nothing where it is `spec`'s.
fn unless_same<T: PartialEq>(mine: Vec<T>, spec: &[T]) -> Vec<T> {
    if mine == spec { Vec::new() } else { mine }
}

fn cut(s: &str) -> String {
    if s.chars().count() <= MAX_REASON {
        s.to_owned()
    } else {
        format!("{}…", s.chars().take(MAX_REASON).collect::<String>())
    }
}
