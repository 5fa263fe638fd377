//! Captions of the scene views on the machine's adapter (Mesa's software Vulkan in CI): what a
//! real task's initial scene shows, hidden objects, colours named back from pixels, and the
//! offline judge's scene alignment on top of them.

mod common;

use assay_model::caption::{CaptionObject, SceneCaption, offline_alignment};
use assay_render::caption::{caption_frames, caption_scene};
use assay_render::{Outputs, Renderer};
use assay_spec::scene::{SceneSnapshot, SnapshotObject, scene_views};
use assay_spec::spec::{COLORS, Camera, Shape, Surface};
use common::task;

fn object(id: &str, shape: Shape, color: [f64; 3], position: [f32; 3]) -> SnapshotObject {
    SnapshotObject {
        color_given: true,
        id: id.into(),
        shape,
        color: color.map(|c| c as f32),
        position,
        rotation: [0.0, 0.0, 0.0, 1.0],
        joints: Default::default(),
    }
}

fn palette(name: &str) -> [f64; 3] {
    COLORS
        .iter()
        .find(|(n, _)| *n == name)
        .expect("a palette colour")
        .1
}

/// The world-axis extent of a snapshot object's shape, rotated as it is (boxes and containers).
fn expected_size(o: &SnapshotObject) -> [f64; 3] {
    let half = match &o.shape {
        Shape::Box { half_extents } => *half_extents,
        Shape::Container {
            inner_half_extents: [x, y, z],
            wall,
        } => [x + wall, y + wall, z + wall / 2.0],
        other => panic!("no expected size for {other:?}"),
    };
    let [qx, qy, qz, qw] = o.rotation.map(f64::from);
    let r = [
        [
            1.0 - 2.0 * (qy * qy + qz * qz),
            2.0 * (qx * qy - qz * qw),
            2.0 * (qx * qz + qy * qw),
        ],
        [
            2.0 * (qx * qy + qz * qw),
            1.0 - 2.0 * (qx * qx + qz * qz),
            2.0 * (qy * qz - qx * qw),
        ],
        [
            2.0 * (qx * qz - qy * qw),
            2.0 * (qy * qz + qx * qw),
            1.0 - 2.0 * (qx * qx + qy * qy),
        ],
    ];
    std::array::from_fn(|k| 2.0 * (0..3).map(|j| r[k][j].abs() * half[j]).sum::<f64>())
}

fn by_segment(c: &SceneCaption, segment: u32) -> &CaptionObject {
    c.objects
        .iter()
        .find(|o| o.segment == segment)
        .expect("every scene object is in the caption")
}

#[test]
fn a_real_task_is_captioned_as_it_renders_and_aligns_with_its_description() {
    let spec = task("assembling/bbsea-put-red-cube-into-box-and-close-lid.yaml");
    let episode = assay_sim::simulate(&spec, 0, "oracle").expect("the episode runs");
    let mut r = Renderer::new().expect("an adapter");
    let caption = caption_scene(&mut r, &episode.initial, 320, 240).unwrap();
    let text = caption.to_text();
    eprintln!("{text}");
    assert_eq!(caption.views.len(), 4);
    assert_eq!(caption.surface, "table");
    let cube = by_segment(&caption, 3);
    let container = by_segment(&caption, 4);
    let lid = by_segment(&caption, 5);
    assert_eq!((cube.colour.as_str(), cube.form.as_str()), ("red", "cube"));
    assert_eq!(
        (container.colour.as_str(), container.form.as_str()),
        ("white", "container")
    );
    assert_eq!((lid.colour.as_str(), lid.form.as_str()), ("brown", "box"));
    for (o, s) in caption.objects.iter().zip(&episode.initial.objects) {
        assert!(o.views_seen >= 3, "{} seen in {} views", s.id, o.views_seen);
        assert!(!o.off_surface && !o.floating, "{}: {o:?}", s.id);
        let want = expected_size(s);
        for k in 0..3 {
            assert!(
                (o.size_m[k] - want[k]).abs() < 0.01,
                "{} size {:?}, expected {want:?}",
                s.id,
                o.size_m
            );
            assert!(
                (o.centre[k] - f64::from(s.position[k])).abs() < 0.01,
                "{} centre {:?} at {:?}",
                s.id,
                o.centre,
                s.position
            );
        }
    }
    assert!(text.contains("a red cube about 4 × 4 × 4 cm"), "{text}");
    assert!(
        text.contains("a white container about 8 × 8 × 6 cm"),
        "{text}"
    );
    assert!(text.contains("a brown flat box"), "{text}");
    assert!(
        !text.contains("lid") && !text.contains("red_cube"),
        "{text}"
    );

    let aligned = offline_alignment(&spec.description, &caption);
    eprintln!("{}: {}", aligned.score, aligned.rationale);
    assert!(aligned.score >= 4.0, "{}", aligned.rationale);
    let wrong = offline_alignment("put the green ball into the yellow bowl", &caption);
    eprintln!("{}: {}", wrong.score, wrong.rationale);
    assert!(wrong.score <= 2.5, "{}", wrong.rationale);
}

