//! The layout ARCHITECTURE.md promises, checked on the source: no import circles between the
//! modules of one folder (a module that uses a sibling which uses it back, directly or around a
//! loop), in every crate of the workspace; and the size of crates and files, printed.
//!
//! A module's imports are its `crate::…` and `super::…` paths outside `#[cfg(test)]` code. Edges
//! go between siblings: `crate::report` in `quality.rs` of `assay-report` is quality → report.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every crate's `src` folder in the workspace (from each member's Cargo.toml).
fn crate_sources() -> Vec<PathBuf> {
    let manifest = std::fs::read_to_string(repo().join("Cargo.toml")).unwrap();
    let members = manifest
        .split_once("members = [")
        .and_then(|(_, rest)| rest.split_once(']'))
        .expect("workspace members")
        .0;
    members
        .split(',')
        .map(|m| m.trim().trim_matches('"'))
        .filter(|m| !m.is_empty())
        .map(|m| repo().join(m).join("src"))
        .filter(|p| p.is_dir())
        .collect()
}

/// The code of a file without its `#[cfg(test)]` items (they sit at the end by house style) and
/// without comments.
fn code(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let text = match text.find("\n#[cfg(test)]") {
        Some(i) => &text[..i],
        None => &text[..],
    };
    text.lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The identifiers that follow `prefix` in `code` (`crate::a::b` with prefix `crate::` gives
/// `a`), including those of a group (`crate::{a, b::c}` gives `a` and `b`).
fn following(code: &str, prefix: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find(prefix) {
        let before = rest[..i].chars().next_back();
        rest = &rest[i + prefix.len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            for item in group[..end].split(',') {
                let name: String = item
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                out.insert(name);
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            out.insert(name);
        }
    }
    out
}

/// The modules of folder `dir` (files `x.rs` and folders `x/` with a `mod.rs` or an `x.rs`
/// beside them), each with every source file that belongs to it.
fn modules(dir: &Path) -> BTreeMap<String, Vec<PathBuf>> {
    let mut out: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            out.entry(stem).or_default().extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs")
            && !["lib", "main", "mod"].contains(&stem.as_str())
        {
            out.entry(stem).or_default().push(path);
        }
    }
    out
}

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out
}

/// Circles among the modules of `dir`, whose path from the crate root is `module_path`
/// (`["cmd"]` for `src/cmd/`). Each circle is listed as the modules on it.
fn circles(dir: &Path, module_path: &[String]) -> Vec<Vec<String>> {
    let mods = modules(dir);
    let names: BTreeSet<&String> = mods.keys().collect();
    let mut edges: BTreeMap<&str, BTreeSet<String>> = BTreeMap::new();
    let crate_prefix = format!(
        "crate::{}",
        module_path
            .iter()
            .map(|m| format!("{m}::"))
            .collect::<String>()
    );
    for (name, files) in &mods {
        let mut to = BTreeSet::new();
        for f in files {
            let code = code(f);
            to.extend(following(&code, &crate_prefix));
            // `super::x` from a file directly in `dir` (not from a file of a sub-folder) is a
            // sibling.
            if f.parent() == Some(dir) {
                to.extend(following(&code, "super::"));
            }
        }
        to.retain(|t| t != name && names.contains(t));
        edges.insert(name, to);
    }
    // A circle exists where a module reaches itself.
    let mut found: Vec<Vec<String>> = Vec::new();
    for start in edges.keys() {
        let mut stack = vec![(start.to_string(), vec![start.to_string()])];
        let mut seen = BTreeSet::new();
        while let Some((at, path)) = stack.pop() {
            for next in edges.get(at.as_str()).into_iter().flatten() {
                if next == start {
                    let mut circle = path.clone();
                    circle.sort();
                    if !found.contains(&circle) {
                        found.push(circle);
                    }
                } else if seen.insert(next.clone()) {
                    let mut p = path.clone();
                    p.push(next.clone());
                    stack.push((next.clone(), p));
                }
            }
        }
    }
    // Sub-folders have siblings of their own.
    for (name, _) in mods {
        let sub = dir.join(&name);
        if sub.is_dir() {
            let mut path = module_path.to_vec();
            path.push(name);
            found.extend(circles(&sub, &path));
        }
    }
    found
}

#[test]
fn no_module_imports_a_sibling_that_imports_it_back() {
    let mut all = Vec::new();
    for src in crate_sources() {
        for circle in circles(&src, &[]) {
            all.push(format!(
                "{}: {}",
                src.strip_prefix(repo()).unwrap().display(),
                circle.join(" ↔ ")
            ));
        }
    }
    assert!(
        all.is_empty(),
        "import circles between sibling modules:\n{}",
        all.join("\n")
    );
}

#[test]
fn the_circle_check_finds_a_circle() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("lib.rs"), "mod a;\nmod b;\n").unwrap();
    std::fs::write(dir.path().join("a.rs"), "use crate::b::B;\npub struct A;\n").unwrap();
    std::fs::write(
        dir.path().join("b.rs"),
        "use crate::{a::A, c};\npub struct B;\n#[cfg(test)]\nuse crate::d;\n",
    )
    .unwrap();
    std::fs::write(dir.path().join("c.rs"), "// crate::a in a comment\n").unwrap();
    std::fs::write(dir.path().join("d.rs"), "use crate::b;\n").unwrap();
    assert_eq!(
        circles(dir.path(), &[]),
        vec![vec!["a".to_owned(), "b".to_owned()]]
    );
}

/// Files over [`FILE_LINES`] lines of code, each with why it is one file (ARCHITECTURE.md,
/// "Crates"). Code lines: not blank, not a comment, not in `#[cfg(test)]`.
/// None now: `workers/trainer/src/world_model.rs` was one until its imagination moved out (issue
/// 27: `imagination.rs`, and the RSSM's service in `world_model/service.rs`).
const OVER: &[(&str, &str)] = &[];

const FILE_LINES: usize = 1000;
const CRATE_LINES: usize = 6000;

fn code_lines(path: &Path) -> usize {
    code(path).lines().filter(|l| !l.trim().is_empty()).count()
}

#[test]
fn crates_and_files_stay_small_enough_to_read() {
    let mut problems = Vec::new();
    let mut over_seen = BTreeSet::new();
    for src in crate_sources() {
        let mut total = 0;
        for f in rust_files(&src) {
            let n = code_lines(&f);
            total += n;
            let rel = f.strip_prefix(repo()).unwrap().display().to_string();
            if n > FILE_LINES {
                if OVER.iter().any(|(p, _)| *p == rel) {
                    over_seen.insert(rel);
                } else {
                    problems.push(format!("{rel}: {n} lines of code (at most {FILE_LINES})"));
                }
            }
        }
        if total > CRATE_LINES {
            problems.push(format!(
                "{}: {total} lines of code (at most {CRATE_LINES})",
                src.strip_prefix(repo()).unwrap().display()
            ));
        }
    }
    for (p, _) in OVER {
        assert!(
            over_seen.contains(*p),
            "{p} is no longer over {FILE_LINES} lines: take it off OVER"
        );
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
