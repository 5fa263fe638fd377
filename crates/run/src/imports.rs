//! The import step of a run: a generator's own output (GenSim, RoboGen, BBSEA) read as task
//! specs with the per-task mapping report, written as spec files and `import-report.json`, and
//! summarised for the run's report; optionally each imported oracle checked in the simulator.
//!
//! Owns: the files an import writes and the summary a report shows. Never translates a generator's
//! output itself (`assay-import` does).

use std::path::{Path, PathBuf};

use anyhow::Context;
use assay_import::{Import, ImportOptions, Pipeline, import, spec_to_yaml};
use assay_plan::TaskDocument;

/// How a failed seed is marked where a goal that fails at the end had held before
/// ([`assay_sim::Episode::goals_held`]): the plan knocked off what it had placed; the note says
/// what the tool carried when it was lost.
const UNDONE: &str = "a goal met earlier came undone";

/// Why a seed's oracle episode failed, and whether a goal met in it came undone.
#[derive(Debug, Clone)]
struct Failure {
    why: String,
    undone: bool,
}

/// The first unmet goal of a failed episode, and the first goal that held before and came
/// undone, with when it was lost and what the tool carried then.
fn failure(ep: &assay_sim::Episode) -> Failure {
    let preds = &ep.outcome.predicates;
    let mut why = preds
        .iter()
        .find(|p| !p.holds)
        .map(|p| format!("{}: {}", p.label, p.detail))
        .unwrap_or_else(|| "the plan did not finish".into());
    let undone = preds
        .iter()
        .zip(&ep.goals_held)
        .find(|(p, g)| !p.holds && g.last.is_some());
    if let Some((p, g)) = undone {
        let held = g.last.unwrap_or_default();
        let lost = match &g.lost {
            Some((step, Some(carried))) => {
                format!("lost at step {step} while the tool carried '{carried}'")
            }
            Some((step, None)) => format!("lost at step {step} with nothing in the tool"),
            None => "not at the end".into(),
        };
        why.push_str(&format!(
            " ({UNDONE}: {} held at step {held}, {lost})",
            p.label
        ));
    }
    Failure {
        why,
        undone: undone.is_some(),
    }
}

/// Whether a generator's reward reached its most: GenSim keeps an episode as a demonstration when
/// its reward is above 0.99 of 1.
fn full_reward(r: &assay_model::episode::GeneratorReward) -> bool {
    r.value > r.max - 0.01
}

/// Runs every imported task's oracle on seeds `0..seeds` and adds what happened to its mapping
/// report: a plan that fails on some seed is reported, not hidden, and a seed where a goal held
/// before the plan undid it says so.
pub fn check_oracles(batch: &mut Import, seeds: u64) {
    use assay_import::{Mapping, MappingStatus};
    let specs: Vec<(usize, assay_spec::spec::TaskSpec)> = batch
        .tasks
        .iter()
        .enumerate()
        .filter_map(|(i, t)| t.spec.clone().map(|s| (i, s)))
        .collect();
    let jobs: Vec<(usize, u64)> = (0..specs.len())
        .flat_map(|k| (0..seeds).map(move |s| (k, s)))
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(vec![Vec::new(); specs.len()]);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&(k, seed)) = jobs.get(j) else {
                        return;
                    };
                    let (why, scored) = match assay_sim::simulate(&specs[k].1, seed, "oracle") {
                        Ok(ep) => (
                            (!ep.outcome.success).then(|| failure(&ep)),
                            ep.outcome.generator_reward.as_ref().map(full_reward),
                        ),
                        Err(e) => (
                            Some(Failure {
                                why: format!("cannot simulate: {e}"),
                                undone: false,
                            }),
                            None,
                        ),
                    };
                    results.lock().expect("not poisoned")[k].push((seed, why, scored));
                }
            });
        }
    });
    let results = results.into_inner().expect("not poisoned");
    for ((i, _), mut rs) in specs.into_iter().zip(results) {
        rs.sort_by_key(|r| r.0);
        let solved = rs.iter().filter(|r| r.1.is_none()).count();
        // GenSim's own verdict where the task has its reward: a demonstration is kept when the
        // episode's reward reaches its most (`total_reward > 0.99` in GenSim's `demos.py`).
        let scored = rs.iter().filter_map(|r| r.2).collect::<Vec<bool>>();
        let by_gensim = if scored.is_empty() {
            String::new()
        } else {
            format!(
                "; GenSim's reward complete on {} of {}",
                scored.iter().filter(|&&b| b).count(),
                scored.len()
            )
        };
        let failed: Vec<String> = rs
            .iter()
            .filter(|r| r.1.is_some())
            .map(|r| r.0.to_string())
            .collect();
        let undone: Vec<String> = rs
            .iter()
            .filter(|r| r.1.as_ref().is_some_and(|f| f.undone))
            .map(|r| r.0.to_string())
            .collect();
        let undone = if undone.is_empty() {
            String::new()
        } else {
            format!(" (on {}, {UNDONE})", undone.join(", "))
        };
        let note = match rs.iter().find_map(|r| r.1.as_ref().map(|f| (r.0, &f.why))) {
            None => {
                format!("checked in the simulator: solves {solved} of {seeds} seeds{by_gensim}")
            }
            Some((seed, why)) => format!(
                "checked in the simulator: solves {solved} of {seeds} seeds{by_gensim}; fails on seed(s) {}{undone}; seed {seed}: {why}",
                failed.join(", ")
            ),
        };
        batch.tasks[i].mapping.push(Mapping {
            field: "oracle (checked)".into(),
            status: MappingStatus::Inferred,
            note,
        });
    }
}

