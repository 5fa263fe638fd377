//! Runs a GenSim task's `reset()` in a sandboxed Python subprocess (`gensim-recorder/recorder.py`,
//! built into the binary) and reads back what it recorded. Nothing of the task's output is
//! trusted: the answer is parsed as data with bounds, and the process runs
//!
//! - with an empty environment, standard input closed, its working directory the library;
//! - under limits the recorder sets on itself (hard limits, so they cannot be raised again)
//!   before the task's code is read: CPU time and address space ([`crate::CodeLimits`]), file
//!   size 0 (no byte can be written to a file), no new processes, no core file;
//! - killed after the limits' wall-clock time, its answer read up to [`MAX_ANSWER`] bytes;
//! - and, inside, behind the recorder's own guards (builtins without `open`/`exec`/`eval`, an
//!   import allow-list, an audit hook that stops the process on any write, process, socket or
//!   native call): see the recorder's docstring.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde::Deserialize;

/// The recorder, built in: nothing is written to disk to run it.
const RECORDER: &str = include_str!("../../gensim-recorder/recorder.py");
/// The largest answer read back.
const MAX_ANSWER: u64 = 16 << 20;

/// What `reset()` built for one seed.
#[derive(Debug, Clone, Deserialize)]
pub(crate) struct SeedRecord {
    pub seed: u64,
    pub class: String,
    pub objects: Vec<ObjectRecord>,
    pub goals: Vec<GoalRecord>,
    #[serde(default)]
    pub lang_goals: Vec<String>,
    pub pos_eps: f64,
    pub rot_eps: f64,
    pub ee: String,
    #[serde(default)]
    pub max_steps: Option<serde_json::Value>,
}

pub(crate) type RecordedPose = ([f64; 3], [f64; 4]);

#[derive(Debug, Clone, Deserialize)]
pub(crate) struct ObjectRecord {
    pub urdf: String,
    #[serde(default)]
    pub fill: BTreeMap<String, serde_json::Value>,
    pub pose: RecordedPose,
    pub category: String,
    pub color: Option<[f64; 3]>,
    pub color_name: Option<String>,
    #[serde(default)]
    pub pile: bool,
}

#[derive(Debug, Clone, Deserialize)]
pub(crate) struct GoalRecord {
    pub objs: Vec<usize>,
    pub symmetries: Vec<f64>,
    pub matches: Vec<Vec<f64>>,
    pub targets: Vec<RecordedPose>,
    pub replace: bool,
    pub rotations: bool,
    pub metric: String,
    #[serde(default)]
    pub zones: Vec<(RecordedPose, Vec<f64>)>,
    #[serde(default)]
    pub matches_shape: Option<Vec<usize>>,
    /// What the goal is worth in GenSim's reward (a missing or unreadable value: 1).
    #[serde(default = "one")]
    pub step_max_reward: f64,
}

fn one() -> f64 {
    1.0
}

/// What one seed's `reset()` gave: a recording, or why there is none (a seed after the first
/// fails alone).
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub(crate) enum SeedOutcome {
    Failed { seed: u64, refused: Refusal },
    Built(Box<SeedRecord>),
}

impl SeedOutcome {
    pub fn seed(&self) -> u64 {
        match self {
            SeedOutcome::Failed { seed, .. } => *seed,
            SeedOutcome::Built(r) => r.seed,
        }
    }
}

#[derive(Debug, Deserialize)]
struct Answer {
    seeds: Option<Vec<SeedOutcome>>,
    #[serde(default)]
    stubbed: Vec<String>,
    /// The network namespace the recorder ran in (`net:[…]`).
    #[serde(default)]
    netns: Option<String>,
    refused: Option<Refusal>,
    error: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
pub(crate) struct Refusal {
    pub field: String,
    pub reason: String,
}

/// Why a task's code could not be recorded: the field (a call, `import`, `open`, `reset`) and
/// the reason.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Refused {
    pub field: String,
    pub reason: String,
}

impl Refused {
    /// The field and reason, cut to a readable length (they may come from the task's code).
    fn new(field: &str, reason: impl Into<String>) -> Self {
        let cut = |s: &str, n: usize| -> String {
            if s.chars().count() <= n {
                s.to_owned()
            } else {
                format!("{}…", s.chars().take(n).collect::<String>())
            }
        };
        Refused {
            field: cut(field, 120),
            reason: cut(&reason.into(), 600),
        }
    }
}

