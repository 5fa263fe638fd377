//! The output folder of `assay eval`: claimed before anything is written, never emptied.
//!
//! A run writes `assay-run.json` into its folder first. It names the batch the folder holds (a
//! hash of the task documents and the settings) and, once submitted, the batch's id in the job
//! store under `run/`. What a new run may do with a folder follows from it:
//! - missing or empty: a new run;
//! - an Assay run of the same batch: the run goes on from its job store (finished episodes are
//!   not run again; a finished batch only gets its report written again); `--force` starts it
//!   anew instead;
//! - an Assay run that never submitted its batch (refused before it ran): a new run;
//! - an Assay run of another batch, or a folder Assay did not make: refused, naming the folder
//!   and why, unless `--force`, which starts a new run there and replaces only what a run
//!   writes (`run/`, `artifacts/`, the report files), never anything else.
//!
//! Owns: the marker and the decision. Never deletes anything but the folder's `run/` job store,
//! and that only when the marker says Assay wrote it or the operator forced it.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

/// The marker's file name inside an output folder.
pub const MARKER: &str = "assay-run.json";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// Always "assay": what wrote the folder.
    pub tool: String,
    /// The version of Assay that started the run.
    pub version: String,
    /// SHA-256 of the batch's task documents and settings ([`batch_key`]).
    pub batch: String,
    /// The batch's id in `run/jobs.db`, once submitted.
    #[serde(default)]
    pub batch_id: Option<String>,
}

/// What a run does with its output folder.
#[derive(Debug, Clone, PartialEq)]
pub enum Claim {
    /// Start the batch: the folder is new, empty, or forced.
    Fresh,
    /// The folder holds this batch already: go on with batch `batch_id` in its job store.
    Resume { batch_id: String },
}

/// Whether `dir` is an Assay output folder (it holds the marker).
pub fn is_output_folder(dir: &Path) -> bool {
    dir.join(MARKER).is_file()
}

fn read_marker(out: &Path) -> anyhow::Result<Option<Marker>> {
    let path = out.join(MARKER);
    match std::fs::read_to_string(&path) {
        Ok(text) => serde_json::from_str(&text)
            .map(Some)
            .with_context(|| format!("{} is not an Assay run marker", path.display())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| format!("reading {}", path.display())),
    }
}

fn write_marker(out: &Path, m: &Marker) -> anyhow::Result<()> {
    let path = out.join(MARKER);
    std::fs::write(&path, format!("{}\n", serde_json::to_string_pretty(m)?))
        .with_context(|| format!("writing {}", path.display()))
}

/// Claims `out` for the batch `batch` (a [`batch_key`]): see the module documentation.
pub fn claim(out: &Path, batch: &str, force: bool) -> anyhow::Result<Claim> {
    if out.exists() && !out.is_dir() {
        bail!("--out {} is a file, not a folder", out.display());
    }
    let marker = if out.is_dir() {
        read_marker(out)
    } else {
        Ok(None)
    };
    let empty = !out.exists()
        || std::fs::read_dir(out)
            .with_context(|| format!("reading {}", out.display()))?
            .next()
            .is_none();
    let fresh = Marker {
        tool: "assay".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        batch: batch.into(),
        batch_id: None,
    };
    let run = out.join("run");
    match (marker, empty) {
        (_, true) => {}
        (Ok(Some(m)), _) if m.batch == batch && !force => {
            if let Some(id) = m.batch_id.filter(|_| run.join("jobs.db").is_file()) {
                return Ok(Claim::Resume { batch_id: id });
            }
            // Assay wrote it and never submitted: nothing of value in its job store.
            remove_run(&run)?;
        }
        // Assay made it but nothing was ever submitted (a refused batch): nothing to keep.
        (Ok(Some(m)), _) if force || m.batch_id.is_none() => remove_run(&run)?,
        (Ok(Some(m)), _) => bail!(
            "--out {} holds an Assay run of another batch (tasks or settings differ{}); choose \
             another --out, or pass --force to start this batch there (its run/ job store is \
             replaced)",
            out.display(),
            m.batch_id
                .map(|id| format!(": it holds batch {id}"))
                .unwrap_or_default()
        ),
        (Ok(None), _) if force => {
            if run.exists() {
                bail!(
                    "--out {} was not made by Assay and has a run/ folder: refusing to replace \
                     it even with --force; choose another --out",
                    out.display()
                );
            }
        }
        (Ok(None), _) => bail!(
            "--out {} is not empty and was not made by Assay (no {MARKER}): refusing to write \
             into it; choose a new or empty folder, or pass --force to write there anyway",
            out.display()
        ),
        (Err(e), _) => return Err(e),
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_marker(out, &fresh)?;
    Ok(Claim::Fresh)
}

fn remove_run(run: &Path) -> anyhow::Result<()> {
    match std::fs::remove_dir_all(run) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("removing {}", run.display()))
        }
        _ => Ok(()),
    }
}

/// Records in `out`'s marker that its batch was submitted as `batch_id`.
pub fn submitted(out: &Path, batch_id: &str) -> anyhow::Result<()> {
    let mut m = read_marker(out)?.context("the output folder lost its marker")?;
    m.batch_id = Some(batch_id.to_owned());
    write_marker(out, &m)
}

