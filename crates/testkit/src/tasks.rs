//! Task documents the tests of several crates share.

/// The smallest useful task: one red block picked and placed into a green zone by suction. Its
/// oracle needs about 1100 physics steps.
pub const PUT_BLOCK_IN_ZONE: &str = r#"
spec_version: 1
id: put-block-in-zone
name: put-block-in-zone
description: Put the red block in the green zone.
group: placement
scene:
  objects:
    - {id: red_block, shape: {box: {half_extents: [0.02, 0.02, 0.02]}}, color: red, pose: {position: [0.5, 0.1, 0.02]}}
  zones:
    - {id: goal, center: [0.5, -0.1], half_extents: [0.05, 0.05], color: green}
end_effector: {type: suction}
goals:
  - in_zone: {object: red_block, zone: goal}
oracle:
  - pick: {object: red_block}
  - place: {target: {zone: goal}}
"#;

/// [`PUT_BLOCK_IN_ZONE`] with its episodes cut off after `max_steps` physics steps.
pub fn put_block_in_zone_within(max_steps: u32) -> String {
    PUT_BLOCK_IN_ZONE.replace(
        "goals:\n",
        &format!("physics: {{max_steps: {max_steps}}}\ngoals:\n"),
    )
}
