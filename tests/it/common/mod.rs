//! Helpers for tests that run the real `assay` binary: processes with logs in a temp folder,
//! killed when dropped, and a gRPC client with deadlines everywhere.

#![allow(dead_code)]

#[cfg(feature = "trainer")]
pub mod torchscript;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use assay_proto::v1 as pb;
use assay_report::report::Report;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

pub fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_assay"))
}

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// GenSim's own library (`../shared/corpora/gensim-library`, read where it lies, never copied),
/// imported as `assay import gensim` imports it (the default options: each task's code run in
/// the sandbox on the 23 default layout seeds, a minute or two of CPU), once per test process
/// and shared by every test that reads it.
pub fn gensim_library() -> &'static assay_import::Import {
    static LIBRARY: std::sync::OnceLock<assay_import::Import> = std::sync::OnceLock::new();
    LIBRARY.get_or_init(|| {
        let root = repo().join("../shared/corpora/gensim-library");
        assert!(
            root.join("generated_tasks.json").exists(),
            "the GenSim corpus is not at {}",
            root.display()
        );
        assay_import::import(
            assay_import::Pipeline::Gensim,
            &root,
            &assay_import::ImportOptions::default(),
        )
    })
}

/// The first `n` of [`gensim_library`]'s specs in name order, written into `dir` as `assay import
/// --out` writes them (`ID.yaml`, [`assay_import::spec_to_yaml`]); `usize::MAX` for all.
pub fn write_gensim_specs(dir: &Path, n: usize) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let mut specs = gensim_library().specs();
    specs.sort_by(|a, b| a.id.cmp(&b.id));
    specs
        .into_iter()
        .take(n)
        .map(|spec| {
            let file = dir.join(format!("{}.yaml", spec.id));
            std::fs::write(&file, assay_import::spec_to_yaml(spec)).unwrap();
            file
        })
        .collect()
}

/// `assay ARGS…` run to its end in the repository, its output kept.
pub fn assay<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> std::process::Output {
    std::process::Command::new(bin())
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap()
}

