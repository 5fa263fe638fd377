//! Articulated URDF objects: joints that move within their limits against their friction, joint
//! goals, and the oracle's `actuate`.

mod common;

use common::column;

use assay_spec::spec::{Format, TaskSpec, parse_task};

fn assets() -> String {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/assets")
        .canonicalize()
        .unwrap()
        .display()
        .to_string()
}

/// A laptop with its lid at `q`, a joint goal, and an optional oracle step.
fn laptop(root: &str, file: &str, q: f64, goal: &str, oracle: &str) -> TaskSpec {
    let text = format!(
        r#"
spec_version: 1
id: laptop-lid
name: laptop-lid
description: Do something with the laptop's lid.
source: {{asset_root: "{root}"}}
group: articulated
scene:
  objects:
    - {{id: laptop, fixed: true, shape: {{urdf: {{path: {file}, articulated: true, joints: {{hinge: {q}}}}}}}, pose: {{position: [0.55, 0.0, 0.016]}}}}
end_effector: {{type: suction}}
goals:
  - {goal}
oracle: [{oracle}]
"#
    );
    parse_task(&text, Format::Yaml, "laptop.yaml").unwrap_or_else(|e| panic!("{e}"))
}

fn final_hinge(spec: &TaskSpec, seed: u64) -> (f64, assay_sim::Episode) {
    let ep = assay_sim::simulate(spec, seed, "oracle").unwrap();
    let snap = &ep.keyframes.last().unwrap().1;
    let q = snap.objects[0].joints["hinge"];
    (q, ep)
}

#[test]
fn the_oracle_opens_and_closes_a_lid_through_its_joint() {
    let root = assets();
    let open = laptop(
        &root,
        "articulated/laptop.urdf",
        0.0,
        "joint_position: {object: laptop, joint: hinge, min: 1.2}",
        "{actuate: {object: laptop, joint: hinge, to: 1.6}}",
    );
    let (q, ep) = final_hinge(&open, 3);
    assert!(
        ep.outcome.success,
        "{q} {:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
    assert!((1.2..=1.9 + 1e-3).contains(&q), "hinge at {q}");
    // The keyframes follow the lid: closed at the start, open at the end.
    let first = ep.keyframes[0].1.objects[0].joints["hinge"];
    assert!(first.abs() < 0.05, "hinge starts at {first}");

    let close = laptop(
        &root,
        "articulated/laptop.urdf",
        1.5,
        "joint_position: {object: laptop, joint: hinge, max: 0.2}",
        "{actuate: {object: laptop, joint: hinge, to: 0.0}}",
    );
    let (q, ep) = final_hinge(&close, 4);
    assert!(
        ep.outcome.success,
        "{q} {:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
    // Without the plan the same goals do not hold: the predicate measures the joint.
    for spec in [open, close] {
        let mut idle = spec.clone();
        idle.oracle.clear();
        let (q, ep) = final_hinge(&idle, 3);
        assert!(!ep.outcome.success, "idle lid at {q}");
    }
}

#[test]
fn friction_holds_a_lid_where_it_is_left_and_without_it_gravity_shuts_it() {
    let root = assets();
    let goal = "joint_position: {object: laptop, joint: hinge, min: 0.9}";
    let held = laptop(&root, "articulated/laptop.urdf", 1.0, goal, "");
    let (q, ep) = final_hinge(&held, 0);
    assert!(ep.outcome.success, "lid with friction at {q}");
    assert!((q - 1.0).abs() < 0.02, "lid with friction moved to {q}");

    // The same laptop with a frictionless hinge.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(format!("{root}/articulated/laptop.urdf")).unwrap();
    let loose = text.replace(r#"<dynamics friction="0.3" damping="0.05"/>"#, "");
    assert_ne!(loose, text);
    std::fs::write(dir.path().join("laptop.urdf"), loose).unwrap();
    let spec = laptop(
        &dir.path().display().to_string(),
        "laptop.urdf",
        1.0,
        goal,
        "",
    );
    let (q, ep) = final_hinge(&spec, 0);
    assert!(!ep.outcome.success);
    // It falls shut and stops at its lower limit, not through the base.
    assert!(q.abs() < 0.05, "frictionless lid at {q}");
}

#[test]
fn a_joint_is_driven_no_further_than_its_limit() {
    let spec = laptop(
        &assets(),
        "articulated/laptop.urdf",
        0.0,
        "joint_position: {object: laptop, joint: hinge, min: 1.8}",
        "{actuate: {object: laptop, joint: hinge, to: 3.0}}",
    );
    let (q, ep) = final_hinge(&spec, 1);
    assert!(q <= 1.9 + 0.02, "hinge at {q}, beyond its upper limit 1.9");
    assert!(ep.outcome.success, "{q} {:?}", ep.notes);
}

#[test]
fn a_joint_the_urdf_does_not_have_is_a_spec_error_naming_the_field() {
    let spec = laptop(
        &assets(),
        "articulated/laptop.urdf",
        0.0,
        "joint_position: {object: laptop, joint: lid_hinge, min: 1.0}",
        "",
    );
    let err = assay_sim::simulate(&spec, 0, "oracle")
        .err()
        .expect("an error");
    assert!(!err.retryable());
    let text = err.to_string();
    assert!(
        text.starts_with("goals[0].joint_position.joint") && text.contains("hinge"),
        "{text}"
    );
}

#[test]
fn joint_positions_are_columns_of_the_episode_file() {
    let spec = laptop(
        &assets(),
        "articulated/laptop.urdf",
        0.0,
        "joint_position: {object: laptop, joint: hinge, min: 1.2}",
        "{actuate: {object: laptop, joint: hinge, to: 1.6}}",
    );
    let ep = assay_sim::simulate(&spec, 2, "oracle").unwrap();
    let col = column(&ep, "laptop.joint.hinge");
    let last = col[col.len() - 1];
    assert!(last > 1.2, "last recorded hinge {last}");
}