/// The Python that runs task code: `ASSAY_PYTHON`, else the environment `scripts/setup-python`
/// installs (`~/.cache/assay/python`, numpy in it) when it is there, else `python3` on the
/// `PATH`.
pub(crate) fn python() -> String {
    python_from(
        std::env::var("ASSAY_PYTHON").ok(),
        std::env::var_os("HOME").map(std::path::PathBuf::from),
    )
}

/// Where Assay's own Python environment lives under a home folder.
pub const PYTHON_ENV: &str = ".cache/assay/python";

/// [`python`] given the value of `ASSAY_PYTHON` and the home folder.
pub(crate) fn python_from(named: Option<String>, home: Option<std::path::PathBuf>) -> String {
    if let Some(p) = named.filter(|p| !p.is_empty()) {
        return p;
    }
    home.map(|h| h.join(PYTHON_ENV).join("bin/python"))
        .filter(|p| p.is_file())
        .map_or_else(|| "python3".into(), |p| p.display().to_string())
}

/// What the recorder answered: each seed asked, and the imports outside the allow-list the
/// code made and never used (stubbed).
#[derive(Debug, Clone)]
pub(crate) struct Recording {
    pub seeds: Vec<SeedOutcome>,
    pub stubbed: Vec<String>,
    /// The network namespace the recorder ran in, as it said.
    pub netns: Option<String>,
}

/// The OS boundary the recorder runs behind where the kernel allows it: util-linux's
/// `unshare` gives it a network namespace of its own (no interface but a loopback that is
/// down), in a user namespace of its own where the process is not root (an unprivileged user
/// may make one there; no ids are mapped, so its files stay its files). Then it executes the
/// recorder in place.
fn unshare_args() -> &'static [&'static str] {
    // Root may make a network namespace directly.
    let root = std::fs::metadata("/proc/self").is_ok_and(|m| {
        use std::os::unix::fs::MetadataExt;
        m.uid() == 0
    });
    if root {
        &["--net", "--"]
    } else {
        &["--user", "--net", "--"]
    }
}

/// `program` with its folder: as found on the `PATH` where it names none (the recorder runs
/// with an empty environment, behind `unshare`).
fn absolute(program: &str) -> String {
    if program.contains('/') {
        return program.to_owned();
    }
    std::env::var_os("PATH")
        .iter()
        .flat_map(std::env::split_paths)
        .map(|d| d.join(program))
        .find(|p| p.is_file())
        .map_or_else(|| program.to_owned(), |p| p.display().to_string())
}

/// Whether the recorder can run behind the OS boundary here (probed once: `unshare` runs
/// `true` in a network namespace of its own). `Err` says why not (no `unshare`, or a kernel or
/// container that refuses namespaces to this user); the recorder then runs behind its Python
/// guards and rlimits only, and `assay doctor` says so.
pub fn boundary() -> Result<(), String> {
    static ANSWER: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    ANSWER
        .get_or_init(|| {
            let out = Command::new("unshare")
                .args(unshare_args())
                .arg("true")
                .env_clear()
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .output();
            match out {
                Ok(o) if o.status.success() => Ok(()),
                Ok(o) => Err(format!(
                    "unshare {} true: {} ({}): the kernel or the container refuses a network \
                     namespace to this user",
                    unshare_args().join(" "),
                    o.status,
                    String::from_utf8_lossy(&o.stderr).trim()
                )),
                Err(e) => Err(format!("cannot run unshare (util-linux): {e}")),
            }
        })
        .clone()
}