/// The batch a request submits: SHA-256 of its tasks (origin and text) and settings, so the
/// same command on the same files gives the same key.
pub fn batch_key(req: &assay_proto::v1::SubmitBatchRequest) -> String {
    let mut canonical = req.clone();
    let mut templates: Vec<(String, String)> = canonical.text_templates.drain().collect();
    templates.sort();
    let text = format!("{canonical:?}\n{templates:?}");
    assay_spec::hash::sha256_hex(text.as_bytes())
}

/// Refuses an output folder that is one of the batch's task paths or holds one of them (the
/// run would read its own outputs as tasks, or write among the tasks).
pub fn check_apart(out: &Path, tasks: &[PathBuf]) -> anyhow::Result<()> {
    let abs = |p: &Path| -> PathBuf {
        let p = if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir().unwrap_or_default().join(p)
        };
        // Resolve what exists (symlinks, ..); keep the rest as written.
        p.canonicalize()
            .unwrap_or_else(|_| assay_spec::assets::lexical(&p))
    };
    let o = abs(out);
    for t in tasks {
        let t_abs = abs(t);
        if t_abs == o || t_abs.starts_with(&o) {
            bail!(
                "--out {} holds the task path {}: a run must not write among its tasks; choose \
                 an output folder outside them",
                out.display(),
                t.display()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_or_empty_folder_is_claimed_and_marked() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("new");
        assert_eq!(claim(&out, "k", false).unwrap(), Claim::Fresh);
        assert!(is_output_folder(&out));
        let empty = dir.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        assert_eq!(claim(&empty, "k", false).unwrap(), Claim::Fresh);
    }

    #[test]
    fn the_same_batch_resumes_once_submitted() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        claim(out, "k", false).unwrap();
        // Not submitted yet: a fresh start (its empty run/ may go).
        std::fs::create_dir_all(out.join("run")).unwrap();
        assert_eq!(claim(out, "k", false).unwrap(), Claim::Fresh);
        std::fs::create_dir_all(out.join("run")).unwrap();
        std::fs::write(out.join("run/jobs.db"), b"db").unwrap();
        submitted(out, "b00001").unwrap();
        assert_eq!(
            claim(out, "k", false).unwrap(),
            Claim::Resume {
                batch_id: "b00001".into()
            }
        );
        assert!(out.join("run/jobs.db").is_file(), "nothing removed");
        // --force starts the same batch anew.
        assert_eq!(claim(out, "k", true).unwrap(), Claim::Fresh);
        assert!(!out.join("run").exists());
    }

    #[test]
    fn a_run_that_never_submitted_leaves_nothing_to_keep() {
        let dir = tempfile::tempdir().unwrap();
        claim(dir.path(), "refused", false).unwrap();
        assert_eq!(claim(dir.path(), "other", false).unwrap(), Claim::Fresh);
    }

    #[test]
    fn another_batch_or_a_foreign_folder_is_refused_unless_forced() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("o");
        claim(&out, "k", false).unwrap();
        std::fs::create_dir_all(out.join("run")).unwrap();
        std::fs::write(out.join("run/jobs.db"), b"db").unwrap();
        submitted(&out, "b00007").unwrap();
        let e = claim(&out, "other", false).unwrap_err().to_string();
        assert!(e.contains("another batch") && e.contains("b00007"), "{e}");
        assert!(
            out.join("run/jobs.db").is_file(),
            "a refusal removes nothing"
        );
        assert_eq!(claim(&out, "other", true).unwrap(), Claim::Fresh);
        assert!(!out.join("run").exists());

        let foreign = dir.path().join("thesis");
        std::fs::create_dir(&foreign).unwrap();
        std::fs::write(foreign.join("chapter1.tex"), "x").unwrap();
        let e = claim(&foreign, "k", false).unwrap_err().to_string();
        assert!(e.contains("not made by Assay"), "{e}");
        assert_eq!(claim(&foreign, "k", true).unwrap(), Claim::Fresh);
        assert!(
            foreign.join("chapter1.tex").is_file(),
            "--force keeps what it did not write"
        );

        let with_run = dir.path().join("theirs");
        std::fs::create_dir_all(with_run.join("run")).unwrap();
        let e = claim(&with_run, "k", true).unwrap_err().to_string();
        assert!(e.contains("refusing to replace"), "{e}");
        assert!(with_run.join("run").is_dir());

        let file = dir.path().join("file");
        std::fs::write(&file, "x").unwrap();
        assert!(claim(&file, "k", true).is_err());
    }

    #[test]
    fn an_output_folder_among_the_tasks_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let tasks = dir.path().join("tasks");
        std::fs::create_dir(&tasks).unwrap();
        let e = check_apart(&tasks, std::slice::from_ref(&tasks))
            .unwrap_err()
            .to_string();
        assert!(e.contains("among its tasks"), "{e}");
        assert!(check_apart(dir.path(), std::slice::from_ref(&tasks)).is_err());
        assert!(check_apart(&tasks.join("../tasks/./"), std::slice::from_ref(&tasks)).is_err());
        check_apart(&dir.path().join("out"), std::slice::from_ref(&tasks)).unwrap();
        // Inside the tasks is allowed: the walk skips output folders.
        check_apart(&tasks.join("out"), std::slice::from_ref(&tasks)).unwrap();
    }
}
