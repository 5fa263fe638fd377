//! Importers: GenSim, RoboGen and BBSEA output → task spec v1.
//!
//! Each importer is pointed at the tool's own tree (see `tests/fixtures/import/README.md`) and
//! returns one [`ImportedTask`] per task it finds, with the spec when the task can be imported,
//! a per-field [`Mapping`] (nothing is dropped silently) and [`SpecError`]s that name the task,
//! the field and the reason. A broken task never stops the rest of the batch.

pub mod bbsea;
pub mod gensim;
mod groups;
pub mod robogen;

use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::Serialize;

use assay_spec::error::SpecError;
use assay_spec::spec::{self, TaskSpec};

/// The generator a batch comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pipeline {
    Gensim,
    Robogen,
    Bbsea,
}

impl Pipeline {
    pub fn name(self) -> &'static str {
        match self {
            Pipeline::Gensim => "gensim",
            Pipeline::Robogen => "robogen",
            Pipeline::Bbsea => "bbsea",
        }
    }
}

impl std::fmt::Display for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Pipeline {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "gensim" => Ok(Pipeline::Gensim),
            "robogen" => Ok(Pipeline::Robogen),
            "bbsea" => Ok(Pipeline::Bbsea),
            other => Err(format!(
                "unknown pipeline '{other}': expected gensim, robogen or bbsea"
            )),
        }
    }
}

/// Import settings.
#[derive(Debug, Clone, Default)]
pub struct ImportOptions {
    /// The folder asset paths are relative to. Default: `ROOT/assets` for GenSim and RoboGen,
    /// `ROOT` for BBSEA (its `model_path`s are relative to the repository root).
    pub asset_root: Option<PathBuf>,
    /// What generated task code may use when it runs (GenSim's `reset()`).
    pub limits: CodeLimits,
    /// The seeds GenSim's `reset()` lays out, one layout each in the spec: `None` is
    /// [`default_layout_seeds`]; empty, none (seed 0's scene with position jitter on every
    /// seed, as before layouts).
    pub layout_seeds: Option<Vec<u64>>,
}

/// Seeds as a command line gives them: `A..B` ranges (B excluded) and single seeds,
/// comma-separated, or `none`.
pub fn parse_seeds(text: &str) -> Result<Vec<u64>, String> {
    const MOST: u64 = spec::MAX_LAYOUTS as u64;
    if text.trim() == "none" {
        return Ok(Vec::new());
    }
    let mut seeds: Vec<u64> = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let number = |s: &str| {
            s.trim()
                .parse::<u64>()
                .map_err(|_| format!("'{s}' is not a seed (a whole number)"))
        };
        match part.split_once("..") {
            Some((a, b)) => {
                let (a, b) = (number(a)?, number(b)?);
                if b <= a {
                    return Err(format!("'{part}' is empty (A..B runs A to B-1)"));
                }
                if b - a > MOST {
                    return Err(format!("'{part}': at most {MOST} seeds"));
                }
                seeds.extend(a..b);
            }
            None => seeds.push(number(part)?),
        }
    }
    seeds.sort_unstable();
    seeds.dedup();
    if seeds.len() as u64 > MOST {
        return Err(format!("{} seeds: at most {MOST}", seeds.len()));
    }
    Ok(seeds)
}

/// The seeds a GenSim task is laid out on unless told: a batch's first 20 (`assay import
/// --check-oracle` runs 20; a batch runs 5 unless told) and the generalization plan's
/// default held-out seeds (1,000,000 to 1,000,002).
pub fn default_layout_seeds() -> Vec<u64> {
    (0..20).chain(1_000_000..1_000_003).collect()
}

/// Bounds on one task's generated code, run in a sandboxed subprocess for all its seeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodeLimits {
    /// CPU seconds.
    pub cpu_seconds: u64,
    /// Wall-clock seconds before the process is killed.
    pub wall_seconds: u64,
    /// Address space (bytes).
    pub memory_bytes: u64,
}

impl Default for CodeLimits {
    fn default() -> Self {
        CodeLimits {
            cpu_seconds: 20,
            wall_seconds: 30,
            memory_bytes: 1 << 30,
        }
    }
}

