//! Runs a GenSim task's `reset()` in a sandboxed Python subprocess (`gensim-recorder/recorder.py`,
//! built into the binary) and reads back what it recorded. Nothing of the task's output is
//! trusted: the answer is parsed as data with bounds, and the process runs
//!
//! - with an empty environment, standard input closed, its working directory the library;
//! - under limits the recorder sets on itself (hard limits, so they cannot be raised again)
//!   before the task's code is read: CPU time and address space ([`crate::CodeLimits`]), file
//!   size 0 (no byte can be written to a file), no new processes, no core file;
//! - killed after the limits' wall-clock time, its answer read up to [`MAX_ANSWER`] bytes;
//! - behind an OS boundary where the kernel allows it ([`boundary`]): a network namespace of its
//!   own (util-linux `unshare`), a Landlock domain that reads the library, the assets, Python and
//!   the system libraries only and writes nowhere, and a seccomp filter that stops processes,
//!   program execution, sockets, tracing, mounts and namespaces; the recorder sets the last two
//!   on itself before the task's code is read (`confine` in the recorder);
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
    /// What of Landlock and seccomp the recorder set on itself.
    #[serde(default)]
    boundary: Option<Applied>,
    refused: Option<Refusal>,
    error: Option<String>,
}

/// What the recorder set of the kernel's confinement, as it said.
#[derive(Debug, Clone, Default, Deserialize)]
pub(crate) struct Applied {
    pub landlock: Option<Part>,
    pub seccomp: Option<Part>,
}

/// One part of the OS boundary: whether it holds, and what it stops (or why it does not).
#[derive(Debug, Clone, Deserialize)]
pub(crate) struct Part {
    pub on: bool,
    pub note: String,
}

impl Part {
    fn result(part: Option<&Part>) -> Result<String, String> {
        match part {
            Some(p) if p.on => Ok(cut(&p.note, 300)),
            Some(p) => Err(cut(&p.note, 300)),
            None => Err("the recorder did not say".into()),
        }
    }
}

fn cut(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_owned()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
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
    /// Landlock's domain over the files, as the recorder set it (or why not).
    pub filesystem: Result<String, String>,
    /// The seccomp filter over the system calls, as the recorder set it (or why not).
    pub syscalls: Result<String, String>,
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

/// The OS boundary GenSim task code runs behind on this machine: each part, or why it does not
/// hold here (the recorder then runs behind what does, its Python guards and rlimits always).
#[derive(Debug, Clone)]
pub struct Boundary {
    /// A network namespace of its own (util-linux `unshare`).
    pub network: Result<(), String>,
    /// A Landlock domain: reads the library, the assets, Python and system libraries; writes
    /// nowhere; no TCP.
    pub filesystem: Result<String, String>,
    /// A seccomp filter: no processes, program execution, sockets, tracing, mounts, namespaces.
    pub syscalls: Result<String, String>,
}

impl Boundary {
    /// Whether every part holds.
    pub fn whole(&self) -> bool {
        self.network.is_ok() && self.filesystem.is_ok() && self.syscalls.is_ok()
    }

    /// Why the parts that do not hold here do not, one line.
    pub fn missing(&self) -> Option<String> {
        let why: Vec<String> = [
            ("network namespace", self.network.as_ref().err()),
            ("Landlock", self.filesystem.as_ref().err()),
            ("seccomp", self.syscalls.as_ref().err()),
        ]
        .into_iter()
        .filter_map(|(part, e)| e.map(|e| format!("no {part} ({e})")))
        .collect();
        (!why.is_empty()).then(|| why.join("; "))
    }
}

/// What the OS boundary gives on this machine, probed once: `unshare` runs `true` in a network
/// namespace of its own, and the recorder (`--probe`) sets its limits, Landlock and seccomp on
/// itself behind it and says what held.
pub fn boundary() -> &'static Boundary {
    static ANSWER: std::sync::OnceLock<Boundary> = std::sync::OnceLock::new();
    ANSWER.get_or_init(|| {
        let network = network_namespace();
        let python = absolute(&python());
        let mut cmd = if network.is_ok() {
            let mut c = Command::new("unshare");
            c.args(unshare_args()).arg(&python);
            c
        } else {
            Command::new(&python)
        };
        let out = cmd
            .args(["-I", "-c", RECORDER, "--probe"])
            .env_clear()
            .env("LC_ALL", "C.UTF-8")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .output();
        let applied = match out {
            Ok(o) => match serde_json::from_slice::<Answer>(&o.stdout) {
                Ok(Answer {
                    boundary: Some(b), ..
                }) => Ok(b),
                Ok(Answer { error: Some(e), .. }) => Err(cut(&e, 300)),
                _ => Err(format!("'{python} --probe' gave no answer ({})", o.status)),
            },
            Err(e) => Err(format!("cannot start '{python}': {e}")),
        };
        match applied {
            Ok(a) => Boundary {
                network,
                filesystem: Part::result(a.landlock.as_ref()),
                syscalls: Part::result(a.seccomp.as_ref()),
            },
            Err(why) => Boundary {
                network,
                filesystem: Err(why.clone()),
                syscalls: Err(why),
            },
        }
    })
}

