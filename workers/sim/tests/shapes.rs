//! Shapes and options the corpus does not use: meshes, the ground surface, a ranged tool start.

use assay_core::spec::{Format, parse_task};

#[test]
fn a_mesh_object_on_the_ground_rests_at_its_hull_height_and_can_be_placed() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("cube.obj");
    let mut text = String::new();
    for x in [-1.0, 1.0] {
        for y in [-1.0, 1.0] {
            for z in [-1.0, 1.0] {
                text.push_str(&format!("v {x} {y} {z}\n"));
            }
        }
    }
    std::fs::write(&obj, text).unwrap();
    let spec = format!(
        r#"
spec_version: 1
id: mesh-cube
name: place-mesh-cube
description: Move the mesh cube onto the target point.
group: placement
scene:
  surface: ground
  objects:
    - {{id: cube, shape: {{mesh: {{path: "{}", scale: 0.02}}}}, pose: {{position: [0.5, 0.1, 0.02]}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: cube, position: [0.5, -0.1, 0.02], tolerance: 0.01}}
variations:
  ee_start: {{min: [0.4, -0.1, 0.3], max: [0.6, 0.1, 0.4]}}
oracle:
  - pick: {{object: cube}}
  - place: {{target: {{at: [0.5, -0.1]}}}}
"#,
        obj.display()
    );
    let spec = parse_task(&spec, Format::Yaml, "mesh.yaml").unwrap();
    let ep = assay_sim::simulate(&spec, 1, "oracle").unwrap();
    assert!(
        ep.outcome.success,
        "{:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
    // Without the plan, the same goal does not hold: the predicate measures something.
    let mut idle = spec.clone();
    idle.oracle.clear();
    assert!(
        !assay_sim::simulate(&idle, 1, "oracle")
            .unwrap()
            .outcome
            .success
    );
}

#[test]
fn an_unreadable_mesh_is_a_spec_error_naming_the_field() {
    let spec = r#"
spec_version: 1
id: missing-mesh
name: missing-mesh
description: A mesh that is not there.
group: placement
scene:
  objects:
    - {id: thing, shape: {mesh: {path: /nonexistent/thing.obj}}, pose: {position: [0.5, 0.0, 0.05]}}
end_effector: {type: suction}
goals:
  - within_distance: {object: thing, point: [0.5, 0.0, 0.05], distance: 0.1}
"#;
    let spec = parse_task(spec, Format::Yaml, "m.yaml").unwrap();
    let err = assay_sim::simulate(&spec, 0, "oracle")
        .err()
        .expect("an error");
    assert!(!err.retryable());
    assert!(
        err.to_string()
            .starts_with("scene.objects[0].shape.mesh.path"),
        "{err}"
    );
}
