//! Policies as labs serve them, through the real cluster on GenSim's own library (imported where
//! it lies): one scripted policy written once in Python (`tests/python/policies/scripted.py`)
//! acts through an openpi websocket server built on the real `openpi-client` package's
//! msgpack-numpy, through the Python policy kit over gRPC, and as a TorchScript module with the
//! same arithmetic, and the three give identical episodes; servers that answer malformed actions,
//! fail, or whose space does not fit fail their episodes with a clear error while the batch goes
//! on; a LeRobot-style policy runs through the kit's adapter.
#![cfg(feature = "trainer")]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::common::torchscript::scripted_torchscript;
use crate::common::{bin, finish_eval, repo, spawn_eval};
use assay_report::report::Report;

/// The Python with the kit's dependencies (scripts/test's venv).
pub fn python() -> String {
    std::env::var("ASSAY_TEST_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// A Python test server kills itself with the test.
pub struct Served {
    child: Child,
    pub url: String,
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `tests/python/serve_policy.py --protocol P --policy NAME` on a free port.
pub fn serve_python(dir: &Path, protocol: &str, policy: &str) -> Served {
    serve_script(
        dir,
        "tests/python/serve_policy.py",
        &["--protocol", protocol, "--policy", policy, "--port", "0"],
        &format!("{protocol}-{policy}"),
    )
}

/// A Python test server (`script` with `args`) that prints `listening on URL` first; its
/// stderr goes to `dir/<log>.log`.
pub fn serve_script(dir: &Path, script: &str, args: &[&str], log: &str) -> Served {
    let mut cmd = Command::new(python());
    cmd.arg(repo().join(script)).args(args);
    serve_command(
        cmd,
        &dir.join(format!("{log}.log")),
        &format!(
            "{script} {args:?} (scripts/test installs the kit's dependencies; or set ASSAY_TEST_PYTHON)"
        ),
    )
}

/// A server started by `cmd` that prints `listening on URL` first; its stderr goes to `log`.
pub fn serve_command(mut cmd: Command, log: &Path, what: &str) -> Served {
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let url = match first.trim().strip_prefix("listening on ") {
        Some(url) => url.to_owned(),
        None => {
            let _ = child.kill();
            panic!(
                "{what}: {first:?}\n{}",
                std::fs::read_to_string(log).unwrap_or_default()
            );
        }
    };
    Served { child, url }
}

/// GenSim's library imported (`common::gensim_library`, once per test process) and its first `n`
/// specs in name order written into `dir/specs`.
pub fn corpus_tasks(dir: &Path, n: usize) -> Vec<PathBuf> {
    crate::common::write_gensim_specs(&dir.join("specs"), n)
}

/// `assay eval` of `tasks` with `policies` on `seeds` seeds (GenSim's assets readable), no judge
/// or diversity.
pub fn eval(dir: &Path, tasks: &[PathBuf], policies: &[&str], seeds: u32) -> Report {
    let assets = repo().join("../shared/corpora/gensim-library/assets");
    let child = spawn_eval(
        dir,
        tasks,
        policies,
        seeds,
        &["--asset-root".as_ref(), assets.as_os_str()],
    );
    finish_eval(child, Duration::from_secs(900), dir)
}

/// The record batches of an episode file, column by column (its metadata, which names the
/// policy, left out).
fn columns(dir: &Path, artifact: &str) -> Vec<Vec<arrow_array::ArrayRef>> {
    let file = std::fs::File::open(dir.join("out/artifacts").join(artifact)).unwrap();
    arrow_ipc::reader::FileReader::try_new(file, None)
        .unwrap()
        .map(|b| b.unwrap().columns().to_vec())
        .collect()
}

/// The scripted policy's interface, as a spec declares it (the gRPC server declares it in Health).
const SCRIPTED: &str = "space=ee_delta,cameras=image:scene@32,state=ee_pos+ee_yaw+holding";
/// 50 control steps an episode.
const STEPS: &str = "max_steps=1200";

#[test]
fn one_python_policy_acts_alike_over_openpi_the_grpc_kit_and_torchscript() {
    let dir = tempfile::tempdir().unwrap();
    let tasks = corpus_tasks(dir.path(), 3);
    let openpi = serve_python(dir.path(), "openpi", "scripted");
    let grpc = serve_python(dir.path(), "grpc", "scripted");
    let module = scripted_torchscript(dir.path());
    let a = format!("openpi:url={},{SCRIPTED},{STEPS}", openpi.url);
    let b = format!("remote:url={},{STEPS}", grpc.url);
    let c = format!("torchscript:path={},{SCRIPTED},{STEPS}", module.display());
    let report = eval(dir.path(), &tasks, &[&a, &b, &c], 2);
    assert_eq!(report.results.tasks.len(), 3);
    let mut moved = 0;
    for t in &report.results.tasks {
        assert!(t.failures.is_empty(), "{}: {:#?}", t.id, t.failures);
        for seed in 0..2 {
            let of = |p: &str| {
                t.episodes
                    .iter()
                    .find(|e| e.policy == p && e.seed == seed)
                    .unwrap_or_else(|| panic!("{}: no episode of {p} seed {seed}", t.id))
            };
            let (ea, eb, ec) = (of(&a), of(&b), of(&c));
            assert_eq!((ea.steps, ea.success), (eb.steps, eb.success));
            assert_eq!((ea.steps, ea.success), (ec.steps, ec.success));
            // The episode files agree column by column: every pose of every step.
            let batches = |e: &assay_report::report::EpisodeRow| columns(dir.path(), &e.artifact);
            let (ca, cb, cc) = (batches(ea), batches(eb), batches(ec));
            assert!(
                ca == cb,
                "{} seed {seed}: openpi and gRPC episodes differ",
                t.id
            );
            assert!(
                ca == cc,
                "{} seed {seed}: openpi and TorchScript episodes differ",
                t.id
            );
            // The policy moved the tool (columns 2 to 4 are its centre x, y, z).
            let travel: f32 = (2..5)
                .map(|k| {
                    let v: Vec<f32> = ca
                        .iter()
                        .flat_map(|b| {
                            b[k].as_any()
                                .downcast_ref::<arrow_array::Float32Array>()
                                .unwrap()
                                .values()
                                .to_vec()
                        })
                        .collect();
                    (v[v.len() - 1] - v[0]).powi(2)
                })
                .sum::<f32>()
                .sqrt();
            moved += usize::from(travel > 0.02);
        }
    }
    assert!(moved >= 4, "the tool moved in {moved} of 6 episodes");
}

#[test]
fn malformed_failing_or_misfit_policies_fail_their_episodes_and_the_batch_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let tasks = corpus_tasks(dir.path(), 1);
    let shape = serve_python(dir.path(), "openpi", "wrong_shape");
    let nan = serve_python(dir.path(), "grpc", "nan");
    let raises = serve_python(dir.path(), "openpi", "raises");
    let scripted = serve_python(dir.path(), "openpi", "scripted");
    let policies = [
        format!("openpi:url={},{SCRIPTED},{STEPS}", shape.url),
        format!("remote:url={},{STEPS}", nan.url),
        format!("openpi:url={},{SCRIPTED},{STEPS}", raises.url),
        // The server answers 7 floats; this spec says its space is ee_pose (8).
        format!(
            "openpi:url={},space=ee_pose,cameras=image:scene@32,state=ee_pos+ee_yaw+holding,{STEPS}",
            scripted.url
        ),
        "oracle".to_string(),
    ];
    let names: Vec<&str> = policies.iter().map(String::as_str).collect();
    let report = eval(dir.path(), &tasks, &names, 2);
    assert_eq!(report.run.state, "completed");
    let t = &report.results.tasks[0];
    let expect = [
        (0, "has 5 floats; its action space ee_delta takes 7"),
        (1, "non-finite"),
        (2, "policy exploded"),
        (3, "has 7 floats; its action space ee_pose takes 8"),
    ];
    for (i, needle) in expect {
        let failed: Vec<_> = t
            .failures
            .iter()
            .filter(|f| f.policy == policies[i])
            .collect();
        assert_eq!(failed.len(), 2, "{}: {:#?}", policies[i], t.failures);
        for f in failed {
            assert!(
                f.error.contains(needle) && f.error.contains("bad answer"),
                "{}: {}",
                policies[i],
                f.error
            );
            // Not retried: a bad answer is the policy's, not the cluster's.
            assert_eq!(f.attempts, 1, "{}", f.error);
        }
    }
    // The oracle's episodes are all there.
    assert_eq!(
        t.episodes.iter().filter(|e| e.policy == "oracle").count(),
        2
    );
}

#[test]
fn a_lerobot_style_policy_acts_through_the_kits_adapter_with_scene_and_wrist_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let tasks = corpus_tasks(dir.path(), 1);
    let server = serve_python(dir.path(), "grpc", "lerobot_standin");
    let policy = format!("remote:url={},{STEPS}", server.url);
    let report = eval(dir.path(), &tasks, &[&policy], 2);
    let t = &report.results.tasks[0];
    // The stand-in refuses a batch without LeRobot's keys, shapes and task string: episodes
    // that ran prove the adapter built them from both cameras and the state.
    assert!(t.failures.is_empty(), "{:#?}", t.failures);
    assert_eq!(t.episodes.len(), 2);
    assert!(t.episodes.iter().all(|e| e.steps >= 1200));
}

/// The kit's own checks (`tests/python/kit_selftest.py`): its stubs are what `generate_stubs.sh`
/// makes from `proto/assay/v1/policy.proto` today, both servers answer the real clients (gRPC
/// stubs, openpi-client's `WebsocketClientPolicy`) as the policy would, refuse what they should
/// (bad requests, missing tokens and API keys), and the LeRobot adapter builds LeRobot's batch.
#[test]
fn the_python_policy_kit_passes_its_self_test_against_the_real_clients() {
    let out = Command::new(python())
        .arg(repo().join("tests/python/kit_selftest.py"))
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    assert!(text.contains("11/11 checks passed"), "{text}");
}

/// `examples/tasks/<path>` carried by the Panda.
fn on_the_panda(dir: &Path, path: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let text = std::fs::read_to_string(repo().join("examples/tasks").join(path)).unwrap();
    let text = edit(text);
    assert!(!text.contains("\narm:"), "{path} has an arm already");
    let out = dir.join(Path::new(path).file_name().unwrap());
    std::fs::write(
        &out,
        format!("{}\narm: {{model: panda}}\n", text.trim_end()),
    )
    .unwrap();
    out
}

/// A 7-D end-effector-delta policy written in Python (`tests/python/policies/vision.py`), served
/// by the kit over gRPC, that finds everything through the top view and the wrist camera it asks
/// for (with depth) and reads its task from the instruction, solves a placement, a stacking and
/// a fixture task carried by the Panda. The fixture task is the example turned: its block starts
/// 40° off a fixture that fits it only square, so the policy must turn what it carries; the
/// same policy that never turns fails it.
#[test]
fn a_seeing_ee_delta_policy_places_stacks_and_turns_blocks_with_the_panda() {
    let dir = tempfile::tempdir().unwrap();
    let tasks = [
        on_the_panda(dir.path(), "placement/put-block-in-bowl.yaml", |t| t),
        on_the_panda(
            dir.path(),
            "stacking/bbsea-stack-green-cube-on-red-cube.yaml",
            |t| t,
        ),
        on_the_panda(
            dir.path(),
            "assembling/insert-block-into-fixture.yaml",
            |t| {
                let turned = t
                    .replace(
                        "pose: {position: [0.42, -0.1, 0.02]}",
                        "pose: {position: [0.42, -0.1, 0.02], yaw_deg: 40}",
                    )
                    .replace(
                        "inner_half_extents: [0.028, 0.028, 0.025]",
                        "inner_half_extents: [0.0235, 0.0235, 0.025]",
                    );
                assert_ne!(turned, t, "the fixture example changed");
                turned
            },
        ),
    ];
    let seeing = serve_python(dir.path(), "grpc", "vision");
    let stiff = serve_python(dir.path(), "openpi", "vision_no_turn");
    let a = format!("remote:url={},max_steps=4000", seeing.url);
    let b = format!(
        "openpi:url={},space=ee_delta,cameras=scene:top@128+wrist:wrist@64,depth=scene+wrist,\
         state=ee_pos+ee_yaw+holding,max_steps=4000",
        stiff.url
    );
    let report = eval(dir.path(), &tasks, &[&a, &b], 3);
    let mut table = Vec::new();
    for t in &report.results.tasks {
        assert!(t.failures.is_empty(), "{}: {:#?}", t.id, t.failures);
        let wins = |p: &str| {
            t.episodes
                .iter()
                .filter(|e| e.policy == p && e.success)
                .count()
        };
        table.push((t.id.clone(), wins(&a), wins(&b)));
    }
    println!("| task (Panda) | seeing ee_delta policy | the same, never turning |");
    for (id, a, b) in &table {
        println!("| {id} | {a}/3 | {b}/3 |");
    }
    for (id, won, stiff_won) in &table {
        assert_eq!(*won, 3, "{id}: the seeing policy solved {won} of 3");
        if id.contains("fixture") {
            assert_eq!(*stiff_won, 0, "{id}: solved without turning");
        }
    }
}

/// A space or camera that a task cannot give, declared in the policy's spec, is refused when the
/// batch is submitted, before anything runs, naming the policy, the task and the field.
#[test]
fn a_declared_space_a_task_cannot_fill_is_refused_before_the_batch_starts() {
    let task = repo().join("examples/tasks/placement/put-block-in-bowl.yaml");
    for (policy, field) in [
        (
            "openpi:url=ws://127.0.0.1:9,space=joint_position,state=joints",
            "action_space joint_position",
        ),
        (
            "torchscript:path=none.pt,space=ee_delta,cameras=image:overhead_left@64",
            "interface.cameras[0].source",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let out = Command::new(bin())
            .arg("eval")
            .arg(&task)
            .args([
                "--seeds",
                "1",
                "--policy",
                policy,
                "--no-judge",
                "--no-diversity",
            ])
            .arg("--out")
            .arg(dir.path().join("out"))
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!out.status.success(), "{policy}: {text}");
        assert!(
            text.contains(&format!(
                "policy '{policy}' does not fit task 'put-block-in-bowl'"
            )) && text.contains(field),
            "{policy}: {text}"
        );
    }
}

/// The Python of LeRobot's environment (`scripts/setup-lerobot`: lerobot 0.4.4 and PyPI's torch,
/// installed once): `ASSAY_LEROBOT_PYTHON`, which scripts/test sets, else the script's answer.
pub fn lerobot_python() -> String {
    if let Ok(py) = std::env::var("ASSAY_LEROBOT_PYTHON") {
        return py;
    }
    let out = Command::new(repo().join("scripts/setup-lerobot"))
        .stderr(Stdio::inherit())
        .output()
        .unwrap();
    assert!(out.status.success(), "scripts/setup-lerobot failed");
    String::from_utf8(out.stdout).unwrap().trim().to_owned()
}

/// The kit's `LeRobotAdapter` with the real LeRobot (`tests/python/lerobot_adapter_check.py`):
/// an ACT and a Diffusion checkpoint saved with dataset statistics and their processors, loaded
/// by `LeRobotAdapter.from_pretrained`, answer every step of an episode as LeRobot's own
/// evaluation pipeline does (its `preprocess_observation`, pre-processor, `select_action`,
/// post-processor) to 1e-5; the policy without its processors (the adapter before) does not; two
/// episodes over one loaded model, their steps in turn, answer as each would alone; the cameras,
/// their sizes and the action space come from the checkpoint.
#[test]
fn the_kit_s_lerobot_adapter_answers_as_lerobot_s_own_pipeline() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(lerobot_python())
        .arg(repo().join("tests/python/lerobot_adapter_check.py"))
        .arg(repo().join("python/assay-policy-kit/src"))
        .arg(dir.path())
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout.lines().last().unwrap_or_default();
    println!("{line}");
    let result: serde_json::Value = serde_json::from_str(line).unwrap();
    assert_eq!(result["lerobot"], "0.4.4");
    for kind in ["act", "diffusion"] {
        let r = &result[kind];
        assert!(r["max_abs_diff"].as_f64().unwrap() <= 1e-5, "{kind}: {r}");
        assert!(
            r["interleaved_max_abs_diff"].as_f64().unwrap() <= 1e-5,
            "{kind}: {r}"
        );
        assert!(
            r["without_processors_max_abs_diff"].as_f64().unwrap() > 1e-2,
            "{kind}: {r}"
        );
    }
}

