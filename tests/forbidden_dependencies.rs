//! Heavy dependencies stay in the crate that needs them: the coordinator, the worker runtime, the
//! protocol and the core never link physics, rendering or torch.

use std::process::Command;

const HEAVY: &[&str] = &[
    "rapier3d",
    "parry3d",
    "wgpu",
    "tch",
    "torch-sys",
    "arrow-ipc",
];

#[test]
fn light_crates_do_not_link_heavy_dependencies() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    for krate in [
        "assay-coordinator",
        "assay-worker-runtime",
        "assay-proto",
        "assay-core",
    ] {
        let out = Command::new(&cargo)
            .args([
                "tree",
                "--offline",
                "-e",
                "normal",
                "--prefix",
                "none",
                "-p",
                krate,
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "cargo tree failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let tree = String::from_utf8_lossy(&out.stdout);
        for heavy in HEAVY {
            assert!(
                !tree
                    .lines()
                    .any(|l| l.split_whitespace().next() == Some(heavy)),
                "{krate} depends on {heavy}"
            );
        }
        // The check itself sees dependencies at all.
        assert!(tree.lines().count() > 1, "{krate}: empty tree");
    }
}
