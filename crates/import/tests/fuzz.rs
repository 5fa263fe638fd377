//! Property tests ("fuzzing") of everything that reads untrusted input: task specs and the three
//! importers. The only property is that nothing panics: every input is either accepted or
//! rejected with errors that name the task, the field and the reason.
//!
//! What is fuzzed:
//!
//! - [`spec::parse_task`] (YAML and JSON) on arbitrary strings, on arbitrary bytes made UTF-8
//!   lossily and on YAML-looking noise;
//! - `parse_task` on *structured mutations* of every spec under `examples/tasks/`: the document
//!   is read as a YAML value, then keys are deleted, scalars replaced by values of other types
//!   (empty strings, `u64::MAX`, `i64::MIN`, ±1e308, NaN, ±inf, `"NaN"`, empty and deeply nested
//!   lists, maps), list elements duplicated, values swapped between fields, keys renamed and
//!   numbers set to f64 extremes; the result is written back as YAML (sometimes truncated at a
//!   random character) and as JSON, and parsed;
//! - `parse_task` on *text mutations* of the same files (truncation, inserted bytes and lines,
//!   deleted lines, replaced tokens, numbers replaced by huge or negative ones);
//! - every spec that parses goes on through [`spec::validate`] (must agree),
//!   [`TaskSpec::for_seed`] (a few seeds, piles laid out), `canonical_json`, `spec_hash`,
//!   `pile_copies` and [`spec_to_yaml`], whose output must parse back to an equal spec;
//! - the GenSim, RoboGen and BBSEA importers on copies of `tests/fixtures/import/<pipeline>`
//!   (well-formed and `malformed/` roots) with one text file (Python, JSON, YAML, URDF, MJCF,
//!   OBJ, substep lists, logs) mutated as above: every task is imported or has errors that name
//!   the task, a field and a reason; `Import::report` and `spec_to_yaml` run on the result, and
//!   an imported spec validates and round-trips through YAML.
//!
//! Running: `cargo test -p assay-import --test fuzz` runs `ASSAY_FUZZ_CASES` cases per property
//! (default 256; measured: 6 s for the whole file in a debug build on a busy 2-core machine,
//! build not counted). Longer: `ASSAY_FUZZ_CASES=100000 cargo test -p assay-import --test fuzz --release`.
//! `ASSAY_FUZZ_SECONDS=N` is a soft time bound for CI: cases that start more than N seconds after
//! the first case of the file return at once. No regression files are written (a failure prints
//! the shrunk input; add it as a unit test next to the code it breaks).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

use assay_import::{Import, ImportOptions, Pipeline, spec_to_yaml};
use assay_spec::error::SpecErrors;
use assay_spec::spec::{self, Format, TaskSpec};
use proptest::prelude::*;
use proptest::test_runner::Config as ProptestConfig;
use serde_yaml_ng::{Mapping, Number, Value};

// ---------------------------------------------------------------------------------------------
// Configuration.

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

fn config() -> ProptestConfig {
    let cases = env_u64("ASSAY_FUZZ_CASES").unwrap_or(256) as u32;
    ProptestConfig {
        cases,
        failure_persistence: None,
        // Shrinking a failure is worth some time, not unbounded time.
        max_shrink_iters: 2048,
        ..ProptestConfig::default()
    }
}

/// The most mutated GenSim libraries imported per run (`ASSAY_FUZZ_GENSIM_CASES`, default 64).
static GENSIM_CASES: std::sync::LazyLock<u64> =
    std::sync::LazyLock::new(|| env_u64("ASSAY_FUZZ_GENSIM_CASES").unwrap_or(64));

/// True once `ASSAY_FUZZ_SECONDS` have passed since the first case of this file.
fn out_of_time() -> bool {
    static START: OnceLock<Instant> = OnceLock::new();
    let start = *START.get_or_init(Instant::now);
    env_u64("ASSAY_FUZZ_SECONDS").is_some_and(|s| start.elapsed().as_secs() >= s)
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn files_under(dir: &Path, keep: &dyn Fn(&Path) -> bool, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_under(&p, keep, out);
        } else if keep(&p) {
            out.push(p);
        }
    }
}

