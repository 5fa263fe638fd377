//! GenSim's own task library (`../shared/corpora/gensim-library`, read where it lies, never
//! copied, no task name special-cased): `assay import gensim --check-oracle 20` runs the inferred
//! oracle of every imported task on 20 seeds — each seed the layout the task's own `reset()`
//! built on it, its random poses drawn as GenSim draws them — and writes what it did into the
//! mapping report; the table of it is printed here. The goal is 90 % of the imported tasks
//! solved (every goal holding at the end) on at least 18 of the 20 seeds; 84 of 92 (91.3 %) are
//! (on seed 0's scene with jitter, 86 of 92), and GenSim's own reward is complete on at least 18
//! seeds for 87 of 92. The rest is code that asks for what cannot stand, draws that put two
//! structures in one place and targets beyond the arm (docs/gensim.md lists them by cause). This
//! test holds the goal, 90 %. `ASSAY_GENSIM_SEEDS=N` runs N seeds instead (the bar scales with
//! it).

use crate::common::*;

#[test]
fn gensim_library_oracles_solve_what_imports() {
    let root = repo().join("../shared/corpora/gensim-library");
    assert!(
        root.join("generated_tasks.json").exists(),
        "the GenSim corpus is not at {}",
        root.display()
    );
    let seeds: u64 = std::env::var("ASSAY_GENSIM_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let out = tempfile::tempdir().unwrap();
    let run = std::process::Command::new(bin())
        .args(["import", "gensim"])
        .arg(&root)
        .args(["--check-oracle", &seeds.to_string(), "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("import-report.json")).unwrap())
            .unwrap();
    let need = (seeds * 9).div_ceil(10);
    let prefix = "checked in the simulator: solves ";
    let (mut imported, mut solved) = (0, 0);
    println!("| group | task | oracle success (of {seeds}) | first failure |");
    println!("|---|---|---:|---|");
    for t in report["tasks"].as_array().unwrap() {
        if t["spec"].is_null() {
            continue;
        }
        imported += 1;
        let note = t["mapping"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["field"] == "oracle (checked)")
            .and_then(|m| m["note"].as_str())
            .unwrap_or_else(|| panic!("{}: no oracle check in its mapping report", t["id"]));
        let rest = note
            .strip_prefix(prefix)
            .unwrap_or_else(|| panic!("{note}"));
        let ok: u64 = rest.split(' ').next().unwrap().parse().unwrap();
        solved += usize::from(ok >= need);
        let first = rest.split_once("; seed ").map_or("", |(_, why)| why);
        let first: String = first.chars().take(300).collect();
        println!(
            "| {} | {} | {ok} | {} |",
            t["spec"]["group"].as_str().unwrap(),
            t["id"].as_str().unwrap(),
            if first.is_empty() {
                String::new()
            } else {
                format!("seed {first}")
            }
        );
    }
    println!("{solved} of {imported} imported tasks solved on at least {need} of {seeds} seeds");
    assert!(imported > 0, "nothing imported");
    assert!(
        solved * 10 >= imported * 9,
        "{solved} of {imported} imported tasks solved by their oracle on at least {need} of {seeds} seeds (the goal is 90 %)"
    );
}

/// Every imported task starts at rest: over the settle before a policy acts, no object on the
/// table is shoved aside or turned by another it was drawn into (generated code declares sizes
/// smaller than the assets it loads; the importer moves such objects clear, as PyBullet pushes
/// overlapping bodies apart), and none rocks (a mesh on a many-sided face once did: see
/// `face_plates` in the sim). Each seed starts where the task's code put its objects: one it
/// put in the air (its bottom over 5 mm above the table) drops, and one with nothing within
/// reach may find its rest on its hull; each may move up to 1 cm and turn up to 3°, and is
/// counted.
#[test]
fn gensim_library_tasks_start_at_rest() {
    let imp = gensim_library();
    let (mut checked, mut settled) = (0, 0);
    let mut shoved = Vec::new();
    for t in &imp.tasks {
        let Some(spec) = &t.spec else { continue };
        for seed in 0..3 {
            let spec = spec.for_seed(seed);
            let mut scene = assay_sim::scene::build_scene(&spec, seed).unwrap();
            let before: Vec<_> = scene.objects.iter().map(|o| scene.pose(o)).collect();
            for _ in 0..spec.physics.settle_steps {
                let at = scene.drive_arm(scene.gripper_position());
                scene.world.bodies[scene.gripper].set_next_kinematic_position(at);
                scene.hold_joints();
                scene.drive_fingers();
                scene.world.step();
            }
            for (k, (o, b)) in scene.objects.iter().zip(&before).enumerate() {
                let a = scene.pose(o);
                let moved = (a.translation - b.translation).truncate().length();
                let turned = a.rotation.angle_between(b.rotation).to_degrees();
                // Whether it started within reach of another object (their footprints' circles
                // meet): only then can it have been shoved.
                let near = scene
                    .objects
                    .iter()
                    .zip(&before)
                    .enumerate()
                    .any(|(q, (p, c))| {
                        let (r, s) = (o.half.truncate().length(), p.half.truncate().length());
                        q != k && (b.translation - c.translation).truncate().length() < r + s
                    });
                // A few millimetres are settling (a mesh finds its rest on its hull), a
                // centimetre for a body the code put in the air or one with nothing beside it;
                // an object drawn into the footprint of an asset
                // larger than its code declared is shoved 1 to 3 cm.
                let dropped = b.translation.z - o.half.z > 0.005;
                let settling = if dropped || !near { 0.01 } else { 0.005 };
                // Nothing turns more than 3° at rest: beside another object a turn is a shove,
                // alone it is a rock.
                if (moved > 0.005 && moved <= settling) || (turned > 1.0 && turned <= 3.0) {
                    settled += 1;
                }
                if moved > settling || turned > 3.0 {
                    shoved.push(format!(
                        "{} seed {seed}: '{}' moved {:.1} mm, turned {turned:.1}°",
                        t.id,
                        o.id,
                        moved * 1000.0
                    ));
                }
            }
            checked += 1;
        }
    }
    println!(
        "{checked} scenes settled; {settled} objects moved 5-10 mm or turned 1-3° (dropped or settling); {} objects shoved or rocking",
        shoved.len()
    );
    assert!(checked > 0);
    assert!(shoved.is_empty(), "{shoved:#?}");
}

/// `assay import gensim` with no `ASSAY_PYTHON` and no `python3` on the `PATH` runs GenSim's
/// task code in the environment `scripts/setup-python` makes under the home folder
/// (`~/.cache/assay/python`; here a home whose environment is the test virtual environment, which
/// has numpy): nothing to set up by hand. Without that environment the same command imports
/// nothing. Only where the Python comes from is in question here, so each task's code runs once
/// (`--layout-seeds none`; the default 23 layout seeds are [`gensim_library`]'s).
#[test]
fn gensim_import_finds_assay_s_own_python_without_settings() {
    let root = repo().join("../shared/corpora/gensim-library");
    let python = std::env::var("ASSAY_TEST_PYTHON")
        .expect("ASSAY_TEST_PYTHON names a Python with numpy (scripts/test sets it up)");
    // The virtual environment itself (a Python finds its environment from where it is run).
    let venv = std::path::Path::new(&python)
        .parent()
        .and_then(std::path::Path::parent)
        .expect("ASSAY_TEST_PYTHON is ENV/bin/python");
    let home = tempfile::tempdir().unwrap();
    let import = |home: &std::path::Path| {
        let run = std::process::Command::new(bin())
            .args(["import", "gensim"])
            .arg(&root)
            .args(["--layout-seeds", "none"])
            .env_remove("ASSAY_PYTHON")
            .env("PATH", "/nonexistent")
            .env("HOME", home)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&run.stdout).into_owned();
        let head = text.lines().next().unwrap_or_default().to_owned();
        let imported: usize = head
            .rsplit_once(", ")
            .and_then(|(_, n)| n.strip_suffix(" imported"))
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no import count in {head:?}\n{text}"));
        (imported, text)
    };
    let (none, _) = import(home.path());
    assert_eq!(
        none, 0,
        "without Assay's Python and no python3, no task code can run"
    );
    std::fs::create_dir_all(home.path().join(".cache/assay")).unwrap();
    std::os::unix::fs::symlink(venv, home.path().join(".cache/assay/python")).unwrap();
    let (imported, text) = import(home.path());
    assert!(imported >= 90, "{imported} imported:\n{text}");
}

/// Whether `px` is `color` under the renderer's shading (`color · k`, k the light on the face):
/// the pixel's deviation from the best `k · color` is small beside its brightness.
fn shade_of(px: &[u8; 3], color: [f32; 3]) -> bool {
    let p = px.map(|c| f32::from(c) / 255.0);
    let cc: f32 = color.iter().map(|c| c * c).sum();
    if cc < 1e-4 {
        return p.iter().all(|c| *c < 0.25);
    }
    let k = p.iter().zip(color).map(|(p, c)| p * c).sum::<f32>() / cc;
    let off: f32 = p
        .iter()
        .zip(color)
        .map(|(p, c)| (p - k * c).powi(2))
        .sum::<f32>()
        .sqrt();
    let norm: f32 = p.iter().map(|c| c * c).sum::<f32>().sqrt().max(0.05);
    (0.15..=1.4).contains(&k) && off / norm < 0.15
}

/// Every imported task is drawn in the colours its code gave (`add_object(..., color=...)`,
/// which PyBullet draws over the base link's material, the other links keeping theirs): in seed
/// 0's first frame, seen by the observation camera, of the pixels of each object the task
/// coloured, at least 80 % show that colour or a material of one of its other links under
/// shading, and of those at least one in four the task's colour (all of them for a one-link
/// asset) — not the base link's own material (GenSim's block, ball and zone assets are red and
/// green whatever the task says; its stand is five links, one recoloured).
#[test]
fn gensim_library_tasks_are_drawn_in_the_colours_their_code_gave() {
    use assay_spec::scene::FIRST_OBJECT_SEGMENT;
    let imp = gensim_library();
    let mut renderer = assay_render::Renderer::new().expect("an adapter");
    let camera = assay_spec::spec::Camera {
        width: 320,
        height: 240,
        ..assay_model::policy::observation_camera()
    };
    let (mut tasks, mut objects, mut hidden, mut uncoloured) = (0, 0, 0, 0);
    let mut wrong = Vec::new();
    for t in &imp.tasks {
        let Some(spec) = &t.spec else { continue };
        let spec = spec.for_seed(0);
        let scene = assay_sim::scene::build_scene(&spec, 0).unwrap();
        let snap = assay_sim::record::live_snapshot(&scene, &spec);
        let f = renderer
            .render_with(&snap, &camera, assay_render::Outputs::ALL)
            .unwrap();
        tasks += 1;
        // ASSAY_GENSIM_FRAMES=DIR keeps each task's frame, to look at.
        if let Some(dir) = std::env::var_os("ASSAY_GENSIM_FRAMES") {
            let png = assay_render::image::Rgb::from_frame(&f).png();
            std::fs::write(
                std::path::Path::new(&dir).join(format!("{}.png", t.id)),
                png,
            )
            .unwrap();
        }
        for (k, o) in snap.objects.iter().enumerate() {
            if !o.color_given {
                uncoloured += 1;
                continue;
            }
            let seg = FIRST_OBJECT_SEGMENT + k as u32;
            let px: Vec<[u8; 3]> = (0..f.segments.len())
                .filter(|&i| f.segments[i] == seg)
                .map(|i| [f.rgba[i * 4], f.rgba[i * 4 + 1], f.rgba[i * 4 + 2]])
                .collect();
            if px.len() < 30 {
                hidden += 1;
                continue;
            }
            objects += 1;
            // The materials of the base link (which the task's colour replaces) and of the
            // other links (which keep theirs).
            let (mut base, mut others): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (Vec::new(), Vec::new());
            if let assay_spec::spec::Shape::Urdf {
                path, fill, joints, ..
            } = &o.shape
            {
                let a = assay_spec::urdf::assemble_filled(
                    std::path::Path::new(path),
                    fill,
                    joints,
                    joints,
                )
                .unwrap();
                for (p, _) in &a.visuals {
                    if let Some(c) = p.color {
                        let to = if p.link == a.urdf.root() {
                            &mut base
                        } else {
                            &mut others
                        };
                        to.push([c[0], c[1], c[2]]);
                    }
                }
            }
            let (mut like, mut theirs, mut own) = (0, 0, 0);
            for p in &px {
                if shade_of(p, o.color) {
                    like += 1;
                } else if others.iter().any(|c| shade_of(p, *c)) {
                    theirs += 1;
                } else if base.iter().any(|c| shade_of(p, *c)) {
                    own += 1;
                }
            }
            let need = if others.is_empty() {
                like
            } else {
                like + theirs
            };
            if need * 10 < px.len() * 8 || own * 20 > px.len() {
                let mut seen = px.clone();
                seen.sort_unstable();
                wrong.push(format!(
                    "{} '{}' ({:?}): {like} of {} pixels its colour {:?}, {theirs} its other \
                     links', {own} its base link's own; e.g. {:?}",
                    t.id,
                    o.id,
                    o.shape,
                    px.len(),
                    o.color,
                    seen[seen.len() / 2]
                ));
            }
        }
    }
    println!(
        "{tasks} tasks: {objects} coloured objects checked, {hidden} hidden from the camera, \
         {uncoloured} given no colour by their task"
    );
    assert!(objects > 100, "only {objects} coloured objects seen");
    assert!(wrong.is_empty(), "{wrong:#?}");
}
