//! Generated task code is untrusted: a GenSim task that loops forever, allocates without bound,
//! reaches for processes, sockets or files, or writes one, is stopped or refused with the task,
//! the field and the reason, while the real tasks beside it in the same library import as they
//! do alone. The real tasks are entries of GenSim's own library (`../shared/corpora`), copied at
//! run time into a temporary library with the hostile ones.

use std::path::{Path, PathBuf};

use assay_import::{CodeLimits, ImportOptions, Pipeline, import};

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/corpora/gensim-library")
}

const HEADER: &str = "import numpy as np\nimport os\nfrom cliport.tasks.task import Task\nfrom cliport.utils import utils\n\n\nclass Hostile(Task):\n    def __init__(self):\n        super().__init__()\n\n    def reset(self, env):\n        super().reset(env)\n";

/// Hostile task bodies (inside `reset`), by name, with the words their refusal must contain.
fn hostile(out: &Path) -> Vec<(&'static str, String, &'static str)> {
    let file = out.display();
    vec![
        // Stopped by its CPU limit (or, on a machine too busy to give it 2 s of CPU in 10, by
        // the wall clock).
        (
            "loop-forever",
            "        while True:\n            pass\n".into(),
            "(stopped)",
        ),
        // Stopped by its address-space limit. `np.empty` claims address space without touching
        // it: with `np.ones` the page faults of filling 1 GiB took 0.1 to 1.6 s of CPU on a fresh
        // VM, and the CPU limit sometimes stopped it first.
        (
            "allocate-forever",
            "        keep = []\n        while True:\n            keep.append(np.empty(10**7))\n"
                .into(),
            "memory",
        ),
        (
            "os-system",
            format!("        os.system('touch {file}/os-system')\n"),
            "os.path only",
        ),
        (
            "import-subprocess",
            format!(
                "        import subprocess\n        subprocess.run(['touch', '{file}/subprocess'])\n"
            ),
            "imports 'subprocess'",
        ),
        (
            "import-socket",
            "        import socket\n        socket.create_connection(('127.0.0.1', 9))\n".into(),
            "imports 'socket'",
        ),
        (
            "open-for-writing",
            format!("        open('{file}/open', 'w').write('x')\n"),
            "may not open files",
        ),
        (
            "numpy-writes-a-file",
            format!("        np.save('{file}/numpy.npy', np.ones(3))\n"),
            "writes a file",
        ),
        (
            "escape-through-random",
            format!("        import random\n        random._os.system('touch {file}/escape')\n"),
            "os.system",
        ),
        (
            "escape-through-subclasses",
            format!(
                "        for c in ().__class__.__base__.__subclasses__():\n            if c.__name__ == '_wrap_close':\n                c.__init__.__globals__['system']('touch {file}/subclasses')\n"
            ),
            "os.system",
        ),
        (
            "reads-outside",
            "        np.loadtxt('/etc/hostname')\n".into(),
            "outside the library",
        ),
    ]
}

/// A library of `(name, code)` entries ([`assay_testkit::gensim::write_library`]).
fn write_library(root: &Path, entries: &[(String, String)]) {
    let tasks: Vec<assay_testkit::gensim::Task<'_>> = entries
        .iter()
        .map(|(name, code)| assay_testkit::gensim::Task {
            name,
            description: "d",
            assets: &[],
            code,
        })
        .collect();
    assay_testkit::gensim::write_library(root, &tasks);
}