/// Its standard output, after asserting that `out` exited 0 (else showing both streams).
pub fn ok(out: &std::process::Output) -> String {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `assay eval TASKS --seeds N --policy P… --no-judge --no-diversity --image-size 160x120
/// --quiet [EXTRA…] --out DIR/out`, its output in `DIR/eval.log`; [`finish_eval`] waits for it.
pub fn spawn_eval(
    dir: &Path,
    tasks: &[PathBuf],
    policies: &[&str],
    seeds: u32,
    extra: &[&std::ffi::OsStr],
) -> Child {
    let log = std::fs::File::create(dir.join("eval.log")).unwrap();
    let mut cmd = Command::new(bin());
    cmd.arg("eval")
        .args(tasks)
        .args(["--seeds", &seeds.to_string()]);
    for p in policies {
        cmd.args(["--policy", p]);
    }
    cmd.args([
        "--no-judge",
        "--no-diversity",
        "--image-size",
        "160x120",
        "--quiet",
    ])
    .args(extra)
    .arg("--out")
    .arg(dir.join("out"))
    .stdin(Stdio::null())
    .stdout(log.try_clone().unwrap())
    .stderr(log)
    .spawn()
    .unwrap()
}

/// Waits at most `within` for a [`spawn_eval`] to succeed and reads its `report.json`; fails the
/// test with its log otherwise.
pub fn finish_eval(mut child: Child, within: Duration, dir: &Path) -> Report {
    let start = Instant::now();
    let log = || std::fs::read_to_string(dir.join("eval.log")).unwrap_or_default();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "assay eval failed: {status}\n{}", log());
            break;
        }
        if start.elapsed() > within {
            let _ = child.kill();
            panic!("assay eval still running after {within:?}\n{}", log());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let text = std::fs::read_to_string(dir.join("out/report.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// A child process that is SIGKILLed and reaped when dropped.
pub struct Proc {
    pub name: String,
    pub child: Child,
    pub log: PathBuf,
}

impl Proc {
    pub fn spawn(name: &str, args: &[&str], dir: &Path) -> Proc {
        Self::spawn_env(name, args, dir, &[])
    }

    /// Runs `program args` (a wrapper such as `ip netns exec NS assay ...`) as [`Proc::spawn`]
    /// runs the binary.
    #[allow(dead_code)]
    pub fn spawn_cmd(name: &str, program: &str, args: &[&str], dir: &Path) -> Proc {
        Self::start(name, Command::new(program), args, dir, &[])
    }

    /// [`Proc::spawn`] with extra environment variables.
    pub fn spawn_env(name: &str, args: &[&str], dir: &Path, env: &[(&str, &str)]) -> Proc {
        Self::start(name, Command::new(bin()), args, dir, env)
    }

    /// [`Proc::spawn_env`] in the working folder `cwd`.
    #[allow(dead_code)]
    pub fn spawn_in(
        name: &str,
        args: &[&str],
        dir: &Path,
        cwd: &Path,
        env: &[(&str, &str)],
    ) -> Proc {
        let mut cmd = Command::new(bin());
        cmd.current_dir(cwd);
        Self::start(name, cmd, args, dir, env)
    }

    /// Starts `cmd args` with JSON logs at info into `dir/<name>.log`.
    fn start(
        name: &str,
        mut cmd: Command,
        args: &[&str],
        dir: &Path,
        env: &[(&str, &str)],
    ) -> Proc {
        let log = dir.join(format!("{}.log", name.replace(' ', "-")));
        let f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log)
            .unwrap();
        let child = cmd
            .args(args)
            .envs(env.iter().copied())
            .env("ASSAY_LOG_FORMAT", "json")
            .env("ASSAY_LOG", "info")
            .stdin(Stdio::null())
            .stdout(f.try_clone().unwrap())
            .stderr(f)
            .spawn()
            .unwrap();
        Proc {
            name: name.into(),
            child,
            log,
        }
    }

    /// Waits (at most `within`, else panics with the log) for the process to exit by itself.
    #[allow(dead_code)]
    pub fn wait_exit(&mut self, within: Duration) -> std::process::ExitStatus {
        let deadline = Instant::now() + within;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            assert!(
                Instant::now() < deadline,
                "{} still running after {within:?}:\n{}",
                self.name,
                self.log_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then waits up to `grace` for a clean exit; returns whether it exited by itself.
    pub fn term(&mut self, grace: Duration) -> bool {
        let _ = kill(Pid::from_raw(self.child.id() as i32), Signal::SIGTERM);
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return status.success();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.kill9();
        false
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill9();
    }
}

/// Starts a coordinator; `listen` may use port 0. Returns it and its `http://` address.
/// Waits (30 s at most) until `p` has written `path`, e.g. a ready or address file.
pub fn wait_for_file(p: &Proc, path: &Path, what: &str) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while !path.exists() {
        assert!(Instant::now() < deadline, "{what}:\n{}", p.log_text());
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn coordinator(dir: &Path, listen: &str, extra: &[&str]) -> (Proc, String) {
    let addr_file = dir.join("coordinator.addr");
    let _ = std::fs::remove_file(&addr_file);
    let store = dir.join("jobs.db");
    let artifacts = dir.join("artifacts");
    let mut args = vec![
        "coordinator",
        "--listen",
        listen,
        "--store",
        store.to_str().unwrap(),
        "--artifacts",
        artifacts.to_str().unwrap(),
        "--addr-file",
        addr_file.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let mut p = Proc::spawn("coordinator", &args, dir);
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if let Ok(s) = std::fs::read_to_string(&addr_file)
            && s.ends_with('\n')
        {
            return (
                p,
                format!("http://{}", s.lines().next().unwrap_or_default().trim()),
            );
        }
        if let Ok(Some(st)) = p.child.try_wait() {
            panic!("coordinator exited: {st}\n{}", p.log_text());
        }
        assert!(
            Instant::now() < deadline,
            "coordinator did not start:\n{}",
            p.log_text()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn worker(dir: &Path, addr: &str, i: usize, capacity: u32) -> Proc {
    let id = format!("test/worker-{i}");
    let cap = capacity.to_string();
    Proc::spawn(
        &format!("worker {i}"),
        &[
            "worker",
            "--coordinator",
            addr,
            "--roles",
            "sim",
            "--capacity",
            &cap,
            "--worker-id",
            &id,
        ],
        dir,
    )
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

pub async fn client(
    addr: &str,
) -> pb::coordinator_client::CoordinatorClient<tonic::transport::Channel> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        match pb::coordinator_client::CoordinatorClient::connect(addr.to_owned()).await {
            Ok(c) => return c.max_decoding_message_size(assay_proto::MAX_MESSAGE_BYTES),
            Err(e) => {
                assert!(Instant::now() < deadline, "no coordinator at {addr}: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

pub fn documents(paths: &[&str]) -> Vec<pb::TaskDocument> {
    let mut files = Vec::new();
    for p in paths {
        let full = repo().join(p);
        if full.is_dir() {
            let mut stack = vec![full];
            while let Some(d) = stack.pop() {
                for e in std::fs::read_dir(d).unwrap() {
                    let p = e.unwrap().path();
                    if p.is_dir() {
                        stack.push(p);
                    } else {
                        files.push(p);
                    }
                }
            }
        } else {
            files.push(full);
        }
    }
    files.sort();
    files
        .into_iter()
        .map(|f| pb::TaskDocument {
            origin: f.strip_prefix(repo()).unwrap().display().to_string(),
            format: String::new(),
            content: std::fs::read_to_string(&f).unwrap(),
        })
        .collect()
}

pub async fn submit(addr: &str, paths: &[&str], seeds: u64) -> pb::SubmitBatchResponse {
    submit_for(addr, paths, seeds, "oracle").await
}

/// [`submit`] for another policy.
pub async fn submit_for(
    addr: &str,
    paths: &[&str],
    seeds: u64,
    policy: &str,
) -> pb::SubmitBatchResponse {
    let mut c = client(addr).await;
    c.submit_batch(pb::SubmitBatchRequest {
        name: "test".into(),
        tasks: documents(paths),
        policies: vec![pb::PolicyRef {
            name: policy.into(),
        }],
        seeds: (0..seeds).collect(),
        max_attempts: 0,
        ..Default::default()
    })
    .await
    .unwrap()
    .into_inner()
}

/// Polls the batch until `done` holds or `timeout` passes (then panics with the status).
pub async fn wait_for(
    addr: &str,
    batch: &str,
    timeout: Duration,
    done: impl Fn(&pb::BatchStatus) -> bool,
) -> pb::BatchStatus {
    let deadline = Instant::now() + timeout;
    let mut last = None;
    loop {
        if let Ok(mut c) = pb::coordinator_client::CoordinatorClient::connect(addr.to_owned()).await
            && let Ok(s) = c
                .get_batch(pb::GetBatchRequest {
                    batch_id: batch.into(),
                })
                .await
        {
            let s = s.into_inner();
            if done(&s) {
                return s;
            }
            last = Some(s);
        }
        assert!(
            Instant::now() < deadline,
            "timed out waiting; last status: {last:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

pub fn finished(s: &pb::BatchStatus) -> bool {
    s.state == pb::BatchState::Completed as i32
}

pub async fn report(addr: &str, batch: &str) -> Report {
    let mut c = client(addr).await;
    let r = c
        .get_report(pb::GetReportRequest {
            batch_id: batch.into(),
        })
        .await
        .unwrap()
        .into_inner();
    serde_json::from_str(&r.report_json).unwrap()
}

/// Every (task, seed) of the report appears once, and every planned episode completed.
pub fn assert_each_episode_once(r: &Report, tasks: usize, seeds: u64) {
    let t = &r.results.totals;
    assert_eq!(t.episodes_planned, tasks as u64 * seeds);
    assert_eq!(
        t.episodes_completed,
        t.episodes_planned,
        "failures: {:?}",
        r.results
            .tasks
            .iter()
            .flat_map(|t| &t.failures)
            .collect::<Vec<_>>()
    );
    let mut seen = std::collections::BTreeSet::new();
    for task in &r.results.tasks {
        for e in &task.episodes {
            assert!(
                seen.insert((task.id.clone(), e.seed, e.policy.clone())),
                "episode counted twice: {} seed {}",
                task.id,
                e.seed
            );
        }
    }
    assert_eq!(seen.len() as u64, t.episodes_planned);
}

/// Opens `html` in headless Chromium (no network, viewport 1280 × 1000) and saves a screenshot
/// as `screenshot` in the test's temporary target folder. `None` when Chromium is not installed,
/// unless `ASSAY_REQUIRE_CHROMIUM` is set (scripts/test sets it), which fails the test instead.
#[allow(dead_code)]
pub fn chromium_check(html: &Path, screenshot: &str) -> Option<assay_browser_check::PageCheck> {
    if assay_browser_check::find_chromium().is_err()
        && std::env::var_os("ASSAY_REQUIRE_CHROMIUM").is_none()
    {
        return None;
    }
    let shot = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(screenshot);
    let page = assay_browser_check::check_file(
        html,
        &assay_browser_check::Options {
            viewport: (1280, 1000),
            screenshot: Some(shot.clone()),
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("Chromium on {}: {e}", html.display()));
    eprintln!("screenshot of {}: {}", html.display(), shot.display());
    Some(page)
}

/// The child processes of `pid` whose second argument (the subcommand) is `role`.
pub fn children(pid: u32, role: &str) -> Vec<i32> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(child) = entry.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{child}/stat")) else {
            continue;
        };
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1))
            .and_then(|p| p.parse::<u32>().ok());
        let cmdline = std::fs::read(format!("/proc/{child}/cmdline")).unwrap_or_default();
        let args: Vec<&[u8]> = cmdline.split(|b| *b == 0).collect();
        if ppid == Some(pid) && args.get(1) == Some(&role.as_bytes()) {
            out.push(child);
        }
    }
    out
}