/// An example spec: its path, text and YAML value.
struct Example {
    origin: String,
    text: String,
    value: Value,
}

fn examples() -> &'static [Example] {
    static EXAMPLES: OnceLock<Vec<Example>> = OnceLock::new();
    EXAMPLES.get_or_init(|| {
        let mut files = Vec::new();
        files_under(
            &repo().join("examples/tasks"),
            &|p| p.extension().is_some_and(|e| e == "yaml" || e == "yml"),
            &mut files,
        );
        assert!(files.len() > 10, "examples/tasks has its specs");
        files
            .into_iter()
            .map(|p| {
                let text = std::fs::read_to_string(&p).unwrap();
                let value = serde_yaml_ng::from_str(&text).unwrap();
                Example {
                    origin: p.display().to_string(),
                    text,
                    value,
                }
            })
            .collect()
    })
}

// ---------------------------------------------------------------------------------------------
// What must hold.

/// A parse result: a spec that passes everything downstream, or errors that say what is wrong.
fn check_parse(result: Result<TaskSpec, SpecErrors>, origin: &str) {
    match result {
        Ok(spec) => exercise(&spec, origin),
        Err(errors) => check_errors(&errors, origin),
    }
}

fn check_errors(errors: &SpecErrors, origin: &str) {
    assert!(!errors.0.is_empty(), "an Err with no errors");
    for e in &errors.0 {
        assert!(
            !e.reason.trim().is_empty(),
            "an error without a reason: {e:?}"
        );
        assert_eq!(e.origin, origin, "an error that does not name its origin");
    }
    assert!(!errors.to_string().is_empty());
}

/// Everything a valid spec goes through after parsing.
fn exercise(spec: &TaskSpec, origin: &str) {
    let again = spec::validate(spec, origin);
    assert!(
        again.is_empty(),
        "a parsed spec fails validation: {again:?}"
    );
    let _ = spec.canonical_json();
    assert_eq!(spec.spec_hash().len(), 64);
    for seed in [0, 1, 7, u64::MAX] {
        let s = spec.for_seed(seed);
        let _ = s.spec_hash();
        for pile in &spec.scene.piles {
            for id in spec.pile_copies(&pile.id) {
                assert!(
                    s.object(&id).is_some(),
                    "pile copy {id} missing for seed {seed}"
                );
            }
        }
        // Expanding twice changes nothing more.
        assert_eq!(s.for_seed(seed).canonical_json(), s.canonical_json());
    }
    let yaml = spec_to_yaml(spec);
    match spec::parse_task(&yaml, Format::Yaml, origin) {
        Ok(back) => assert_eq!(&back, spec, "spec_to_yaml does not round-trip:\n{yaml}"),
        Err(e) => panic!("spec_to_yaml output does not parse back: {e}\n{yaml}"),
    }
}

fn check_import(imp: &Import) {
    for e in &imp.errors {
        assert!(
            !e.reason.trim().is_empty(),
            "batch error without a reason: {e:?}"
        );
    }
    for t in &imp.tasks {
        assert!(
            t.spec.is_some() || !t.errors.is_empty(),
            "task {} is neither imported nor has errors",
            t.id
        );
        for e in &t.errors {
            assert!(
                e.task.is_some(),
                "task {}: an error naming no task: {e:?}",
                t.id
            );
            // `path` may be empty: a task-level problem (its source file is missing) names the
            // whole document.
            assert!(
                !e.reason.trim().is_empty(),
                "task {}: an error without a reason: {e:?}",
                t.id
            );
        }
        if let Some(spec) = &t.spec {
            let origin = spec.source.origin.clone().unwrap_or_default();
            exercise(spec, &origin);
        }
    }
    let _ = imp.report();
}

// ---------------------------------------------------------------------------------------------
// Structured mutations of a YAML value.

#[derive(Debug, Clone)]
enum Seg {
    Key(Value),
    Idx(usize),
}

fn paths(v: &Value, prefix: &mut Vec<Seg>, out: &mut Vec<Vec<Seg>>) {
    out.push(prefix.clone());
    match v {
        Value::Mapping(m) => {
            for (k, c) in m {
                prefix.push(Seg::Key(k.clone()));
                paths(c, prefix, out);
                prefix.pop();
            }
        }
        Value::Sequence(s) => {
            for (i, c) in s.iter().enumerate() {
                prefix.push(Seg::Idx(i));
                paths(c, prefix, out);
                prefix.pop();
            }
        }
        _ => {}
    }
}

