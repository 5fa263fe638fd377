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
    let g = &ep.goals_held;
    assert_eq!(g.len(), 3);
    // The zone held until the block was picked up again and carried off.
    let zone = g[0].last.expect("the zone held once");
    let (lost, carried) = g[0].lost.clone().expect("and then no longer");
    assert!(zone < lost, "{g:?}");
    assert_eq!(carried.as_deref(), Some("red_block"), "{g:?}");
    // The last spot held to the end; the other spot never did.
    assert!(g[1].last.unwrap() > lost, "{g:?}");
    assert_eq!(g[1].lost, None, "{g:?}");
    assert_eq!(g[2], assay_sim::GoalHeld::default(), "never met");
}
