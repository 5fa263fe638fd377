//! deploy/: the Kubernetes manifests validate against Kubernetes' own schemas (strictly, the GPU
//! overlay merged into the base), and the configuration they mount is one the binary accepts.

use std::process::Command;

use crate::common::*;

fn python() -> String {
    std::env::var("ASSAY_TEST_PYTHON").unwrap_or_else(|_| "python3".into())
}

#[test]
fn the_kubernetes_manifests_validate_against_the_kubernetes_schemas() {
    let out = Command::new(python())
        .arg(repo().join("tests/python/validate_k8s.py"))
        .arg(repo().join("deploy/k8s"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}\n(scripts/test installs kubernetes-validate; or set ASSAY_TEST_PYTHON)",
        String::from_utf8_lossy(&out.stderr)
    );
    // Every kind the deployment needs was checked.
    for kind in [
        "StatefulSet/assay-coordinator",
        "Service/assay-coordinator",
        "Deployment/assay-worker-sim",
        "Deployment/assay-worker-judge",
        "Deployment/assay-worker-trainer",
        "HorizontalPodAutoscaler/assay-worker-sim",
        "ConfigMap/assay-config",
        "Secret/assay-secrets",
        "PersistentVolumeClaim/assay-artifacts",
        "NetworkPolicy/assay-coordinator",
    ] {
        assert!(
            text.contains(&format!(": {kind}")),
            "{kind} not checked:\n{text}"
        );
    }
    assert!(text.contains("gpu-workers.yaml on"), "{text}");
    assert!(
        text.contains("a broken HorizontalPodAutoscaler is refused"),
        "{text}"
    );
}

#[test]
fn the_mounted_configuration_is_accepted_by_every_role() {
    let manifest = std::fs::read_to_string(repo().join("deploy/k8s/base/config.yaml")).unwrap();
    let toml: String = manifest
        .lines()
        .skip_while(|l| !l.trim_start().starts_with("assay.toml: |"))
        .skip(1)
        .map(|l| l.strip_prefix("    ").unwrap_or(l))
        .collect::<Vec<_>>()
        .join("\n");
    assert!(toml.contains("[coordinator]"), "{toml}");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("assay.toml");
    for (text, ok) in [
        (toml.clone(), true),
        (toml.replace("heartbeat-ms", "heartbeat-msec"), false),
    ] {
        std::fs::write(&file, &text).unwrap();
        for sub in ["coordinator", "worker"] {
            let out = Command::new(bin())
                .args([sub, "--help"])
                .env("ASSAY_CONFIG", &file)
                .output()
                .unwrap();
            assert_eq!(
                out.status.success(),
                ok,
                "{sub}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
}