/// One batch.
#[derive(Debug, Clone, Serialize)]
pub struct Import {
    pub pipeline: Pipeline,
    pub root: PathBuf,
    pub tasks: Vec<ImportedTask>,
    /// Problems not tied to one task (a broken BBSEA scene file, an unreadable library).
    pub errors: Vec<SpecError>,
}

/// One source task.
#[derive(Debug, Clone, Serialize)]
pub struct ImportedTask {
    pub id: String,
    pub name: String,
    /// The source file (or BBSEA task directory).
    pub source: PathBuf,
    /// SHA-256 over the source bytes the task was built from.
    pub content_hash: String,
    /// `None` when the task cannot be imported (see `errors`).
    pub spec: Option<TaskSpec>,
    pub mapping: Vec<Mapping>,
    pub errors: Vec<SpecError>,
    /// Recorded episodes with the generator's own success label (BBSEA).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub episodes: Vec<ImportedEpisode>,
}

/// What happened to one source field.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Mapping {
    pub field: String,
    pub status: MappingStatus,
    pub note: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MappingStatus {
    /// Carried over as it is (units and frames converted).
    Mapped,
    /// A guess: a fallback, a goal read from text, a plan from substeps.
    Inferred,
    /// Dropped, with the reason.
    NotMapped,
}

/// One recorded episode of a generator.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ImportedEpisode {
    pub id: String,
    pub video: PathBuf,
    /// The episode's log, when there is one.
    pub log: Option<PathBuf>,
    /// `Some(true)` success, `Some(false)` failure, `None` unknown (`not sure`).
    pub label: Option<bool>,
    /// Who labelled it (`llm` for BBSEA's self-judgement).
    pub label_source: String,
    /// The label as written (`True`, `False`, `not sure`).
    pub raw_label: String,
}

/// Imports every task under `root`.
pub fn import(pipeline: Pipeline, root: &Path, options: &ImportOptions) -> Import {
    let asset_root = options
        .asset_root
        .clone()
        .unwrap_or_else(|| match pipeline {
            Pipeline::Gensim | Pipeline::Robogen => root.join("assets"),
            Pipeline::Bbsea => root.to_path_buf(),
        });
    let mut out = Import {
        pipeline,
        root: root.to_path_buf(),
        tasks: Vec::new(),
        errors: Vec::new(),
    };
    let asset_root = match asset_root.canonicalize() {
        Ok(p) => p,
        Err(e) => {
            out.errors.push(SpecError {
                task: None,
                origin: asset_root.display().to_string(),
                path: String::new(),
                reason: format!("asset root {}: {e}", asset_root.display()),
            });
            return out;
        }
    };
    let (tasks, errors) = match pipeline {
        Pipeline::Gensim => gensim::import(
            root,
            &asset_root,
            options.limits,
            &options
                .layout_seeds
                .clone()
                .unwrap_or_else(default_layout_seeds),
        ),
        Pipeline::Robogen => robogen::import(root, &asset_root),
        Pipeline::Bbsea => bbsea::import(root, &asset_root),
    };
    out.tasks = tasks;
    out.errors = errors;
    out
}

impl Import {
    /// The specs that were imported.
    pub fn specs(&self) -> Vec<&TaskSpec> {
        self.tasks.iter().filter_map(|t| t.spec.as_ref()).collect()
    }

    /// A human-readable per-task report: what was imported, what was guessed, what was dropped.
    pub fn report(&self) -> String {
        let mut s = format!(
            "import {} from {}: {} task(s), {} imported\n",
            self.pipeline,
            self.root.display(),
            self.tasks.len(),
            self.specs().len()
        );
        for e in &self.errors {
            s.push_str(&format!("error: {e}\n"));
        }
        for t in &self.tasks {
            s.push_str(&format!(
                "\n{} ({})\n  source: {}\n  hash: {}\n  {}\n",
                t.id,
                t.name,
                t.source.display(),
                &t.content_hash[..t.content_hash.len().min(12)],
                if t.spec.is_some() {
                    "imported"
                } else {
                    "NOT imported"
                }
            ));
            for m in &t.mapping {
                let tag = match m.status {
                    MappingStatus::Mapped => continue,
                    MappingStatus::Inferred => "inferred",
                    MappingStatus::NotMapped => "not mapped",
                };
                s.push_str(&format!("  {tag}: {}: {}\n", m.field, m.note));
            }
            for e in &t.errors {
                s.push_str(&format!("  error: {e}\n"));
            }
            for ep in &t.episodes {
                let label = match ep.label {
                    Some(true) => "success",
                    Some(false) => "failure",
                    None => "no label",
                };
                s.push_str(&format!(
                    "  episode {}: {label} ({}: '{}')\n",
                    ep.id, ep.label_source, ep.raw_label
                ));
            }
        }
        s
    }
}