/// Whether `unshare` can give a process a network namespace of its own here.
fn network_namespace() -> Result<(), String> {
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
            "unshare {} true: {} ({}): the kernel or the container refuses a network namespace \
             to this user",
            unshare_args().join(" "),
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Err(e) => Err(format!("cannot run unshare (util-linux): {e}")),
    }
}

/// Which of the recorder's defences a run leaves out: none, outside the importer's own tests
/// (which show that the OS boundary holds without the Python guards, and that they can tell).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Defences {
    #[cfg(test)]
    pub without_python_guards: bool,
    #[cfg(test)]
    pub without_os_boundary: bool,
}

impl Defences {
    fn os_boundary(self) -> bool {
        #[cfg(test)]
        if self.without_os_boundary {
            return false;
        }
        true
    }

    fn apply(self, cmd: &mut Command) {
        #[cfg(test)]
        {
            if self.without_python_guards {
                cmd.env("ASSAY_RECORDER_TEST_UNGUARDED", "1");
            }
            if self.without_os_boundary {
                cmd.env("ASSAY_RECORDER_TEST_NO_BOUNDARY", "1");
            }
        }
        let _ = cmd;
    }
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
    record_with(
        assets,
        library,
        task_file,
        seeds,
        limits,
        Defences::default(),
    )
}

