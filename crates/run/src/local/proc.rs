//! Child processes of a local cluster: started with their logs in files, stopped with
//! grace → SIGTERM → SIGKILL, always reaped.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

/// Set on every child of a local cluster to its parent's pid: the child dies with its parent
/// ([`die_with_parent`]), so a killed `assay eval` leaves no process holding its job store.
pub const PARENT_VAR: &str = "ASSAY_LOCAL_PARENT";

/// In a child of a local cluster, asks the kernel for SIGKILL when the parent dies, and exits
/// at once if it already has (the parent's pid no longer ours). Elsewhere does nothing.
///
/// The kernel's "parent" is the thread that spawned the child: local clusters start and restart
/// their processes from the command's main thread (`block_on` drives its future there), never
/// from a runtime worker thread that could end first. The `assay` binary calls this first thing.
pub fn die_with_parent() {
    let Some(parent) = std::env::var(PARENT_VAR)
        .ok()
        .and_then(|v| v.parse::<i32>().ok())
    else {
        return;
    };
    #[cfg(target_os = "linux")]
    {
        let _ = nix::sys::prctl::set_pdeathsig(Signal::SIGKILL);
        if nix::unistd::getppid() != Pid::from_raw(parent) {
            std::process::exit(1);
        }
    }
}

pub struct ChildProc {
    pub name: String,
    pub child: Child,
}

impl ChildProc {
    /// Starts `exe` with `args`, its output in `log` (replaced).
    pub fn spawn(exe: &Path, name: &str, args: &[String], log: &Path) -> anyhow::Result<Self> {
        Self::spawn_logging(exe, name, args, log, false)
    }

    /// Starts the process again after it exited: its log is appended to, not replaced.
    pub fn respawn(exe: &Path, name: &str, args: &[String], log: &Path) -> anyhow::Result<Self> {
        Self::spawn_logging(exe, name, args, log, true)
    }

    fn spawn_logging(
        exe: &Path,
        name: &str,
        args: &[String],
        log: &Path,
        append: bool,
    ) -> anyhow::Result<Self> {
        let log_file = std::fs::OpenOptions::new()
            .create(true)
            .write(true)
            .append(append)
            .truncate(!append)
            .open(log)
            .with_context(|| format!("creating {}", log.display()))?;
        let child = Command::new(exe)
            .args(args)
            .env(PARENT_VAR, std::process::id().to_string())
            .stdin(Stdio::null())
            .stdout(log_file.try_clone()?)
            .stderr(log_file)
            .spawn()
            .with_context(|| format!("starting {name}"))?;
        Ok(Self {
            name: name.to_owned(),
            child,
        })
    }

    /// SIGTERM, wait up to `grace`, then SIGKILL; reaps the process.
    pub fn stop(&mut self, grace: Duration) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        let pid = Pid::from_raw(self.child.id() as i32);
        let _ = kill(pid, Signal::SIGTERM);
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for ChildProc {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(3));
    }
}

/// Waits for a file a child writes (its bound address), up to `timeout`.
pub fn wait_for_file(
    path: &Path,
    timeout: Duration,
    child: &mut ChildProc,
) -> anyhow::Result<String> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Ok(s) = std::fs::read_to_string(path)
            && s.ends_with('\n')
        {
            return Ok(s.trim().to_owned());
        }
        if let Ok(Some(status)) = child.child.try_wait() {
            anyhow::bail!("{} exited early ({status}); see its log", child.name);
        }
        if Instant::now() > deadline {
            anyhow::bail!("{} did not start within {timeout:?}", child.name);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
