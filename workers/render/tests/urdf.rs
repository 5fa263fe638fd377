//! URDF objects drawn from their visual elements: the cabinet fixture with its drawer shut and
//! pulled out, seen by the top-down camera through depth and segmentation.

use std::collections::BTreeMap;

use assay_model::policy::observation_camera;
use assay_render::{Outputs, Renderer};
use assay_spec::scene::{FIRST_OBJECT_SEGMENT, Observation, SceneSnapshot, SnapshotObject};
use assay_spec::spec::{Camera, Shape, Surface};

fn cabinet(drawer: f64) -> (SceneSnapshot, [f64; 3]) {
    cabinet_coloured(drawer, false)
}

/// The cabinet in magenta, given by its task (`color_given`) or not.
fn cabinet_coloured(drawer: f64, color_given: bool) -> (SceneSnapshot, [f64; 3]) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/assets/cabinet/cabinet.urdf")
        .canonicalize()
        .unwrap();
    let joints = BTreeMap::from([("drawer_slide".to_owned(), drawer)]);
    let half = assay_spec::urdf::assemble(&path, &joints).unwrap().half;
    let scene = SceneSnapshot {
        surface: Surface::Table,
        objects: vec![SnapshotObject {
            id: "cabinet".into(),
            shape: Shape::Urdf {
                path: path.display().to_string(),
                joints,
                articulated: false,
                fill: Default::default(),
            },
            color: [1.0, 0.0, 1.0],
            color_given,
            position: [0.5, 0.0, half[2] as f32],
            rotation: [0.0, 0.0, 0.0, 1.0],
            joints: Default::default(),
        }],
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    };
    (scene, half)
}

/// World points of the cabinet's pixels, and their colours, from `camera`.
fn seen(r: &mut Renderer, scene: &SceneSnapshot, camera: &Camera) -> Vec<([f64; 3], [u8; 3])> {
    let f = r.render_with(scene, camera, Outputs::ALL).unwrap();
    let obs = Observation {
        camera: camera.clone(),
        depth: f.depth,
        segments: f.segments,
    };
    let mut out = Vec::new();
    for y in 0..camera.height {
        for x in 0..camera.width {
            let i = (y * camera.width + x) as usize;
            if obs.segments[i] == FIRST_OBJECT_SEGMENT {
                let c = &f.rgba[i * 4..i * 4 + 3];
                out.push((obs.point(x, y).unwrap(), [c[0], c[1], c[2]]));
            }
        }
    }
    out
}

#[test]
fn the_cabinet_is_drawn_from_its_urdf_and_its_drawer_shows_where_the_joint_puts_it() {
    let mut r = Renderer::new().expect("an adapter");
    let camera = Camera {
        width: 640,
        height: 480,
        ..observation_camera()
    };
    let (shut, shut_half) = cabinet(0.0);
    let (open, open_half) = cabinet(0.12);
    let a = seen(&mut r, &shut, &camera);
    let b = seen(&mut r, &open, &camera);
    assert!(
        a.len() > 5000 && b.len() > a.len(),
        "{} {}",
        a.len(),
        b.len()
    );
    let span = |pts: &[([f64; 3], [u8; 3])], k: usize| {
        let lo = pts.iter().map(|p| p.0[k]).fold(f64::MAX, f64::min);
        let hi = pts.iter().map(|p| p.0[k]).fold(f64::MIN, f64::max);
        (lo, hi)
    };
    // The top panel is 0.20 m above the table, whatever the drawer does.
    for pts in [&a, &b] {
        let top = span(pts, 2).1;
        assert!((top - 0.20).abs() < 0.003, "top at {top}");
    }
    // Seen from above, the cabinet reaches 0.12 m further forward with the drawer out, and its
    // seen length matches the bounding box the sim collides with (a pixel is about 1.9 mm).
    let (sa, sb) = (span(&a, 0), span(&b, 0));
    let grown = (sb.1 - sb.0) - (sa.1 - sa.0);
    assert!(
        (grown - 0.12).abs() < 0.006,
        "grew {grown}: {sa:?} → {sb:?}"
    );
    for ((lo, hi), half) in [(sa, shut_half), (sb, open_half)] {
        assert!(
            ((hi - lo) - 2.0 * half[0]).abs() < 0.006,
            "{lo}..{hi} vs ±{}",
            half[0]
        );
    }
    // The URDF's own colours (grey panels) are drawn, not the spec's magenta.
    let magenta = a.iter().filter(|p| p.1[1] < 30 && p.1[0] > 150).count();
    assert_eq!(magenta, 0);
    let grey = a
        .iter()
        .filter(|p| p.1[0].abs_diff(p.1[1]) < 12 && p.1[1].abs_diff(p.1[2]) < 12)
        .count();
    assert!(grey * 2 > a.len(), "{grey} of {} grey", a.len());
}

#[test]
fn a_colour_the_task_gives_is_drawn_over_the_base_link_only_as_pybullet_does() {
    let mut r = Renderer::new().expect("an adapter");
    let camera = Camera {
        width: 640,
        height: 480,
        ..observation_camera()
    };
    let magenta = |c: &[u8; 3]| c[0] > 120 && c[2] > 120 && c[1] < 40;
    let (shut, _) = cabinet_coloured(0.0, true);
    let (open, _) = cabinet_coloured(0.12, true);
    let a = seen(&mut r, &shut, &camera);
    let b = seen(&mut r, &open, &camera);
    // The body (the root link, the top panel at 0.20 m among its parts) in the task's colour.
    let top: Vec<_> = a.iter().filter(|p| (p.0[2] - 0.20).abs() < 0.003).collect();
    assert!(top.len() > 1000, "{} top pixels", top.len());
    let on_top = top.iter().filter(|p| magenta(&p.1)).count();
    assert!(
        on_top * 10 > top.len() * 9,
        "{on_top} of {} top pixels magenta",
        top.len()
    );
    // The drawer, a child link, keeps its wood: the pixels past the shut cabinet's front.
    let front = a.iter().map(|p| p.0[0]).fold(f64::MIN, f64::max);
    let drawer: Vec<_> = b.iter().filter(|p| p.0[0] > front + 0.01).collect();
    assert!(drawer.len() > 200, "{} drawer pixels", drawer.len());
    assert!(
        drawer.iter().all(|p| !magenta(&p.1)),
        "the drawer took the base link's colour"
    );
}