fn record_with(
    assets: &Path,
    library: &Path,
    task_file: &Path,
    seeds: &[u64],
    limits: crate::CodeLimits,
    defences: Defences,
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
    let mut cmd = if defences.os_boundary() && boundary().network.is_ok() {
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
        // glibc's heap keeps what numpy frees (the sampler's grids, a few hundred KB each,
        // every draw): mapped and unmapped each time, they tripled the import's time.
        .env("MALLOC_MMAP_THRESHOLD_", "16777216")
        .env("MALLOC_TRIM_THRESHOLD_", "67108864")
        .env("ASSAY_RECORDER_PYTHON", &python)
        .env("ASSAY_RECORDER_CPU_SECONDS", cpu_seconds.to_string())
        .env("ASSAY_RECORDER_MEMORY_BYTES", memory_bytes.to_string())
        .current_dir(&library)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    defences.apply(&mut cmd);

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
            boundary,
            ..
        }) if status.success() => Ok(Recording {
            netns: netns.map(|n| n.chars().take(40).collect()),
            filesystem: Part::result(boundary.as_ref().and_then(|b| b.landlock.as_ref())),
            syscalls: Part::result(boundary.as_ref().and_then(|b| b.seccomp.as_ref())),
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

    /// Task code that reaches for the world by paths the Python guards would stop: a socket to
    /// a listener on loopback, a read outside the library with Python's open and with numpy's
    /// C reader, a file written outside it, and a fork through ctypes. Each says how it went.
    const HOSTILE: &str = r#"
import json, os, socket, ctypes
import numpy as np
from cliport.tasks.task import Task

def attempt(f):
    try:
        f()
        return 'ok'
    except BaseException as e:
        return f"{type(e).__name__}({getattr(e, 'errno', None)})"

class Hostile(Task):
    def reset(self, env):
        out = {}
        def connect():
            s = socket.socket()
            s.settimeout(5)
            s.connect(('127.0.0.1', PORT))
            s.sendall(b'escaped')
        out['socket'] = attempt(connect)
        out['read'] = attempt(lambda: open(SECRET).read())
        out['numpy'] = attempt(lambda: np.fromfile(SECRET, dtype=np.uint8))
        out['write'] = attempt(lambda: open(WRITTEN, 'w').close())
        libc = ctypes.CDLL(None, use_errno=True)
        def fork():
            pid = libc.fork()
            if pid == 0:
                libc._exit(0)
            if pid < 0:
                raise OSError(ctypes.get_errno(), 'fork')
        out['fork'] = attempt(fork)
        raise RuntimeError('OUTCOME ' + json.dumps(out))
"#;

    /// With the Python guards off (this test build only), the OS boundary alone stops every one
    /// of them; with the boundary off too, the same code gets through — the test can tell.
    #[test]
    fn the_os_boundary_stops_hostile_code_without_the_python_guards() {
        if let Some(why) = boundary().missing() {
            if std::env::var("ASSAY_TEST_WITHOUT_OS_BOUNDARY").as_deref() == Ok("1") {
                println!("skipped, as asked: {why}");
                return;
            }
            panic!(
                "part of the OS boundary is missing on this machine: {why} (set \
                 ASSAY_TEST_WITHOUT_OS_BOUNDARY=1 to skip this test where the kernel lacks it)"
            );
        }
        let library = tempfile::tempdir().unwrap();
        let outside = tempfile::tempdir().unwrap();
        let secret = outside.path().join("secret.txt");
        std::fs::write(&secret, "not for task code").unwrap();
        let written = outside.path().join("written");
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let code = HOSTILE
            .replace("PORT", &listener.local_addr().unwrap().port().to_string())
            .replace("SECRET", &format!("{:?}", secret.display().to_string()))
            .replace("WRITTEN", &format!("{:?}", written.display().to_string()));
        let tasks = library.path().join("generated_tasks");
        std::fs::create_dir_all(&tasks).unwrap();
        std::fs::write(tasks.join("hostile.py"), code).unwrap();
        let run = |defences: Defences| -> BTreeMap<String, String> {
            let refused = record_with(
                library.path(),
                library.path(),
                &tasks.join("hostile.py"),
                &[0],
                crate::CodeLimits::default(),
                defences,
            )
            .expect_err("the task raises what it saw");
            let json = refused
                .reason
                .split_once("OUTCOME ")
                .and_then(|(_, r)| r.rsplit_once('}'))
                .map(|(j, _)| format!("{j}}}"))
                .unwrap_or_else(|| panic!("{refused:?}"));
            serde_json::from_str(&json).unwrap_or_else(|e| panic!("{e}: {refused:?}"))
        };

        let bounded = run(Defences {
            without_python_guards: true,
            without_os_boundary: false,
        });
        // seccomp answers EPERM (the rlimit on processes would say EAGAIN); Landlock EACCES.
        assert_eq!(bounded["socket"], "PermissionError(1)", "{bounded:?}");
        assert_eq!(bounded["fork"], "PermissionError(1)", "{bounded:?}");
        assert_eq!(bounded["read"], "PermissionError(13)", "{bounded:?}");
        assert_eq!(bounded["numpy"], "PermissionError(13)", "{bounded:?}");
        assert_eq!(bounded["write"], "PermissionError(13)", "{bounded:?}");
        assert!(!written.exists());
        assert!(
            listener.accept().is_err(),
            "nothing reached the listener through the boundary"
        );

        let open = run(Defences {
            without_python_guards: true,
            without_os_boundary: true,
        });
        for reach in ["socket", "read", "numpy", "write"] {
            assert_eq!(open[reach], "ok", "{reach} without any boundary: {open:?}");
        }
        assert!(written.exists());
        assert!(
            listener.accept().is_ok(),
            "the same code reaches it unbounded"
        );
    }

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
