//! Dependencies stay in the layer that needs them (ARCHITECTURE.md, "Crates"): the domain crates
//! (spec, stats, model, plan) link no drawing, HTTP server, physics, rendering or torch; reports,
//! exports and importers no physics, rendering or torch; the coordinator, the worker runtime and
//! the protocol no physics, rendering or torch; each engine none of the others; nothing that
//! ships links the test kit. Every crate of the workspace has its line (a test checks), so a new
//! crate says what it never links. Checked on `cargo tree`'s normal dependencies, so a
//! dev-dependency (a test's fixture server) does not count.

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

/// Physics, rendering and torch (the engines).
const ENGINES: &[&str] = &["rapier3d", "parry3d", "wgpu", "tch", "torch-sys"];

/// Every crate of the workspace, with what it never links.
fn forbidden() -> Vec<(&'static str, Vec<&'static str>)> {
    let domain: Vec<&str> = HEAVY.iter().chain(PRESENTATION).copied().collect();
    let with = |base: &[&'static str], more: &[&'static str]| -> Vec<&'static str> {
        base.iter().chain(more).copied().collect()
    };
    vec![
        ("assay-spec", domain.clone()),
        ("assay-stats", domain.clone()),
        ("assay-model", domain.clone()),
        (
            "assay-plan",
            with(&domain, &["rusqlite", "zenoh", "assay-proto"]),
        ),
        (
            "assay-report",
            with(HEAVY, &["rusqlite", "assay-coordinator"]),
        ),
        ("assay-import", HEAVY.to_vec()),
        // Parquet's arrow support brings arrow-ipc; the episodes are drawn by the layer above.
        (
            "assay-export",
            with(ENGINES, &["rusqlite", "assay-coordinator"]),
        ),
        (
            "assay-openai",
            with(HEAVY, &["rusqlite", "zenoh", "iceoryx2"]),
        ),
        ("assay-testkit", HEAVY.to_vec()),
        ("assay-coordinator", HEAVY.to_vec()),
        ("assay-worker-runtime", HEAVY.to_vec()),
        ("assay-proto", HEAVY.to_vec()),
        ("assay-telemetry", with(HEAVY, &["rusqlite", "iceoryx2"])),
        (
            "assay-framebus",
            with(HEAVY, &["tonic", "zenoh", "rusqlite"]),
        ),
        (
            "assay-sim",
            with(
                &["wgpu", "tch", "torch-sys"],
                &["tonic", "zenoh", "reqwest", "rusqlite"],
            ),
        ),
        (
            "assay-render",
            with(
                &["rapier3d", "parry3d", "tch", "torch-sys"],
                &["tonic", "zenoh", "rusqlite"],
            ),
        ),
        (
            "assay-policy",
            vec!["rapier3d", "wgpu", "rusqlite", "assay-coordinator"],
        ),
        (
            "assay-judge",
            with(ENGINES, &["axum", "rusqlite", "assay-testkit"]),
        ),
        (
            "assay-trainer",
            vec!["assay-judge", "axum", "wgpu", "rapier3d", "rusqlite"],
        ),
        (
            "assay-embed",
            vec![
                "assay-trainer",
                "assay-judge",
                "axum",
                "wgpu",
                "rapier3d",
                "rusqlite",
            ],
        ),
        (
            "assay-worker",
            vec!["rusqlite", "assay-coordinator", "assay-testkit"],
        ),
        ("assay-run", vec!["assay-testkit"]),
        ("assay", vec!["assay-testkit"]),
        (
            "assay-browser-check",
            vec![
                "assay-spec",
                "assay-model",
                "assay-report",
                "assay-proto",
                "assay-run",
            ],
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
fn every_crate_of_the_workspace_says_what_it_never_links() {
    let manifest =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml")).unwrap();
    let members = manifest
        .split_once("members = [")
        .and_then(|(_, rest)| rest.split_once(']'))
        .expect("workspace members")
        .0;
    let listed: Vec<&str> = forbidden().iter().map(|(k, _)| *k).collect();
    for member in members.split(',').map(|m| m.trim().trim_matches('"')) {
        if member.is_empty() {
            continue;
        }
        let toml = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join(member)
                .join("Cargo.toml"),
        )
        .unwrap();
        let name = toml
            .lines()
            .find_map(|l| l.strip_prefix("name = \""))
            .and_then(|l| l.strip_suffix('"'))
            .unwrap_or_else(|| panic!("{member}: no package name"));
        assert!(
            listed.contains(&name),
            "{name} ({member}) has no line in forbidden(): say what it never links"
        );
    }
}

#[test]
fn the_check_sees_a_heavy_dependency_where_there_is_one() {
    // Without this the test above would pass on a `cargo tree` that printed nothing useful.
    assert!(tree("assay-sim").iter().any(|d| d == "rapier3d"));
    assert!(tree("assay-report").iter().any(|d| d == "plotters"));
}