/// The spec as YAML that [`spec::parse_task`] reads back to an equal spec.
pub fn spec_to_yaml(spec: &TaskSpec) -> String {
    let mut out = Vec::new();
    let mut ser = serde_yaml_ng::Serializer::new(&mut out);
    serde_yaml_ng::with::singleton_map_recursive::serialize(spec, &mut ser)
        .expect("task spec serialises");
    String::from_utf8(out).expect("YAML is UTF-8")
}

// ---------------------------------------------------------------------------------------------
// Shared helpers.

/// The entries of `dir` that `keep` accepts, sorted by path (none when it cannot be read).
pub(crate) fn sorted_entries(dir: &Path, keep: impl Fn(&Path) -> bool) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().map(|e| e.path()).filter(|p| keep(p)).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// Collects mapping lines and errors for one task.
#[derive(Debug, Default)]
pub(crate) struct Notes {
    pub mapping: Vec<Mapping>,
    pub errors: Vec<SpecError>,
    pub task: String,
    pub origin: String,
}

impl Notes {
    /// Ends a task: `spec` (if one was built) is kept when it validates, else its validation
    /// errors join the task's; the mapping lines and errors go to `task`.
    pub fn settle(mut self, task: &mut ImportedTask, spec: Option<TaskSpec>) {
        if let Some(spec) = spec {
            let errs = spec::validate(&spec, &self.origin);
            if errs.is_empty() {
                task.spec = Some(spec);
            } else {
                self.errors.extend(errs);
            }
        }
        task.mapping = self.mapping;
        task.errors = self.errors;
    }

    pub fn new(task: &str, origin: &str) -> Self {
        Notes {
            task: task.into(),
            origin: origin.into(),
            ..Default::default()
        }
    }
    fn push(&mut self, field: &str, status: MappingStatus, note: impl Into<String>) {
        self.mapping.push(Mapping {
            field: field.into(),
            status,
            note: note.into(),
        });
    }
    pub fn mapped(&mut self, field: &str, note: impl Into<String>) {
        self.push(field, MappingStatus::Mapped, note);
    }
    pub fn inferred(&mut self, field: &str, note: impl Into<String>) {
        self.push(field, MappingStatus::Inferred, note);
    }
    pub fn not_mapped(&mut self, field: &str, note: impl Into<String>) {
        self.push(field, MappingStatus::NotMapped, note);
    }
    pub fn error(&mut self, field: &str, reason: impl Into<String>) {
        self.errors.push(SpecError {
            task: Some(self.task.clone()),
            origin: self.origin.clone(),
            path: field.into(),
            reason: reason.into(),
        });
    }
}

/// Lowercase slug: letters and digits kept, runs of anything else become `sep`.
pub(crate) fn slug(s: &str, sep: char) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.is_empty() && !out.ends_with(sep) {
            out.push(sep);
        }
    }
    while out.ends_with(sep) {
        out.pop();
    }
    out
}

/// Group from the task name, as GenSim's groups go; else the pipeline name.
pub(crate) fn group_for(name: &str, pipeline: Pipeline, notes: &mut Notes) -> String {
    let lower = name.to_ascii_lowercase();
    for (key, group) in [
        ("stack", "stacking"),
        ("place", "placement"),
        ("pile", "piles"),
        ("build", "assembling"),
    ] {
        if lower.contains(key) {
            notes.inferred("group", format!("'{group}': the name contains '{key}'"));
            return group.into();
        }
    }
    notes.inferred(
        "group",
        format!(
            "'{}': no group rule (stack, place, pile, build) matches the name; the pipeline name is the fallback",
            pipeline.name()
        ),
    );
    pipeline.name().into()
}

