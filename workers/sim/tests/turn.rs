//! The oracle's `turn`: what the suction cup holds comes to the yaw the plan asks (modulo its
//! symmetry), with or without an arm; without the turn it lands as it was picked up.

use assay_spec::spec::{Arm, Format, Goal, Primitive, TaskSpec, parse_task};

fn task(turn: Option<Primitive>, arm: bool) -> TaskSpec {
    let mut spec = parse_task(
        assay_testkit::tasks::PUT_BLOCK_IN_ZONE,
        Format::Yaml,
        "turn.yaml",
    )
    .unwrap();
    spec.scene.objects[0].pose.as_mut().unwrap().yaw_deg = 10.0;
    spec.goals.push(Goal::PoseWithin {
        object: "red_block".into(),
        position: [0.5, -0.1, 0.0],
        tolerance: 0.02,
        yaw_deg: Some(70.0),
        yaw_tolerance_deg: Some(3.0),
        relative_to: None,
        planar: true,
        yaw_symmetry_deg: None,
    });
    if let Some(t) = turn {
        spec.oracle.insert(1, t);
    }
    if arm {
        spec.arm = Some(Arm {
            model: "ur5".into(),
            base: [0.0; 3],
            base_yaw_deg: 0.0,
        });
    }
    assert!(assay_spec::spec::validate(&spec, "turn.yaml").is_empty());
    spec
}

fn yaw_error(spec: &TaskSpec) -> (bool, String) {
    let ep = assay_sim::simulate(spec, 0, "oracle").unwrap();
    let p = ep
        .outcome
        .predicates
        .iter()
        .find(|p| p.label.starts_with("pose_within"))
        .unwrap();
    (ep.outcome.success, p.detail.clone())
}

#[test]
fn the_oracle_turns_what_it_holds_to_the_yaw_asked() {
    for arm in [false, true] {
        let (ok, detail) = yaw_error(&task(
            Some(Primitive::Turn {
                yaw_deg: 70.0,
                symmetry_deg: None,
            }),
            arm,
        ));
        assert!(ok, "arm {arm}: {detail}");
        // A block that looks the same every 90°: the shorter way, to 70° or -20° or 160°...
        let (ok, detail) = yaw_error(&task(
            Some(Primitive::Turn {
                yaw_deg: -20.0,
                symmetry_deg: Some(90.0),
            }),
            arm,
        ));
        assert!(
            !ok,
            "arm {arm}: 70° asked modulo nothing, -20° mod 90° given: {detail}"
        );
        let (ok, detail) = yaw_error(&task(None, arm));
        assert!(!ok, "arm {arm}: no turn, yet {detail}");
        assert!(detail.contains("yaw error 60"), "arm {arm}: {detail}");
    }
}

#[test]
fn a_turn_with_nothing_held_is_refused() {
    let mut spec = task(None, false);
    spec.oracle.insert(
        0,
        Primitive::Turn {
            yaw_deg: 0.0,
            symmetry_deg: None,
        },
    );
    let errors = assay_spec::spec::validate(&spec, "turn.yaml");
    assert!(
        errors
            .iter()
            .any(|e| e.path == "oracle[0].turn" && e.reason.contains("nothing is held")),
        "{errors:?}"
    );
}
