//! The scripts' own setup paths, which no other test runs: a pinned Python set installed without
//! dependency resolution (`scripts/bench-embeddings`) must stay complete as the packages it pins
//! gain imports. Resolved by pip from PyPI's metadata (a dry run; nothing is installed).

use std::process::Command;

use crate::common::*;

fn check_pins(requirements: &std::path::Path, allowed: &[&str]) -> (bool, serde_json::Value) {
    let python = std::env::var("ASSAY_TEST_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(python)
        .arg(repo().join("tests/python/check_pins.py"))
        .arg(requirements)
        .args(allowed)
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&out.stdout);
    let value = serde_json::from_str(printed.trim())
        .unwrap_or_else(|e| panic!("{e}: {printed}\n{}", String::from_utf8_lossy(&out.stderr)));
    (out.status.success(), value)
}

#[test]
fn the_embeddings_benchmarks_pinned_set_is_complete() {
    // What the script leaves out on purpose: the CUDA libraries (stubbed), triton, setuptools.
    let allowed = ["nvidia-.*", "cuda-.*", "triton", "setuptools"];
    let (ok, found) = check_pins(&repo().join("bench/embeddings/requirements.txt"), &allowed);
    assert!(
        ok,
        "bench/embeddings/requirements.txt is incomplete: {found}"
    );
    // The check sees a missing pin where there is one: joblib 1.6 imports cloudpickle.
    let dir = tempfile::tempdir().unwrap();
    let partial = dir.path().join("requirements.txt");
    std::fs::write(&partial, "joblib==1.6.0\n").unwrap();
    let (ok, found) = check_pins(&partial, &allowed);
    assert!(!ok);
    assert!(
        found["unpinned"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p.as_str().unwrap().starts_with("cloudpickle==")),
        "{found}"
    );
}