/// Checks an asset path from its text, then on the file system: inside `asset_root` and present.
pub(crate) fn check_asset(asset_root: &Path, path: &str) -> Result<PathBuf, String> {
    spec::check_asset_path(path)?;
    let full = asset_root.join(path);
    let c = full.canonicalize().map_err(|_| {
        format!(
            "asset '{path}' not found under the asset root {}",
            asset_root.display()
        )
    })?;
    if !c.starts_with(asset_root) {
        return Err(format!(
            "'{path}' leads out of the asset root {} (to {})",
            asset_root.display(),
            c.display()
        ));
    }
    Ok(c)
}

/// SHA-256 over several named byte strings (length-prefixed, so boundaries count).
pub(crate) fn hash_parts(parts: &[(&str, &[u8])]) -> String {
    let mut buf = Vec::new();
    for (name, bytes) in parts {
        buf.extend_from_slice(&(name.len() as u64).to_le_bytes());
        buf.extend_from_slice(name.as_bytes());
        buf.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
        buf.extend_from_slice(bytes);
    }
    assay_spec::hash::sha256_hex(&buf)
}

/// Rounds to 1e-6 so that golden files stay readable and stable.
pub(crate) fn r6(x: f64) -> f64 {
    let y = (x * 1e6).round() / 1e6;
    if y == 0.0 { 0.0 } else { y }
}

/// Rounds to millimetres.
pub(crate) fn r3(x: f64) -> f64 {
    let y = (x * 1e3).round() / 1e3;
    if y == 0.0 { 0.0 } else { y }
}

/// Collision-free initial positions: one deterministic draw per object (seeded by the task id),
/// footprints as circles with a margin, so that independent ranges never start objects
/// overlapping (spec v1's `pose_range` draws each object independently).
pub(crate) struct Placer {
    rng: assay_spec::rng::Rng,
    placed: Vec<([f64; 2], f64)>,
}

/// Clearance between footprints (m), more than twice the position jitter the importers set.
pub(crate) const PLACE_MARGIN: f64 = 0.03;
/// The position jitter imported tasks get.
pub(crate) const JITTER: f64 = 0.01;

impl Placer {
    pub fn new(task: &str) -> Self {
        Placer {
            rng: assay_spec::rng::Rng::new(0, &format!("import/{task}")),
            placed: Vec::new(),
        }
    }

    /// Reserves a footprint that is already placed.
    pub fn reserve(&mut self, centre: [f64; 2], radius: f64) {
        self.placed.push((centre, radius));
    }

    fn clear(&self, c: [f64; 2], radius: f64) -> bool {
        self.placed.iter().all(|(p, r)| {
            let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2)).sqrt();
            d >= r + radius + PLACE_MARGIN
        })
    }

    /// A free centre in [lo, hi] (x, y), rounded to millimetres; reserved.
    pub fn place(&mut self, lo: [f64; 2], hi: [f64; 2], radius: f64) -> Option<[f64; 2]> {
        for _ in 0..2000 {
            let c = [
                r3(self.rng.uniform(lo[0], hi[0].max(lo[0]))),
                r3(self.rng.uniform(lo[1], hi[1].max(lo[1]))),
            ];
            if self.clear(c, radius) {
                self.reserve(c, radius);
                return Some(c);
            }
        }
        None
    }
}

/// Half-diagonal of a footprint.
pub(crate) fn radius(half: [f64; 3]) -> f64 {
    (half[0] * half[0] + half[1] * half[1]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_are_read_as_ranges_and_single_seeds_or_none() {
        assert_eq!(parse_seeds("0..3,7, 5").unwrap(), vec![0, 1, 2, 5, 7]);
        assert_eq!(parse_seeds("none").unwrap(), Vec::<u64>::new());
        assert_eq!(
            parse_seeds("0..20,1000000..1000003").unwrap(),
            default_layout_seeds()
        );
        for bad in ["3..3", "x", "0..2000", "-1"] {
            assert!(parse_seeds(bad).is_err(), "{bad}");
        }
    }
}