/// Imports a batch, failing only when nothing under `path` can be read at all.
pub fn read(
    pipeline: Pipeline,
    path: &Path,
    asset_root: Option<PathBuf>,
    layout_seeds: Option<Vec<u64>>,
) -> anyhow::Result<Import> {
    anyhow::ensure!(path.exists(), "{}: no such file or folder", path.display());
    let batch = import(
        pipeline,
        path,
        &ImportOptions {
            asset_root,
            layout_seeds,
            ..ImportOptions::default()
        },
    );
    anyhow::ensure!(
        !batch.tasks.is_empty() || !batch.errors.is_empty(),
        "no {pipeline} tasks found under {}",
        path.display()
    );
    Ok(batch)
}

/// Tasks that could not be imported, and batch-level errors.
pub fn failed(batch: &Import) -> usize {
    batch.tasks.iter().filter(|t| t.spec.is_none()).count() + batch.errors.len()
}

/// Writes every imported spec (`ID.yaml`) and `import-report.json` to `out`.
pub fn write(batch: &Import, out: &Path) -> anyhow::Result<usize> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let specs = batch.specs();
    for spec in &specs {
        let file = out.join(format!("{}.yaml", spec.id));
        std::fs::write(&file, spec_to_yaml(spec))
            .with_context(|| format!("writing {}", file.display()))?;
    }
    let report = out.join("import-report.json");
    std::fs::write(&report, serde_json::to_vec_pretty(batch)?)
        .with_context(|| format!("writing {}", report.display()))?;
    Ok(specs.len())
}

/// What the report says of an imported tree (`mapping_file`: its mapping, relative to the
/// report).
pub fn summary(
    batch: &Import,
    path: &Path,
    mapping_file: &str,
) -> assay_report::report::ImportSummary {
    use assay_import::MappingStatus;
    let lines = |t: &assay_import::ImportedTask, status: MappingStatus| -> Vec<String> {
        t.mapping
            .iter()
            .filter(|m| m.status == status)
            .map(|m| format!("{}: {}", m.field, m.note))
            .collect()
    };
    assay_report::report::ImportSummary {
        pipeline: batch.pipeline.name().into(),
        root: path.display().to_string(),
        mapping_file: mapping_file.into(),
        tasks: batch
            .tasks
            .iter()
            .map(|t| assay_report::report::ImportedTaskSummary {
                id: t.id.clone(),
                name: t.name.clone(),
                source: t.source.display().to_string(),
                imported: t.spec.is_some(),
                errors: t
                    .errors
                    .iter()
                    .map(|e| match e.path.as_str() {
                        "" => e.reason.clone(),
                        field => format!("{field}: {}", e.reason),
                    })
                    .collect(),
                inferred: lines(t, MappingStatus::Inferred),
                not_mapped: lines(t, MappingStatus::NotMapped),
            })
            .collect(),
    }
}

/// The imported specs as task documents for a batch (origin: the source file).
pub fn documents(batch: &Import) -> Vec<TaskDocument> {
    batch
        .specs()
        .into_iter()
        .map(|spec| TaskDocument {
            origin: spec
                .source
                .origin
                .clone()
                .unwrap_or_else(|| spec.id.clone()),
            format: "yaml".into(),
            content: spec_to_yaml(spec),
        })
        .collect()
}
