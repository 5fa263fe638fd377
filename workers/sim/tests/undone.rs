//! An episode says, per goal, when it last held with nothing in the tool: a goal met and then
//! undone by the plan (the oracle check's "a goal met earlier came undone") is told apart from
//! one never met.

use assay_spec::spec::{Format, Goal, PlaceTarget, Primitive, parse_task};

#[test]
fn a_goal_met_and_then_undone_is_told_from_one_never_met() {
    let mut spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "undone.yaml",
    )
    .unwrap();
    let at = |xy: [f64; 2]| Goal::PoseWithin {
        object: "red_block".into(),
        position: [xy[0], xy[1], 0.0],
        tolerance: 0.02,
        yaw_deg: None,
        yaw_tolerance_deg: None,
        relative_to: None,
        planar: true,
        yaw_symmetry_deg: None,
    };
    // The block goes to the zone, then on to (0.4, 0.2): the zone held, then no longer; the
    // last spot holds; (0.6, 0.3) never does.
    spec.goals.push(at([0.4, 0.2]));
    spec.goals.push(at([0.6, 0.3]));
    spec.oracle.extend([
        Primitive::Pick {
            object: "red_block".into(),
        },
        Primitive::Place {
            target: PlaceTarget::Spot {
                xy: [0.4, 0.2],
                relative_to: None,
            },
        },
    ]);
    assert!(assay_spec::spec::validate(&spec, "undone.yaml").is_empty());
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    let holds: Vec<bool> = ep.outcome.predicates.iter().map(|p| p.holds).collect();
    assert_eq!(holds, [false, true, false], "{:?}", ep.outcome.predicates);
    let last = &ep.goals_last_held;
    assert_eq!(last.len(), 3);
    let (zone, spot) = (last[0].expect("the zone held once"), last[1].unwrap());
    assert!(zone < spot, "{last:?}");
    assert_eq!(last[2], None, "never met");
}
