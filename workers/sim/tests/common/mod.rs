//! Helpers shared by the sim's integration tests (each test file uses some of them).
#![allow(dead_code)]

/// Column `name` of an episode's Arrow file, as float32 values.
pub fn column(ep: &assay_sim::Episode, name: &str) -> Vec<f32> {
    let reader =
        arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(ep.file.clone()), None)
            .unwrap();
    let batch = reader.into_iter().next().unwrap().unwrap();
    batch
        .column_by_name(name)
        .unwrap_or_else(|| panic!("no column {name}"))
        .as_any()
        .downcast_ref::<arrow_array::Float32Array>()
        .unwrap()
        .values()
        .to_vec()
}

/// A red block to carry into a zone and leave turned by 45°, by suction; `arm` is appended.
pub fn turn_block_task(arm: &str) -> assay_spec::spec::TaskSpec {
    let yaml = format!(
        r#"
spec_version: 1
id: turn-block-into-zone
name: turn-block-into-zone
description: Put the red block on the green square, turned by 45 degrees.
group: placement
scene:
  objects:
    - {{id: red_block, shape: {{box: {{half_extents: [0.03, 0.02, 0.02]}}}}, color: red, pose: {{position: [0.5, 0.1, 0.02]}}}}
  zones:
    - {{id: goal, center: [0.5, -0.1], half_extents: [0.05, 0.05], color: green}}
end_effector: {{type: suction}}
physics: {{max_steps: 4800}}
goals:
  - pose_within: {{object: red_block, position: [0.5, -0.1, 0.02], tolerance: 0.02, yaw_deg: 45, yaw_tolerance_deg: 5, planar: true, yaw_symmetry_deg: 180}}
oracle:
  - pick: {{object: red_block}}
  - place: {{target: {{zone: goal}}}}
{arm}
"#
    );
    assay_spec::spec::parse_task(&yaml, assay_spec::spec::Format::Yaml, "t.yaml").unwrap()
}

/// Over the block, down, hold, up, turn 45° while carrying it over the zone, down, let go, up.
pub fn carry_and_turn() -> Vec<([f32; 3], f32, f32)> {
    let quarter = std::f32::consts::FRAC_PI_4;
    // The tool's centre when its face touches the block's top: 0.04 + 0.05.
    vec![
        ([0.5, 0.1, 0.2], 0.0, 0.0),
        ([0.5, 0.1, 0.09], 0.0, 0.0),
        ([0.5, 0.1, 0.09], 0.0, 1.0),
        ([0.5, 0.1, 0.2], 0.0, 1.0),
        ([0.5, -0.1, 0.2], quarter, 1.0),
        ([0.5, -0.1, 0.093], quarter, 1.0),
        ([0.5, -0.1, 0.093], quarter, 0.0),
        ([0.5, -0.1, 0.2], quarter, 0.0),
    ]
}