/// A LeRobot checkpoint served by the kit's own command (`python -m assay_policy_kit lerobot
/// --checkpoint DIR`), in LeRobot's environment: Assay reads the interface it declares in Health
/// from the checkpoint (the top and wrist cameras at 64 px, 8 floats of state, 7-D `ee_delta`
/// actions) and runs two episodes at once through one loaded model on the Panda. (The ACT
/// checkpoint is untrained: what is checked is that it acts, not that it succeeds.)
#[test]
fn a_lerobot_checkpoint_served_by_the_kit_runs_in_assay_at_its_own_interface() {
    let dir = tempfile::tempdir().unwrap();
    let checkpoints = dir.path().join("checkpoints");
    std::fs::create_dir_all(&checkpoints).unwrap();
    let py = lerobot_python();
    let kit = repo().join("python/assay-policy-kit/src");
    let made = Command::new(&py)
        .arg(repo().join("tests/python/lerobot_adapter_check.py"))
        .arg(&kit)
        .arg(&checkpoints)
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let serve = |protocol: &str| {
        let mut cmd = Command::new(&py);
        cmd.args(["-m", "assay_policy_kit", "lerobot", "--checkpoint"])
            .arg(checkpoints.join("act"))
            .args([
                "--device",
                "cpu",
                "--state",
                "ee_pos+ee_quat+gripper",
                "--port",
                "0",
                "--serve",
                protocol,
            ])
            .env("PYTHONPATH", &kit)
            .env("HF_HUB_OFFLINE", "1");
        serve_command(
            cmd,
            &dir.path().join(format!("lerobot-serve-{protocol}.log")),
            "python -m assay_policy_kit lerobot",
        )
    };
    let served = serve("grpc");
    // What the server says about itself, as `assay policy check` reads it.
    let check = Command::new(bin())
        .args(["policy", "check", &served.url])
        .output()
        .unwrap();
    let health = String::from_utf8_lossy(&check.stdout).to_string();
    assert!(
        check.status.success(),
        "{health}{}",
        String::from_utf8_lossy(&check.stderr)
    );
    println!("{health}");
    let health: serde_json::Value = serde_json::from_str(&health).unwrap();
    let text = health.to_string();
    for want in ["lerobot-act", "ee_delta", "\"wrist\"", "\"top\"", "ee_quat"] {
        assert!(text.contains(want), "{want} not in {text}");
    }
    let task = on_the_panda(dir.path(), "placement/put-block-in-bowl.yaml", |t| t);
    let grpc = format!("remote:url={},{STEPS}", served.url);
    // The same checkpoint over openpi's protocol, which declares no interface: the spec gives
    // the one the gRPC server declared.
    let iface = &health["interface"];
    let cameras: Vec<String> = iface["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            format!(
                "{}:{}@{}x{}",
                c["name"].as_str().unwrap(),
                c["source"].as_str().unwrap(),
                c["width"],
                c["height"]
            )
        })
        .collect();
    let state: Vec<&str> = iface["state"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap())
        .collect();
    let openpi_served = serve("openpi");
    let openpi = format!(
        "openpi:url={},space={},cameras={},state={},{STEPS}",
        openpi_served.url,
        iface["action_space"].as_str().unwrap(),
        cameras.join("+"),
        state.join("+")
    );
    let report = eval(dir.path(), &[task], &[&grpc, &openpi], 2);
    let t = &report.results.tasks[0];
    assert!(t.failures.is_empty(), "{:#?}", t.failures);
    assert_eq!(t.episodes.len(), 4);
    assert!(
        t.episodes.iter().all(|e| e.steps >= 1200),
        "{:?}",
        t.episodes
    );
    // One checkpoint, one adapter, two protocols: the same episodes, row for row.
    for seed in 0..2 {
        let file = |policy: &str| {
            let e = t
                .episodes
                .iter()
                .find(|e| e.policy == policy && e.seed == seed)
                .unwrap_or_else(|| panic!("no episode of {policy} on seed {seed}"));
            columns(dir.path(), &e.artifact)
        };
        assert!(
            file(&grpc) == file(&openpi),
            "seed {seed}: the episodes differ"
        );
    }
}
