//! Dynamics clip states: taken every 24 physics steps from the recorded rows, with the tool's
//! position and holding as proprioception and its commanded velocity and hold command as action.

use std::path::Path;

use arrow_array::{Array, Float32Array, Int16Array, RecordBatch, UInt32Array};
use assay_model::clip::{ACTION_DIMS, CLIP_STRIDE_STEPS, PROPRIO_DIMS};
use assay_sim::{ClipStates, Episode, SimOptions, simulate, simulate_with};
use assay_spec::spec::{Format, TaskSpec, parse_task};

fn task(rel: &str) -> TaskSpec {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/tasks")
        .join(rel);
    let text = std::fs::read_to_string(&p).unwrap();
    parse_task(&text, Format::Yaml, &p.display().to_string()).unwrap_or_else(|e| panic!("{e}"))
}

fn with_clip(spec: &TaskSpec, seed: u64) -> Episode {
    let options = SimOptions {
        clip: true,
        ..Default::default()
    };
    simulate_with(spec, seed, "oracle", options).unwrap()
}

fn table(file: &[u8]) -> RecordBatch {
    let r = arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(file), None).unwrap();
    let batches: Vec<RecordBatch> = r.map(|b| b.unwrap()).collect();
    assert_eq!(batches.len(), 1);
    batches.into_iter().next().unwrap()
}

fn f32s(t: &RecordBatch, name: &str) -> Vec<f32> {
    let c = t.column_by_name(name).unwrap();
    let a = c.as_any().downcast_ref::<Float32Array>().unwrap();
    (0..a.len()).map(|i| a.value(i)).collect()
}

#[test]
fn clip_states_are_the_recorded_rows_every_24_steps() {
    let spec = task("placement/put-block-in-bowl.yaml");
    let ep = with_clip(&spec, 0);
    assert!(ep.outcome.success);
    let c: &ClipStates = ep.clip.as_ref().expect("clip states were asked for");
    let t = table(&ep.file);
    let steps_col = t
        .column_by_name("step")
        .unwrap()
        .as_any()
        .downcast_ref::<UInt32Array>()
        .unwrap()
        .values()
        .to_vec();
    let grasped = t
        .column_by_name("grasped")
        .unwrap()
        .as_any()
        .downcast_ref::<Int16Array>()
        .unwrap()
        .values()
        .to_vec();
    let ee = ["ee_x", "ee_y", "ee_z"].map(|n| f32s(&t, n));
    let cmd = ["ee_cmd_x", "ee_cmd_y", "ee_cmd_z"].map(|n| f32s(&t, n));

    // 10 Hz from the first policy step to the end of the episode.
    let dt = spec.physics.dt;
    assert!((f64::from(c.interval_s) - CLIP_STRIDE_STEPS as f64 * dt).abs() < 1e-6);
    assert_eq!(c.steps[0], ep.initial_step);
    assert!(c.steps.windows(2).all(|w| w[1] - w[0] == CLIP_STRIDE_STEPS));
    let span = ep.outcome.steps - ep.initial_step;
    assert_eq!(c.len() as u64, span / CLIP_STRIDE_STEPS + 1, "{span} steps");
    assert!(c.len() > 20, "{} frames", c.len());
    assert_eq!(c.scenes.len(), c.len());
    assert_eq!(c.proprio.len(), c.len() * PROPRIO_DIMS);
    assert_eq!(c.actions.len(), c.len() * ACTION_DIMS);

    let row_of = |step: u64| {
        steps_col
            .iter()
            .position(|&s| u64::from(s) == step)
            .unwrap_or_else(|| panic!("no recorded row at step {step}"))
    };
    for (k, &step) in c.steps.iter().enumerate() {
        let row = row_of(step);
        let p = &c.proprio[k * PROPRIO_DIMS..][..PROPRIO_DIMS];
        assert_eq!(&p[..3], &[ee[0][row], ee[1][row], ee[2][row]], "frame {k}");
        assert_eq!(p[3], if grasped[row] >= 0 { 1.0 } else { 0.0 }, "frame {k}");
        assert_eq!(c.scenes[k].tool, Some([ee[0][row], ee[1][row], ee[2][row]]));
        let a = &c.actions[k * ACTION_DIMS..][..ACTION_DIMS];
        if k + 1 == c.len() {
            assert_eq!(a, &[0.0; ACTION_DIMS]);
            continue;
        }
        let next = row_of(c.steps[k + 1]);
        for i in 0..3 {
            let v = (cmd[i][next] - cmd[i][row]) / c.interval_s;
            assert!(
                (a[i] - v).abs() < 1e-4,
                "frame {k} axis {i}: {} vs {v}",
                a[i]
            );
        }
        // The hold command is the holding of the next frame.
        assert_eq!(a[3], c.proprio[(k + 1) * PROPRIO_DIMS + 3], "frame {k}");
    }

    // The tool is kinematic: it reaches its commanded position every step, so the commanded
    // velocity is also the tool's velocity.
    for row in 0..steps_col.len() {
        for i in 0..3 {
            assert!((ee[i][row] - cmd[i][row]).abs() < 1e-5, "row {row}");
        }
    }

    // Pick and place: holding goes 0, then 1 for a while, then 0 again.
    let holding: Vec<f32> = c.proprio.chunks(PROPRIO_DIMS).map(|p| p[3]).collect();
    let flips = holding.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!((holding[0], flips), (0.0, 2), "{holding:?}");
    assert_eq!(*holding.last().unwrap(), 0.0);
    // The tool moves: some frames command more than 10 cm/s.
    assert!(
        c.actions
            .chunks(ACTION_DIMS)
            .any(|a| a[..3].iter().map(|v| v * v).sum::<f32>().sqrt() > 0.1)
    );
}