fn node_mut<'a>(v: &'a mut Value, path: &[Seg]) -> Option<&'a mut Value> {
    let mut cur = v;
    for s in path {
        cur = match (s, cur) {
            (Seg::Key(k), Value::Mapping(m)) => m.get_mut(k)?,
            (Seg::Idx(i), Value::Sequence(s)) => s.get_mut(*i)?,
            _ => return None,
        };
    }
    Some(cur)
}

fn nested(depth: usize) -> Value {
    (0..depth).fold(Value::Number(1.into()), |v, _| Value::Sequence(vec![v]))
}

fn f(x: f64) -> Value {
    Value::Number(Number::from(x))
}

/// A value of some other type.
fn replacement(b: usize) -> Value {
    match b % 20 {
        0 => Value::String("x".into()),
        1 => Value::String(String::new()),
        2 => Value::Number(0.into()),
        3 => Value::Number((-1).into()),
        4 => Value::Number(u64::MAX.into()),
        5 => Value::Number(i64::MIN.into()),
        6 => f(1e308),
        7 => f(f64::NAN),
        8 => f(f64::INFINITY),
        9 => f(f64::NEG_INFINITY),
        10 => Value::Bool(true),
        11 => Value::Null,
        12 => Value::String("NaN".into()),
        13 => Value::String("-.inf".into()),
        14 => Value::Sequence(Vec::new()),
        15 => nested(200),
        16 => nested(20),
        17 => Value::Mapping(Mapping::new()),
        18 => Value::String("é\u{0}🦀 ../../../etc/passwd".into()),
        _ => Value::String("x".repeat(10_000)),
    }
}

fn extreme(b: usize) -> Value {
    match b % 10 {
        0 => f(1e308),
        1 => f(-1e308),
        2 => f(0.0),
        3 => f(-0.0),
        4 => f(5e-324),
        5 => f(f64::MIN_POSITIVE),
        6 => f(f64::MAX),
        7 => f(-1.0),
        8 => Value::Number(u32::MAX.into()),
        _ => Value::Number((u64::from(u32::MAX) + 1).into()),
    }
}

