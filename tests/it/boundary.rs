//! One trust boundary, set by the operator: a task spec cannot make Assay read asset files from
//! outside the folders the command line allows, neither at validation (the coordinator's
//! planner, `assay validate`) nor at a worker, whose `--asset-root` folders (its working folder
//! when it is given none) bound every asset file it opens; nor can a batch's policy names make a
//! worker load a model from elsewhere.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use crate::common::*;
use assay_proto::v1 as pb;

const URDF: &str = r#"<robot name="thing"><link name="base"><visual><geometry><box size="0.05 0.05 0.05"/></geometry></visual></link></robot>"#;

fn spec(id: &str, source: &str) -> String {
    format!(
        r#"spec_version: 1
id: {id}
name: {id}
description: Move the thing onto the target point.
source: {source}
group: boundary
scene:
  objects:
    - {{id: thing, shape: {{urdf: {{path: thing.urdf}}}}, pose: {{position: [0.5, 0.1, 0.05]}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: thing, position: [0.5, -0.1, 0.05], tolerance: 0.01}}
oracle:
  - pick: {{object: thing}}
  - place: {{target: {{at: [0.5, -0.1]}}}}
"#
    )
}

/// `project/tasks/` holds three specs that each point their asset root at `outside/` (absolute,
/// by their own origin, and by climbing), where a URDF waits; a fourth reads its URDF beside
/// itself.
fn layout(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let project = dir.join("project");
    let tasks = project.join("tasks");
    let outside = dir.join("outside");
    std::fs::create_dir_all(&tasks).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(outside.join("thing.urdf"), URDF).unwrap();
    std::fs::write(tasks.join("thing.urdf"), URDF).unwrap();
    let o = outside.display();
    for (id, source) in [
        ("by-asset-root", format!("{{asset_root: \"{o}\"}}")),
        ("by-origin", format!("{{origin: \"{o}/x.yaml\"}}")),
        ("by-climbing", "{asset_root: ../../outside}".to_owned()),
        ("inside", "{}".to_owned()),
    ] {
        std::fs::write(tasks.join(format!("{id}.yaml")), spec(id, &source)).unwrap();
    }
    (project, outside)
}

#[test]
fn a_spec_cannot_widen_the_operators_asset_roots() {
    let dir = tempfile::tempdir().unwrap();
    let (project, outside) = layout(dir.path());
    let validate = |extra: &[&str]| {
        Command::new(bin())
            .args(["validate", "tasks"])
            .args(extra)
            .current_dir(&project)
            .output()
            .unwrap()
    };
    let o = validate(&[]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{stderr}");
    for (id, field) in [
        ("by-asset-root", "source.asset_root"),
        ("by-origin", "source.origin"),
        ("by-climbing", "source.asset_root"),
    ] {
        let line = stderr
            .lines()
            .find(|l| l.contains(&format!("task {id}:")))
            .unwrap_or_else(|| panic!("{id} not refused:\n{stderr}"));
        assert!(
            line.contains(field) && line.contains("outside the folders the operator allowed"),
            "{line}"
        );
    }
    assert!(!stderr.contains("task inside:"), "{stderr}");
    assert!(stderr.contains("1 valid, 3 invalid"), "{stderr}");
    // The operator may allow the folder; then the same specs are valid.
    let o = validate(&["--asset-root", outside.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A client that sends no roots (an older one, or a hostile one) gets past the planner; a worker
/// started with `--asset-root` still opens nothing outside it: the episodes of the tasks whose
/// asset root lies outside fail, naming the task, the field and why, and the rest of the batch
/// runs. The URDF outside is a valid one: had the worker opened it, those episodes would have
/// run.
#[test]
fn a_worker_with_asset_roots_opens_nothing_outside_them() {
    let dir = tempfile::tempdir().unwrap();
    let (project, _outside) = layout(dir.path());
    let tasks = project.join("tasks");
    let worker = ["--asset-root", tasks.to_str().unwrap()];
    escapes_fail_and_the_rest_runs(dir.path(), &tasks, &worker, dir.path(), &[]);
}

/// The same with the roots in `ASSAY_ASSET_ROOTS` (colon-separated), as a manifest sets them.
#[test]
fn a_worker_takes_its_asset_roots_from_the_environment() {
    let dir = tempfile::tempdir().unwrap();
    let (project, _outside) = layout(dir.path());
    let tasks = project.join("tasks");
    let elsewhere = dir.path().join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let roots = format!("{}:{}", elsewhere.display(), tasks.display());
    let env = [("ASSAY_ASSET_ROOTS", roots.as_str())];
    escapes_fail_and_the_rest_runs(dir.path(), &tasks, &[], dir.path(), &env);
}

/// Closed by default: a worker given no roots opens asset files below its working folder only,
/// never below the root a task names.
#[test]
fn a_worker_without_asset_roots_opens_below_its_working_folder_only() {
    let dir = tempfile::tempdir().unwrap();
    let (project, _outside) = layout(dir.path());
    let tasks = project.join("tasks");
    escapes_fail_and_the_rest_runs(dir.path(), &tasks, &[], &tasks, &[]);
}

/// Submits the four tasks of [`layout`] to a coordinator and one sim worker started with
/// `worker_args` in `cwd` with `env`, and checks the report: the three whose asset root lies
/// outside `tasks/` fail, the one inside runs.
fn escapes_fail_and_the_rest_runs(
    dir: &Path,
    tasks: &Path,
    worker_args: &[&str],
    cwd: &Path,
    env: &[(&str, &str)],
) {
    let (_coordinator, addr) = coordinator(dir, "127.0.0.1:0", &[]);
    let mut args = vec!["worker", "--coordinator", &addr, "--roles", "sim"];
    args.extend_from_slice(worker_args);
    let _worker = Proc::spawn_in("worker", &args, dir, cwd, env);
    let rt = runtime();
    let doc = |id: &str| {
        let f = tasks.join(format!("{id}.yaml"));
        pb::TaskDocument {
            origin: f.display().to_string(),
            format: String::new(),
            content: std::fs::read_to_string(&f).unwrap(),
        }
    };
    let report = rt.block_on(async {
        let mut c = client(&addr).await;
        let r = c
            .submit_batch(pb::SubmitBatchRequest {
                name: "boundary".into(),
                tasks: vec![
                    doc("by-asset-root"),
                    doc("by-origin"),
                    doc("by-climbing"),
                    doc("inside"),
                ],
                policies: vec![pb::PolicyRef {
                    name: "oracle".into(),
                }],
                seeds: vec![0],
                max_attempts: 1,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        assert!(r.rejected.is_empty(), "{:?}", r.rejected);
        wait_for(&addr, &r.batch_id, Duration::from_secs(120), finished).await;
        report(&addr, &r.batch_id).await
    });
    let task = |id: &str| {
        report
            .results
            .tasks
            .iter()
            .find(|t| t.id == id)
            .unwrap_or_else(|| panic!("{id}"))
    };
    for (id, field) in [
        ("by-asset-root", "source.asset_root"),
        ("by-origin", "source.origin"),
        ("by-climbing", "source.asset_root"),
    ] {
        let escaped = task(id);
        assert!(escaped.episodes.is_empty(), "{id}: {:?}", escaped.episodes);
        let error = &escaped.failures[0].error;
        assert!(
            error.contains(&format!("task {id}: {field}: "))
                && error.contains("outside the folders the operator allowed"),
            "{id}: {error}"
        );
    }
    assert_eq!(task("inside").episodes.len(), 1, "a task inside runs");
}

/// A batch's policy names cannot widen the roots either: a worker started with `--asset-root`
/// loads a TorchScript module below them (or its artifact store) only. An absolute path to a
/// module outside and a `..` climb to it fail that policy's episodes, naming the policy, the
/// argument and why, while the module inside acts. The module outside is the same valid module:
/// had the worker opened it, its episodes would have run.
#[cfg(feature = "trainer")]
#[test]
fn a_worker_loads_no_policy_model_outside_its_roots() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().canonicalize().unwrap();
    let (tasks, outside) = (root.join("project/tasks"), root.join("outside"));
    std::fs::create_dir_all(&tasks).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    let inside = crate::common::torchscript::torchscript(&tasks);
    let escaped = crate::common::torchscript::torchscript(&outside);
    let task = tasks.join("task.yaml");
    std::fs::write(&task, assay_testkit::tasks::put_block_in_zone_within(240)).unwrap();
    let (_coordinator, addr) = coordinator(&root, "127.0.0.1:0", &[]);
    let _worker = Proc::spawn_in(
        "worker",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim,render",
            "--asset-root",
            tasks.to_str().unwrap(),
        ],
        &root,
        &root,
        &[],
    );
    let by_path = format!("torchscript:path={}", escaped.display());
    let by_climbing = "torchscript:path=project/tasks/../../outside/controller.pt".to_owned();
    let allowed = format!("torchscript:path={}", inside.display());
    let report = runtime().block_on(async {
        let mut c = client(&addr).await;
        let r = c
            .submit_batch(pb::SubmitBatchRequest {
                name: "policy-boundary".into(),
                tasks: vec![pb::TaskDocument {
                    origin: task.display().to_string(),
                    format: String::new(),
                    content: std::fs::read_to_string(&task).unwrap(),
                }],
                policies: [&by_path, &by_climbing, &allowed]
                    .into_iter()
                    .map(|p| pb::PolicyRef { name: p.clone() })
                    .collect(),
                seeds: vec![0],
                max_attempts: 1,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        assert!(r.rejected.is_empty(), "{:?}", r.rejected);
        wait_for(&addr, &r.batch_id, Duration::from_secs(120), finished).await;
        report(&addr, &r.batch_id).await
    });
    let t = &report.results.tasks[0];
    for policy in [&by_path, &by_climbing] {
        assert!(
            t.episodes.iter().all(|e| &e.policy != policy),
            "{policy} ran"
        );
        let failure = t
            .failures
            .iter()
            .find(|f| &f.policy == policy)
            .unwrap_or_else(|| panic!("{policy}: no failure in {:#?}", t.failures));
        assert!(
            failure.error.contains(&format!("policy '{policy}'"))
                && failure.error.contains("path=")
                && failure
                    .error
                    .contains("outside the folders the operator allowed"),
            "{policy}: {}",
            failure.error
        );
    }
    assert_eq!(
        t.episodes.iter().filter(|e| e.policy == allowed).count(),
        1,
        "the module inside acts: {:#?}",
        t.failures
    );
}

/// A coordinator that anyone on the network can reach without a token says so at start.
#[test]
fn a_coordinator_beyond_loopback_without_a_token_warns() {
    let dir = tempfile::tempdir().unwrap();
    let (mut open, _) = coordinator(dir.path(), "0.0.0.0:0", &[]);
    let log = open.log_text();
    open.kill9();
    assert!(
        log.contains("beyond loopback, without a cluster token"),
        "{log}"
    );
    let quiet = tempfile::tempdir().unwrap();
    let (mut local, _) = coordinator(quiet.path(), "127.0.0.1:0", &[]);
    let log = local.log_text();
    local.kill9();
    assert!(!log.contains("without a cluster token"), "{log}");
}
