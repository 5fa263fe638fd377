//! Policy ranking by the world-model proxy with the real cluster: `assay eval` runs four scripted
//! oracles (the training policies), trains a ladder of diffusion policies on the oracle's
//! episodes and runs them, trains each group's world model and frame judge on the training
//! policies' episodes only, has every ranked policy (the ladder's and a TorchScript one) act
//! inside the world model and prints r and MMRV; a VLM judge (a local OpenAI-compatible fixture)
//! is asked about every imagined rollout's keyframes and is ranked as a proxy of its own; the
//! report joins real and proxy success per task and policy and the correlation plots are
//! written beside it. A lab's world model served over `assay.v1.WorldModel` (a Python server)
//! drives a ranking the same way, and so does Assay's video model written again in PyTorch
//! (the kit's example, on the real torch wheel); a served model that declares another interface
//! than the ranked policy's is refused naming the field. Bad ranking settings — a scripted oracle ranked among them —
//! are refused before anything runs, naming the setting; the coordinator refuses over gRPC a
//! batch seed among the ladder's held-out seeds.
#![cfg(feature = "trainer")]

use std::process::Command;
use std::sync::Arc;

use crate::common::torchscript::torchscript;
use crate::common::*;
use crate::real_policies::{lerobot_python, serve_command, serve_script};
use assay_proto::v1 as pb;
use assay_report::report::Report;
use assay_testkit::fixture::{Fixture, Received, Reply, Script};
use base64::Engine;

const TASKS: [&str; 2] = [
    "examples/tasks/placement/put-block-in-bowl.yaml",
    "examples/tasks/placement/place-cans-on-coasters.yaml",
];

fn eval(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(bin())
        .arg("eval")
        .args(TASKS)
        .args(["--seeds", "2", "--no-diversity", "--image-size", "160x120"])
        .args(["--policy", "oracle", "--policy", "oracle:noise=0.05"])
        .args([
            "--policy",
            "oracle:noise=0.01",
            "--policy",
            "oracle:noise=0.03",
        ])
        .args(extra)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .current_dir(repo())
        .output()
        .unwrap()
}

/// Width and height of the PNG behind a `data:image/png;base64,…` URL.
fn png_size(url: &str) -> (u32, u32) {
    let b64 = url.split_once("base64,").unwrap().1;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(b64)
        .unwrap();
    let be = |k: usize| u32::from_be_bytes(bytes[k..k + 4].try_into().unwrap());
    (be(16), be(20))
}

