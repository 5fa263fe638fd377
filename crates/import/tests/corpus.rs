//! GenSim's own task library (`../shared/corpora/gensim-library`, 100 of its 152 entries, their
//! task code and GenSim's assets, unchanged): how much of it imports, and why the rest is refused.
//! The corpus is read where it lies, never copied; no task name is special-cased.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use assay_import::{ImportOptions, Pipeline, import};

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/corpora/gensim-library")
}

#[test]
fn gensim_library_imports() {
    let root = corpus();
    assert!(
        root.join("generated_tasks.json").exists(),
        "the GenSim corpus is not at {} (CI and the workspace have ../shared)",
        root.display()
    );
    let imp = import(Pipeline::Gensim, &root, &ImportOptions::default());
    assert!(imp.errors.is_empty(), "{:?}", imp.errors);
    let with_code: Vec<_> = imp
        .tasks
        .iter()
        .filter(|t| t.source.extension().is_some_and(|e| e == "py"))
        .collect();
    let imported = with_code.iter().filter(|t| t.spec.is_some()).count();
    let mut causes: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for t in &with_code {
        if t.spec.is_none() {
            let e = &t.errors[0];
            causes
                .entry(format!(
                    "{}: {}",
                    e.path,
                    e.reason.chars().take(90).collect::<String>()
                ))
                .or_default()
                .push(t.name.clone());
        }
    }
    println!(
        "{} entries, {} with task code, {imported} imported",
        imp.tasks.len(),
        with_code.len()
    );
    for (cause, tasks) in &causes {
        println!("refused ({}): {cause} — {}", tasks.len(), tasks.join(", "));
    }
    // Every refusal names the task, the field and the reason.
    for t in imp.tasks.iter().filter(|t| t.spec.is_none()) {
        assert!(!t.errors.is_empty(), "{} refused without a reason", t.name);
        for e in &t.errors {
            assert_eq!(e.task.as_deref(), Some(t.id.as_str()));
            assert!(!e.reason.is_empty());
        }
    }
    assert!(
        imported * 10 >= with_code.len() * 9,
        "{imported} of {} entries with task code imported (wanted 90 %)",
        with_code.len()
    );
}
