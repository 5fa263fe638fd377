//! Helpers shared by the render crate's integration tests.

use std::path::{Path, PathBuf};

use assay_spec::spec::{Format, TaskSpec, parse_task};

/// A task of the example corpus, by its path below `examples/tasks`.
pub fn task(rel: &str) -> TaskSpec {
    let p: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/tasks")
        .join(rel);
    let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    parse_task(&text, Format::Yaml, &p.display().to_string()).unwrap_or_else(|e| panic!("{e}"))
}
