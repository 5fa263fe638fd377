//! Rendering on the machine's adapter (Mesa's software Vulkan in CI): a golden image, segment ids
//! against the objects, and depth against the known geometry.

use assay_render::image::{Rgb, compare};
use assay_render::math::{look_at, mul, perspective, project};
use assay_render::{Renderer, ZFAR, ZNEAR};
use assay_spec::scene::{
    FIRST_OBJECT_SEGMENT, SEGMENT_SURFACE, SEGMENT_TOOL, SceneSnapshot, SnapshotObject,
};
use assay_spec::spec::{Camera, Shape, Surface};

fn object(
    id: &str,
    shape: Shape,
    color: [f32; 3],
    position: [f32; 3],
    yaw_deg: f32,
) -> SnapshotObject {
    let h = (yaw_deg.to_radians() / 2.0).sin_cos();
    SnapshotObject {
        color_given: true,
        id: id.into(),
        shape,
        color,
        position,
        rotation: [0.0, 0.0, h.0, h.1],
        joints: Default::default(),
    }
}

fn scene() -> SceneSnapshot {
    SceneSnapshot {
        surface: Surface::Table,
        objects: vec![
            object(
                "red_box",
                Shape::Box {
                    half_extents: [0.03, 0.03, 0.03],
                },
                [0.84, 0.15, 0.16],
                [0.5, 0.12, 0.03],
                20.0,
            ),
            object(
                "green_ball",
                Shape::Sphere { radius: 0.03 },
                [0.17, 0.63, 0.17],
                [0.42, -0.12, 0.03],
                0.0,
            ),
            object(
                "blue_can",
                Shape::Cylinder {
                    radius: 0.025,
                    half_height: 0.04,
                },
                [0.12, 0.47, 0.71],
                [0.62, -0.02, 0.04],
                0.0,
            ),
            object(
                "bin",
                Shape::Container {
                    inner_half_extents: [0.05, 0.05, 0.02],
                    wall: 0.01,
                },
                [0.5, 0.5, 0.5],
                [0.36, 0.16, 0.025],
                0.0,
            ),
        ],
        tool: Some([0.55, 0.0, 0.3]),
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    }
}

fn camera(name: &str, eye: [f64; 3], target: [f64; 3], w: u32, h: u32) -> Camera {
    Camera {
        name: name.into(),
        eye,
        target,
        fovy_deg: 50.0,
        width: w,
        height: h,
        up: None,
    }
}

