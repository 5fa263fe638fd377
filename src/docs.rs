//! Reading task documents from files and folders.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assay_proto::v1 as pb;

/// Every `.yaml`, `.yml` and `.json` file under `paths` (folders are walked, sorted by path).
pub fn collect(paths: &[PathBuf]) -> anyhow::Result<Vec<pb::TaskDocument>> {
    let mut files = Vec::new();
    for p in paths {
        walk(p, &mut files).with_context(|| format!("reading {}", p.display()))?;
    }
    if files.is_empty() {
        bail!(
            "no task files (.yaml, .yml, .json) under {}",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let content =
                std::fs::read_to_string(&f).with_context(|| format!("reading {}", f.display()))?;
            let format = if f.extension().is_some_and(|e| e == "json") {
                "json"
            } else {
                "yaml"
            };
            Ok(pb::TaskDocument {
                origin: f.display().to_string(),
                format: format.into(),
                content,
            })
        })
        .collect()
}

fn walk(p: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    if p.is_dir() {
        for entry in std::fs::read_dir(p)? {
            walk(&entry?.path(), out)?;
        }
    } else if p.is_file() {
        if assay_spec::spec::Format::from_path(&p.display().to_string()).is_some() {
            out.push(p.to_path_buf());
        }
    } else {
        return Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no such file or folder",
        ));
    }
    Ok(())
}