#[derive(Debug, Clone)]
enum Mutation {
    Delete(usize),
    Replace(usize, usize),
    Duplicate(usize, usize),
    Swap(usize, usize),
    Extreme(usize, usize),
    RenameKey(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let u = || any::<usize>();
    prop_oneof![
        u().prop_map(Mutation::Delete),
        (u(), u()).prop_map(|(a, b)| Mutation::Replace(a, b)),
        (u(), u()).prop_map(|(a, b)| Mutation::Duplicate(a, b)),
        (u(), u()).prop_map(|(a, b)| Mutation::Swap(a, b)),
        (u(), u()).prop_map(|(a, b)| Mutation::Extreme(a, b)),
        (u(), u()).prop_map(|(a, b)| Mutation::RenameKey(a, b)),
    ]
}

fn mutate(v: &mut Value, m: &Mutation) {
    let mut all = Vec::new();
    paths(v, &mut Vec::new(), &mut all);
    let pick = |a: usize, keep: &dyn Fn(&Value) -> bool, v: &mut Value| -> Option<Vec<Seg>> {
        let cands: Vec<&Vec<Seg>> = all
            .iter()
            .filter(|p| node_mut(v, p).is_some_and(|n| keep(n)))
            .collect();
        (!cands.is_empty()).then(|| cands[a % cands.len()].clone())
    };
    match *m {
        Mutation::Delete(a) => {
            let Some(path) = pick(a, &|_| true, v) else {
                return;
            };
            let Some((last, parent)) = path.split_last() else {
                return;
            };
            match (last, node_mut(v, parent)) {
                (Seg::Key(k), Some(Value::Mapping(m))) => {
                    m.remove(k);
                }
                (Seg::Idx(i), Some(Value::Sequence(s))) => {
                    s.remove(*i);
                }
                _ => {}
            }
        }
        Mutation::Replace(a, b) => {
            if let Some(path) = pick(a, &|_| true, v) {
                *node_mut(v, &path).unwrap() = replacement(b);
            }
        }
        Mutation::Duplicate(a, b) => {
            let nonempty = |n: &Value| n.as_sequence().is_some_and(|s| !s.is_empty());
            if let Some(path) = pick(a, &nonempty, v)
                && let Some(Value::Sequence(s)) = node_mut(v, &path)
            {
                let i = b % s.len();
                let e = s[i].clone();
                s.insert(i, e);
            }
        }
        Mutation::Swap(a, b) => {
            let (Some(pa), Some(pb)) = (pick(a, &|_| true, v), pick(b, &|_| true, v)) else {
                return;
            };
            let va = node_mut(v, &pa).unwrap().clone();
            let vb = node_mut(v, &pb).unwrap().clone();
            *node_mut(v, &pa).unwrap() = vb;
            if let Some(n) = node_mut(v, &pb) {
                *n = va;
            }
        }
        Mutation::Extreme(a, b) => {
            if let Some(path) = pick(a, &Value::is_number, v) {
                *node_mut(v, &path).unwrap() = extreme(b);
            }
        }
        Mutation::RenameKey(a, b) => {
            if let Some(path) = pick(a, &Value::is_mapping, v)
                && let Some(Value::Mapping(m)) = node_mut(v, &path)
                && !m.is_empty()
            {
                let keys: Vec<Value> = m.keys().cloned().collect();
                let k = &keys[b % keys.len()];
                let val = m.remove(k).unwrap();
                let name = match (b / keys.len()) % 3 {
                    0 => format!("{}_", k.as_str().unwrap_or("k")),
                    1 => keys[(b / 3) % keys.len()].as_str().unwrap_or("").to_owned(),
                    _ => "spec_version".to_owned(),
                };
                m.insert(Value::String(name), val);
            }
        }
    }
}

fn floor_char_boundary(s: &str, at: usize) -> usize {
    let mut at = at.min(s.len());
    while !s.is_char_boundary(at) {
        at -= 1;
    }
    at
}

// ---------------------------------------------------------------------------------------------
// Text mutations (spec files and importer sources).

#[derive(Debug, Clone)]
enum TextOp {
    Truncate(usize),
    InsertBytes(usize, Vec<u8>),
    InsertLine(usize, String),
    DeleteLine(usize),
    ReplaceToken(usize, String),
    ReplaceNumber(usize, usize),
}

fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<String>(),
        "[a-zA-Z0-9_ .:\\-\\[\\]{}()\"',#=*/\n]{0,16}",
        prop::sample::select(vec![
            "None", "null", "True", "False", "[]", "{}", "(", ")", "[", "]", "\"", "'", "\n", ":",
            "- ", "  ", "\t", "1e308", "-1", "nan", "inf", "0", "-0", "0.0", "&a", "*a",
            "!!binary", "---", "...", "#", "\\", "np.pi", "range(", "/", "../", "é", "🦀",
        ])
        .prop_map(str::to_owned),
    ]
}

