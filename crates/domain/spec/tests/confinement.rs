//! Property test: whatever path a task names (`..`, `.`, absolute, through symbolic links that
//! point in or out), an asset the spec resolves lies inside its asset root, and a path the
//! operator's roots accept lies inside them. Cases: `ASSAY_FUZZ_CASES` (default 256).

use std::path::{Path, PathBuf};

use assay_spec::assets::check_within;
use assay_spec::spec::{Format, parse_task};
use proptest::prelude::*;

/// `base/root` (the asset root) with files, a folder and links in and out; `base/outside` with
/// a secret.
fn tree() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    let outside = dir.path().join("outside");
    std::fs::create_dir_all(root.join("a/b")).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(root.join("f1"), "x").unwrap();
    std::fs::write(root.join("a/f2"), "x").unwrap();
    std::fs::write(outside.join("secret"), "x").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::symlink;
        symlink(&outside, root.join("l_out")).unwrap();
        symlink(outside.join("secret"), root.join("a/l_file")).unwrap();
        symlink(root.join("a"), root.join("l_in")).unwrap();
        symlink("../..", root.join("a/b/up")).unwrap();
    }
    (dir, root, outside)
}

const PARTS: &[&str] = &[
    "a", "b", "f1", "f2", "..", ".", "l_out", "l_in", "l_file", "up", "secret", "outside", "root",
];

fn path_strategy() -> impl Strategy<Value = (bool, Vec<usize>)> {
    (any::<bool>(), prop::collection::vec(0..PARTS.len(), 1..7))
}

fn cases() -> u32 {
    std::env::var("ASSAY_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256)
}

fn joined(base: &Path, absolute: bool, parts: &[usize]) -> String {
    let rel = parts
        .iter()
        .map(|&i| PARTS[i])
        .collect::<Vec<_>>()
        .join("/");
    if absolute {
        format!("{}/{rel}", base.display())
    } else {
        rel
    }
}

/// The property below would hold vacuously if nothing resolved: assets inside do, links out do
/// not.
#[test]
fn the_tree_resolves_inside_and_refuses_outside() {
    let (_dir, root, _outside) = tree();
    let mut spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "t.yaml",
    )
    .unwrap();
    spec.source.asset_root = Some(root.display().to_string());
    assert!(spec.resolve_asset("f1").is_ok());
    assert!(spec.resolve_asset("a/f2").is_ok());
    #[cfg(unix)]
    {
        assert!(spec.resolve_asset("l_in/f2").is_ok());
        assert!(spec.resolve_asset("l_out/secret").is_err());
        assert!(spec.resolve_asset("a/l_file").is_err());
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases()))]

    #[test]
    fn a_resolved_asset_never_lies_outside_the_root((absolute, parts) in path_strategy()) {
        let (dir, root, outside) = tree();
        let mut spec = parse_task(assay_testkit::tasks::PUT_BLOCK_IN_ZONE, Format::Yaml, "t.yaml")
            .unwrap();
        spec.source.asset_root = Some(root.display().to_string());
        let named = joined(dir.path(), absolute, &parts);
        let root_c = root.canonicalize().unwrap();
        let outside_c = outside.canonicalize().unwrap();
        if let Ok(found) = spec.resolve_asset(&named) {
            prop_assert!(found.starts_with(&root_c), "{named} -> {}", found.display());
            prop_assert!(!found.starts_with(&outside_c), "{named} -> {}", found.display());
        }
        // The operator's roots, checked on any path at all.
        let any = root.join(joined(Path::new(""), false, &parts));
        if check_within(&any, std::slice::from_ref(&root_c)).is_ok() {
            let c = any.canonicalize().unwrap();
            prop_assert!(c.starts_with(&root_c), "{} -> {}", any.display(), c.display());
        }
    }
}