#[test]
fn hostile_task_code_is_stopped_and_the_rest_imports() {
    let corpus = corpus();
    let library: serde_json::Map<String, serde_json::Value> = serde_json::from_str(
        &std::fs::read_to_string(corpus.join("generated_tasks.json")).unwrap(),
    )
    .unwrap();
    // The first four entries of the real library that have task code.
    let real: Vec<(String, String)> = library
        .keys()
        .filter_map(|name| {
            let code = corpus
                .join("generated_tasks")
                .join(format!("{}.py", name.replace('-', "_")));
            std::fs::read_to_string(code)
                .ok()
                .map(|c| (name.clone(), c))
        })
        .take(4)
        .collect();
    assert_eq!(real.len(), 4);
    let options = ImportOptions {
        asset_root: Some(corpus.join("assets")),
        limits: CodeLimits {
            cpu_seconds: 2,
            wall_seconds: 10,
            memory_bytes: 1 << 30,
        },
        ..ImportOptions::default()
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("written");
    std::fs::create_dir_all(&out).unwrap();

    let alone = tmp.path().join("alone");
    write_library(&alone, &real);
    let alone = import(Pipeline::Gensim, &alone, &options);
    let imported_alone: Vec<&str> = alone.specs().iter().map(|s| s.name.as_str()).collect();
    assert!(!imported_alone.is_empty(), "{:?}", alone.tasks[0].errors);

    let hostile = hostile(&out);
    let mut entries = real.clone();
    for (name, body, _) in &hostile {
        entries.push((name.to_string(), format!("{HEADER}{body}")));
    }
    let mixed = tmp.path().join("mixed");
    write_library(&mixed, &entries);
    let mixed = import(Pipeline::Gensim, &mixed, &options);
    let imported_mixed: Vec<&str> = mixed.specs().iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        imported_mixed, imported_alone,
        "the real tasks import as they do alone"
    );
    for (name, _, why) in &hostile {
        let t = mixed.tasks.iter().find(|t| t.name == *name).unwrap();
        assert!(t.spec.is_none(), "{name} was imported");
        let e = &t.errors[0];
        assert_eq!(e.task.as_deref(), Some(*name));
        assert!(!e.path.is_empty(), "{name}: no field");
        assert!(
            e.reason.contains(why),
            "{name}: refused as '{}: {}', wanted '{why}'",
            e.path,
            e.reason
        );
    }
    for (name, _, _) in &hostile {
        let t = mixed.tasks.iter().find(|t| t.name == *name).unwrap();
        println!("{name}: {}: {}", t.errors[0].path, t.errors[0].reason);
    }
    let written: Vec<_> = std::fs::read_dir(&out).unwrap().collect();
    assert!(written.is_empty(), "task code wrote {written:?}");
}

/// A leftover debug or plotting import that `reset()` never uses is stubbed (no module is
/// loaded) and noted in the mapping report; the same import used is refused, naming the
/// module and the use.
#[test]
fn unused_imports_outside_the_list_are_stubbed_and_used_ones_refused() {
    let corpus = corpus();
    let code =
        std::fs::read_to_string(corpus.join("generated_tasks/align_boxes_on_line.py")).unwrap();
    let leftover = format!(
        "import IPython\nimport matplotlib.pyplot as plt\nfrom pdb import set_trace\n{code}"
    );
    let used = leftover.replace(
        "super().reset(env)",
        "super().reset(env)\n        plt.figure()",
    );
    assert_ne!(used, leftover, "the task calls super().reset(env)");
    // A use the code catches is refused all the same.
    let caught = leftover.replace(
        "super().reset(env)",
        "super().reset(env)\n        try:\n            IPython.embed()\n        except Exception:\n            pass",
    );
    let tmp = tempfile::tempdir().unwrap();
    write_library(
        tmp.path(),
        &[
            ("leftover-imports".into(), leftover),
            ("used-import".into(), used),
            ("caught-use".into(), caught),
        ],
    );
    let imp = import(
        Pipeline::Gensim,
        tmp.path(),
        &ImportOptions {
            asset_root: Some(corpus.join("assets")),
            layout_seeds: Some(vec![0, 1]),
            ..ImportOptions::default()
        },
    );
    let leftover = imp
        .tasks
        .iter()
        .find(|t| t.name == "leftover-imports")
        .unwrap();
    assert!(leftover.spec.is_some(), "{:?}", leftover.errors);
    let stubbed: Vec<&str> = leftover
        .mapping
        .iter()
        .filter(|m| m.field == "import")
        .map(|m| m.note.as_str())
        .collect();
    for m in ["'IPython'", "'matplotlib.pyplot'", "'pdb'"] {
        assert!(
            stubbed
                .iter()
                .any(|n| n.starts_with(m) && n.contains("stubbed")),
            "{m}: {stubbed:?}"
        );
    }
    let used = imp.tasks.iter().find(|t| t.name == "used-import").unwrap();
    assert!(used.spec.is_none());
    let e = &used.errors[0];
    assert_eq!(e.path, "import");
    assert!(
        e.reason
            .contains("imports 'matplotlib' and uses 'matplotlib.pyplot.figure(...)'"),
        "{}",
        e.reason
    );
}

