//! Shapes and options the corpus does not use: meshes, the ground surface, a ranged tool start.

use assay_spec::spec::{Format, parse_task};

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
    // Its six faces (vertex k is 1 + 4·[x > 0] + 2·[y > 0] + [z > 0]).
    for f in [
        "1 2 4 3", "5 7 8 6", "1 5 6 2", "3 4 8 7", "1 3 7 5", "2 6 8 4",
    ] {
        text.push_str(&format!("f {f}\n"));
    }
    std::fs::write(&obj, text).unwrap();
    let spec = format!(
        r#"
spec_version: 1
id: mesh-cube
name: place-mesh-cube
description: Move the mesh cube onto the target point.
source: {{asset_root: "{}"}}
group: placement
scene:
  surface: ground
  objects:
    - {{id: cube, shape: {{mesh: {{path: cube.obj, scale: 0.02}}}}, pose: {{position: [0.5, 0.1, 0.02]}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: cube, position: [0.5, -0.1, 0.02], tolerance: 0.01}}
variations:
  ee_start: {{min: [0.4, -0.1, 0.3], max: [0.6, 0.1, 0.4]}}
oracle:
  - pick: {{object: cube}}
  - place: {{target: {{at: [0.5, -0.1]}}}}
"#,
        dir.path().display()
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
    - {id: thing, shape: {mesh: {path: nonexistent/thing.obj}}, pose: {position: [0.5, 0.0, 0.05]}}
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

/// The asset root of the example cabinet (`cabinet/cabinet.urdf` under it).
fn assets() -> String {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/assets")
        .canonicalize()
        .unwrap()
        .display()
        .to_string()
}

#[test]
fn a_urdf_cabinet_is_a_solid_support_at_its_height() {
    let spec = format!(
        r#"
spec_version: 1
id: block-on-cabinet
name: put-block-on-cabinet
description: Put the red block on top of the cabinet.
source: {{asset_root: "{}"}}
group: placement
scene:
  objects:
    - {{id: cabinet, fixed: true, shape: {{urdf: {{path: cabinet/cabinet.urdf, joints: {{drawer_slide: 0.0}}}}}}, pose: {{position: [0.62, 0.0, 0.1]}}}}
    - {{id: block, shape: {{box: {{half_extents: [0.02, 0.02, 0.02]}}}}, color: red, pose: {{position: [0.4, 0.15, 0.02]}}}}
end_effector: {{type: suction}}
goals:
  - on_top_of: {{object: block, support: cabinet}}
oracle:
  - pick: {{object: block}}
  - place: {{target: {{on: cabinet}}}}
"#,
        assets()
    );
    let spec = parse_task(&spec, Format::Yaml, "cabinet.yaml").unwrap();
    let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
    assert!(
        ep.outcome.success,
        "{:?} {:?}",
        ep.outcome.predicates, ep.notes
    );
    // The block rests on the cabinet's top panel (0.20 m), not inside it or on the table.
    let block = &ep.keyframes.last().unwrap().1.objects[1];
    assert!(
        (block.position[2] - 0.22).abs() < 0.004,
        "block at {:?}",
        block.position
    );
    // The snapshot names the URDF by a path a renderer anywhere on the node can open.
    let assay_spec::spec::Shape::Urdf { path, .. } = &ep.keyframes[0].1.objects[0].shape else {
        panic!("the cabinet is drawn from its URDF");
    };
    assert!(std::path::Path::new(path).is_absolute(), "{path}");
}

#[test]
fn a_bad_urdf_is_a_spec_error_naming_the_field_and_the_joint() {
    let spec = |joints: &str| {
        format!(
            r#"
spec_version: 1
id: bad-cabinet
name: bad-cabinet
description: A cabinet posed beyond its limits.
source: {{asset_root: "{}"}}
group: placement
scene:
  objects:
    - {{id: cabinet, fixed: true, shape: {{urdf: {{path: cabinet/cabinet.urdf, joints: {joints}}}}}, pose: {{position: [0.62, 0.0, 0.1]}}}}
end_effector: {{type: suction}}
goals:
  - within_distance: {{object: cabinet, point: [0.62, 0.0, 0.1], distance: 0.1}}
"#,
            assets()
        )
    };
    let run = |joints: &str| {
        let spec = parse_task(&spec(joints), Format::Yaml, "c.yaml").unwrap();
        assay_sim::simulate(&spec, 0, "oracle")
            .err()
            .expect("an error")
            .to_string()
    };
    let beyond = run("{drawer_slide: 0.5}");
    assert!(
        beyond.starts_with("scene.objects[0].shape.urdf") && beyond.contains("drawer_slide"),
        "{beyond}"
    );
    let unknown = run("{no_such_joint: 0.1}");
    assert!(unknown.contains("no_such_joint"), "{unknown}");
}

#[test]
fn a_recoloured_distractor_changes_what_is_drawn_and_nothing_the_physics_does() {
    let task = |variations: &str| {
        let text = format!(
            r#"
spec_version: 1
id: recolour
name: put-red-block-in-zone
description: Put the red block in the zone.
group: placement
scene:
  objects:
    - {{id: red_block, shape: {{box: {{half_extents: [0.02, 0.02, 0.02]}}}}, color: red, pose: {{position: [0.45, 0.1, 0.02]}}}}
    - {{id: distractor, shape: {{box: {{half_extents: [0.02, 0.02, 0.02]}}}}, color: blue, pose: {{position: [0.6, 0.15, 0.02]}}}}
  zones:
    - {{id: goal, center: [0.5, -0.1], half_extents: [0.05, 0.05]}}
end_effector: {{type: suction}}
goals:
  - in_zone: {{object: red_block, zone: goal}}
variations: {{position_jitter: 0.01{variations}}}
oracle:
  - pick: {{object: red_block}}
  - place: {{target: {{zone: goal}}}}
"#
        );
        parse_task(&text, Format::Yaml, "recolour.yaml").unwrap()
    };
    let plain = task("");
    let varied = task(", colors: [orange, purple, cyan, pink], recolor: [distractor]");
    let mut drawn = std::collections::BTreeSet::new();
    for seed in 0..6 {
        let (a, b) = (
            assay_sim::simulate(&plain, seed, "oracle").unwrap(),
            assay_sim::simulate(&varied, seed, "oracle").unwrap(),
        );
        assert!(b.outcome.success);
        // The same physics, step for step, and the hash of the task as submitted.
        assert_eq!(a.outcome.steps, b.outcome.steps);
        assert_eq!(b.outcome.spec_hash, varied.spec_hash());
        let (pa, pb) = (&a.initial.objects, &b.initial.objects);
        for (x, y) in pa.iter().zip(pb) {
            assert_eq!((x.position, x.rotation), (y.position, y.rotation));
        }
        // The block the description names keeps its colour; the distractor takes this seed's.
        assert_eq!(pa[0].color, pb[0].color);
        let expected = varied.for_seed(seed).scene.objects[1]
            .color
            .as_ref()
            .and_then(|c| c.rgb())
            .unwrap();
        assert_eq!(pb[1].color, expected.map(|x| x as f32));
        assert!(
            b.keyframes
                .iter()
                .all(|(_, s)| s.objects[1].color == pb[1].color)
        );
        assert_ne!(pb[1].color, pa[1].color);
        drawn.insert(format!("{:?}", pb[1].color));
    }
    assert!(drawn.len() >= 2, "six seeds drew one colour: {drawn:?}");
}

/// A mesh with a hollow (a box open at the top, written as five solid slabs): decomposed into
/// convex parts it keeps its hollow and a cube dropped over it falls inside; as its convex hull
/// the hollow is filled and the cube rests on top.
#[test]
fn a_decomposed_mesh_keeps_its_hollow_and_its_hull_does_not() {
    let dir = tempfile::tempdir().unwrap();
    // Slabs (min, max) of an open box 10 × 10 × 6 cm, walls and floor 1 cm thick; a mesh is
    // placed by its own origin, here the middle of its bottom.
    let slabs: [([f32; 3], [f32; 3]); 5] = [
        ([-0.05, -0.05, 0.0], [0.05, 0.05, 0.01]),
        ([-0.05, -0.05, 0.0], [-0.04, 0.05, 0.06]),
        ([0.04, -0.05, 0.0], [0.05, 0.05, 0.06]),
        ([-0.04, -0.05, 0.0], [0.04, -0.04, 0.06]),
        ([-0.04, 0.04, 0.0], [0.04, 0.05, 0.06]),
    ];
    let mut text = String::new();
    for (k, (lo, hi)) in slabs.iter().enumerate() {
        for c in 0..8 {
            let p = |a: usize| if c & (1 << a) == 0 { lo[a] } else { hi[a] };
            text.push_str(&format!("v {} {} {}\n", p(0), p(1), p(2)));
        }
        let b = 8 * k + 1;
        for [i, j, l] in [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ] {
            text.push_str(&format!("f {} {} {}\n", b + i, b + j, b + l));
        }
    }
    std::fs::write(dir.path().join("tray.obj"), text).unwrap();
    let rest = |collision: &str| {
        let spec = format!(
            r#"
spec_version: 1
id: cube-in-tray
name: cube-in-tray
description: A cube falls onto a tray.
source: {{asset_root: "{}"}}
group: placement
scene:
  objects:
    - {{id: tray, fixed: true, shape: {{mesh: {{path: tray.obj, collision: {collision}}}}}, pose: {{position: [0.5, 0.0, 0.0]}}}}
    - {{id: cube, shape: {{box: {{half_extents: [0.015, 0.015, 0.015]}}}}, pose: {{position: [0.5, 0.0, 0.12]}}}}
end_effector: {{type: suction}}
goals:
  - within_distance: {{object: cube, point: [0.5, 0.0, 0.025], distance: 0.01}}
"#,
            dir.path().display()
        );
        let spec = parse_task(&spec, Format::Yaml, "tray.yaml").unwrap_or_else(|e| panic!("{e}"));
        let ep = assay_sim::simulate(&spec, 0, "oracle").unwrap();
        (
            ep.outcome.success,
            ep.keyframes.last().unwrap().1.objects[1].position[2],
        )
    };
    let (inside, z) = rest("decomposition");
    assert!(inside, "decomposed: the cube rests at z {z}");
    let (inside, z) = rest("hull");
    assert!(!inside && z > 0.07, "hull: the cube rests at z {z}");
}

/// GenSim's layouts put blocks side by side with no gap (4 cm blocks 4 cm apart, turned as the
/// pallet under them). A `spot` place keeps a hair's gap from what stands beside its spot, so
/// that the block it lowers does not catch its neighbour's edge and shove it off its own spot.
#[test]
fn a_spot_place_beside_a_block_leaves_the_block_where_it_stands() {
    let yaw: f64 = -143.0;
    let (s, c) = yaw.to_radians().sin_cos();
    // The neighbour's spot: 4 cm from the first along the blocks' own y axis.
    let (dx, dy) = (-0.04 * s, 0.04 * c);
    for seed in 0..4 {
        let spec = format!(
            r#"
spec_version: 1
id: side-by-side
name: side-by-side
description: Put the blue block beside the red one, touching it.
group: placement
scene:
  objects:
    - {{id: red, shape: {{box: {{half_extents: [0.02, 0.02, 0.02]}}}}, color: red, pose: {{position: [0.5, 0.1, 0.02], yaw_deg: {yaw}}}}}
    - {{id: blue, shape: {{box: {{half_extents: [0.02, 0.02, 0.02]}}}}, color: blue, pose: {{position: [0.45, -0.2, 0.02], yaw_deg: {yaw}}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: red, position: [0.5, 0.1, 0.0], tolerance: 0.003, planar: true}}
  - pose_within: {{object: blue, position: [{x}, {y}, 0.0], tolerance: 0.01, planar: true}}
oracle:
  - pick: {{object: blue}}
  - place: {{target: {{spot: {{xy: [{x}, {y}]}}}}}}
"#,
            x = 0.5 + dx,
            y = 0.1 + dy,
        );
        let spec = parse_task(&spec, Format::Yaml, "side-by-side.yaml").unwrap();
        let ep = assay_sim::simulate(&spec, seed, "oracle").unwrap();
        assert!(
            ep.outcome.success,
            "seed {seed}: {:?}",
            ep.outcome
                .predicates
                .iter()
                .filter(|p| !p.holds)
                .map(|p| &p.detail)
                .collect::<Vec<_>>()
        );
    }
}

/// A mesh on a many-sided face rests on it. parry builds a face-to-face contact from the first
/// four corners of each face only, so a 64-sided disc touched the table along a short stretch
/// of its rim and rocked for ever (GenSim's round kit pieces did, 2-6°); the sim lines such
/// faces with plates whose four corners span them.
#[test]
fn a_mesh_on_a_many_sided_face_rests_without_rocking() {
    let dir = tempfile::tempdir().unwrap();
    let sides: u32 = 64;
    let mut text = String::new();
    for z in [0.0, 1.0] {
        for k in 0..sides {
            let a = std::f64::consts::TAU * f64::from(k) / f64::from(sides);
            text.push_str(&format!("v {} {} {z}\n", 3.0 * a.cos(), 3.0 * a.sin()));
        }
    }
    let ring = |base: u32| {
        (1..=sides)
            .map(|k| (base + k).to_string())
            .collect::<Vec<_>>()
    };
    text.push_str(&format!("f {}\n", ring(0).join(" ")));
    text.push_str(&format!("f {}\n", ring(sides).join(" ")));
    std::fs::write(dir.path().join("disc.obj"), text).unwrap();
    let spec = format!(
        r#"
spec_version: 1
id: mesh-disc
name: disc-at-rest
description: A disc lies on the table.
source: {{asset_root: "{}"}}
group: placement
scene:
  objects:
    - {{id: disc, shape: {{mesh: {{path: disc.obj, scale: 0.01, collision: hull}}}}, pose: {{position: [0.5, 0.1, 0.005]}}}}
end_effector: {{type: suction}}
goals:
  - pose_within: {{object: disc, position: [0.5, 0.1, 0.005], tolerance: 0.01}}
oracle: []
"#,
        dir.path().display()
    );
    let spec = parse_task(&spec, Format::Yaml, "disc.yaml").unwrap();
    let mut scene = assay_sim::scene::build_scene(&spec, 0).unwrap();
    let (mut tilt, mut spin) = (0.0f32, 0.0f32);
    for step in 0..1200 {
        scene.world.step();
        let o = &scene.objects[0];
        if step >= 600 {
            let up = scene.pose(o).rotation * rapier3d::prelude::Vec3::Z;
            tilt = tilt.max(up.z.clamp(-1.0, 1.0).acos().to_degrees());
            spin = spin.max(scene.world.bodies[o.body].angvel().length());
        }
    }
    assert!(
        tilt < 0.2 && spin < 0.01,
        "tilt {tilt:.2}°, spin {spin:.3} rad/s"
    );
}