fn text_op() -> impl Strategy<Value = TextOp> {
    let u = || any::<usize>();
    prop_oneof![
        u().prop_map(TextOp::Truncate),
        (u(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(a, b)| TextOp::InsertBytes(a, b)),
        (u(), token()).prop_map(|(a, s)| TextOp::InsertLine(a, s)),
        u().prop_map(TextOp::DeleteLine),
        (u(), token()).prop_map(|(a, s)| TextOp::ReplaceToken(a, s)),
        (u(), u()).prop_map(|(a, b)| TextOp::ReplaceNumber(a, b)),
    ]
}

const NUMBERS: &[&str] = &[
    "1e308",
    "-1e308",
    "99999999999999999999999",
    "-5",
    "0",
    "1e-320",
    "nan",
    "inf",
    "-0",
    "4294967296",
    "18446744073709551616",
    "1000000000",
    "-1000000000",
];

/// Runs of bytes that `is_tok` accepts: (start, end).
fn runs(b: &[u8], is_tok: impl Fn(u8) -> bool) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if is_tok(b[i]) {
            let s = i;
            while i < b.len() && is_tok(b[i]) {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

fn apply_text(text: &[u8], op: &TextOp) -> Vec<u8> {
    let mut b = text.to_vec();
    let lines =
        |b: &[u8]| -> Vec<Vec<u8>> { b.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect() };
    match op {
        TextOp::Truncate(p) => {
            let at = p % (b.len() + 1);
            let at = match std::str::from_utf8(&b) {
                Ok(s) => floor_char_boundary(s, at),
                Err(_) => at,
            };
            b.truncate(at);
        }
        TextOp::InsertBytes(p, bytes) => {
            let at = p % (b.len() + 1);
            b.splice(at..at, bytes.iter().copied());
        }
        TextOp::InsertLine(l, s) => {
            let mut ls = lines(&b);
            let at = l % (ls.len() + 1);
            ls.insert(at, s.as_bytes().to_vec());
            b = ls.join(&b'\n');
        }
        TextOp::DeleteLine(l) => {
            let mut ls = lines(&b);
            let at = l % ls.len();
            ls.remove(at);
            b = ls.join(&b'\n');
        }
        TextOp::ReplaceToken(k, s) => {
            let toks = runs(&b, |c| c.is_ascii_alphanumeric() || c == b'_');
            if !toks.is_empty() {
                let (x, y) = toks[k % toks.len()];
                b.splice(x..y, s.bytes());
            }
        }
        TextOp::ReplaceNumber(k, n) => {
            let nums = runs(&b, |c| c.is_ascii_digit() || c == b'.');
            let nums: Vec<_> = nums
                .into_iter()
                .filter(|&(x, y)| b[x..y].iter().any(u8::is_ascii_digit))
                .collect();
            if !nums.is_empty() {
                let (x, y) = nums[k % nums.len()];
                b.splice(x..y, NUMBERS[n % NUMBERS.len()].bytes());
            }
        }
    }
    b
}

// ---------------------------------------------------------------------------------------------
// Importers.

fn fixtures() -> PathBuf {
    repo().join("tests/fixtures/import")
}

const PIPELINES: [Pipeline; 3] = [Pipeline::Gensim, Pipeline::Robogen, Pipeline::Bbsea];

/// The text files of one pipeline's fixture tree, relative to it.
fn text_files(p: Pipeline) -> &'static [PathBuf] {
    static FILES: OnceLock<Vec<Vec<PathBuf>>> = OnceLock::new();
    &FILES.get_or_init(|| {
        PIPELINES
            .iter()
            .map(|p| {
                let root = fixtures().join(p.name());
                let mut files = Vec::new();
                files_under(
                    &root,
                    &|f| {
                        f.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                            ["json", "py", "yaml", "yml", "txt", "urdf", "xml", "obj"].contains(&e)
                        })
                    },
                    &mut files,
                );
                assert!(!files.is_empty());
                files
                    .into_iter()
                    .map(|f| f.strip_prefix(&root).unwrap().to_path_buf())
                    .collect()
            })
            .collect()
    })[PIPELINES.iter().position(|q| *q == p).unwrap()]
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}

/// Imports `p`'s fixture tree with `file` mutated by `ops`: the well-formed root and the
/// `malformed/` one (assets as `tests/import.rs` passes them).
fn import_mutated(p: Pipeline, file: usize, ops: &[TextOp]) {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join(p.name());
    copy_tree(&fixtures().join(p.name()), &root);
    let files = text_files(p);
    let rel = &files[file % files.len()];
    let path = root.join(rel);
    let mut bytes = std::fs::read(&path).unwrap();
    for op in ops {
        bytes = apply_text(&bytes, op);
    }
    std::fs::write(&path, &bytes).unwrap();

    check_import(&assay_import::import(p, &root, &ImportOptions::default()));
    let assets = match p {
        Pipeline::Bbsea => root.clone(),
        _ => root.join("assets"),
    };
    let malformed = assay_import::import(
        p,
        &root.join("malformed"),
        &ImportOptions {
            asset_root: Some(assets),
            ..ImportOptions::default()
        },
    );
    check_import(&malformed);
}

// ---------------------------------------------------------------------------------------------
// The properties.