/// Records `reset()` of the task in `task_file` for each of `seeds`: the first seed's failure
/// is the task's (`Err`), another's is that seed's alone.
pub(crate) fn record(
    assets: &Path,
    library: &Path,
    task_file: &Path,
    seeds: &[u64],
    limits: crate::CodeLimits,
) -> Result<Recording, Refused> {
    let crate::CodeLimits {
        cpu_seconds,
        wall_seconds,
        memory_bytes,
    } = limits;
    // Absolute paths: the recorder runs in the library, not where Assay was started.
    let canonical = |p: &Path| {
        p.canonicalize()
            .map_err(|e| Refused::new("code", format!("{}: {e}", p.display())))
    };
    let (assets, library, task_file) = (
        canonical(assets)?,
        canonical(library)?,
        canonical(task_file)?,
    );
    if !task_file.starts_with(&library) {
        return Err(Refused::new(
            "code",
            format!("{} leads out of the library", task_file.display()),
        ));
    }
    let python = absolute(&python());
    // Under the Python guards, the OS boundary where the kernel allows it (`boundary`): no
    // socket reaches anything, whatever path the code finds to one.
    let mut cmd = if boundary().is_ok() {
        let mut c = Command::new("unshare");
        c.args(unshare_args()).arg(&python);
        c
    } else {
        Command::new(&python)
    };
    cmd.arg("-I")
        .arg("-c")
        .arg(RECORDER)
        .arg(&assets)
        .arg(&library)
        .arg(&task_file)
        .args(seeds.iter().map(u64::to_string))
        .env_clear()
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("OMP_NUM_THREADS", "1")
        .env("MKL_NUM_THREADS", "1")
        .env("LC_ALL", "C.UTF-8")
        .env("ASSAY_RECORDER_PYTHON", &python)
        .env("ASSAY_RECORDER_CPU_SECONDS", cpu_seconds.to_string())
        .env("ASSAY_RECORDER_MEMORY_BYTES", memory_bytes.to_string())
        .current_dir(&library)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null());

    let mut child = cmd.spawn().map_err(|e| {
        Refused::new(
            "python",
            format!(
                "cannot start '{python}' ({e}): GenSim task code runs in a sandboxed Python 3 \
                 with numpy; install one or set ASSAY_PYTHON"
            ),
        )
    })?;
    let mut stdout = child.stdout.take().expect("piped");
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = (&mut stdout).take(MAX_ANSWER).read_to_end(&mut buf);
        buf
    });
    let start = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break Some(status),
            Ok(None) if start.elapsed() >= Duration::from_secs(wall_seconds) => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return Err(Refused::new("reset", format!("waiting for Python: {e}"))),
        }
    };
    let out = reader.join().unwrap_or_default();
    let Some(status) = status else {
        return Err(Refused::new(
            "reset",
            format!("did not finish within {wall_seconds} s of wall-clock time (stopped)"),
        ));
    };
    let answer: Option<Answer> = serde_json::from_slice(&out).ok();
    match answer {
        Some(Answer {
            refused: Some(r), ..
        }) => Err(Refused::new(&r.field, r.reason)),
        Some(Answer { error: Some(e), .. }) => Err(Refused::new("python", e)),
        Some(Answer {
            seeds: Some(seeds),
            stubbed,
            netns,
            ..
        }) if status.success() => Ok(Recording {
            netns: netns.map(|n| n.chars().take(40).collect()),
            seeds,
            stubbed: stubbed
                .into_iter()
                .take(50)
                .map(|s| s.chars().take(100).collect())
                .collect(),
        }),
        _ => {
            use std::os::unix::process::ExitStatusExt;
            let why = match status.signal() {
                Some(24) => format!("used more than {cpu_seconds} s of CPU time (stopped)"),
                Some(9) => "was killed (out of memory or time)".to_string(),
                Some(s) => format!("died of signal {s}"),
                None if out.len() as u64 >= MAX_ANSWER => {
                    format!("answered more than {MAX_ANSWER} bytes")
                }
                None => format!(
                    "exited with {status} without an answer the importer can read \
                     (is '{python}' a Python 3 with numpy?)"
                ),
            };
            Err(Refused::new("reset", why))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_python_named_wins_then_assay_s_own_environment_then_python3() {
        let home = tempfile::tempdir().unwrap();
        let at =
            |named: Option<&str>| python_from(named.map(str::to_owned), Some(home.path().into()));
        assert_eq!(at(None), "python3", "no environment yet");
        let bin = home.path().join(PYTHON_ENV).join("bin");
        std::fs::create_dir_all(&bin).unwrap();
        std::fs::write(bin.join("python"), "").unwrap();
        assert_eq!(at(None), bin.join("python").display().to_string());
        assert_eq!(at(Some("")), bin.join("python").display().to_string());
        assert_eq!(at(Some("/opt/py/bin/python3")), "/opt/py/bin/python3");
        assert_eq!(python_from(None, None), "python3");
    }
}