#[test]
fn hidden_objects_are_not_captioned_as_visible() {
    let scene = SceneSnapshot {
        surface: Surface::Table,
        objects: vec![
            object(
                "big_box",
                Shape::Box {
                    half_extents: [0.06, 0.06, 0.06],
                },
                palette("red"),
                [0.5, 0.0, 0.06],
            ),
            // Entirely inside the big box.
            object(
                "blue_cube",
                Shape::Box {
                    half_extents: [0.02, 0.02, 0.02],
                },
                palette("blue"),
                [0.5, 0.0, 0.05],
            ),
            // Far outside every view.
            object(
                "green_ball",
                Shape::Sphere { radius: 0.03 },
                palette("green"),
                [5.0, 5.0, 0.03],
            ),
            object(
                "can",
                Shape::Cylinder {
                    radius: 0.025,
                    half_height: 0.04,
                },
                palette("yellow"),
                [0.4, 0.2, 0.04],
            ),
        ],
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    };
    let mut r = Renderer::new().expect("an adapter");
    let caption = caption_scene(&mut r, &scene, 320, 240).unwrap();
    let text = caption.to_text();
    eprintln!("{text}");
    let seen: Vec<u32> = caption.objects.iter().map(|o| o.views_seen).collect();
    assert_eq!(seen[1], 0, "the cube inside the box: {seen:?}");
    assert_eq!(seen[2], 0, "the ball far away: {seen:?}");
    assert!(seen[0] == 4 && seen[3] >= 3, "{seen:?}");
    assert_eq!(by_segment(&caption, 4).colour, "unknown");
    assert!(
        text.contains("2 more objects of the scene are not visible in any view"),
        "{text}"
    );
    assert!(!text.contains("blue") && !text.contains("green"), "{text}");
    let s = offline_alignment("put the blue cube next to the green ball", &caption);
    assert!(s.score <= 2.0, "{}", s.rationale);
    let s = offline_alignment("put the yellow can on the red block", &caption);
    assert!(s.score >= 4.0, "{}", s.rationale);
}

#[test]
fn every_palette_colour_is_named_back_from_the_top_view() {
    let mut r = Renderer::new().expect("an adapter");
    let top = Camera {
        width: 320,
        height: 240,
        ..scene_views().remove(0)
    };
    for (name, rgb) in COLORS {
        let scene = SceneSnapshot {
            surface: Surface::Table,
            objects: vec![object(
                name,
                Shape::Box {
                    half_extents: [0.03, 0.03, 0.03],
                },
                *rgb,
                [0.5, 0.1, 0.03],
            )],
            tool: None,
            tool_rotation: None,
            fingers: Vec::new(),
            arm: Vec::new(),
        };
        let frame = r.render_with(&scene, &top, Outputs::ALL).unwrap();
        let caption = caption_frames(&scene, &[(top.name.clone(), top.clone(), frame)]);
        let o = &caption.objects[0];
        assert_eq!(o.colour, *name, "{name} measured as {:?}", o.rgb);
        assert_eq!(o.views_seen, 1);
    }
}

#[test]
fn stacks_containers_and_floating_objects_are_measured() {
    let scene = SceneSnapshot {
        surface: Surface::Table,
        objects: vec![
            object(
                "red",
                Shape::Box {
                    half_extents: [0.025, 0.025, 0.025],
                },
                palette("red"),
                [0.45, -0.1, 0.025],
            ),
            object(
                "green",
                Shape::Box {
                    half_extents: [0.02, 0.02, 0.02],
                },
                palette("green"),
                [0.45, -0.1, 0.07],
            ),
            object(
                "bowl",
                Shape::Container {
                    inner_half_extents: [0.05, 0.05, 0.03],
                    wall: 0.01,
                },
                palette("white"),
                [0.6, 0.15, 0.035],
            ),
            object(
                "ball",
                Shape::Sphere { radius: 0.02 },
                palette("orange"),
                [0.6, 0.15, 0.03],
            ),
            object(
                "floating",
                Shape::Cylinder {
                    radius: 0.02,
                    half_height: 0.03,
                },
                palette("purple"),
                [0.35, 0.2, 0.2],
            ),
        ],
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    };
    let mut r = Renderer::new().expect("an adapter");
    let caption = caption_scene(&mut r, &scene, 320, 240).unwrap();
    let text = caption.to_text();
    eprintln!("{text}");
    let rel: Vec<(u32, &str, u32)> = caption
        .relations
        .iter()
        .map(|r| (r.subject, r.relation.as_str(), r.object))
        .collect();
    assert!(rel.contains(&(4, "on", 3)), "{rel:?}");
    assert!(rel.contains(&(6, "in", 5)), "{rel:?}");
    let floating: Vec<bool> = caption.objects.iter().map(|o| o.floating).collect();
    assert_eq!(floating, [false, false, false, false, true], "{text}");
    assert!(text.contains("the green cube is on the red cube"), "{text}");
    assert!(
        text.contains("the orange sphere is in the white container"),
        "{text}"
    );
    assert!(text.contains("a purple cylinder"), "{text}");
    assert!(text.contains("floating"), "{text}");
}
