//! Rolling friction as PyBullet applies it to GenSim's URDFs (`<rolling_friction value="0.0001"/>`
//! on every ball, block and container of its library), on the library's own ball, read where it
//! lies in `../shared/corpora/gensim-library`.

use assay_spec::spec::{Format, parse_task};
use rapier3d::prelude::Vec3;

/// GenSim's asset root.
fn gensim_assets() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/corpora/gensim-library/assets")
        .canonicalize()
        .expect("the GenSim corpus lies in ../shared/corpora")
}

/// A scene of one 3 cm ball from `root/path` on the table, nothing else moving.
fn ball_scene(root: &std::path::Path, path: &str) -> assay_sim::scene::SimScene {
    let spec = format!(
        r#"
spec_version: 1
id: rolling-ball
name: rolling-ball
description: A ball rolls on the table.
source: {{asset_root: "{}"}}
group: placement
scene:
  objects:
    - {{id: ball, shape: {{urdf: {{path: {path}, fill: {{DIM0: "0.03"}}}}}}, pose: {{position: [0.5, -0.2, 0.03]}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: ball, position: [0.5, -0.2, 0.03], tolerance: 0.01}}
oracle: []
"#,
        root.display()
    );
    let spec = parse_task(&spec, Format::Yaml, "ball.yaml").unwrap();
    assay_sim::scene::build_scene(&spec, 0).unwrap()
}

/// Sets the ball rolling along x at `speed` (without slipping), then steps for `seconds`;
/// returns how far it went and its speed at the end.
fn roll(scene: &mut assay_sim::scene::SimScene, speed: f32, seconds: f32) -> (f32, f32) {
    let ball = scene.object("ball").unwrap().clone();
    for _ in 0..120 {
        scene.step();
    }
    let start = scene.world.bodies[ball.body].translation();
    let r = ball.half.z;
    let body = &mut scene.world.bodies[ball.body];
    body.set_linvel(Vec3::new(speed, 0.0, 0.0), true);
    body.set_angvel(Vec3::new(0.0, speed / r, 0.0), true);
    let steps = (seconds * 240.0) as usize;
    for _ in 0..steps {
        scene.step();
    }
    let body = &scene.world.bodies[ball.body];
    let moved = body.translation() - start;
    (moved.x, body.linvel().length())
}

/// A GenSim ball set rolling at 2 cm/s stops where Bullet's rolling friction stops it. Bullet
/// resists rolling with a torque of at most `μ_r · N`, `μ_r = r_ball · f_table + r_table ·
/// f_ball`; with the table's rolling friction 0 that is 0.0001 · 0.8 m here. Rolling about the
/// contact point (inertia 7/5 m r²), the ball slows at `μ_r g / (1.4 r)` = 18.7 mm/s² and comes
/// to rest after `v² / 2a` = 10.7 mm. The same ball with the rolling friction taken out of its
/// URDF is still rolling after 3 s.
#[test]
fn a_gensim_ball_rolls_to_a_stop_as_bullets_rolling_friction_stops_it() {
    let root = gensim_assets();
    let (speed, r) = (0.02f32, 0.03f32);
    let decel = 0.0001 * assay_sim::tabletop::OBJECT_FRICTION * 9.81 / (1.4 * r);
    let expected = speed * speed / (2.0 * decel);

    let mut scene = ball_scene(&root, "ball/ball-template.urdf");
    assert_eq!(scene.object("ball").unwrap().rolling_friction, 0.0001);
    let (moved, left) = roll(&mut scene, speed, 3.0);
    println!(
        "rolled {:.1} mm (Bullet's formula: {:.1} mm)",
        moved * 1e3,
        expected * 1e3
    );
    assert!(left < 1e-3, "still rolling at {left} m/s after 3 s");
    assert!(
        (moved - expected).abs() < 0.3 * expected,
        "rolled {:.1} mm, Bullet's rolling friction stops it after {:.1} mm",
        moved * 1e3,
        expected * 1e3
    );

    // The same URDF without its <contact> block: nothing resists the rolling.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root.join("ball/ball-template.urdf")).unwrap();
    let start = text.find("<contact>").unwrap();
    let end = text.find("</contact>").unwrap() + "</contact>".len();
    std::fs::write(
        dir.path().join("ball.urdf"),
        format!("{}{}", &text[..start], &text[end..]),
    )
    .unwrap();
    let mut scene = ball_scene(dir.path(), "ball.urdf");
    assert_eq!(scene.object("ball").unwrap().rolling_friction, 0.0);
    let (moved, left) = roll(&mut scene, speed, 3.0);
    assert!(
        left > 0.5 * speed && moved > 3.0 * expected,
        "without rolling friction the ball rolled {:.1} mm and slowed to {left} m/s",
        moved * 1e3
    );
}

/// A URDF's rolling friction is read, and a bad one is refused naming the link and the field.
#[test]
fn a_urdf_rolling_friction_is_read_and_a_bad_one_refused() {
    let urdf = |value: &str| {
        format!(
            r#"<robot name="r"><link name="base"><contact><rolling_friction value="{value}"/></contact>
            <collision><geometry><sphere radius="0.02"/></geometry></collision></link></robot>"#
        )
    };
    let ok = assay_spec::urdf::parse(&urdf("0.002")).unwrap();
    assert_eq!(ok.links[0].rolling_friction, 0.002);
    let none = assay_spec::urdf::parse(
        &urdf("0").replace("<contact><rolling_friction value=\"0\"/></contact>", ""),
    )
    .unwrap();
    assert_eq!(none.links[0].rolling_friction, 0.0);
    for bad in ["-1", "slippery", "inf"] {
        let err = assay_spec::urdf::parse(&urdf(bad)).unwrap_err();
        assert!(
            err.contains("'base'") && err.contains("rolling_friction"),
            "{bad}: {err}"
        );
    }
}
