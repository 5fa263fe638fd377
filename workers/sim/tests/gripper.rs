//! A parallel gripper that grasps by friction: two finger pads close on the object and only
//! their contact holds it.

mod common;

use common::column;

use assay_spec::spec::{Format, TaskSpec, parse_task};

fn lift(grasp: &str, object: &str) -> TaskSpec {
    let text = format!(
        r#"
spec_version: 1
id: lift-it
name: lift-it
description: Pick up the object and hold it above the table.
group: robomimic
scene:
  objects:
    - {{id: thing, {object}, color: red, pose: {{position: [0.5, 0.05, 0.025], yaw_deg: 30}}}}
end_effector: {{type: parallel_gripper, max_opening: 0.08, grasp: {grasp}}}
goals:
  - lifted: {{object: thing, height: 0.1}}
oracle:
  - pick: {{object: thing}}
"#
    );
    parse_task(&text, Format::Yaml, "lift.yaml").unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn finger_pads_turn_to_the_object_close_on_it_and_lift_it_by_friction() {
    let spec = lift(
        "friction",
        "shape: {box: {half_extents: [0.025, 0.02, 0.025]}}",
    );
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    assert!(
        ep.outcome.success,
        "{:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
    // The pads closed on the cube's narrower side (4 cm), turned to its yaw (30°: that side
    // across the pads), and stopped against it: driven towards 3 cm, they press it with their
    // motors' force and sink a little into it, no further.
    let opening = column(&ep, "gripper_opening");
    let yaw = column(&ep, "gripper_yaw");
    let last = opening.len() - 1;
    assert!((opening[0] - 0.08).abs() < 1e-3, "{}", opening[0]);
    assert!((0.031..0.04).contains(&opening[last]), "{}", opening[last]);
    assert!(
        (yaw[last] - 30f32.to_radians()).abs() < 0.02,
        "{}",
        yaw[last]
    );
    // Drawn as two pads with the tool.
    let (_, snap) = ep.keyframes.last().unwrap();
    assert_eq!(snap.fingers.len(), 2);
    let welded = assay_sim::simulate(
        &lift(
            "attach",
            "shape: {box: {half_extents: [0.025, 0.02, 0.025]}}",
        ),
        0,
        "oracle",
    )
    .unwrap();
    assert!(welded.outcome.success);
}

/// Only friction holds it: a 5 kg cube weighs 49 N, more than the pads' two motors (10 N each)
/// press with times the pads' friction, so it slips out; a welded grasp lifts it.
#[test]
fn a_cube_heavier_than_the_grip_can_hold_slips_out_of_the_pads() {
    let heavy = "shape: {box: {half_extents: [0.025, 0.02, 0.025]}}, mass: 5.0";
    let ep = assay_sim::simulate(&lift("friction", heavy), 0, "oracle").unwrap();
    assert!(!ep.outcome.success, "{:?}", ep.outcome.predicates);
    let ep = assay_sim::simulate(&lift("attach", heavy), 0, "oracle").unwrap();
    assert!(ep.outcome.success, "{:?}", ep.outcome.predicates);
    // And a 0.5 kg one (4.9 N) stays in them.
    let ep = assay_sim::simulate(
        &lift(
            "friction",
            "shape: {box: {half_extents: [0.025, 0.02, 0.025]}}, mass: 0.5",
        ),
        0,
        "oracle",
    )
    .unwrap();
    assert!(ep.outcome.success, "{:?}", ep.outcome.predicates);
}

#[test]
fn an_object_wider_than_the_pads_open_is_not_grasped() {
    let spec = lift(
        "friction",
        "shape: {box: {half_extents: [0.05, 0.05, 0.025]}}",
    );
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    assert!(!ep.outcome.success);
    assert!(
        ep.notes.iter().any(|n| n.contains("grasp of 'thing' failed")
            && n.contains("the gripper opens 0.080")),
        "{:?}",
        ep.notes
    );
}