fn golden_path(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

/// Pixel (column, row) where a world point lands.
fn pixel(cam: &Camera, p: [f32; 3]) -> (u32, u32) {
    let vp = mul(
        &perspective(
            (cam.fovy_deg as f32).to_radians(),
            cam.width as f32 / cam.height as f32,
            ZNEAR,
            ZFAR,
        ),
        &look_at(
            cam.eye.map(|x| x as f32),
            cam.target.map(|x| x as f32),
            cam.up.map(|u| u.map(|x| x as f32)),
        ),
    );
    let n = project(&vp, p);
    (
        ((n[0] + 1.0) / 2.0 * cam.width as f32) as u32,
        ((1.0 - n[1]) / 2.0 * cam.height as f32) as u32,
    )
}

#[test]
fn a_fixed_scene_matches_the_golden_image() {
    let mut r =
        Renderer::new().expect("a graphics adapter (CI uses Mesa's lavapipe: mesa-vulkan-drivers)");
    let cam = camera("front", [1.0, 0.0, 0.6], [0.5, 0.0, 0.05], 320, 240);
    let frame = r.render(&scene(), &cam).unwrap();
    let actual = Rgb::from_frame(&frame);
    let path = golden_path("front-320x240.png");
    if std::env::var_os("ASSAY_UPDATE_GOLDEN").is_some() {
        std::fs::write(&path, actual.png()).unwrap();
    }
    let golden = Rgb::from_png(&std::fs::read(&path).unwrap()).unwrap();
    let (mean, share) = compare(&actual, &golden, 24).unwrap();
    if mean > 1.0 || share > 0.005 {
        let out = std::env::temp_dir().join("assay-render-front-actual.png");
        std::fs::write(&out, actual.png()).unwrap();
        panic!(
            "rendered image differs from {}: mean |diff| {mean:.3}/255, {:.2} % of pixels off by > 24 (adapter {}); actual in {}",
            path.display(),
            share * 100.0,
            r.adapter(),
            out.display()
        );
    }
}

#[test]
fn segment_ids_match_the_objects_and_depth_matches_the_geometry() {
    let mut r = Renderer::new().expect("a graphics adapter");
    let cam = camera("top", [0.5, 0.0, 1.25], [0.5, 0.0, 0.0], 400, 300);
    let s = scene();
    let f = r.render(&s, &cam).unwrap();
    let at = |p: [f32; 3]| {
        let (x, y) = pixel(&cam, p);
        let i = (y * f.width + x) as usize;
        (f.segments[i], f.depth[i])
    };
    // Tops of the box and the can, the ball's top, the table: id and distance from a camera at
    // height 1.25 looking straight down.
    let cases = [
        ([0.5, 0.12, 0.06], FIRST_OBJECT_SEGMENT, 1.25 - 0.06),
        ([0.42, -0.12, 0.06], FIRST_OBJECT_SEGMENT + 1, 1.25 - 0.06),
        ([0.62, -0.02, 0.08], FIRST_OBJECT_SEGMENT + 2, 1.25 - 0.08),
        ([0.8, -0.3, 0.0], SEGMENT_SURFACE, 1.25),
        // Inside the bin: its floor (top of a 1 cm plate).
        ([0.36, 0.16, 0.01], FIRST_OBJECT_SEGMENT + 3, 1.25 - 0.01),
        ([0.55, 0.0, 0.35], SEGMENT_TOOL, 1.25 - 0.35),
    ];
    for (p, id, dist) in cases {
        let (seg, depth) = at(p);
        assert_eq!(seg, id, "segment at {p:?}");
        assert!(
            (depth - dist).abs() < 0.003,
            "depth at {p:?}: {depth} m, expected {dist} m"
        );
    }
    // Every object is visible, and nothing is background from above the table.
    for id in 0..s.objects.len() as u32 {
        assert!(
            f.segments
                .iter()
                .filter(|&&x| x == FIRST_OBJECT_SEGMENT + id)
                .count()
                > 50,
            "object {id} hardly visible"
        );
    }
    assert!(f.depth.iter().all(|d| d.is_finite()));
}

#[test]
fn any_size_and_the_end_effector_camera_render() {
    let mut r = Renderer::new().expect("a graphics adapter");
    let s = scene();
    let ee = Camera {
        fovy_deg: 70.0,
        ..camera(assay_spec::scene::EE_CAMERA, [0.0; 3], [0.0; 3], 97, 61)
    };
    let f = r.render(&s, &ee).unwrap();
    assert_eq!((f.width, f.height, f.rgba.len()), (97, 61, 97 * 61 * 4));
    // Straight down from the tool: the table (or an object) fills the centre.
    let centre = f.segments[(30 * 97 + 48) as usize];
    assert!(
        centre == SEGMENT_SURFACE || centre >= FIRST_OBJECT_SEGMENT,
        "{centre}"
    );
    let big = r
        .render(
            &s,
            &camera("front", [1.0, 0.0, 0.6], [0.5, 0.0, 0.05], 1280, 720),
        )
        .unwrap();
    assert_eq!(big.segments.len(), 1280 * 720);
}

#[test]
fn rendering_into_a_caller_buffer_gives_the_same_pixels() {
    let mut r = Renderer::new().expect("a graphics adapter");
    let cam = camera("front", [1.0, 0.0, 0.6], [0.5, 0.0, 0.05], 160, 120);
    let frame = r.render(&scene(), &cam).unwrap();
    let mut dst = vec![0u8; 160 * 120 * 4];
    r.render_rgba_into(&scene(), &cam, &mut dst).unwrap();
    assert_eq!(dst, frame.rgba);
    assert!(r.render_rgba_into(&scene(), &cam, &mut dst[..100]).is_err());
}

/// A friction gripper's finger pads are drawn as the tool: seen from the side, with their
/// segment id and at their depth.
#[test]
fn finger_pads_are_drawn_as_the_tool() {
    let mut r = Renderer::new().expect("a graphics adapter");
    let cam = camera("side", [0.55, -1.0, 0.2], [0.55, 0.0, 0.2], 320, 240);
    let mut s = scene();
    s.objects.clear();
    let pad = |y: f32| assay_spec::scene::SnapshotBox {
        position: [0.55, y, 0.2],
        rotation: [0.0, 0.0, 0.0, 1.0],
        half_extents: [0.01, 0.005, 0.025],
    };
    s.tool = None;
    s.fingers = vec![pad(-0.03), pad(0.03)];
    let f = r.render(&s, &cam).unwrap();
    // The nearer pad's face (y = -0.035) is 0.965 m from the camera.
    let (x, y) = pixel(&cam, [0.55, -0.035, 0.2]);
    let i = (y * f.width + x) as usize;
    assert_eq!(f.segments[i], SEGMENT_TOOL);
    assert!((f.depth[i] - 0.965).abs() < 0.003, "{}", f.depth[i]);
    // Beside the pads there is nothing but the background.
    let (x, y) = pixel(&cam, [0.62, 0.0, 0.2]);
    assert_ne!(f.segments[(y * f.width + x) as usize], SEGMENT_TOOL);
}

/// A turned tool is drawn turned: pitched by 90° its box (0.02 × 0.02 × 0.05 half extents) lies
/// along x, seen from the side; the end-effector camera looks along its axis, no longer down.
#[test]
fn a_turned_tool_is_drawn_turned_and_its_camera_looks_along_its_axis() {
    let mut r = Renderer::new().expect("a graphics adapter");
    let cam = camera("side", [0.55, -1.0, 0.3], [0.55, 0.0, 0.3], 320, 240);
    let mut s = scene();
    s.objects.clear();
    let mut tool_at = |s: &SceneSnapshot, p: [f32; 3]| {
        let f = r.render(s, &cam).unwrap();
        let (x, y) = pixel(&cam, p);
        f.segments[(y * f.width + x) as usize] == SEGMENT_TOOL
    };
    // Pointing down: 4 cm above its centre is tool, 4 cm beside it is not.
    let (above, beside) = ([0.55, 0.0, 0.34], [0.59, 0.0, 0.3]);
    assert!(tool_at(&s, above) && !tool_at(&s, beside));
    // Pitched by -90° about y (its axis along +x): the other way round.
    let h = std::f32::consts::FRAC_PI_4;
    s.tool_rotation = Some([0.0, -h.sin(), 0.0, h.cos()]);
    assert!(!tool_at(&s, above) && tool_at(&s, beside));
    // Its camera looks along +x from 6 cm in front of its centre: at a box standing 0.3 m ahead
    // at the tool's height, where pointing down it saw the table.
    let ee = Camera {
        fovy_deg: 70.0,
        ..camera(assay_spec::scene::EE_CAMERA, [0.0; 3], [0.0; 3], 64, 48)
    };
    s.objects = vec![object(
        "wall",
        Shape::Box {
            half_extents: [0.02, 0.2, 0.2],
        },
        [0.8, 0.3, 0.3],
        [0.9, 0.0, 0.3],
        0.0,
    )];
    let centre = |s: &SceneSnapshot, r: &mut Renderer| {
        let f = r.render(s, &ee).unwrap();
        f.segments[(24 * 64 + 32) as usize]
    };
    assert_eq!(centre(&s, &mut r), FIRST_OBJECT_SEGMENT);
    s.tool_rotation = None;
    assert_eq!(centre(&s, &mut r), SEGMENT_SURFACE);
}
