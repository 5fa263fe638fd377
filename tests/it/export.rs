//! `assay export`: a finished run as a LeRobotDataset, as TensorBoard scalars and as a W&B
//! offline run, read back by the readers a lab uses. Called by `eval::eval_runs_a_batch_on_a_local_cluster_and_writes_both_reports`
//! on its run (rendered episodes with 64-pixel dynamics clips), so no batch runs twice.

use std::path::Path;
use std::process::Command;

use crate::common::*;
use assay_report::report::Report;

fn python() -> String {
    std::env::var("ASSAY_TEST_PYTHON").expect(
        "ASSAY_TEST_PYTHON names the test Python (scripts/test sets it up: tests/python/requirements.txt)",
    )
}

/// `assay export lerobot RUN OUT EXTRA…`.
fn export_lerobot(run: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "export".as_ref(),
        "lerobot".as_ref(),
        run.as_os_str(),
        out.as_os_str(),
    ];
    args.extend(extra.iter().map(|a| std::ffi::OsStr::new(*a)));
    assay(&args)
}

/// Reads `dataset` with tests/python/read_lerobot.py against `run`: what it checked.
fn read_lerobot(dataset: &Path, run: &Path) -> serde_json::Value {
    let out = Command::new(python())
        .arg(repo().join("tests/python/read_lerobot.py"))
        .args([dataset, run])
        .output()
        .unwrap();
    serde_json::from_str(&ok(&out)).unwrap()
}