#[test]
fn asking_for_a_clip_changes_nothing_else_and_is_deterministic() {
    let spec = task("stacking/build-two-block-tower.yaml");
    let a = with_clip(&spec, 3);
    let b = with_clip(&spec, 3);
    let plain = simulate(&spec, 3, "oracle").unwrap();
    assert!(plain.clip.is_none());
    assert_eq!(a.file, plain.file);
    assert_eq!(a.outcome, plain.outcome);
    assert_eq!(a.clip, b.clip);
    let other = with_clip(&spec, 4);
    assert_ne!(a.clip.unwrap().proprio, other.clip.unwrap().proprio);
}

/// An episode file read back gives the states the episode's clip was made of, exactly: the
/// scenes (objects, tool, pads, arm, joints), proprioception and actions — for a plain task, an
/// arm with a friction gripper, an articulated object and a pile.
#[test]
fn an_episode_file_read_back_gives_the_clip_states_it_was_recorded_with() {
    for (rel, seed) in [
        ("placement/put-block-in-bowl.yaml", 1),
        ("robomimic/lift-cube.yaml", 0),
        ("articulated/open-cabinet-door.yaml", 2),
        ("robomimic/nut-on-square-peg.yaml", 0),
        ("piles/align-pile-along-line.yaml", 0),
    ] {
        let spec = task(rel);
        let ep = with_clip(&spec, seed);
        let recorded = ep.clip.as_ref().expect("clip states were asked for");
        let read = assay_sim::recorded_states(&spec, seed, &ep.file, CLIP_STRIDE_STEPS)
            .unwrap_or_else(|e| panic!("{rel}: {e}"));
        assert_eq!(&read, recorded, "{rel}");
        // Other strides take every matching recorded row.
        let fine = assay_sim::recorded_states(&spec, seed, &ep.file, 8).unwrap();
        assert_eq!(fine.steps[0], recorded.steps[0], "{rel}");
        assert!(fine.steps.windows(2).all(|w| w[1] - w[0] == 8), "{rel}");
        let span = ep.outcome.steps - ep.initial_step;
        assert_eq!(fine.len() as u64, span / 8 + 1, "{rel}");
        // Refused: another seed, another task, a stride between recorded rows.
        let e = assay_sim::recorded_states(&spec, seed + 1, &ep.file, 24).unwrap_err();
        assert!(e.to_string().contains("seed"), "{e}");
        let mut other = spec.clone();
        other.description.push('!');
        let e = assay_sim::recorded_states(&other, seed, &ep.file, 24).unwrap_err();
        assert!(e.to_string().contains("recorded for task"), "{e}");
        let e = assay_sim::recorded_states(&spec, seed, &ep.file, 6).unwrap_err();
        assert!(e.to_string().contains("multiple of 4"), "{e}");
    }
}

/// `oracle:grasp=P`: an episode drawn open goes through the plan's motions, carrying nothing to
/// the place, and fails; its actions match the grasping oracle's until the grasp and never command
/// a hold. Over seeds about the chance given grasps, and the draw is the episode's own.
#[test]
fn an_open_handed_oracle_moves_as_the_oracle_does_without_holding() {
    let spec = task("placement/put-block-in-bowl.yaml");
    let clip_of = |policy: &str, seed: u64| {
        let options = SimOptions {
            clip: true,
            ..Default::default()
        };
        simulate_with(&spec, seed, policy, options).unwrap()
    };
    let open = clip_of("oracle:grasp=0", 0);
    let closed = clip_of("oracle", 0);
    assert!(closed.outcome.success);
    assert!(!open.outcome.success);
    let (o, c) = (open.clip.unwrap(), closed.clip.unwrap());
    let holds = |s: &ClipStates| {
        s.actions
            .chunks(ACTION_DIMS)
            .filter(|a| a[3] != 0.0)
            .count()
    };
    assert_eq!(holds(&o), 0);
    assert!(holds(&c) > 5, "{}", holds(&c));
    // The same approach up to the grasp, then the carry to the bowl: most of the closed
    // episode's frames, and the tool ends over the bowl in both.
    let first_hold = c
        .actions
        .chunks(ACTION_DIMS)
        .position(|a| a[3] != 0.0)
        .unwrap();
    assert_eq!(
        o.actions[..first_hold * ACTION_DIMS],
        c.actions[..first_hold * ACTION_DIMS]
    );
    assert!(o.len() + 3 >= c.len(), "{} vs {} frames", o.len(), c.len());
    let last_tool = |s: &ClipStates| s.scenes.last().unwrap().tool.unwrap();
    let (a, b) = (last_tool(&o), last_tool(&c));
    let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    assert!(
        d < 0.03,
        "the open tool ends {d} m from where the grasping one does"
    );
    assert!(format!("{:?}", open.notes).contains("left open"));

    // grasp=1 is the oracle itself; the draw differs between seeds, not the noise's draws.
    let (one, oracle) = (clip_of("oracle:grasp=1", 2), clip_of("oracle", 2));
    assert_eq!(one.clip, oracle.clip);
    assert_eq!(
        (one.outcome.steps, one.outcome.predicates),
        (oracle.outcome.steps, oracle.outcome.predicates)
    );
    let opened = (0..12)
        .filter(|&s| {
            !simulate(&spec, s, "oracle:grasp=0.5")
                .unwrap()
                .outcome
                .success
        })
        .count();
    assert!((2..=10).contains(&opened), "{opened} of 12 drawn open");
}