#[test]
fn eval_ranks_a_ladder_by_the_world_model_proxy() {
    // The VLM: scene alignment 4, completion 8 for real rollouts; for the world model's 64×64
    // imagined rollouts, 9 on the bowl task and 2 on the other.
    let script: Script = Arc::new(|r: &Received| {
        let imagined = r.image_urls().iter().any(|u| png_size(u) == (64, 64));
        let score = match (r.prompt_version.as_deref(), imagined) {
            (Some("scene-alignment/v1"), _) => 4,
            (_, false) => 8,
            (_, true) if r.text.contains("bowl") => 9,
            (_, true) => 2,
        };
        Reply::text(format!("Score: {score}"))
    });
    let vlm = Fixture::start(script).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("assay.toml");
    std::fs::write(
        &config,
        format!(
            "[judges.vlm]\nbackend = \"openai\"\nbase_url = \"{}\"\nmodel = \"test-vlm\"\n",
            vlm.base_url()
        ),
    )
    .unwrap();
    let module = torchscript(dir.path());
    let learned = format!("torchscript:path={},max_steps=480", module.display());
    // The report goes to its own folder: `dir` holds the configuration and the module.
    let out_dir = dir.path().join("out");
    let out = eval(
        &out_dir,
        &[
            "--judge",
            "vlm",
            "--judge-repeats",
            "1",
            "--config",
            config.to_str().unwrap(),
            "--policy",
            &learned,
            "--rank-train-policies",
            TRAIN,
            "--rank-ladder",
            LADDER,
            "--proxy",
            r#"{"judge_steps": 30, "video": {"steps": 30}, "leak_ablation": true}"#,
            // A task of another group, evaluated but not ranked.
            STACKING,
            "--rank-groups",
            "placement",
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("policy ranking, world-model against sim (3 policies): Pearson r")
            && stdout.contains("MMRV"),
        "{stdout}"
    );
    let report: Report =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();
    let k = report.results.ranking.expect("a ranking section");
    // The ranked policies: the TorchScript one and the ladder's two diffusion policies (its
    // checkpoint at step 10 and its final one), trained by the cluster on the oracle's episodes.
    assert_eq!(k.ranked_policies.len(), 3, "{:?}", k.ranked_policies);
    assert_eq!(k.ranked_policies[0], learned);
    let ladder: Vec<&String> = k.ranked_policies[1..].iter().collect();
    assert!(
        ladder
            .iter()
            .all(|p| p.starts_with("diffusion:model=policies/") && p.ends_with(",max_steps=480")),
        "{ladder:?}"
    );
    assert_ne!(ladder[0], ladder[1]);
    assert_eq!(
        k.train_policies,
        [
            "oracle",
            "oracle:noise=0.05",
            "oracle:noise=0.01",
            "oracle:noise=0.03"
        ]
    );
    // 2 tasks × 3 ranked policies, each with real and proxy success over the 2 seeds.
    assert_eq!(k.rows.len(), 6);
    for r in &k.rows {
        assert_eq!(r.real.trials, 2);
        assert_eq!(r.proxy.as_ref().map(|p| p.trials), Some(2), "{r:?}");
    }
    assert_eq!(k.groups.len(), 1);
    let g = &k.groups[0];
    assert_eq!((g.group.as_str(), g.predictions.len()), ("placement", 12));
    // The proxy started from the world model (the default, the video model) fitted while the
    // ladder trained: at its last step, training no further.
    let video = g.video_model.as_ref().expect("the video model's fit");
    assert_eq!(
        (video.steps, video.resumed_from_step),
        (30, Some(30)),
        "{video:?}"
    );
    assert_eq!(g.world_model.steps, 30);
    // The stacking task ran the batch's five policies (the oracles and the TorchScript one) on
    // its 2 seeds, and nothing of the ranking: no ladder policy, no row.
    let stacking = report
        .results
        .tasks
        .iter()
        .find(|t| t.group == "stacking")
        .expect("the stacking task");
    assert_eq!(stacking.success.trials, 5 * 2, "{:?}", stacking.by_policy);
    assert!(k.rows.iter().all(|r| r.group == "placement"));
    assert!(
        g.world_model_name.contains("video model"),
        "{}",
        g.world_model_name
    );
    let test = g.action_test.as_ref().expect("the action test");
    assert_eq!((test.episodes, test.horizon), (12, 16));
    assert!(test.true_actions_mse > 0.0 && test.shuffled_actions_mse > 0.0);
    assert!(test.zero_actions_mse > 0.0 && test.psnr > 0.0 && test.ssim > 0.0);
    // The judge learned from the real and imagined last frames of every training episode (4
    // policies × 2 tasks × 2 seeds), and from earlier, not-yet-done frames of them.
    assert!(g.judge_examples >= 2 * 16, "{}", g.judge_examples);
    for p in &g.predictions {
        assert!((0.0..=1.0).contains(&p.p_success));
        // Never longer than the step budget of 480 physics steps (21 clip frames), and shorter
        // only when the frame judge called it done.
        assert!(
            p.imagined_frames == 21 || (p.done_by_judge && p.imagined_frames < 21),
            "{p:?}"
        );
        assert!(p.leak.is_some(), "the leak ablation was asked for");
    }
    // Every imagined rollout of a ranked episode was shown to the VLM: 8 frames of 64×64, asked
    // about completion only (a rollout that was never seen has no scene to align).
    let got = vlm.received();
    let imagined: Vec<&Received> = got
        .iter()
        .filter(|r| r.image_urls().iter().all(|u| png_size(u) == (64, 64)))
        .collect();
    assert_eq!(imagined.len(), 12, "one per ranked episode");
    for r in &imagined {
        assert_eq!(r.image_urls().len(), 8);
        assert_eq!(r.prompt_version.as_deref(), Some("completion/v1"));
    }
    for r in &k.rows {
        let j = &r.judged_proxy;
        assert_eq!(j.len(), 1, "{r:?}");
        let expected = if r.task_id == "put-block-in-bowl" {
            (2, 9.0)
        } else {
            (0, 2.0)
        };
        assert_eq!(
            (j[0].success.successes, j[0].mean_completion),
            (expected.0, Some(expected.1))
        );
    }
    assert!(k.judging_errors.is_empty(), "{:?}", k.judging_errors);
    // The judges' agreement: the frame judge's, then the VLM's on the 12 ranked episodes —
    // real rollouts (it said 8 to every one: done) against the simulator, and its imagined
    // verdicts against the simulator and against the frame judge's.
    let judges: Vec<&str> = k
        .judge_agreements
        .iter()
        .map(|a| a.judge.as_str())
        .collect();
    assert_eq!(judges, ["frame judge", "vlm"]);
    let vlm = &k.judge_agreements[1];
    let real_ok: u64 = k.rows.iter().map(|r| r.real.successes).sum();
    assert_eq!(
        vlm.real_vs_sim.as_ref().map(|p| (p.successes, p.trials)),
        Some((real_ok, 12))
    );
    assert_eq!(vlm.imagined_vs_sim.as_ref().map(|p| p.trials), Some(12));
    assert_eq!(
        vlm.imagined_vs_frame_judge.as_ref().map(|p| p.trials),
        Some(12)
    );
    let ranking = k.ranking.expect("statistics");
    assert_eq!(ranking.comparisons[0].policies.len(), 3);
    let judged = &ranking.comparisons[1];
    assert_eq!(judged.proxy, "world-model+vlm");
    // The fixture's verdicts depend on the task only: every policy gets R_S = 0.5, so r is
    // undefined and says why.
    assert!(judged.policies.iter().all(|p| p.proxy == 0.5));
    assert!(judged.pearson.undefined.is_some(), "{:?}", judged.pearson);
    assert!(stdout.contains("world-model+vlm against sim"), "{stdout}");
    assert!(out_dir.join("ranking-vlm.svg").is_file());
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(md.contains("| `put-block-in-bowl` | diffusion "), "{md}");
    assert!(md.contains("world-model-leak (ablation)"), "{md}");
    assert!(md.contains("training policies") && md.contains("ranked policies"));
    let svg = std::fs::read_to_string(out_dir.join("ranking.svg")).unwrap();
    assert!(svg.contains("<svg"));
    // The frame judge's reliability on the ranked episodes, beside the report.
    assert!(
        md.contains("### Reliability of the predicted probabilities"),
        "{md}"
    );
    let svg = std::fs::read_to_string(out_dir.join("ranking-reliability.svg")).unwrap();
    assert!(svg.contains("world-model (ECE "), "{svg}");
}

/// A task of the stacking group.
const STACKING: &str = "examples/tasks/stacking/build-two-block-tower.yaml";

/// The four oracles of [`eval`]: they train the world model; none of them may be ranked.
const TRAIN: &str = "oracle,oracle:noise=0.05,oracle:noise=0.01,oracle:noise=0.03";

/// A ladder small enough for a test: one run on 2 oracle episodes, kept at steps 10 and 20.
const LADDER: &str = r#"{"episodes": [2], "checkpoints": [10, 20], "max_steps": 480}"#;

/// [`eval`] ranking `learned` with the proxy settings `proxy` (no judge), and its report.
fn rank_served(
    out_dir: &std::path::Path,
    learned: &str,
    proxy: &str,
) -> (std::process::Output, Report) {
    let out = eval(
        out_dir,
        &[
            "--no-judge",
            "--policy",
            learned,
            "--rank-train-policies",
            TRAIN,
            "--proxy",
            proxy,
        ],
    );
    let report = std::fs::read_to_string(out_dir.join("report.json"))
        .map_err(|e| e.to_string())
        .and_then(|t| serde_json::from_str(&t).map_err(|e| e.to_string()))
        .unwrap_or_else(|e| panic!("{e}\n{}", String::from_utf8_lossy(&out.stderr)));
    (out, report)
}

#[test]
fn a_world_model_served_over_grpc_by_python_drives_the_ranking() {
    let dir = tempfile::tempdir().unwrap();
    let server = serve_script(
        dir.path(),
        "tests/python/world_models/trivial.py",
        &["--port", "0"],
        "world-model",
    );
    let module = torchscript(dir.path());
    let learned = format!("torchscript:path={},max_steps=480", module.display());
    let proxy = format!(
        r#"{{"judge_steps": 30, "external": {{"url": "{}", "timeout_ms": 20000}}}}"#,
        server.url
    );
    let out_dir = dir.path().join("out");
    let (out, report) = rank_served(&out_dir, &learned, &proxy);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let k = report.results.ranking.expect("a ranking section");
    assert!(k.errors.is_empty(), "{:?}", k.errors);
    assert_eq!(k.ranked_policies, [learned.as_str()]);
    let g = &k.groups[0];
    // The served model imagined, and was not trained: no RSSM step ran.
    assert!(
        g.world_model_name.contains("trivial") && g.world_model_name.contains(&server.url),
        "{}",
        g.world_model_name
    );
    assert_eq!(g.world_model.steps, 0);
    assert_eq!(
        g.predictions.len(),
        4,
        "2 tasks × 2 seeds of the ranked policy"
    );
    // The action test ran through the server too (the trivial model draws a square over the
    // first frame, so it errs against the real frames whatever the actions).
    let test = g.action_test.as_ref().expect("the action test");
    assert_eq!(test.episodes, 4);
    assert!(test.true_actions_mse > 0.0 && test.shuffled_actions_mse > 0.0);
    for p in &g.predictions {
        assert!(p.imagined_frames >= 2 && p.imagined_frames <= 21, "{p:?}");
    }
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(md.contains("trivial"), "{md}");

    // A world model that is down: the proxy is retried as a remote policy's episode is, then
    // reported as the group's ranking error naming the server; the real episodes stay counted.
    drop(server);
    let dead =
        r#"{"judge_steps": 30, "external": {"url": "http://127.0.0.1:9", "timeout_ms": 2000}}"#;
    let (_, report) = rank_served(&dir.path().join("dead"), &learned, dead);
    let k = report.results.ranking.expect("a ranking section");
    assert_eq!(k.errors.len(), 1, "{:?}", k.errors);
    let (group, error) = &k.errors[0];
    assert_eq!(group, "placement");
    assert!(
        error.contains("unavailable") && error.contains("127.0.0.1:9"),
        "{error}"
    );
    // 4 oracles and the ranked policy on 2 tasks × 2 seeds.
    assert_eq!(report.results.totals.episodes_completed, 20);
}

/// `python/assay-policy-kit/examples/torch_video_model.py serve` with `args`, on the torch of
/// scripts/setup-lerobot's environment.
fn serve_torch_model(
    dir: &std::path::Path,
    args: &[&str],
    log: &str,
) -> crate::real_policies::Served {
    let mut cmd = Command::new(lerobot_python());
    cmd.arg(repo().join("python/assay-policy-kit/examples/torch_video_model.py"))
        .args(["serve", "--port", "0"])
        .args(args);
    serve_command(
        cmd,
        &dir.join(format!("{log}.log")),
        "the kit's PyTorch video model (scripts/setup-lerobot installs torch; or set ASSAY_LEROBOT_PYTHON)",
    )
}

#[test]
fn a_pytorch_world_model_served_by_the_kit_drives_the_ranking_at_its_declared_interface() {
    let dir = tempfile::tempdir().unwrap();
    let module = torchscript(dir.path());
    let learned = format!("torchscript:path={},max_steps=480", module.display());
    let proxy = |url: &str| {
        format!(r#"{{"judge_steps": 30, "external": {{"url": "{url}", "timeout_ms": 60000}}}}"#)
    };

    // Assay's video network in PyTorch, 30 training steps on synthetic clips at start.
    let server = serve_torch_model(dir.path(), &["--train-steps", "30"], "torch");
    let out_dir = dir.path().join("out");
    let (out, report) = rank_served(&out_dir, &learned, &proxy(&server.url));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let k = report.results.ranking.expect("a ranking section");
    assert!(k.errors.is_empty(), "{:?}", k.errors);
    let g = &k.groups[0];
    assert!(
        g.world_model_name
            .contains("torch-video-model (277714 parameters")
            && g.world_model_name.contains(&server.url),
        "{}",
        g.world_model_name
    );
    assert_eq!(
        g.world_model.steps, 0,
        "a served model is not trained by Assay"
    );
    assert_eq!(
        g.predictions.len(),
        4,
        "2 tasks × 2 seeds of the ranked policy"
    );
    for p in &g.predictions {
        assert!(p.imagined_frames >= 2 && p.imagined_frames <= 21, "{p:?}");
    }
    // The action test ran through the PyTorch model: its frames follow the actions it is given,
    // so the true, shuffled and zero actions give three different errors.
    let test = g.action_test.as_ref().expect("the action test");
    assert_eq!(test.episodes, 4);
    let errors = [
        test.true_actions_mse,
        test.shuffled_actions_mse,
        test.zero_actions_mse,
    ];
    assert!(
        errors.iter().all(|e| e.is_finite() && *e > 0.0),
        "{errors:?}"
    );
    assert!(
        errors[0] != errors[1] && errors[0] != errors[2],
        "the PyTorch model ignores its actions: {errors:?}"
    );
    drop(server);

    // The same model declaring the interface of a 7-D, two-camera policy only: the TorchScript
    // policy (the original interface) is refused before anything is imagined, naming the model,
    // the policy and the field; the real episodes stay counted.
    let seven = "ee_delta/ee_pos+ee_quat+gripper/image:scene@224x224+wrist_image:wrist@224x224";
    let server = serve_torch_model(dir.path(), &["--declare", seven], "torch-7d");
    let (_, report) = rank_served(&dir.path().join("7d"), &learned, &proxy(&server.url));
    let k = report.results.ranking.expect("a ranking section");
    assert_eq!(k.errors.len(), 1, "{:?}", k.errors);
    let error = &k.errors[0].1;
    assert!(
        error.contains("world model 'torch-video-model")
            && error.contains(&format!("cannot imagine policy '{learned}'"))
            && error.contains(
                "action_space: the policy answers in tool_velocity, the model takes ee_delta"
            ),
        "{error}"
    );
    assert_eq!(report.results.totals.episodes_completed, 20);
}

/// The interface of [`eval_ranks_policies_at_a_seven_d_two_camera_interface`]: a scene and a wrist
/// camera at 32², the tool's position, orientation and gripper, 7-D end-effector deltas.
const SEVEN_D: &str =
    "space=ee_delta,cameras=image:scene@32+wrist:wrist@32,state=ee_pos+ee_quat+gripper";

#[test]
fn eval_ranks_policies_at_a_seven_d_two_camera_interface() {
    use crate::common::torchscript::seven_d_torchscript;
    use assay_model::policy::Interface;
    let dir = tempfile::tempdir().unwrap();
    // Two TorchScript policies at that interface: one reaches for the block, one stands still.
    let policies = [("reach", 0.5), ("still", 0.0)].map(|(name, gain)| {
        let module = seven_d_torchscript(dir.path(), name, gain);
        format!(
            "torchscript:path={},{SEVEN_D},max_steps=480",
            module.display()
        )
    });
    let proxy =
        format!(r#"{{"judge_steps": 30, "video": {{"steps": 30}}, "interface": "{SEVEN_D}"}}"#);
    let out_dir = dir.path().join("out");
    let out = eval(
        &out_dir,
        &[
            "--no-judge",
            "--policy",
            &policies[0],
            "--policy",
            &policies[1],
            "--rank-train-policies",
            TRAIN,
            "--proxy",
            &proxy,
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let report: Report =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();

    // Every episode's clip, the oracles' included, is at the interface: the scene camera as
    // its frames, the wrist camera as a view, 8 floats of state and 7 of action per frame.
    let mut clips = 0;
    for t in &report.results.tasks {
        for e in &t.episodes {
            let key = e.imagery.as_ref().and_then(|i| i.clip.clone()).unwrap();
            let bytes = std::fs::read(out_dir.join("artifacts").join(&key)).unwrap();
            let c = assay_model::clip::Clip::decode(&bytes).unwrap();
            assert_eq!(
                Interface::parse_args(&c.interface),
                Interface::parse_args(SEVEN_D),
                "{key}"
            );
            assert_eq!(
                (c.width, c.height, c.proprio_dims, c.action_dims),
                (32, 32, 8, 7)
            );
            assert_eq!(c.views.len(), 1);
            assert_eq!((c.views[0].name.as_str(), c.views[0].width), ("wrist", 32));
            // The oracle's tool moves: its end-effector deltas are not all zero.
            if e.policy == "oracle" {
                assert!(c.actions.chunks(7).any(|a| a[0].abs() + a[2].abs() > 1e-3));
            }
            clips += 1;
        }
    }
    assert_eq!(clips, 2 * 2 * 6, "2 tasks × 2 seeds × 6 policies");

    // The video model learned the oracles' clips at that interface, and each ranked policy
    // acted inside it at its own interface.
    let k = report.results.ranking.expect("a ranking section");
    assert!(k.errors.is_empty(), "{:?}", k.errors);
    assert_eq!(k.ranked_policies, policies);
    assert_eq!(k.config.as_ref().unwrap().interface, SEVEN_D);
    let g = &k.groups[0];
    let video = g.video_model.as_ref().expect("the video model imagined");
    assert_eq!(video.train_clips, 2 * 2 * 4, "the 4 oracles' episodes only");
    assert_eq!(
        g.predictions.len(),
        2 * 2 * 2,
        "2 tasks × 2 seeds × 2 ranked policies"
    );
    for p in &g.predictions {
        assert!(p.imagined_frames >= 2, "{p:?}");
    }
    let test = g.action_test.as_ref().expect("the action test");
    assert!(
        test.true_actions_mse.is_finite() && test.shuffled_actions_mse.is_finite(),
        "{test:?}"
    );
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(md.contains(SEVEN_D), "the report names the interface");

    // The run exported as a LeRobot dataset at the same interface, read from the episode files:
    // the real LeRobot loads both cameras, their frames are the clips' (within H.264's loss),
    // and the states and actions are the clips', value for value.
    let dataset = dir.path().join("dataset");
    let said = ok(&assay(&[
        "export".as_ref(),
        "lerobot".as_ref(),
        out_dir.as_os_str(),
        dataset.as_os_str(),
        "--interface".as_ref(),
        SEVEN_D.as_ref(),
    ]));
    assert!(said.contains(&format!("with {clips} episodes")), "{said}");
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dataset.join("meta/info.json")).unwrap()).unwrap();
    let f = &info["features"];
    assert_eq!(
        f["observation.images.wrist"]["shape"],
        serde_json::json!([32, 32, 3])
    );
    assert_eq!(
        f["observation.state"]["names"],
        serde_json::json!([
            "ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw", "gripper"
        ])
    );
    assert_eq!(
        f["action"]["names"],
        serde_json::json!(["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"])
    );
    let loaded = Command::new(lerobot_python())
        .arg(repo().join("tests/python/load_with_lerobot.py"))
        .args([&dataset, &out_dir])
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .unwrap();
    let loaded: serde_json::Value =
        serde_json::from_str(ok(&loaded).lines().last().unwrap_or_default()).unwrap();
    println!("LeRobotDataset at {SEVEN_D}: {loaded}");
    assert_eq!(
        loaded["cameras"],
        serde_json::json!(["image", "wrist"]),
        "{loaded}"
    );
    let frames = loaded["lerobot_frames"].as_u64().unwrap();
    assert_eq!(
        loaded["frames_compared_with_clips"].as_u64().unwrap(),
        2 * frames,
        "{loaded}"
    );
    assert_eq!(
        loaded["values_compared_with_clips"].as_u64().unwrap(),
        15 * frames,
        "{loaded}"
    );
}

#[test]
fn ranking_settings_that_cannot_work_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = eval(
        dir.path(),
        &["--no-judge", "--rank-train-policies", "oracle:noise=0.2"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("ranking settings: training policy")
            && stderr.contains("oracle:noise=0.2")
            && stderr.contains("is not one of the batch's policies"),
        "{stderr}"
    );
    let out = eval(
        dir.path(),
        &[
            "--no-judge",
            "--rank-train-policies",
            "oracle:noise=0.01",
            "--proxy",
            r#"{"threshold": 2}"#,
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("threshold: 2 is outside [0, 1]"),
        "{stderr}"
    );
    // The cross-family ablation fits the video model again: not with the RSSM.
    let out = eval(
        dir.path(),
        &[
            "--no-judge",
            "--rank-train-policies",
            "oracle:noise=0.01",
            "--proxy",
            r#"{"model": "rssm", "cross_family_ablation": true}"#,
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("cross_family_ablation") && stderr.contains("model = \"video\""),
        "{stderr}"
    );
    // Cross-fitting with one fold would imagine each policy by a model that saw it.
    let out = eval(
        dir.path(),
        &[
            "--no-judge",
            "--rank-train-policies",
            "oracle:noise=0.01",
            "--proxy",
            r#"{"cross_fit_folds": 1}"#,
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr
            .contains("cross_fit_folds: 1 fold would imagine every policy by a model that saw it"),
        "{stderr}"
    );
    // A scripted oracle cannot act inside a world model: ranking one is refused.
    let out = eval(
        dir.path(),
        &[
            "--no-judge",
            "--rank-train-policies",
            "oracle,oracle:noise=0.01",
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("oracle:noise=0.05")
            && stderr.contains("scripted oracle")
            && stderr.contains("cannot act inside a world model"),
        "{stderr}"
    );
}

/// A lab's client submits over gRPC, not through `assay eval`: the coordinator itself refuses a
/// batch one of whose seeds lies among its ladder's held-out seeds (they would not be held out),
/// naming the setting and the seed, and stores nothing of it; the same batch with the held-out
/// seeds moved past its own is taken.
#[test]
fn the_coordinator_refuses_a_batch_seed_among_the_held_out_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &[]);
    let request = |base: u64| pb::SubmitBatchRequest {
        name: "held-out".into(),
        tasks: documents(&["examples/tasks/placement/put-block-in-bowl.yaml"]),
        policies: vec![pb::PolicyRef {
            name: "oracle".into(),
        }],
        seeds: (0..4).collect(),
        ranking_json: serde_json::json!({
            "train_policies": ["oracle"],
            "ladder": {"episodes": [2], "held_out_seeds": 2, "held_out_seed_base": base},
        })
        .to_string(),
        ..Default::default()
    };
    runtime().block_on(async {
        let mut c = client(&addr).await;
        let e = c.submit_batch(request(3)).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
        assert!(
            e.message().contains(
                "ladder.held_out_seed_base: batch seed 3 is one of the held-out seeds 3..5"
            ),
            "{}",
            e.message()
        );
        let listed = c.list_batches(pb::ListBatchesRequest {}).await.unwrap();
        assert!(listed.into_inner().batches.is_empty());
        let taken = c.submit_batch(request(4)).await.unwrap().into_inner();
        let listed = c.list_batches(pb::ListBatchesRequest {}).await.unwrap();
        let ids: Vec<String> = listed
            .into_inner()
            .batches
            .into_iter()
            .map(|b| b.batch_id)
            .collect();
        assert_eq!(ids, std::slice::from_ref(&taken.batch_id));
        c.cancel_batch(pb::GetBatchRequest {
            batch_id: taken.batch_id,
        })
        .await
        .unwrap();
    });
}

/// Issue 45's shape end to end, small: two task groups, each with a ladder of both policy
/// families (U-Net and transformer diffusion, kept at two steps), ranked per group and pooled,
/// with the calibrated proxy wherever a group's training episodes have both outcomes, the
/// cross-fitted proxy, the object judge and the cross-family ablation.
#[test]
fn each_group_ranks_a_ladder_of_both_families_on_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(bin())
        .arg("eval")
        .args([TASKS[0], STACKING])
        .args(["--seeds", "3", "--no-diversity", "--no-judge"])
        .args(["--image-size", "160x120", "--quiet"])
        .args(["--policy", "oracle", "--policy", "oracle:noise=0.05"])
        .args(["--rank-train-policies", "oracle,oracle:noise=0.05"])
        .args([
            "--rank-ladder",
            r#"{"episodes": [3], "checkpoints": [5, 10], "train_checkpoints": [7],
                "max_steps": 480, "backbones": ["unet", "transformer"]}"#,
            "--proxy",
            r#"{"judge_steps": 20, "video": {"steps": 10, "object_weight": 1.0},
                "cross_family_ablation": true, "cross_fit_folds": 2, "object_judge": true}"#,
        ])
        .arg("--out")
        .arg(dir.path())
        .current_dir(repo())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: Report =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let k = report.results.ranking.expect("a ranking section");
    // 2 groups × 2 families × 2 ranked kept policies, each labelled by its family; the policy
    // each run kept at step 7 trains the proxy (2 groups × 2 families) and is never ranked.
    assert_eq!(k.ranked_policies.len(), 8, "{:?}", k.ranked_policies);
    assert_eq!(k.train_policies.len(), 2 + 4, "{:?}", k.train_policies);
    let label = |p: &String| {
        k.labels
            .iter()
            .find(|(q, _)| q == p)
            .map(|(_, l)| l.as_str())
    };
    for group in ["placement", "stacking"] {
        for family in ["diffusion", "transformer diffusion"] {
            for (step, policies) in [
                (5, &k.ranked_policies),
                (7, &k.train_policies),
                (10, &k.ranked_policies),
            ] {
                let want = format!("{family} 3 ep @ {step}, {group}");
                assert!(
                    policies.iter().any(|p| label(p) == Some(want.as_str())),
                    "{want}: {:?}",
                    k.labels
                );
            }
        }
    }
    // Ranked on the batch's seeds, the demonstrations' own among them: the report cautions.
    let seeds = k.ladder_seeds.as_ref().expect("the ladder's seeds");
    assert!(seeds.describe().0, "{seeds:?}");
    // Each group ranked on its own tasks, over its own ladder's 4 policies.
    let mut groups: Vec<&str> = k.per_group.iter().map(|g| g.group.as_str()).collect();
    groups.sort_unstable();
    assert_eq!(groups, ["placement", "stacking"]);
    for g in &k.per_group {
        let ranking = g.ranking.as_ref().unwrap_or_else(|| panic!("{g:?}"));
        let main = &ranking.comparisons[0];
        assert_eq!(main.proxy, "world-model");
        assert_eq!(main.policies.len(), 4, "{:?}", main.policies);
        assert!(main.calibration_mae.is_some());
        // The bar the trials' noise sets: both sides counted, so the rerun is defined, within
        // [-1, 1] with an interval around it.
        let rerun = main.retest.as_ref().unwrap_or_else(|| panic!("{main:?}"));
        assert!(rerun.mmrv.value.is_some(), "{rerun:?}");
        for e in [&rerun.pearson, &rerun.mmrv] {
            if let (Some(v), Some([lo, hi])) = (e.value, e.ci95) {
                assert!((-1.0..=1.0).contains(&v) && lo <= hi, "{e:?}");
            }
        }
        assert!(
            main.policies
                .iter()
                .all(|p| p.policy.ends_with(",max_steps=480"))
        );
    }
    // Reliability of the frame judge's probabilities: over every ranked episode the proxy
    // judged, then per group over that group's.
    let judged = |group: Option<&str>| -> u64 {
        k.groups
            .iter()
            .filter(|p| group.is_none_or(|g| p.group == g))
            .map(|p| p.predictions.len() as u64)
            .sum()
    };
    let curves: Vec<(Option<&str>, u64)> = k
        .reliability
        .iter()
        .filter(|c| c.source == "world-model")
        .map(|c| (c.group.as_deref(), c.reliability.predictions))
        .collect();
    assert_eq!(curves.len(), 3, "{curves:?}");
    for (group, predictions) in curves {
        assert_eq!(predictions, judged(group), "{group:?}");
    }
    // The calibration, where a group has one: fitted on its 12 training episodes (the training
    // policies' 6 and the training-only ladder policies' 6), read by every ranked prediction
    // and ranked as a proxy of its own.
    for p in &k.groups {
        match &p.calibration {
            Some(c) => {
                assert_eq!((c.episodes, c.folds), (12, 2), "{c:?}");
                // Its reliability where it was fitted: every one of those episodes, raw and
                // calibrated.
                let fit = c.train_reliability.as_ref().expect("the fit's reliability");
                assert_eq!((fit.raw.predictions, fit.calibrated.predictions), (12, 12));
                assert!(p.predictions.iter().all(|x| x.p_calibrated.is_some()));
                let per_group = k.per_group.iter().find(|g| g.group == p.group).unwrap();
                let proxies: Vec<&str> = per_group
                    .ranking
                    .as_ref()
                    .unwrap()
                    .comparisons
                    .iter()
                    .map(|c| c.proxy.as_str())
                    .collect();
                assert!(proxies.contains(&"world-model-calibrated"), "{proxies:?}");
            }
            None => assert!(p.predictions.iter().all(|x| x.p_calibrated.is_none())),
        }
    }
    // Whether `group`'s own ranking has a comparison of `proxy`.
    let ranks = |group: &str, proxy: &str| {
        k.per_group
            .iter()
            .find(|g| g.group == group)
            .and_then(|g| g.ranking.as_ref())
            .is_some_and(|r| r.comparisons.iter().any(|c| c.proxy == proxy))
    };
    // The cross-family ablation: per group one model per family, trained with the other
    // family's 6 ranked episodes (2 kept policies × 3 seeds) beside the 12 training ones, and a
    // verdict for every ranked episode, ranked per group as an ablation. (The families come in
    // the order their episodes were planned: whichever training finished first.)
    for p in &k.groups {
        let mut fits: Vec<(&str, &[String], u32)> = p
            .cross_family
            .iter()
            .map(|f| (f.family.as_str(), f.trained_with.as_slice(), f.train_clips))
            .collect();
        fits.sort_unstable();
        assert_eq!(
            fits,
            [
                ("transformer", &["unet".to_owned()][..], 18),
                ("unet", &["transformer".to_owned()][..], 18),
            ],
            "{}",
            p.group
        );
        assert!(p.predictions.iter().all(|x| x.cross_family.is_some()));
        assert!(ranks(&p.group, "world-model-cross-family"), "{}", p.group);
    }
    // Cross-fitting: per group two folds, each one ranked policy of each family (the ranked
    // steps dealt in turn), trained with the other fold's 6 ranked episodes beside the 12
    // training ones; every episode imagined by its fold's model, ranked per group as a proxy.
    for p in &k.groups {
        assert_eq!(p.cross_fit.len(), 2, "{}", p.group);
        for f in &p.cross_fit {
            assert_eq!((f.policies.len(), f.trained_with.len()), (2, 2), "{f:?}");
            assert!(
                f.policies.iter().all(|x| !f.trained_with.contains(x)),
                "{f:?}"
            );
            assert_eq!(f.train_clips, 18, "{f:?}");
        }
        assert!(p.predictions.iter().all(|x| x.cross_fit.is_some()));
        assert!(ranks(&p.group, "world-model-cross-fit"), "{}", p.group);
    }
    // The object judge: the render role's clips carried each scene's objects to the trainer,
    // whose video model predicted them; every ranked episode has its verdict, ranked per group
    // as a proxy of its own.
    for p in &k.groups {
        let accuracy = p.object_judge_train_accuracy;
        assert!(
            accuracy.is_some_and(|a| (0.0..=1.0).contains(&a)),
            "{accuracy:?}"
        );
        assert!(p.predictions.iter().all(|x| x.object_judge.is_some()));
        assert!(ranks(&p.group, "world-model-objects"), "{}", p.group);
    }
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("### Per task group"), "{md}");
    assert!(
        md.contains("## Policy ranking: world-model-objects against sim"),
        "{md}"
    );
    assert!(
        md.contains("## Policy ranking: world-model-cross-fit against sim"),
        "{md}"
    );
    assert!(
        md.contains("## Policy ranking: world-model-cross-family (ablation) against sim"),
        "{md}"
    );
    assert!(
        md.contains("| placement |") && md.contains("| stacking |"),
        "{md}"
    );
    assert!(
        md.contains("transformer diffusion 3 ep @ 10, stacking"),
        "{md}"
    );
}
