//! Dynamics clips: an example task simulated with the oracle and drawn at 64 × 64 from its camera
//! on the machine's adapter (Mesa's software Vulkan in CI).

mod common;

use std::time::Instant;

use assay_model::clip::{ACTION_DIMS, CLIP_STRIDE_STEPS, Clip, PROPRIO_DIMS};
use assay_render::Renderer;
use assay_render::imagery::render_clip;
use assay_sim::{Episode, SimOptions};
use assay_spec::scene::task_cameras;
use assay_spec::spec::TaskSpec;
use common::task;

const SIZE: u32 = 64;

fn episode(spec: &TaskSpec, seed: u64) -> Episode {
    let options = SimOptions {
        clip: true,
        ..Default::default()
    };
    assay_sim::simulate_with(spec, seed, "oracle", options).unwrap()
}

/// The clip of `ep` as the worker draws it: from the task's first camera.
fn clip(r: &mut Renderer, spec: &TaskSpec, ep: &Episode) -> Clip {
    let c = ep.clip.clone().expect("clip states");
    let camera = task_cameras(&spec.cameras).remove(0);
    render_clip(
        r,
        &c.scenes,
        &camera,
        SIZE,
        c.interval_s,
        c.proprio,
        c.actions,
    )
    .unwrap()
}

#[test]
fn a_pick_and_place_clip_shows_the_tool_moving_and_holding() {
    let spec = task("placement/put-block-in-bowl.yaml");
    let ep = episode(&spec, 0);
    let states = ep.clip.as_ref().unwrap();
    let mut r = Renderer::new().expect("an adapter");
    let started = Instant::now();
    let bytes = clip(&mut r, &spec, &ep).encode();
    let ms = started.elapsed().as_secs_f64() * 1e3;
    println!(
        "{} frames at {SIZE}x{SIZE} in {ms:.1} ms ({:.2} ms a frame) on {}",
        states.len(),
        ms / states.len() as f64,
        r.adapter()
    );
    let c = Clip::decode(&bytes).expect("the clip decodes");

    assert_eq!((c.width, c.height), (SIZE, SIZE));
    assert_eq!(
        (c.proprio_dims, c.action_dims),
        (PROPRIO_DIMS as u32, ACTION_DIMS as u32)
    );
    assert!((c.interval_s - 0.1).abs() < 1e-6, "{}", c.interval_s);
    let policy_steps = (ep.outcome.steps - ep.initial_step) as f64;
    let want = policy_steps / CLIP_STRIDE_STEPS as f64;
    assert!(
        (c.len() as f64 - want).abs() <= 1.0,
        "{} frames for {policy_steps} steps",
        c.len()
    );
    assert_eq!(c.proprio, states.proprio);
    assert_eq!(c.actions, states.actions);

    // Proprioception is the recorded tool position at each frame's step.
    for (k, p) in c.proprio.chunks(PROPRIO_DIMS).enumerate() {
        assert_eq!(Some([p[0], p[1], p[2]]), states.scenes[k].tool, "frame {k}");
    }
    // The objects' section: each scene object's position at each frame, in the scene's order;
    // the block is carried (it moves), the bowl is not.
    let n = states.scenes[0].objects.len();
    assert_eq!(c.object_dims as usize, 3 * n);
    for (k, scene) in states.scenes.iter().enumerate() {
        let want: Vec<f32> = scene.objects.iter().flat_map(|o| o.position).collect();
        assert_eq!(c.objects_at(k), &want[..], "frame {k}");
    }
    let moved: Vec<f32> = (0..n)
        .map(|i| {
            let (a, b) = (
                &c.objects_at(0)[3 * i..][..3],
                &c.objects_at(c.len() - 1)[3 * i..][..3],
            );
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).powi(2))
                .sum::<f32>()
                .sqrt()
        })
        .collect();
    assert!(moved.iter().any(|&d| d > 0.05), "{moved:?}");
    assert!(moved.iter().any(|&d| d < 0.01), "{moved:?}");

    // Holding flips to 1 when the block is picked and back to 0 when it is placed; the hold
    // command is the next frame's holding.
    let holding: Vec<f32> = c.proprio.chunks(PROPRIO_DIMS).map(|p| p[3]).collect();
    let flips = holding.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!((holding[0], flips, holding[c.len() - 1]), (0.0, 2, 0.0));
    for (k, a) in c.actions.chunks(ACTION_DIMS).enumerate() {
        match holding.get(k + 1) {
            Some(&next) => assert_eq!(a[3], next, "frame {k}"),
            None => assert_eq!(a, &[0.0; ACTION_DIMS]),
        }
    }

    // Frames change while the tool moves, and the scene is drawn (not a blank background).
    let frame = (SIZE * SIZE * 3) as usize;
    let frames: Vec<&[u8]> = c.rgb.chunks(frame).collect();
    let differ = |a: &[u8], b: &[u8]| a.iter().zip(b).filter(|(x, y)| x != y).count();
    let moving = (1..frames.len())
        .filter(|&k| {
            let a = &c.actions[(k - 1) * ACTION_DIMS..][..3];
            a.iter().map(|v| v * v).sum::<f32>().sqrt() > 0.05
        })
        .collect::<Vec<_>>();
    assert!(moving.len() > 5, "{moving:?}");
    for &k in &moving {
        assert!(
            differ(frames[k - 1], frames[k]) > 0,
            "frame {k} is frame {}",
            k - 1
        );
    }
    assert!(differ(frames[0], frames[frames.len() / 2]) > 40);
    let colours: std::collections::BTreeSet<&[u8]> = frames[0].chunks(3).collect();
    assert!(colours.len() > 10, "{} colours", colours.len());

    // The same episode gives the same clip, byte for byte.
    assert_eq!(clip(&mut r, &spec, &episode(&spec, 0)).encode(), bytes);
}