#[test]
fn examples_parse_and_survive_the_checks() {
    for ex in examples() {
        let spec = spec::parse_task(&ex.text, Format::Yaml, &ex.origin)
            .unwrap_or_else(|e| panic!("{}: {e}", ex.origin));
        exercise(&spec, &ex.origin);
    }
}

#[test]
fn fixtures_import_and_survive_the_checks() {
    for p in PIPELINES {
        import_mutated(p, 0, &[]);
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn parse_arbitrary_strings(text in any::<String>(), json in any::<bool>()) {
        if out_of_time() { return Ok(()); }
        let format = if json { Format::Json } else { Format::Yaml };
        check_parse(spec::parse_task(&text, format, "fuzz"), "fuzz");
    }

    #[test]
    fn parse_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..512), json in any::<bool>()) {
        if out_of_time() { return Ok(()); }
        let text = String::from_utf8_lossy(&bytes);
        let format = if json { Format::Json } else { Format::Yaml };
        check_parse(spec::parse_task(&text, format, "fuzz"), "fuzz");
    }

    #[test]
    fn parse_yaml_looking_noise(
        text in "(id: [a-z_-]{0,8}\n|spec_version: [0-9]\n|scene:\n|  objects:\n|  - |\\{|\\}|\\[|\\]|: |, |[a-z_]{1,10}|-?[0-9.e]{1,6}|\n  |\n)*",
        json in any::<bool>(),
    ) {
        if out_of_time() { return Ok(()); }
        let format = if json { Format::Json } else { Format::Yaml };
        check_parse(spec::parse_task(&text, format, "fuzz"), "fuzz");
    }

    #[test]
    fn parse_structured_mutations_of_examples(
        which in any::<usize>(),
        mutations in prop::collection::vec(mutation(), 1..5),
        truncate in prop::option::weighted(0.2, any::<usize>()),
    ) {
        if out_of_time() { return Ok(()); }
        let ex = &examples()[which % examples().len()];
        let mut value = ex.value.clone();
        for m in &mutations {
            mutate(&mut value, m);
        }
        if let Ok(mut yaml) = serde_yaml_ng::to_string(&value) {
            if let Some(t) = truncate {
                let at = floor_char_boundary(&yaml, t % (yaml.len() + 1));
                yaml.truncate(at);
            }
            check_parse(spec::parse_task(&yaml, Format::Yaml, &ex.origin), &ex.origin);
        }
        if let Ok(json) = serde_json::to_string(&value) {
            check_parse(spec::parse_task(&json, Format::Json, &ex.origin), &ex.origin);
        }
    }

    #[test]
    fn parse_text_mutations_of_examples(
        which in any::<usize>(),
        ops in prop::collection::vec(text_op(), 1..4),
    ) {
        if out_of_time() { return Ok(()); }
        let ex = &examples()[which % examples().len()];
        let mut bytes = ex.text.as_bytes().to_vec();
        for op in &ops {
            bytes = apply_text(&bytes, op);
        }
        let text = String::from_utf8_lossy(&bytes);
        check_parse(spec::parse_task(&text, Format::Yaml, &ex.origin), &ex.origin);
    }

    #[test]
    fn import_gensim_mutated(file in any::<usize>(), ops in prop::collection::vec(text_op(), 1..4)) {
        // Each case runs every task's code in a Python subprocess: a smaller share of the
        // time budget than the readers' properties get.
        static CASES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        if out_of_time() || CASES.fetch_add(1, std::sync::atomic::Ordering::Relaxed) >= *GENSIM_CASES {
            return Ok(());
        }
        import_mutated(Pipeline::Gensim, file, &ops);
    }

    #[test]
    fn import_robogen_mutated(file in any::<usize>(), ops in prop::collection::vec(text_op(), 1..4)) {
        if out_of_time() { return Ok(()); }
        import_mutated(Pipeline::Robogen, file, &ops);
    }

    #[test]
    fn import_bbsea_mutated(file in any::<usize>(), ops in prop::collection::vec(text_op(), 1..4)) {
        if out_of_time() { return Ok(()); }
        import_mutated(Pipeline::Bbsea, file, &ops);
    }
}
