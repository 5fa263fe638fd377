//! Where an episode ends without measuring success: the step limit (an outcome with its reason)
//! and physics that blew up (an error of the shard, not a policy's failure).

use assay_spec::spec::{Format, parse_task};

#[test]
fn a_plan_cut_off_at_the_step_limit_says_so() {
    let text = assay_testkit::tasks::put_block_in_zone_within(60);
    let spec = parse_task(&text, Format::Yaml, "t.yaml").unwrap();
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    assert!(!ep.outcome.success);
    let why = ep.outcome.cutoff.as_deref().expect("a reason");
    assert!(
        why.contains("step limit") && why.contains("max_steps = 60"),
        "{why}"
    );
    // With room to finish, no cutoff.
    let spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "t.yaml",
    )
    .unwrap();
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    assert!(ep.outcome.success && ep.outcome.cutoff.is_none());
}

#[test]
fn a_non_finite_physics_state_is_seen() {
    let spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "t.yaml",
    )
    .unwrap();
    let mut scene = assay_sim::scene::build_scene(&spec, 0).unwrap();
    assert_eq!(assay_sim::blown_up(&scene), None);
    let body = scene.objects[0].body;
    let mut at = scene.world.bodies[body].translation();
    at.x = f32::NAN;
    scene.world.bodies[body].set_translation(at, true);
    assert_eq!(assay_sim::blown_up(&scene), Some("red_block"));
    // Far is not broken: an object off the table falls as far as the episode lasts.
    at.x = 0.5;
    at.z = -5e3;
    scene.world.bodies[body].set_translation(at, true);
    assert_eq!(assay_sim::blown_up(&scene), None);
}