/// The LeRobot export of `run`, a finished `assay eval` folder whose episodes have dynamics clips
/// of 64 pixels: loads as the format says, its states and actions are the episode files' rows,
/// its frames are the clips' frames; filters work; broken episodes are left out by name while
/// the rest are written.
pub fn lerobot_export_of(run: &Path, r: &Report) {
    let tmp = tempfile::tempdir().unwrap();
    let dataset = tmp.path().join("dataset");
    let said = ok(&export_lerobot(run, &dataset, &["--size", "64"]));
    let episodes: Vec<_> = r.results.tasks.iter().flat_map(|t| &t.episodes).collect();
    assert!(
        said.contains(&format!("with {} episodes", episodes.len())),
        "{said}"
    );
    let checked = read_lerobot(&dataset, run);
    assert_eq!(checked["episodes"], episodes.len());
    // The real LeRobot (lerobot 0.4.4's LeRobotDataset, offline) loads it: its states and actions
    // are the frames table's, its decoded frames the clips' (H.264 within 4 of 255 a frame).
    let loaded = Command::new(crate::real_policies::lerobot_python())
        .arg(repo().join("tests/python/load_with_lerobot.py"))
        .args([&dataset, run])
        .env("HF_HUB_OFFLINE", "1")
        .output()
        .unwrap();
    let loaded: serde_json::Value =
        serde_json::from_str(ok(&loaded).lines().last().unwrap_or_default()).unwrap();
    println!("LeRobotDataset: {loaded}");
    assert_eq!(loaded["lerobot_episodes"], episodes.len(), "{loaded}");
    assert!(
        loaded["frames_compared_with_clips"].as_u64().unwrap() > 0,
        "{loaded}"
    );
    let with_clips = episodes
        .iter()
        .filter(|e| e.imagery.as_ref().is_some_and(|i| i.clip.is_some()))
        .count();
    assert!(
        with_clips > 0,
        "the run measured dynamics: its episodes have clips"
    );
    assert_eq!(
        checked["clips_compared"], with_clips,
        "every episode with a clip has the clip's frames, states and actions: {checked}"
    );

    // Only the oracle's successful episodes.
    let oracle = tmp.path().join("oracle");
    ok(&export_lerobot(
        run,
        &oracle,
        &[
            "--size",
            "32",
            "--fps",
            "20",
            "--policy",
            "oracle",
            "--successful",
        ],
    ));
    let wanted = episodes
        .iter()
        .filter(|e| e.policy == "oracle" && e.success)
        .count();
    assert_eq!(read_lerobot(&oracle, run)["episodes"], wanted);

    // Nothing matches: refused, and nothing is left in the folder.
    let none = tmp.path().join("none");
    let refused = export_lerobot(run, &none, &["--policy", "no-such-policy"]);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("none matches --policy"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    assert_eq!(std::fs::read_dir(&none).map_or(0, |d| d.count()), 0);

    // A rate the recorded rows do not divide into, and an odd frame size: refused with why.
    for (args, why) in [
        (["--fps", "7"], "--fps 7: physics.dt"),
        (
            ["--size", "63"],
            "--size 63: frames are an even number of pixels",
        ),
    ] {
        let out = export_lerobot(run, &tmp.path().join("refused"), &args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains(why),
            "{why}: {stderr}"
        );
    }

    // A folder that holds something is not written into.
    let refused = export_lerobot(run, &dataset, &[]);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("is not empty"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );

    // One episode file gone, another changed since the run: both left out, named by task, seed
    // and policy with the reason; the others are exported and read back as before.
    let (t0, t1) = (&r.results.tasks[0], &r.results.tasks[1]);
    let (gone, changed) = (&t0.episodes[0], &t1.episodes[0]);
    let gone_path = run.join("artifacts").join(&gone.artifact);
    let kept = tmp.path().join("kept.arrow");
    std::fs::rename(&gone_path, &kept).unwrap();
    let changed_path = run.join("artifacts").join(&changed.artifact);
    let original = std::fs::read(&changed_path).unwrap();
    let mut altered = original.clone();
    let mid = altered.len() / 2;
    altered[mid] ^= 0xff;
    std::fs::write(&changed_path, &altered).unwrap();
    let partial = tmp.path().join("partial");
    let out = export_lerobot(run, &partial, &["--size", "64"]);
    std::fs::rename(&kept, &gone_path).unwrap();
    std::fs::write(&changed_path, &original).unwrap();
    ok(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    for (t, e, why) in [
        (t0, gone, "No such file"),
        (t1, changed, "does not match its content address"),
    ] {
        let line = format!(
            "left out: task {} seed {} policy {}: ",
            t.id, e.seed, e.policy
        );
        assert!(
            stderr
                .lines()
                .any(|l| l.starts_with(&line) && l.contains(why)),
            "{line}…{why} in:\n{stderr}"
        );
    }
    let checked = read_lerobot(&partial, run);
    assert_eq!(checked["episodes"], episodes.len() - 2);
}

/// The TensorBoard export of `run`: tbparse reads the report's figures back at their steps.
pub fn tensorboard_export_of(run: &Path, r: &Report) {
    let tmp = tempfile::tempdir().unwrap();
    let logdir = tmp.path().join("tb");
    ok(&assay(&[
        "export".as_ref(),
        "tensorboard".as_ref(),
        run.as_os_str(),
        logdir.as_os_str(),
    ]));
    let out = Command::new(python())
        .arg(repo().join("tests/python/read_tensorboard.py"))
        .arg(&logdir)
        .output()
        .unwrap();
    let scalars: Vec<serde_json::Value> = serde_json::from_str(&ok(&out)).unwrap();
    let value = |tag: &str, step: i64| {
        scalars
            .iter()
            .find(|s| s["tag"] == tag && s["step"] == step)
            .and_then(|s| s["value"].as_f64())
            .unwrap_or_else(|| panic!("no scalar {tag} at step {step} in {scalars:?}"))
    };
    for p in &r.results.by_policy {
        let rate = p.success.rate.expect("episodes ran");
        assert!((value(&format!("success/{}", p.policy), 0) - rate).abs() < 1e-6);
    }
    for g in &r.results.groups {
        for p in &g.by_policy {
            let rate = p.success.rate.expect("episodes ran");
            let tag = format!("success/{}/{}", g.group, p.policy);
            assert!((value(&tag, 0) - rate).abs() < 1e-6, "{tag}");
        }
    }
    let d = r.results.diversity.as_ref().expect("diversity");
    for f in &d.dynamics {
        let tag = format!("diversity/dynamics/{}/eval_image_mse", f.group);
        let got = value(&tag, i64::from(f.budget));
        assert!(
            (got - f.eval_image_mse).abs() <= 1e-6 * f.eval_image_mse.abs().max(1.0),
            "{tag}: {got} vs {}",
            f.eval_image_mse
        );
    }
    let q = r.results.quality.as_ref().expect("judged");
    for j in &q.judges {
        let mean = j.completion.mean.expect("episodes judged");
        let tag = format!("quality/{}/completion", j.judge);
        assert!((value(&tag, 0) - mean).abs() < 1e-5, "{tag}");
    }
}

/// The W&B export of `run`: the real `wandb sync` (wandb 0.30's wandb-core reads the file)
/// uploads it to a stand-in for W&B's server (tests/python/sync_wandb.py), which receives the
/// run's config, a history row per step with the report's figures, and its summary.
pub fn wandb_export_of(run: &Path, r: &Report) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("wandb");
    let printed = ok(&assay(&[
        "export".as_ref(),
        "wandb".as_ref(),
        run.as_os_str(),
        out.as_os_str(),
        "--project".as_ref(),
        "assay-it".as_ref(),
    ]));
    let dirs: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    let name = dirs[0].file_name().unwrap().to_string_lossy().into_owned();
    assert!(name.starts_with("offline-run-"), "{name}");
    let run_id = name.rsplit('-').next().unwrap().to_owned();
    assert!(printed.contains(&run_id), "{printed}");
    let synced = Command::new(python())
        .arg(repo().join("tests/python/sync_wandb.py"))
        .arg(&dirs[0])
        .output()
        .unwrap();
    let got: serde_json::Value = serde_json::from_str(&ok(&synced)).unwrap();
    assert_eq!(got["exit_code"], 0, "wandb sync: {}", got["output"]);
    assert_eq!(got["complete"], true, "the run was never finished: {got}");
    assert_eq!(got["exitcode"], 0);
    assert_eq!(got["run"]["name"], run_id.as_str());
    assert_eq!(got["run"]["project"], "assay-it");
    assert_eq!(got["run"]["displayName"], r.run.batch_id.as_str());
    assert_eq!(got["config"]["batch_id"], r.run.batch_id.as_str());
    // The run's resolved settings travel as its config.
    assert!(got["config"]["policy"].is_array(), "{}", got["config"]);
    let history = got["history"].as_array().unwrap();
    let row = |step: i64| {
        history
            .iter()
            .find(|h| h["_step"] == step)
            .unwrap_or_else(|| panic!("no history row at step {step}: {history:?}"))
    };
    let close = |got: &serde_json::Value, want: f64, what: &str| {
        let got = got.as_f64().unwrap_or_else(|| panic!("{what}: {got}"));
        assert!(
            (got - want).abs() <= 1e-9 * want.abs().max(1.0),
            "{what}: {got} vs {want}"
        );
    };
    for p in &r.results.by_policy {
        let tag = format!("success/{}", p.policy);
        close(&row(0)[&tag], p.success.rate.unwrap(), &tag);
        close(&got["summary"][&tag], p.success.rate.unwrap(), &tag);
    }
    for g in &r.results.groups {
        for p in &g.by_policy {
            let tag = format!("success/{}/{}", g.group, p.policy);
            close(&row(0)[&tag], p.success.rate.unwrap(), &tag);
        }
    }
    let q = r.results.quality.as_ref().expect("judged");
    for j in &q.judges {
        let tag = format!("quality/{}/completion", j.judge);
        close(&row(0)[&tag], j.completion.mean.unwrap(), &tag);
    }
    // The diversity-against-budget curve: a row per budget, ascending, and the largest budget's
    // figure as the summary.
    let d = r.results.diversity.as_ref().expect("diversity");
    let steps: Vec<i64> = history
        .iter()
        .map(|h| h["_step"].as_i64().unwrap())
        .collect();
    assert!(steps.windows(2).all(|w| w[0] < w[1]), "{steps:?}");
    for f in &d.dynamics {
        let tag = format!("diversity/dynamics/{}/eval_image_mse", f.group);
        close(&row(i64::from(f.budget))[&tag], f.eval_image_mse, &tag);
        let last = d
            .dynamics
            .iter()
            .filter(|o| o.group == f.group)
            .map(|o| o.budget)
            .max();
        if last == Some(f.budget) {
            close(&got["summary"][&tag], f.eval_image_mse, &tag);
        }
    }
}

/// Real input: tasks of GenSim's own library (imported where it lies, the first three in name
/// order, their URDF assets read from the library) run with dynamics clips and exported as a
/// LeRobotDataset, which loads as the format says with every frame, state and action equal to
/// the run's.
#[cfg(feature = "trainer")]
#[test]
fn gensim_library_tasks_export_as_a_lerobot_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let tasks = crate::real_policies::corpus_tasks(dir.path(), 3);
    let run = dir.path().join("run");
    let assets = repo().join("../shared/corpora/gensim-library/assets");
    let mut args: Vec<&std::ffi::OsStr> = vec!["eval".as_ref()];
    args.extend(tasks.iter().map(|t| t.as_os_str()));
    args.extend(
        [
            "--seeds",
            "2",
            "--workers",
            "2",
            "--policy",
            "oracle",
            "--policy",
            "oracle:noise=0.05",
            "--no-judge",
            "--dynamics-budgets",
            "2",
            "--world-model",
            r#"{"steps": 10}"#,
            "--quiet",
        ]
        .iter()
        .map(std::ffi::OsStr::new),
    );
    args.extend([
        "--asset-root".as_ref(),
        assets.as_os_str(),
        "--out".as_ref(),
        run.as_os_str(),
    ]);
    ok(&assay(&args));
    let r: Report =
        serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    assert_eq!(r.results.tasks.len(), 3);
    assert!(r.results.tasks.iter().all(|t| t.pipeline == "gensim"));
    let episodes: Vec<_> = r.results.tasks.iter().flat_map(|t| &t.episodes).collect();
    assert_eq!(episodes.len(), 12);
    let dataset = dir.path().join("dataset");
    ok(&export_lerobot(&run, &dataset, &["--size", "64"]));
    let checked = read_lerobot(&dataset, &run);
    assert_eq!(checked["episodes"], episodes.len(), "{checked}");
    let with_clips = episodes
        .iter()
        .filter(|e| e.imagery.as_ref().is_some_and(|i| i.clip.is_some()))
        .count();
    assert!(with_clips > 0, "the run measured dynamics: {checked}");
    assert_eq!(checked["clips_compared"], with_clips, "{checked}");
}
