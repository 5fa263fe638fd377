//! A UR5 from URDF carrying the tool, driven by inverse kinematics.

mod common;

use common::column;

use std::path::Path;

use assay_spec::spec::{Arm, Format, TaskSpec, parse_task};

fn read(rel: &str) -> TaskSpec {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/tasks")
        .join(rel);
    let text = std::fs::read_to_string(&p).unwrap();
    parse_task(&text, Format::Yaml, &p.display().to_string()).unwrap()
}

fn with_ur5(mut spec: TaskSpec) -> TaskSpec {
    spec.arm = Some(Arm {
        model: "ur5".into(),
        base: [0.0; 3],
        base_yaw_deg: 0.0,
    });
    spec
}

/// One task of each group, carried by the arm: the oracle still succeeds, and the tool is where
/// it was commanded (the arm reaches the whole workspace) with the arm's joints recorded and its
/// links drawn.
#[test]
fn the_arm_carries_the_tool_through_a_task_of_every_group() {
    for rel in [
        "stacking/build-two-block-tower.yaml",
        "placement/put-block-in-bowl.yaml",
        "assembling/insert-block-into-fixture.yaml",
        "piles/push-block-pile-into-zone.yaml",
        "clutter/pick-red-block-out-of-clutter.yaml",
        "articulated/open-drawer.yaml",
        "robomimic/pick-place-can.yaml",
    ] {
        let spec = with_ur5(read(rel));
        for seed in 0..3 {
            let ep = assay_sim::simulate(&spec, seed, "oracle").unwrap();
            assert!(
                ep.outcome.success,
                "{rel} seed {seed}: {:?} {:?}",
                ep.outcome.predicates, ep.notes
            );
            let worst = ["x", "y", "z"]
                .iter()
                .map(|a| {
                    let (ee, cmd) = (
                        column(&ep, &format!("ee_{a}")),
                        column(&ep, &format!("ee_cmd_{a}")),
                    );
                    ee.iter()
                        .zip(&cmd)
                        .map(|(e, c)| (e - c).abs())
                        .fold(0.0f32, f32::max)
                })
                .fold(0.0f32, f32::max);
            assert!(
                worst < 0.002,
                "{rel}: the tool strayed {worst} m from its command"
            );
            assert_eq!(
                column(&ep, "arm.shoulder_pan_joint").len(),
                column(&ep, "ee_x").len()
            );
            assert_eq!(
                ep.keyframes[0].1.arm.len(),
                7,
                "{rel}: the arm's 7 link boxes are drawn"
            );
        }
    }
}

/// The arm bounds where the tool can go: a block at the table's far corner, 1.3 m from the
/// UR5's base, is out of its 0.85 m reach; the free-floating tool picks it.
#[test]
fn a_block_out_of_the_arms_reach_is_not_picked() {
    let text = r#"
spec_version: 1
id: far-block
name: far-block
description: Put the far red block in the zone.
group: placement
scene:
  objects:
    - {id: block, shape: {box: {half_extents: [0.02, 0.02, 0.02]}}, color: red, pose: {position: [1.05, 0.75, 0.02]}}
  zones:
    - {id: goal, center: [0.5, 0.0], half_extents: [0.05, 0.05]}
end_effector: {type: suction}
goals:
  - in_zone: {object: block, zone: goal}
oracle:
  - pick: {object: block}
  - place: {target: {zone: goal}}
"#;
    let free = parse_task(text, Format::Yaml, "far.yaml").unwrap();
    assert!(
        assay_sim::simulate(&free, 0, "oracle")
            .unwrap()
            .outcome
            .success
    );
    let ep = assay_sim::simulate(&with_ur5(free), 0, "oracle").unwrap();
    assert!(!ep.outcome.success);
    assert!(
        ep.notes
            .iter()
            .any(|n| n.contains("grasp of 'block' failed")),
        "{:?}",
        ep.notes
    );
}

#[test]
fn an_unknown_arm_is_a_spec_error_naming_the_field() {
    let spec = with_ur5(read("placement/put-block-in-bowl.yaml"));
    let mut text = serde_json::to_value(&spec).unwrap();
    text["arm"]["model"] = "kuka".into();
    let errors = parse_task(&text.to_string(), Format::Json, "t.json").unwrap_err();
    assert!(
        errors
            .0
            .iter()
            .any(|e| e.path == "arm.model" && e.reason.contains("ur5")),
        "{errors}"
    );
}
