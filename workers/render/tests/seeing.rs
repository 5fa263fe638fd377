//! A policy that sees: the oracle plan locating objects only from the depth and segmentation
//! images rendered every 8 physics steps while it acts (`oracle:sense=camera`), against the real
//! renderer on the machine's adapter.

mod common;

use assay_model::policy::observation_camera;
use assay_render::{Outputs, Renderer};
use assay_sim::Observer;
use assay_sim::perception::Tracker;
use assay_spec::scene::{Observation, SceneSnapshot, SnapshotObject};
use assay_spec::spec::{Camera, Shape, Surface};
use common::task;
use rapier3d::prelude::Vec3;

/// Renders in the test's thread; `shift` moves the camera that actually draws away from the one
/// the policy is told about (a miscalibrated camera).
struct InProcess {
    renderer: Renderer,
    shift: [f64; 3],
}

impl Observer for InProcess {
    fn observe(
        &mut self,
        scene: SceneSnapshot,
        _step: u64,
        camera: &Camera,
    ) -> Result<Observation, String> {
        let mut drawn = camera.clone();
        for k in 0..3 {
            drawn.eye[k] += self.shift[k];
            drawn.target[k] += self.shift[k];
        }
        let f = self
            .renderer
            .render_with(&scene, &drawn, Outputs::ALL)
            .map_err(|e| e.to_string())?;
        Ok(Observation {
            camera: camera.clone(),
            depth: f.depth,
            segments: f.segments,
        })
    }
}

#[test]
fn the_camera_sees_a_box_where_it_is() {
    let mut r = Renderer::new().expect("an adapter");
    let yaw = (25f32.to_radians() / 2.0).sin_cos();
    let scene = SceneSnapshot {
        surface: Surface::Table,
        objects: vec![SnapshotObject {
            color_given: true,
            id: "box".into(),
            shape: Shape::Box {
                half_extents: [0.03, 0.02, 0.025],
            },
            color: [0.8, 0.2, 0.2],
            position: [0.58, -0.11, 0.025],
            rotation: [0.0, 0.0, yaw.0, yaw.1],
            joints: Default::default(),
        }],
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
    };
    let camera = observation_camera();
    let f = r.render_with(&scene, &camera, Outputs::ALL).unwrap();
    let mut t = Tracker::new(1);
    t.update(
        &Observation {
            camera,
            depth: f.depth,
            segments: f.segments,
        },
        0,
    );
    let s = t.get(0).expect("the box is in view");
    // One pixel of the 320 × 240 top view is about 3.7 mm on the table.
    assert!((s.top.x - 0.58).abs() < 0.003, "{:?}", s.top);
    assert!((s.top.y + 0.11).abs() < 0.003, "{:?}", s.top);
    assert!((s.top.z - 0.05).abs() < 0.002, "{:?}", s.top);
    // Along its own long axis (yawed 25°) the box reaches 3 cm from its centre.
    let axis = Vec3::new(25f32.to_radians().cos(), 25f32.to_radians().sin(), 0.0);
    let e = s.extent_along(axis);
    assert!((e - 0.03).abs() < 0.004, "extent {e}");
}

/// Tasks of every group: stacking, placement into containers and onto targets, pushing.
const TASKS: &[&str] = &[
    "stacking/build-two-block-tower.yaml",
    "stacking/stack-blocks-by-size.yaml",
    "placement/put-block-in-bowl.yaml",
    "placement/place-blocks-in-matching-zones.yaml",
    "assembling/build-bridge.yaml",
    "piles/push-block-pile-into-zone.yaml",
    // A cube right under the parked tool: the policy must move it aside to see.
    "piles/robogen-clear-small-cubes-from-table-center.yaml",
    "clutter/pick-red-block-out-of-clutter.yaml",
];

fn run(shift: [f64; 3], seeds: u64) -> Vec<(String, u64, bool, u64)> {
    let mut eyes = InProcess {
        renderer: Renderer::new().expect("an adapter"),
        shift,
    };
    let mut out = Vec::new();
    for rel in TASKS {
        let spec = task(rel);
        for seed in 0..seeds {
            let options = assay_sim::SimOptions {
                observer: Some(&mut eyes),
                ..Default::default()
            };
            let ep = assay_sim::simulate_with(&spec, seed, "oracle:sense=camera", options)
                .unwrap_or_else(|e| panic!("{rel} seed {seed}: {e}"));
            out.push((spec.id.clone(), seed, ep.outcome.success, ep.observations));
        }
    }
    out
}

#[test]
fn the_seeing_oracle_solves_tasks_from_its_frames_and_fails_with_a_miscalibrated_camera() {
    let seeing = run([0.0; 3], 2);
    for (id, seed, ok, frames) in &seeing {
        println!("seeing oracle  {id} seed {seed}: success {ok}, {frames} frames");
    }
    let solved = seeing.iter().filter(|r| r.2).count();
    assert!(
        solved * 10 >= seeing.len() * 9,
        "the seeing oracle solved {solved} of {} episodes",
        seeing.len()
    );
    // Frames were rendered while it acted: about one per 8 physics steps of the policy phase.
    assert!(seeing.iter().all(|r| r.3 > 20), "{seeing:?}");

    // The same plan with a camera 4 cm off from where the policy believes it is: every object is
    // seen 4 cm away from where it is, so stacks and placements miss.
    let blind = run([0.04, 0.0, 0.0], 1);
    let solved_blind = blind.iter().filter(|r| r.2).count();
    for (id, seed, ok, _) in &blind {
        println!("miscalibrated  {id} seed {seed}: success {ok}");
    }
    assert!(
        solved_blind * 2 < blind.len(),
        "a miscalibrated camera still solved {solved_blind} of {}",
        blind.len()
    );

    // Without a camera the seeing policy cannot run, and says why.
    let spec = task(TASKS[0]);
    let err = match assay_sim::simulate(&spec, 0, "oracle:sense=camera") {
        Ok(_) => panic!("a seeing policy ran without a camera"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("render role"), "{err}");
}