/// Where the kernel allows it, task code runs behind the OS boundary — a network namespace of its
/// own (no interface but a loopback that is down), Landlock, seccomp — under the Python guards,
/// and the mapping report says so; where a part does not hold, the report says which and why.
#[test]
fn task_code_runs_behind_the_os_boundary_where_the_kernel_allows() {
    let corpus = corpus();
    let code =
        std::fs::read_to_string(corpus.join("generated_tasks/align_boxes_on_line.py")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    write_library(tmp.path(), &[("align-boxes-on-line".into(), code)]);
    let imp = import(
        Pipeline::Gensim,
        tmp.path(),
        &ImportOptions {
            asset_root: Some(corpus.join("assets")),
            layout_seeds: Some(vec![0]),
            ..ImportOptions::default()
        },
    );
    let t = &imp.tasks[0];
    assert!(t.spec.is_some(), "{:?}", t.errors);
    let note = t
        .mapping
        .iter()
        .find(|m| m.field == "sandbox")
        .expect("the mapping report says how the code ran");
    let own = std::fs::read_link("/proc/self/ns/net").unwrap();
    let b = assay_import::gensim::boundary();
    if b.network.is_ok() {
        assert!(
            note.note.contains("network namespace of its own"),
            "{}",
            note.note
        );
        assert!(note.note.contains("net:["), "{}", note.note);
        assert!(
            !note.note.contains(&own.display().to_string()),
            "{}: the import's own namespace",
            note.note
        );
    }
    if b.filesystem.is_ok() {
        assert!(note.note.contains("Landlock ABI"), "{}", note.note);
    }
    if b.syscalls.is_ok() {
        assert!(note.note.contains("seccomp ("), "{}", note.note);
    }
    match b.missing() {
        None => assert!(
            note.note.contains("ran behind the OS boundary"),
            "{}",
            note.note
        ),
        Some(why) => {
            println!("part of the OS boundary is missing here: {why}");
            assert!(
                note.note.contains("behind part of the OS boundary"),
                "{}",
                note.note
            );
        }
    }
}

/// GenSim's `get_random_pose` keeps clear of what the scene shows, not of the size the code
/// declared for it: a pallet declared 0.15 m across whose asset is 0.30 × 0.25 m, then blocks
/// drawn with their 4 cm size, land clear of the pallet as drawn (by half their diagonal, less a
/// pixel of GenSim's grid), on every seed.
#[test]
fn random_poses_keep_clear_of_the_assets_as_drawn() {
    let code = r#"
import numpy as np
from cliport.tasks.task import Task
from cliport.utils import utils

class PalletThenBlocks(Task):
    def reset(self, env):
        super().reset(env)
        pallet_pose = self.get_random_pose(env, (0.15, 0.15, 0.02))
        env.add_object('pallet/pallet.urdf', pallet_pose, 'fixed')
        for _ in range(3):
            env.add_object('block/block.urdf', self.get_random_pose(env, (0.04, 0.04, 0.04)))
        self.add_goal(objs=[1], matches=np.ones((1, 1)), targ_poses=[pallet_pose], replace=False,
                      rotations=False, metric='pose', params=None, step_max_reward=1)
"#;
    let tmp = tempfile::tempdir().unwrap();
    write_library(tmp.path(), &[("pallet-then-blocks".into(), code.into())]);
    let seeds: Vec<u64> = (0..20).collect();
    let placed = assay_import::gensim::reset_objects(
        tmp.path(),
        &corpus().join("assets"),
        "pallet-then-blocks",
        &seeds,
    )
    .unwrap();
    // The pallet's mesh spans ±0.15 m in x and ±0.125 m in y about its origin.
    let (hx, hy) = (0.15, 0.125);
    let clear = (0.04f64.hypot(0.04)) / 2.0 - 0.003125;
    for (seed, objects) in seeds.iter().zip(placed) {
        let objects = objects.unwrap();
        let pallet = &objects[0];
        let q = pallet.rotation;
        let yaw =
            (2.0 * (q[3] * q[2] + q[0] * q[1])).atan2(1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]));
        for block in &objects[1..] {
            let (dx, dy) = (
                block.position[0] - pallet.position[0],
                block.position[1] - pallet.position[1],
            );
            let (lx, ly) = (
                yaw.cos() * dx + yaw.sin() * dy,
                -yaw.sin() * dx + yaw.cos() * dy,
            );
            // Distance from the block's centre to the pallet's rectangle.
            let out = ((lx.abs() - hx).max(0.0)).hypot((ly.abs() - hy).max(0.0));
            assert!(
                out >= clear,
                "seed {seed}: a block {:.1} mm from the pallet as drawn (at least {:.1})",
                out * 1000.0,
                clear * 1000.0
            );
        }
    }
}