#[test]
fn a_clip_of_a_task_without_cameras_is_drawn_from_the_keyframe_camera() {
    let mut spec = task("stacking/build-two-block-tower.yaml");
    spec.cameras.clear();
    let ep = episode(&spec, 1);
    let mut r = Renderer::new().expect("an adapter");
    let c = clip(&mut r, &spec, &ep);
    assert_eq!(c.len(), ep.clip.as_ref().unwrap().len());
    // Without cameras of its own a task's keyframes, and so its clip, come from the first default
    // camera (the top view).
    assert_eq!(task_cameras(&spec.cameras)[0].name, "top");
    // Drawn at another size in between, the clip comes out the same (targets are kept by size).
    let cam = task_cameras(&spec.cameras).remove(0);
    r.render_with(&ep.initial, &cam, assay_render::Outputs::ALL)
        .unwrap();
    assert_eq!(clip(&mut r, &spec, &ep), c);
    let states = ep.clip.unwrap();
    assert!(
        render_clip(&mut r, &states.scenes, &cam, 0, 0.1, vec![], vec![]).is_err(),
        "an empty frame size is refused"
    );
    assert!(
        render_clip(
            &mut r,
            &states.scenes,
            &cam,
            SIZE,
            0.1,
            states.proprio.clone(),
            vec![]
        )
        .is_err(),
        "actions must match the frames"
    );
}

#[test]
fn a_clip_at_a_policys_interface_draws_each_camera_where_it_was() {
    use assay_model::policy::Interface;
    let spec = task("placement/put-block-in-bowl.yaml");
    let args = "space=ee_delta,cameras=image:scene@64+wrist:wrist@24,state=ee_pos+ee_quat+gripper";
    let interface = Interface::parse_args(args).unwrap();
    let options = SimOptions {
        clip: true,
        clip_interface: Some(interface.clone()),
        ..Default::default()
    };
    let ep = assay_sim::simulate_with(&spec, 0, "oracle", options).unwrap();
    let states = ep.clip.clone().unwrap();
    let mut r = Renderer::new().expect("an adapter");
    let bytes = assay_render::imagery::render_clip_at(
        &mut r,
        &states.scenes,
        &states.cameras,
        states.interval_s,
        states.proprio.clone(),
        states.actions.clone(),
        &interface.to_args(),
    )
    .unwrap()
    .encode();
    let c = Clip::decode(&bytes).expect("the clip decodes");
    assert_eq!(c.interface, interface.to_args());
    assert_eq!(
        (c.width, c.height, c.proprio_dims, c.action_dims),
        (64, 64, 8, 7)
    );
    assert_eq!(c.len(), states.len());
    assert_eq!(c.views.len(), 1);
    let wrist = &c.views[0];
    assert_eq!(
        (wrist.name.as_str(), wrist.width, wrist.height),
        ("wrist", 24, 24)
    );

    // The scene camera is the task's: its frames are the original clip's, pixel for pixel.
    let original = clip(&mut r, &spec, &episode(&spec, 0));
    assert_eq!(original.rgb, c.rgb);

    // The wrist camera rides on the tool: its view changes as the tool moves to the block, and
    // close above it (at the grasp) the block's red fills much of it. Mounted beside the tool, it
    // sees a block the suction tool carries from outside: part of the view, the scene around it.
    let holding_from = (0..c.len())
        .find(|&t| c.actions[t * 7 + 6] == 1.0)
        .expect("a grasp");
    let changed = (1..holding_from)
        .filter(|&t| wrist.frame(t) != wrist.frame(t - 1))
        .count();
    assert!(
        changed + 1 >= holding_from && holding_from > 5,
        "{changed} of the {holding_from} wrist frames before the grasp changed"
    );
    let red = |rgb: &[u8]| {
        rgb.chunks(3)
            .filter(|p| p[0] > 120 && p[1] < 80 && p[2] < 80)
            .count() as f64
            / (rgb.len() / 3) as f64
    };
    let above_block = (0..=holding_from + 1)
        .map(|t| red(wrist.frame(t)))
        .fold(0.0, f64::max);
    let at_start = red(wrist.frame(0));
    let carried: Vec<f64> = (holding_from + 3..c.len())
        .take_while(|&t| c.actions[t * 7 + 6] == 1.0)
        .map(|t| red(wrist.frame(t)))
        .collect();
    println!(
        "red share of the wrist view: {at_start:.2} at the start, {above_block:.2} above the block, {carried:.2?} carrying it"
    );
    assert!(
        above_block > 0.4 && at_start < 0.05,
        "red share of the wrist view: {at_start:.2} at the start, {above_block:.2} above the block"
    );
    assert!(
        !carried.is_empty() && carried.iter().all(|&r| r > 0.05 && r < 0.7),
        "red share of the wrist view while carrying: {carried:.2?}"
    );
}
