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
        "Deployment/assay-worker-render",
        "Deployment/assay-worker-judge",
        "Deployment/assay-worker-trainer",
        "HorizontalPodAutoscaler/assay-worker-sim",
        "HorizontalPodAutoscaler/assay-worker-render",
        "ConfigMap/assay-config",
        "Secret/assay-cluster-token",
        "Secret/assay-worker-key",
        "Secret/assay-submitter-key",
        "Secret/assay-viewer-key",
        "Secret/assay-judge-keys",
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
        (
            toml.replace("heartbeat-ms", "heartbeat-msec")
                .replace("\ncoordinator = \"http", "\ncoordinatr = \"http"),
            false,
        ),
    ] {
        std::fs::write(&file, &text).unwrap();
        // Each role reads its own section when it starts: a bad key stops it at once, naming
        // the file; a good file lets it run (stopped after a moment).
        let store = dir.path().join("jobs.db");
        let artifacts = dir.path().join("artifacts");
        let coordinator: Vec<&str> = vec![
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--metrics-listen",
            "off",
            "--telemetry",
            "off",
            "--store",
            store.to_str().unwrap(),
            "--artifacts",
            artifacts.to_str().unwrap(),
        ];
        let worker: Vec<&str> = vec!["worker", "--coordinator", "http://127.0.0.1:9"];
        for args in [coordinator, worker] {
            let mut child = Command::new(bin())
                .args(&args)
                .env("ASSAY_CONFIG", &file)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap();
            let deadline = std::time::Instant::now() + std::time::Duration::from_secs(3);
            let exited = loop {
                if let Some(st) = child.try_wait().unwrap() {
                    break Some(st);
                }
                if std::time::Instant::now() > deadline {
                    break None;
                }
                std::thread::sleep(std::time::Duration::from_millis(50));
            };
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            match (ok, exited) {
                (true, None) => {}
                (false, Some(st)) => {
                    assert!(!st.success());
                    let key = match args[0] {
                        "coordinator" => "heartbeat-msec",
                        _ => "coordinatr",
                    };
                    assert!(
                        stderr.contains(&format!("has no option '{key}'")),
                        "{}: {stderr}",
                        args[0]
                    );
                }
                other => panic!("{}: {other:?}: {stderr}", args[0]),
            }
        }
    }
}
