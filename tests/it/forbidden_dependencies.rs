//! Dependencies stay in the layer that needs them (ARCHITECTURE.md, "Crates"): the domain crates
//! (spec, stats, model) link no drawing, HTTP server, physics, rendering or torch; reports and
//! importers no physics, rendering or torch; the coordinator, the worker runtime and the protocol
//! no physics, rendering or torch; the trainer does not link the judge. Checked on `cargo tree`'s
//! normal dependencies, so a dev-dependency (a test's fixture server) does not count.

use std::process::Command;

/// Physics, rendering, torch and the episode files' Arrow writer.
const HEAVY: &[&str] = &[
    "rapier3d",
    "parry3d",
    "wgpu",
    "tch",
    "torch-sys",
    "arrow-ipc",
];

/// What a domain crate never links beyond [`HEAVY`]: drawing, images and HTTP servers.
const PRESENTATION: &[&str] = &["plotters", "png", "axum", "hyper", "tonic", "reqwest"];

fn forbidden() -> Vec<(&'static str, Vec<&'static str>)> {
    let domain: Vec<&str> = HEAVY.iter().chain(PRESENTATION).copied().collect();
    vec![
        ("assay-spec", domain.clone()),
        ("assay-stats", domain.clone()),
        ("assay-model", domain),
        ("assay-report", HEAVY.to_vec()),
        ("assay-import", HEAVY.to_vec()),
        ("assay-coordinator", HEAVY.to_vec()),
        ("assay-worker-runtime", HEAVY.to_vec()),
        ("assay-proto", HEAVY.to_vec()),
        (
            "assay-trainer",
            vec!["assay-judge", "axum", "wgpu", "rapier3d"],
        ),
    ]
}

/// The names of every crate in `krate`'s normal dependency tree.
fn tree(krate: &str) -> Vec<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
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
        "cargo tree -p {krate} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_owned))
        .collect()
}

#[test]
fn each_layer_links_only_what_it_needs() {
    for (krate, never) in forbidden() {
        let deps = tree(krate);
        // The check itself sees dependencies at all.
        assert!(deps.len() > 1, "{krate}: empty tree");
        for dep in never {
            assert!(
                !deps.iter().any(|d| d == dep),
                "{krate} depends on {dep} (ARCHITECTURE.md says it never does)"
            );
        }
    }
}

#[test]
fn the_check_sees_a_heavy_dependency_where_there_is_one() {
    // Without this the test above would pass on a `cargo tree` that printed nothing useful.
    assert!(tree("assay-sim").iter().any(|d| d == "rapier3d"));
    assert!(tree("assay-report").iter().any(|d| d == "plotters"));
}
