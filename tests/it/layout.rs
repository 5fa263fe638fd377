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

/// A function of a source file: its name, its first line (1-based) and its length in lines,
/// from its `fn` line to the `}` at the same indent. Functions in `#[cfg(test)]` code (at the end
/// by house style) are left out; trait declarations without a body too.
fn functions(text: &str) -> Vec<(String, usize, usize)> {
    let text = match text.find("\n#[cfg(test)]") {
        Some(i) => &text[..i],
        None => text,
    };
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let rest = line.trim_start();
        let indent = &line[..line.len() - rest.len()];
        let mut rest = rest;
        for prefix in [
            "pub(crate) ",
            "pub(super) ",
            "pub ",
            "const ",
            "async ",
            "unsafe ",
        ] {
            rest = rest.strip_prefix(prefix).unwrap_or(rest);
        }
        let Some(sig) = rest.strip_prefix("fn ") else {
            continue;
        };
        let name: String = sig
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if line.trim_end().ends_with(';') || name.is_empty() {
            continue;
        }
        let close = format!("{indent}}}");
        if let Some(end) = (i..lines.len()).find(|&j| lines[j] == close) {
            out.push((name, i + 1, end - i + 1));
        }
    }
    out
}

/// The `.rs` files under `dir`, recursively.
fn sources_under(dir: &Path) -> Vec<PathBuf> {
    if dir.is_dir() {
        rust_files(dir)
    } else {
        Vec::new()
    }
}

/// At most this many lines per function of the command line (`src/`): a command parses, calls
/// one library function and prints (STYLE.md, "Functions"; issue 41).
const CLI_FUNCTION_LINES: usize = 100;
/// At most this many lines of code in `src/cmd/eval.rs` and `src/cmd/watch.rs`.
const RUN_COMMAND_LINES: usize = 150;
/// The ceiling for every function of the workspace. It falls as long functions are split: the
/// four longest (RoboGen's `import_one`, 656 lines; the spec's `validate`, 562; GenSim's
/// `translate`, 515; the sim's `simulate_with`, 309) and the report read model (375) were split
/// by section in issue 41.
const FUNCTION_LINES: usize = 300;

#[test]
fn the_command_line_is_thin_and_no_command_uses_another() {
    let src = repo().join("src");
    let mut problems = Vec::new();
    for f in rust_files(&src) {
        let rel = f.strip_prefix(repo()).unwrap().display().to_string();
        for (name, line, n) in functions(&std::fs::read_to_string(&f).unwrap()) {
            if n > CLI_FUNCTION_LINES {
                problems.push(format!(
                    "{rel}:{line}: fn {name} is {n} lines (at most {CLI_FUNCTION_LINES})"
                ));
            }
        }
    }
    for run in ["eval", "watch"] {
        let n = code_lines(&src.join(format!("cmd/{run}.rs")));
        if n > RUN_COMMAND_LINES {
            problems.push(format!(
                "src/cmd/{run}.rs: {n} lines of code (at most {RUN_COMMAND_LINES})"
            ));
        }
    }
    let commands: Vec<String> = modules(&src.join("cmd")).into_keys().collect();
    for (command, files) in modules(&src.join("cmd")) {
        for f in files {
            let code = code(&f);
            let used = following(&code, "super::")
                .into_iter()
                .chain(following(&code, "crate::cmd::"));
            for other in used.filter(|u| *u != command && commands.contains(u)) {
                problems.push(format!(
                    "src/cmd/{command}: uses the command `{other}` (shared code goes in a \
                     library or in src/ outside cmd/)"
                ));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn no_function_of_the_workspace_is_over_the_ceiling() {
    let mut all = Vec::new();
    for src in crate_sources() {
        for f in rust_files(&src) {
            let rel = f.strip_prefix(repo()).unwrap().display().to_string();
            for (name, line, n) in functions(&std::fs::read_to_string(&f).unwrap()) {
                all.push((n, format!("{rel}:{line}: fn {name}")));
            }
        }
    }
    all.sort_by_key(|b| std::cmp::Reverse(b.0));
    println!("the longest functions:");
    for (n, at) in all.iter().take(10) {
        println!("  {n:>4} {at}");
    }
    let over: Vec<String> = all
        .iter()
        .filter(|(n, _)| *n > FUNCTION_LINES)
        .map(|(n, at)| format!("{at} is {n} lines (at most {FUNCTION_LINES})"))
        .collect();
    assert!(over.is_empty(), "{}", over.join("\n"));
}

#[test]
fn the_function_check_measures_functions() {
    let text = "pub fn a() {\n    one();\n}\n\nimpl X {\n    pub(crate) async fn b(\n        x: u8,\n    ) -> u8 {\n        x\n    }\n    fn decl();\n}\n#[cfg(test)]\nfn t() {\n}\n";
    assert_eq!(
        functions(text),
        vec![("a".to_owned(), 1, 3), ("b".to_owned(), 6, 5)]
    );
}

#[test]
fn nothing_outside_the_coordinator_uses_its_grpc_service_module() {
    // Planning is `assay-plan`'s: the coordinator's gRPC service module serves it, nothing else
    // links it for its helpers.
    let mut users = Vec::new();
    for dir in [
        "src",
        "crates",
        "workers",
        "telemetry",
        "proto",
        "tools",
        "tests",
    ] {
        for f in sources_under(&repo().join(dir)) {
            if std::fs::read_to_string(&f)
                .unwrap()
                .contains(concat!("assay_coordinator", "::service"))
            {
                users.push(f.strip_prefix(repo()).unwrap().display().to_string());
            }
        }
    }
    assert!(users.is_empty(), "{}", users.join("\n"));
}
