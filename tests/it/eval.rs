//! `assay eval`, the embedded default, as a user runs it: reports, invalid input, determinism.

use std::process::Command;

use crate::common::*;
use assay_report::report::Report;

fn eval(
    paths: &[&str],
    seeds: &str,
    out: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    let mut args = vec!["eval"];
    args.extend_from_slice(paths);
    args.extend_from_slice(&[
        "--seeds",
        seeds,
        "--workers",
        "2",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    args.extend_from_slice(extra);
    Command::new(bin())
        .args(&args)
        .current_dir(repo())
        .output()
        .unwrap()
}

/// An episode video: MP4 where ffmpeg is installed, else a GIF of 48 frames at half the image
/// size (640 × 480 by default) in which something moves.
fn check_video(out: &std::path::Path, key: &str) {
    let bytes = std::fs::read(out.join("artifacts").join(key)).unwrap();
    if key.ends_with(".mp4") {
        assert_eq!(&bytes[4..8], b"ftyp", "{key} is an MP4 file");
        return;
    }
    assert!(key.ends_with(".gif"), "{key}");
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut dec = opts.read_info(bytes.as_slice()).unwrap();
    assert_eq!((dec.width(), dec.height()), (320, 240), "{key}");
    let mut frames = Vec::new();
    while let Some(f) = dec.read_next_frame().unwrap() {
        frames.push(f.buffer.to_vec());
    }
    assert_eq!(frames.len(), 48, "{key}");
    assert_ne!(frames.first(), frames.last(), "{key}: nothing moved");
}

/// Asserts that a finished command exited 0, showing its stderr when it did not.
fn succeeded(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn read_report(out: &std::path::Path) -> Report {
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn eval_runs_a_batch_on_a_local_cluster_and_writes_both_reports() {
    let dir = tempfile::tempdir().unwrap();
    // The default world model trains 600 steps per fit; 30 keep this test short.
    let out = eval(
        &["tests/fixtures/small"],
        "3",
        dir.path(),
        &["--video", "--world-model", r#"{"steps": 30}"#],
    );
    succeeded(&out);
    let r = read_report(dir.path());
    assert_eq!(r.results.totals.episodes_completed, 12);
    assert_eq!(r.results.tasks.len(), 4);
    assert_eq!(r.run.state, "completed");
    assert_eq!(
        r.run.workers,
        [
            "local/judge-0",
            "local/trainer-0",
            "local/worker-0",
            "local/worker-1"
        ],
        "both sim worker processes ran episodes, the judge worker judged them, the trainer \
         worker measured diversity"
    );
    // By default: text diversity with minilm per group and for All, and a world model per group
    // and budget on the rendered clips (the quick profile's 4 and 8 episodes).
    let d = r.results.diversity.as_ref().expect("diversity");
    let text = d.text.as_ref().expect("text diversity");
    assert_eq!(text.models[0].name, "minilm");
    assert_eq!(text.rows.last().map(|r| r.group.as_str()), Some("All"));
    assert_eq!(text.rows.last().map(|r| r.n), Some(4));
    assert!(!d.dynamics.is_empty(), "{:?}", d.errors);
    // One task of 3 episodes per group: the 4-episode budget trains on all 3, and the larger
    // budget, which would repeat that fit, is not queued.
    assert_eq!(d.dynamics.len(), 4, "{:?}", d.errors);
    assert!(d.dynamics.iter().all(|f| f.eval_image_mse.is_finite()
        && (f.budget, f.train_episodes, f.eval_episodes, f.steps) == (4, 3, 3, 30)));
    // The embedded default judges every episode with the offline judge: both quality scores
    // for every task.
    let q = r.results.quality.as_ref().expect("quality");
    assert_eq!(q.judges.len(), 1);
    assert!(q.judges[0].offline);
    assert_eq!(q.judges[0].episodes_judged, 12);
    assert_eq!(q.tasks.len(), 4);
    for t in &q.tasks {
        assert_eq!((t.scene_alignment.n, t.completion.n), (15, 15), "{t:?}");
        assert!(t.errors.is_empty(), "{t:?}");
    }
    for t in &r.results.tasks {
        let [lo, hi] = t.success.ci95.unwrap();
        assert!(lo <= t.success.rate.unwrap() && t.success.rate.unwrap() <= hi);
    }
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(
        md.contains("## Success per group") && md.contains("small-stack-two-blocks"),
        "{md}"
    );

    // report.html: one self-contained file, opened in headless Chromium: no console error, no
    // failed or non-local request, no broken image; the screenshot of its overview is kept.
    let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
    for view in [
        "id=\"figure-4\"",
        "id=\"figure-3\"",
        "id=\"table-1\"",
        "id=\"table-2\"",
        "id=\"table-3\"",
        "id=\"ranking\"",
    ] {
        assert!(html.contains(view), "report.html has no {view}");
    }
    assert!(html.matches("<svg").count() >= 4, "figures drawn inline");
    for t in &r.results.tasks {
        assert!(html.contains(&format!("id=\"task-{}\"", t.id)), "{}", t.id);
    }
    match chromium_check(&dir.path().join("report.html"), "report-overview.png") {
        Some(page) => {
            assert!(
                page.is_clean(),
                "report.html in Chromium: {:?}",
                page.problems()
            );
            // Every task page shows its 4 scene views and 8 keyframes as thumbnails.
            assert_eq!(page.images, 4 * 12, "{page:?}");
            assert_eq!(page.broken_images, 0);
            assert!(page.title.contains("small"), "{}", page.title);
        }
        None => eprintln!("SKIPPED the Chromium check of report.html: no chromium installed"),
    }

    // Every episode file is in the artifact store under its hash, readable as Arrow IPC.
    for t in &r.results.tasks {
        for e in &t.episodes {
            let path = dir.path().join("artifacts").join(&e.artifact);
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(
                format!("episodes/{}.arrow", assay_spec::hash::sha256_hex(&bytes)),
                e.artifact
            );
            let reader =
                arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(bytes), None).unwrap();
            let meta = reader.schema().metadata().clone();
            assert_eq!(meta["assay.task_id"], t.id);
            assert_eq!(meta["assay.seed"], e.seed.to_string());
            assert_eq!(meta["assay.success"], e.success.to_string());
            let rows: usize = reader.map(|b| b.unwrap().num_rows()).sum();
            assert!(rows > 10);
        }
    }

    // Every episode has its pictures: 4 views of the initial scene, 8 keyframes, a contact sheet,
    // all PNGs in the artifact store, the sheet shown in report.md, the adapter recorded.
    for t in &r.results.tasks {
        for e in &t.episodes {
            let img = e
                .imagery
                .as_ref()
                .unwrap_or_else(|| panic!("{} seed {} has no imagery", t.id, e.seed));
            assert_eq!(
                img.views
                    .iter()
                    .map(|v| v.name.as_str())
                    .collect::<Vec<_>>(),
                ["top", "front", "oblique_left", "oblique_right"]
            );
            assert_eq!(img.keyframes.len(), 8);
            assert!(
                img.keyframes.windows(2).all(|k| k[0].step < k[1].step),
                "keyframes in order"
            );
            assert!(!img.adapter.is_empty());
            for key in img
                .views
                .iter()
                .map(|v| &v.artifact)
                .chain(img.keyframes.iter().map(|k| &k.artifact))
            {
                let png = std::fs::read(dir.path().join("artifacts").join(key)).unwrap();
                assert_eq!(&png[1..4], b"PNG", "{key}");
            }
            assert!(
                dir.path()
                    .join("artifacts")
                    .join(&img.contact_sheet)
                    .exists()
            );
            check_video(
                dir.path(),
                img.video.as_deref().expect("--video gives a video"),
            );
        }
        let first = t.episodes[0].imagery.as_ref().unwrap();
        assert!(
            md.contains(&format!("](artifacts/{})", first.contact_sheet)),
            "report.md shows {}'s contact sheet",
            t.id
        );
        assert!(
            md.contains(&format!("](artifacts/{})", first.video.as_ref().unwrap())),
            "report.md links {}'s video",
            t.id
        );
        for e in &t.episodes {
            let video = e.imagery.as_ref().and_then(|i| i.video.as_ref()).unwrap();
            assert!(
                html.contains(&format!("href=\"artifacts/{video}\"")),
                "report.html links {} seed {}'s video",
                t.id,
                e.seed
            );
        }
    }

    // And from Python, as a lab's own scripts read them.
    let python = std::env::var("ASSAY_TEST_PYTHON").expect(
        "ASSAY_TEST_PYTHON names a Python with pyarrow (scripts/test sets it up: tests/python/requirements.txt)",
    );
    let (task, e) = r
        .results
        .tasks
        .iter()
        .find_map(|t| t.episodes.first().map(|e| (t, e)))
        .unwrap();
    let out = Command::new(&python)
        .arg(repo().join("tests/python/read_episode.py"))
        .arg(dir.path().join("artifacts").join(&e.artifact))
        .output()
        .unwrap();
    succeeded(&out);
    let py: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // The flat table beside the report: one row per episode, the report's own values.
    let table = Command::new(&python)
        .arg(repo().join("tests/python/read_table.py"))
        .arg(dir.path().join("episodes.parquet"))
        .output()
        .unwrap();
    succeeded(&table);
    let table: serde_json::Value = serde_json::from_slice(&table.stdout).unwrap();
    let rows = table["rows"].as_array().unwrap();
    assert_eq!(rows.len() as u64, r.results.totals.episodes_planned);
    let mut from_table: Vec<(String, u64, String, bool, u64, String)> = rows
        .iter()
        .map(|row| {
            (
                row["task"].as_str().unwrap().to_owned(),
                row["seed"].as_u64().unwrap(),
                row["policy"].as_str().unwrap().to_owned(),
                row["success"].as_bool().unwrap(),
                row["steps"].as_u64().unwrap(),
                row["episode"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    let mut from_report: Vec<(String, u64, String, bool, u64, String)> = r
        .results
        .tasks
        .iter()
        .flat_map(|t| {
            t.episodes.iter().map(|e| {
                (
                    t.id.clone(),
                    e.seed,
                    e.policy.clone(),
                    e.success,
                    e.steps,
                    format!("artifacts/{}", e.artifact),
                )
            })
        })
        .collect();
    from_table.sort();
    from_report.sort();
    assert_eq!(from_table, from_report);
    assert!(rows.iter().all(|row| row["completed"] == true
        && row["group"].is_string()
        && dir.path().join(row["episode"].as_str().unwrap()).is_file()));
    assert_eq!(table["types"][4], "uint64", "seed: {:?}", table["types"]);
    // Each judge's scores of each episode (the mean over its repeats) beside its row.
    let q = r.results.quality.as_ref().expect("judged");
    let mut scored = 0;
    for t in &q.tasks {
        for e in &t.episodes {
            let row = rows
                .iter()
                .find(|row| {
                    row["task"] == t.task_id.as_str()
                        && row["seed"] == e.seed
                        && row["policy"] == e.policy.as_str()
                })
                .unwrap();
            let column = format!("{}.completion", t.judge);
            assert_eq!(row[&column].as_f64(), e.completion, "{column}");
            scored += 1;
        }
    }
    assert_eq!(
        scored,
        rows.len(),
        "every episode was judged and has its scores"
    );
    assert_eq!(py["task_id"], task.id.as_str());
    assert_eq!(py["seed"], e.seed);
    assert_eq!(py["success"], e.success);
    assert_eq!(py["columns"][0], "step");
    assert!(py["rows"].as_u64().unwrap() > 10);
    // Every object's final centre is above the table and finite.
    for (id, p) in py["final_positions"].as_object().unwrap() {
        let z = p[2].as_f64().unwrap_or_else(|| panic!("{id}: {p}"));
        assert!(z > 0.0 && z < 1.0, "{id} ends at z = {z}");
    }

    // The same run exported as a LeRobotDataset, as TensorBoard scalars and as a W&B offline run
    // (tests/it/export.rs).
    crate::export::lerobot_export_of(dir.path(), &r);
    crate::export::tensorboard_export_of(dir.path(), &r);
    crate::export::wandb_export_of(dir.path(), &r);
}

#[test]
fn invalid_specs_are_reported_by_task_field_and_reason_and_the_rest_runs() {
    let dir = tempfile::tempdir().unwrap();
    let out = eval(
        &["tests/fixtures/small", "tests/fixtures/invalid"],
        "2",
        dir.path(),
        &["--world-model", r#"{"steps": 10}"#],
    );
    assert!(
        out.status.success(),
        "the batch completes: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    let r = read_report(dir.path());
    assert_eq!(
        r.results.totals.episodes_completed, 8,
        "the 4 valid tasks ran"
    );
    let errs = &r.results.invalid_tasks;
    let find = |task: &str| {
        errs.iter()
            .find(|e| e.task.as_deref() == Some(task))
            .unwrap_or_else(|| panic!("no error for {task}: {errs:#?}"))
    };
    let e = find("invalid-negative-size");
    assert_eq!(e.path, "scene.objects[0].shape.box.half_extents[1]");
    assert!(
        e.reason.contains("between 0.001 and 5 m, got -")
            && e.origin.ends_with("negative-size.yaml"),
        "{e:?}"
    );
    let e = find("invalid-nan-pose");
    assert!(
        e.path.starts_with("scene.objects[0].pose.position[") && e.reason.contains("finite"),
        "{e:?}"
    );
    let e = find("invalid-unknown-field");
    assert!(
        e.path.ends_with("colour") && e.reason.contains("unknown field"),
        "{e:?}"
    );
    let e = find("invalid-bad-goal-ref");
    assert!(
        e.path.starts_with("goals[0]") && e.reason.contains("ghost_block"),
        "{e:?}"
    );
    let dup = errs
        .iter()
        .find(|e| e.reason.contains("duplicate task id"))
        .expect("duplicate id reported");
    assert_eq!(dup.path, "id");
    let broken = errs
        .iter()
        .find(|e| e.origin.ends_with("not-yaml.yaml"))
        .expect("broken YAML reported");
    assert!(!broken.reason.is_empty());
    assert_eq!(r.results.totals.invalid_tasks, 6);
    // The user sees each one on the terminal too, and --strict turns them into a failure.
    assert!(
        stderr.contains("invalid task invalid-negative-size"),
        "{stderr}"
    );
    let strict = eval(
        &["tests/fixtures/small", "tests/fixtures/invalid"],
        "1",
        dir.path(),
        &["--strict", "--no-diversity"],
    );
    assert!(!strict.status.success());
}

#[test]
fn the_same_batch_twice_gives_identical_results() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let out = eval(
        &[
            "tests/fixtures/small",
            "examples/tasks/piles/push-block-pile-into-zone.yaml",
        ],
        "3",
        a.path(),
        // Diversity included (short fits): world models are seeded and deterministic.
        &["--world-model", r#"{"steps": 30}"#],
    );
    succeeded(&out);
    // The second time from the first run's resolved configuration alone (into another folder).
    let resolved = a.path().join("config.toml");
    let written = std::fs::read_to_string(&resolved).unwrap();
    assert!(
        written.contains("[eval.world-model]") && written.contains("steps = 30"),
        "{written}"
    );
    let out = Command::new(bin())
        .args(["eval", "--config"])
        .arg(&resolved)
        .arg("--out")
        .arg(b.path())
        .current_dir(repo())
        .output()
        .unwrap();
    succeeded(&out);
    let (ra, rb) = (read_report(a.path()), read_report(b.path()));
    assert_eq!(
        serde_json::to_string_pretty(&ra.results).unwrap(),
        serde_json::to_string_pretty(&rb.results).unwrap()
    );
    // Timings and ids are the only difference.
    assert_ne!(ra.run.submitted_at_unix_ms, 0);
}

#[test]
fn a_malformed_nested_setting_is_refused_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("lab.toml");
    let out_dir = dir.path().join("out");
    // `assay eval tests/fixtures/small ARGS… --out OUT` fails with a message holding every one
    // of `want`, and writes nothing.
    let refused = |args: &[&str], want: &[&str]| {
        let out = Command::new(bin())
            .args(["eval", "tests/fixtures/small"])
            .args(args)
            .arg("--out")
            .arg(&out_dir)
            .current_dir(repo())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(want.iter().all(|w| err.contains(w)), "{err}");
        assert!(!out_dir.exists(), "nothing started, nothing written");
    };
    let file = config.to_str().unwrap();
    std::fs::write(
        &config,
        "[eval]\nseeds = 2\n\n[eval.world-model]\nsteps = 300\nimage_sise = 32\n",
    )
    .unwrap();
    refused(
        &["--config", file],
        &[
            &format!("configuration file {file}"),
            "[eval] world-model",
            "image_sise: unknown field `image_sise`",
        ],
    );
    // Settings that read well but that the coordinator would refuse: refused by the same check,
    // still before anything starts.
    refused(
        &[
            "--policy",
            "oracle",
            "--policy",
            "oracle:noise=0.02",
            "--rank-train-policies",
            "oracle",
        ],
        &["the batch's settings: ranking settings: policy \"oracle:noise=0.02\" is ranked"],
    );
    // A group the batch's tasks do not carry (a misspelt one, in the file), also before.
    std::fs::write(
        &config,
        "[eval]\nrank-train-policies = [\"oracle\"]\nrank-groups = [\"stakcing\"]\n\
         [eval.rank-ladder]\nepisodes = [2]\n",
    )
    .unwrap();
    refused(
        &["--config", file],
        &[
            "the batch's settings: ranking settings: groups: no task of the batch is in group \"stakcing\"",
        ],
    );
    // Held-out seeds that a batch seed falls among would not be held out.
    std::fs::write(
        &config,
        "[eval]\nseeds = 4\nrank-train-policies = [\"oracle\"]\n\
         [eval.rank-ladder]\nepisodes = [2]\nheld_out_seeds = 2\nheld_out_seed_base = 3\n",
    )
    .unwrap();
    refused(
        &["--config", file],
        &[
            "the batch's settings: ranking settings: ladder.held_out_seed_base: batch seed 3 is one \
             of the held-out seeds 3..5",
        ],
    );
}

/// The shapes and tools of issue 7 through the render role: an articulated drawer (its joint
/// moves in every drawn frame), a cube lifted by friction pads on a Panda (pads and arm drawn),
/// a swept heap of beans, and a wrench hung with a welded grasp — every episode rendered, judged
/// and successful.
#[test]
fn articulated_objects_arms_pads_and_piles_are_rendered_and_judged() {
    let dir = tempfile::tempdir().unwrap();
    let out = eval(
        &[
            "examples/tasks/articulated/open-drawer.yaml",
            "examples/tasks/robomimic/lift-cube.yaml",
            "examples/tasks/robomimic/hang-tool-on-stand.yaml",
            "examples/tasks/piles/sweep-bean-pile-into-zone.yaml",
        ],
        // Seeds 2 and 3 of the drawer once ended with the joint a hair past its limit, which the
        // renderer refused to draw.
        "4",
        dir.path(),
        &["--no-diversity"],
    );
    succeeded(&out);
    let r = read_report(dir.path());
    assert_each_episode_once(&r, 4, 4);
    for t in &r.results.tasks {
        assert!(t.success.successes >= 3, "{}: {:?}", t.id, t.failures);
        for e in &t.episodes {
            let img = e.imagery.as_ref().expect("rendered");
            assert_eq!(img.keyframes.len(), 8, "{}", t.id);
        }
    }
}

/// `assay eval` of `tests/fixtures/small` (4 tasks) with physics only, into `out`.
fn small_sim_eval(seeds: u32, workers: u32, out: &std::path::Path) -> Vec<String> {
    let (seeds, workers) = (seeds.to_string(), workers.to_string());
    [
        "eval",
        "tests/fixtures/small",
        "--seeds",
        &seeds,
        "--workers",
        &workers,
        "--roles",
        "sim",
        "--no-diversity",
        "--quiet",
        "--out",
    ]
    .iter()
    .map(|s| s.to_string())
    .chain([out.display().to_string()])
    .collect()
}

/// Files under `dir`, at any depth.
fn files_under(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |entries| {
        entries
            .flatten()
            .map(|e| {
                let p = e.path();
                if p.is_dir() { files_under(&p) } else { 1 }
            })
            .sum()
    })
}

/// SIGKILL of the whole `assay eval` mid-batch (its local coordinator and workers die with it),
/// then the same command again: it goes on with the same batch from its job store, finishes, and
/// its results equal a clean run's. An output folder holding another batch is refused, with
/// nothing of it removed.
#[test]
fn an_eval_killed_mid_batch_goes_on_from_its_job_store() {
    let dir = tempfile::tempdir().unwrap();
    let (out, clean) = (dir.path().join("out"), dir.path().join("clean"));
    let args = |out: &std::path::Path| small_sim_eval(6, 1, out);
    let mut run = Command::new(bin())
        .args(args(&out))
        .current_dir(repo())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Kill it once the batch is submitted and some, not all, of its 24 episodes are stored.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    let batch_id = loop {
        assert!(std::time::Instant::now() < deadline, "no episode finished");
        let marker: Option<serde_json::Value> = std::fs::read_to_string(out.join("assay-run.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
        let id = marker.and_then(|m| m["batch_id"].as_str().map(str::to_owned));
        if let Some(id) = id
            && files_under(&out.join("artifacts")) >= 2
        {
            break id;
        }
        assert!(
            run.try_wait().unwrap().is_none(),
            "eval ended before it was killed"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    run.kill().unwrap();
    run.wait().unwrap();
    // The local processes follow their parent (the kernel's parent-death signal).
    std::thread::sleep(std::time::Duration::from_secs(1));
    assert!(
        !out.join("report.json").exists(),
        "killed before it finished"
    );

    let again = Command::new(bin())
        .args(args(&out))
        .current_dir(repo())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success(), "{stderr}");
    assert!(stderr.contains("going on from the job store"), "{stderr}");
    let resumed = read_report(&out);
    assert_eq!(resumed.run.batch_id, batch_id, "the same batch went on");
    assert_eq!(resumed.results.totals.episodes_completed, 24);

    let fresh = Command::new(bin())
        .args(args(&clean))
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(fresh.status.success());
    assert_eq!(
        serde_json::to_value(&resumed.results).unwrap(),
        serde_json::to_value(&read_report(&clean).results).unwrap(),
        "a resumed run gives the clean run's results"
    );

    // Another batch into the same folder is refused, and nothing of the first is removed.
    let mut other = args(&out);
    other[3] = "2".into();
    let refused = Command::new(bin())
        .args(&other)
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        stderr.contains("holds an Assay run of another batch"),
        "{stderr}"
    );
    assert!(out.join("run/jobs.db").is_file() && out.join("report.json").is_file());
    // A task folder is never an output folder.
    let mut into_tasks = args(&out);
    *into_tasks.last_mut().unwrap() = "tests/fixtures/small".into();
    let refused = Command::new(bin())
        .args(&into_tasks)
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("among its tasks"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
}

/// SIGKILL of a local worker, then of the local coordinator, mid-`eval`: each is started again,
/// the command ends 0 with every episode in the report, the report says what happened, and its
/// results equal a clean run's on the same seeds.
#[test]
fn local_processes_killed_mid_batch_are_started_again_and_the_batch_finishes() {
    let dir = tempfile::tempdir().unwrap();
    let args = |out: &std::path::Path| small_sim_eval(8, 2, out);
    let clean = dir.path().join("clean");
    let fresh = Command::new(bin())
        .args(args(&clean))
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(fresh.status.success());
    let clean = read_report(&clean);
    for victim in ["worker", "coordinator"] {
        let out = dir.path().join(victim);
        let run = Command::new(bin())
            .args(args(&out))
            .current_dir(repo())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
        while files_under(&out.join("artifacts")) < 3 {
            assert!(std::time::Instant::now() < deadline, "no episode finished");
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        let pids = children(run.id(), victim);
        assert!(!pids.is_empty(), "no local {victim} process");
        nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(pids[0]),
            nix::sys::signal::Signal::SIGKILL,
        )
        .unwrap();
        let o = run.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{victim}: {stderr}");
        assert!(stderr.contains("starting it again"), "{victim}: {stderr}");
        let r = read_report(&out);
        assert_eq!(r.results.totals.episodes_completed, 32, "{victim}");
        assert!(
            r.run
                .events
                .iter()
                .any(|e| e.contains(victim) && e.contains("exited")),
            "{victim}: {:?}",
            r.run.events
        );
        assert_eq!(
            serde_json::to_value(&r.results).unwrap(),
            serde_json::to_value(&clean.results).unwrap(),
            "{victim}: the same results as a clean run"
        );
    }
}
