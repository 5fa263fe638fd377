//! Files a task names (URDF documents, meshes): opened only below the folders the process's
//! operator allowed, and read with a size bound, so that a task can neither make a worker open a
//! file elsewhere (a service-account token, a secret) nor read an unbounded file into memory.
//!
//! A worker sets its roots once at start ([`set_roots`]: its `--asset-root` folders, or its
//! working folder when none is given); a root a task names (`source.asset_root`) may narrow
//! what the task reads but never widens these. Every open under a root starts from a descriptor
//! of the root folder: Linux `openat2` with `RESOLVE_BENEATH | RESOLVE_NO_MAGICLINKS` where the
//! kernel has it, else a walk one component at a time with `openat(O_NOFOLLOW)` that follows
//! only relative links and never climbs above the root. What a path check said before the open
//! does not matter: a link swapped in between cannot lead the open outside.
//!
//! A policy's model file (`torchscript:path=…`, `diffusion:model=…`) is opened the same way
//! ([`open_in`]), below these roots or the worker's artifact store.
//!
//! Owns: the process's asset roots, every open of a file a task or a policy's spec names, the
//! size bound of asset files. Never: takes a root from a task or a batch; opens a task's or a
//! policy's file by its path alone in a process that set roots; reads more than
//! [`MAX_ASSET_BYTES`] of one asset file.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folders this process may read asset files from, set once by the operator
/// ([`set_roots`]). Unset, the process is no worker (an importer reading its user's own corpus,
/// a test): reads are bounded but not confined.
static ROOTS: OnceLock<Vec<Root>> = OnceLock::new();

/// A folder asset files are opened below: its canonical path and a descriptor every open starts
/// from (the folder as it was when the operator named it, whatever is renamed later).
#[derive(Debug)]
struct Root {
    path: PathBuf,
    dir: beneath::Dir,
}

/// Confines every asset read of this process to `roots` (canonicalised here); none given, to the
/// working folder. Set once, at start: setting the same roots again is harmless (a process that
/// runs two workers), other roots are an error. Returns the canonical roots.
pub fn set_roots(roots: &[PathBuf]) -> Result<Vec<PathBuf>, String> {
    let given = if roots.is_empty() {
        vec![std::env::current_dir().map_err(|e| format!("the working folder: {e}"))?]
    } else {
        roots.to_vec()
    };
    let mut opened = Vec::with_capacity(given.len());
    for r in &given {
        let path = r
            .canonicalize()
            .map_err(|e| format!("asset root {}: {e}", r.display()))?;
        let dir =
            beneath::Dir::at(&path).map_err(|e| format!("asset root {}: {e}", r.display()))?;
        if !opened.iter().any(|o: &Root| o.path == path) {
            opened.push(Root { path, dir });
        }
    }
    let paths: Vec<PathBuf> = opened.iter().map(|r| r.path.clone()).collect();
    if let Err(opened) = ROOTS.set(opened) {
        drop(opened);
        if roots_of(ROOTS.get()) != Some(paths.clone()) {
            return Err("the asset roots are already set, to other folders".to_owned());
        }
    }
    Ok(paths)
}

fn roots_of(roots: Option<&Vec<Root>>) -> Option<Vec<PathBuf>> {
    roots.map(|r| r.iter().map(|r| r.path.clone()).collect())
}

/// The canonical roots set by [`set_roots`]; `None` when this process set none (it is no
/// worker, and its reads are not confined).
pub fn roots() -> Option<Vec<PathBuf>> {
    roots_of(ROOTS.get())
}

/// Refuses `path` unless, symbolic links followed, it lies inside one of `roots` (canonical).
/// No roots: anything. A check for a clear, early error only: the open itself is what confines
/// ([`read`]).
pub fn check_within(path: &Path, roots: &[PathBuf]) -> Result<(), String> {
    if roots.is_empty() {
        return Ok(());
    }
    let canonical = path.canonicalize().map_err(|e| e.to_string())?;
    if roots.iter().any(|r| canonical.starts_with(r)) {
        Ok(())
    } else {
        Err(outside(
            &canonical.display().to_string(),
            roots,
            "asset roots",
        ))
    }
}

fn outside(what: &str, roots: &[PathBuf], noun: &str) -> String {
    format!(
        "{what} is outside the {noun} the operator allowed ({})",
        roots
            .iter()
            .map(|r| r.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// `a/./b/../c` as `a/c`, without the file system: for a path that may not exist (where
/// `canonicalize` cannot help).
pub fn lexical(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// [`check_within`] the roots set by [`set_roots`].
pub fn check_allowed(path: &Path) -> Result<(), String> {
    check_within(path, &roots().unwrap_or_default())
}

/// The largest asset file a worker reads.
pub const MAX_ASSET_BYTES: u64 = 256 * 1024 * 1024;

/// Reads `path` — below the process's roots, by descriptor, when it set any — refusing
/// anything but a regular file and a file larger than [`MAX_ASSET_BYTES`]. The error is the
/// reason only; callers name the file and the field.
pub fn read(path: &Path) -> Result<Vec<u8>, String> {
    let file = open_confined(path)?;
    read_bounded(file, MAX_ASSET_BYTES)
}

/// [`read`] as UTF-8 text.
pub fn read_to_string(path: &Path) -> Result<String, String> {
    String::from_utf8(read(path)?).map_err(|_| "not UTF-8 text".to_owned())
}

/// Opens `rel` (a relative path: an artifact key, a file inside a model folder) for reading
/// below the folder `root`, by descriptor as [`read`] does: neither `..` nor a link, relative
/// or absolute, leads the open out of `root`. No size bound; for files the operator's own
/// stores hold but a shard names.
pub fn open_beneath(root: &Path, rel: &Path) -> std::io::Result<File> {
    let dir = beneath::Dir::at(root)?;
    dir.open(rel)
}

/// Opens `path` for reading below the process's roots or below one of `also` — further
/// folders of the operator's own, such as a worker's artifact store — by descriptor as [`read`]
/// does: a path below none of them is refused unopened, and neither `..` nor a link leads the
/// open out of the folder it starts from. Refuses anything but a regular file; no size bound (a
/// policy's model may be large). A process that set no roots opens `path` as given. The error
/// is the reason only, "… is outside the folders the operator allowed (…)" for a refusal;
/// callers name the file and the field.
pub fn open_in(path: &Path, also: &[PathBuf]) -> Result<File, String> {
    let Some(roots) = ROOTS.get() else {
        return open_plain(path);
    };
    let extra: Vec<Root> = also
        .iter()
        .filter_map(|p| {
            let path = p.canonicalize().ok()?;
            let dir = beneath::Dir::at(&path).ok()?;
            Some(Root { path, dir })
        })
        .collect();
    let all: Vec<&Root> = extra.iter().chain(roots).collect();
    open_below(path, &all, "folders")
}

/// Opens `path` below the first root that holds it, spelled as given or as its canonical
/// form (a root reached through a link). A path below no root is refused unopened.
fn open_confined(path: &Path) -> Result<File, String> {
    let Some(roots) = ROOTS.get() else {
        return open_plain(path);
    };
    open_below(path, &roots.iter().collect::<Vec<_>>(), "asset roots")
}

fn open_plain(path: &Path) -> Result<File, String> {
    let file = File::open(path).map_err(|e| e.to_string())?;
    check_regular(&file)?;
    Ok(file)
}

/// [`open_confined`] below `roots`; `noun` names them in a refusal.
fn open_below(path: &Path, roots: &[&Root], noun: &str) -> Result<File, String> {
    let abs = std::path::absolute(path).map_err(|e| e.to_string())?;
    let canonical = abs.canonicalize().ok();
    for spelled in std::iter::once(&abs).chain(canonical.as_ref()) {
        if let Some((root, rel)) = roots
            .iter()
            .find_map(|r| spelled.strip_prefix(&r.path).ok().map(|rel| (r, rel)))
        {
            let file = root.dir.open(rel).map_err(|e| match e.raw_os_error() {
                Some(code) if code == beneath::ESCAPED => outside(
                    &format!("{} (by `..` or a link)", abs.display()),
                    std::slice::from_ref(&root.path),
                    noun,
                ),
                _ => e.to_string(),
            })?;
            check_regular(&file)?;
            return Ok(file);
        }
    }
    let paths: Vec<PathBuf> = roots.iter().map(|r| r.path.clone()).collect();
    Err(outside(&abs.display().to_string(), &paths, noun))
}

/// Refuses a device, a FIFO, a socket or a folder: an asset is a regular file.
fn check_regular(file: &File) -> Result<(), String> {
    let kind = file.metadata().map_err(|e| e.to_string())?.file_type();
    if kind.is_file() {
        Ok(())
    } else if kind.is_dir() {
        Err("a folder, not a file".to_owned())
    } else {
        Err("not a regular file (a device, FIFO or socket)".to_owned())
    }
}

fn too_large(max: u64) -> String {
    format!(
        "larger than the {} MiB an asset may be",
        max.div_ceil(1024 * 1024)
    )
}

/// Reads `file` to its end, refusing one longer than `max` bytes without reading past it.
fn read_bounded(file: File, max: u64) -> Result<Vec<u8>, String> {
    let len = file.metadata().map_err(|e| e.to_string())?.len();
    if len > max {
        return Err(format!(
            "{} MiB, {}",
            len.div_ceil(1024 * 1024),
            too_large(max)
        ));
    }
    // The length can lie (a device, a file still growing): never read more than the bound.
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| e.to_string())?;
    if bytes.len() as u64 > max {
        return Err(too_large(max));
    }
    Ok(bytes)
}

/// Opening below a folder's descriptor.
#[cfg(target_os = "linux")]
mod beneath {
    use std::collections::VecDeque;
    use std::ffi::OsString;
    use std::fs::File;
    use std::io;
    use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
    use std::os::unix::ffi::OsStringExt;
    use std::path::{Component, Path};
    use std::sync::atomic::{AtomicBool, Ordering};

    use rustix::fs::{FileType, Mode, OFlags, ResolveFlags, fstat, openat, openat2, readlinkat};
    use rustix::io::Errno;

    /// The error of an open that would leave its folder (`EXDEV`, as `openat2` says it).
    pub const ESCAPED: i32 = Errno::XDEV.raw_os_error();

    /// Links followed in one open before it is refused (the kernel's own limit).
    const MAX_LINKS: usize = 40;

    /// Whether the kernel answers `openat2` (false after an `ENOSYS`: an old kernel, or a
    /// seccomp filter that hides it).
    static OPENAT2: AtomicBool = AtomicBool::new(true);

    /// A folder, held open.
    #[derive(Debug)]
    pub struct Dir(OwnedFd);

    impl Dir {
        pub fn at(path: &Path) -> io::Result<Self> {
            let fd = rustix::fs::open(
                path,
                OFlags::PATH | OFlags::DIRECTORY | OFlags::CLOEXEC,
                Mode::empty(),
            )?;
            Ok(Self(fd))
        }

        /// Opens `rel` for reading below this folder: `openat2` where the kernel has it, else
        /// [`walk`].
        pub fn open(&self, rel: &Path) -> io::Result<File> {
            if rel.is_absolute() {
                return Err(Errno::XDEV.into());
            }
            if OPENAT2.load(Ordering::Relaxed) {
                match resolve(self.0.as_fd(), rel) {
                    Err(Errno::NOSYS) => OPENAT2.store(false, Ordering::Relaxed),
                    // A seccomp filter may answer EPERM; the walk says what is really wrong.
                    Err(Errno::PERM) => {}
                    r => return Ok(File::from(r?)),
                }
            }
            Ok(File::from(walk(self.0.as_fd(), rel)?))
        }
    }

    const READ: OFlags = OFlags::RDONLY
        .union(OFlags::CLOEXEC)
        .union(OFlags::NOCTTY)
        // A FIFO must not block the open; it is refused once open (`check_regular`).
        .union(OFlags::NONBLOCK);

    /// `openat2(RESOLVE_BENEATH | RESOLVE_NO_MAGICLINKS)`, again on `EAGAIN` (a rename
    /// elsewhere in the file system raced a `..`).
    pub fn resolve(dir: BorrowedFd<'_>, rel: &Path) -> Result<OwnedFd, Errno> {
        let how = ResolveFlags::BENEATH | ResolveFlags::NO_MAGICLINKS;
        let mut tries = 0;
        loop {
            match openat2(dir, rel, READ, Mode::empty(), how) {
                Err(Errno::AGAIN) if tries < 16 => tries += 1,
                r => return r,
            }
        }
    }

    /// What `RESOLVE_BENEATH` does, one component at a time: each is opened with `O_PATH |
    /// O_NOFOLLOW` from the folder before it; a relative link is read and its components walked
    /// in its place, an absolute one refused; `..` goes back to the folder walked before and is
    /// refused at the root; the file itself is opened with `O_NOFOLLOW` from its folder, so a
    /// link swapped in after the walk looked is refused, not followed.
    pub fn walk(root: BorrowedFd<'_>, rel: &Path) -> io::Result<OwnedFd> {
        let mut todo: VecDeque<OsString> = VecDeque::new();
        push_front(&mut todo, rel)?;
        let mut folders: Vec<OwnedFd> = Vec::new();
        let mut links = 0;
        while let Some(name) = todo.pop_front() {
            let here = folders.last().map_or(root, |f| f.as_fd());
            if name == ".." {
                if folders.pop().is_none() {
                    return Err(Errno::XDEV.into());
                }
                continue;
            }
            let fd = openat(
                here,
                name.as_os_str(),
                OFlags::PATH | OFlags::NOFOLLOW | OFlags::CLOEXEC,
                Mode::empty(),
            )?;
            match FileType::from_raw_mode(fstat(&fd)?.st_mode) {
                FileType::Symlink => {
                    links += 1;
                    if links > MAX_LINKS {
                        return Err(Errno::LOOP.into());
                    }
                    let target = readlinkat(&fd, c"", Vec::new())?;
                    let target = OsString::from_vec(target.into_bytes());
                    push_front(&mut todo, Path::new(&target))?;
                }
                FileType::Directory if !todo.is_empty() => folders.push(fd),
                _ if !todo.is_empty() => return Err(Errno::NOTDIR.into()),
                _ => {
                    return Ok(openat(
                        here,
                        name.as_os_str(),
                        READ | OFlags::NOFOLLOW,
                        Mode::empty(),
                    )?);
                }
            }
        }
        // `rel` named a folder (`a/..`, `.`): open it, which the caller refuses as no file.
        let here = folders.last().map_or(root, |f| f.as_fd());
        Ok(openat(here, c".", READ, Mode::empty())?)
    }

    /// Puts the components of `p` (relative: an absolute one leaves the folder) before `todo`.
    fn push_front(todo: &mut VecDeque<OsString>, p: &Path) -> io::Result<()> {
        for c in p.components().rev() {
            match c {
                Component::Normal(n) => todo.push_front(n.to_owned()),
                Component::ParentDir => todo.push_front(OsString::from_vec(b"..".to_vec())),
                Component::CurDir => {}
                Component::RootDir | Component::Prefix(_) => return Err(Errno::XDEV.into()),
            }
        }
        Ok(())
    }
}

/// Elsewhere: a path check, then the open (not proof against a link swapped in between).
#[cfg(not(target_os = "linux"))]
mod beneath {
    use std::fs::File;
    use std::io;
    use std::path::{Path, PathBuf};

    pub const ESCAPED: i32 = 18;

    #[derive(Debug)]
    pub struct Dir(PathBuf);

    impl Dir {
        pub fn at(path: &Path) -> io::Result<Self> {
            Ok(Self(path.canonicalize()?))
        }

        pub fn open(&self, rel: &Path) -> io::Result<File> {
            let full = self.0.join(rel).canonicalize()?;
            if rel.is_absolute() || !full.starts_with(&self.0) {
                return Err(io::Error::from_raw_os_error(ESCAPED));
            }
            File::open(full)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_are_confined_to_the_roots_links_followed() {
        let dir = tempfile::tempdir().unwrap();
        let (inside, outside) = (dir.path().join("in"), dir.path().join("out"));
        std::fs::create_dir_all(&inside).unwrap();
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(inside.join("a.obj"), "v 0 0 0").unwrap();
        std::fs::write(outside.join("b.obj"), "v 0 0 0").unwrap();
        let roots = [inside.canonicalize().unwrap()];
        check_within(&inside.join("a.obj"), &roots).unwrap();
        let e = check_within(&outside.join("b.obj"), &roots).unwrap_err();
        assert!(e.contains("outside the asset roots"), "{e}");
        assert!(check_within(&inside.join("../out/b.obj"), &roots).is_err());
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(outside.join("b.obj"), inside.join("link.obj")).unwrap();
            assert!(check_within(&inside.join("link.obj"), &roots).is_err());
        }
        check_within(&outside.join("b.obj"), &[]).unwrap();
    }

    #[test]
    fn files_over_the_bound_are_refused_without_being_read() {
        let dir = tempfile::tempdir().unwrap();
        let small = dir.path().join("small.obj");
        std::fs::write(&small, "v 0 0 0\n").unwrap();
        assert_eq!(read_to_string(&small).unwrap(), "v 0 0 0\n");
        // A sparse file just over the bound: refused from its length, no disk or memory used.
        let huge = dir.path().join("huge.obj");
        std::fs::File::create(&huge)
            .unwrap()
            .set_len(MAX_ASSET_BYTES + 1)
            .unwrap();
        let e = read(&huge).unwrap_err();
        assert_eq!(e, "257 MiB, larger than the 256 MiB an asset may be");
        // A device whose length says nothing: cut off once the bound is passed (and refused
        // before that by `read`, which opens regular files only).
        let zero = File::open("/dev/zero").unwrap();
        let e = read_bounded(zero, 4096).unwrap_err();
        assert_eq!(e, "larger than the 1 MiB an asset may be");
        let e = read(Path::new("/dev/zero")).unwrap_err();
        assert!(e.contains("not a regular file"), "{e}");
        assert!(read(&dir.path().join("missing.obj")).is_err());
        std::fs::write(&small, [0xff, 0xfe]).unwrap();
        assert_eq!(read_to_string(&small).unwrap_err(), "not UTF-8 text");
    }

    /// `root/` with a file, a folder, links that stay inside (relative) and links out
    /// (absolute and by `..`); `outside/secret` beside it.
    #[cfg(unix)]
    fn tree() -> (tempfile::TempDir, PathBuf, PathBuf) {
        use std::os::unix::fs::symlink;
        let dir = tempfile::tempdir().unwrap();
        let (root, outside) = (dir.path().join("root"), dir.path().join("outside"));
        std::fs::create_dir_all(root.join("a/b")).unwrap();
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(root.join("a/f"), "inside").unwrap();
        std::fs::write(outside.join("secret"), "outside").unwrap();
        symlink("a/f", root.join("rel_in")).unwrap();
        symlink("../f", root.join("a/b/up_in")).unwrap();
        symlink("b/../../a", root.join("a/dir_in")).unwrap();
        symlink(outside.join("secret"), root.join("abs_out")).unwrap();
        symlink(root.join("a/f"), root.join("abs_in")).unwrap();
        symlink("../outside/secret", root.join("rel_out")).unwrap();
        symlink("../../..", root.join("a/b/climb")).unwrap();
        symlink("loop", root.join("loop")).unwrap();
        (dir, root, outside)
    }

    /// A way of opening a path below the root, reading the file as text.
    #[cfg(target_os = "linux")]
    type Open = Box<dyn Fn(&str) -> std::io::Result<String>>;

    /// Every way of opening below a folder, the kernel's and the walk, answers the same.
    #[cfg(target_os = "linux")]
    fn opens(root: &Path) -> Vec<(&'static str, Open)> {
        use std::os::fd::AsFd;
        let read = |f: std::io::Result<File>| -> std::io::Result<String> {
            let mut s = String::new();
            f?.read_to_string(&mut s)?;
            Ok(s)
        };
        let (r1, r2, r3) = (root.to_owned(), root.to_owned(), root.to_owned());
        vec![
            (
                "open_beneath",
                Box::new(move |p: &str| read(open_beneath(&r1, Path::new(p)))),
            ),
            (
                "openat2",
                Box::new(move |p: &str| {
                    let dir = File::open(&r2)?;
                    let fd = beneath::resolve(dir.as_fd(), Path::new(p))?;
                    read(Ok(File::from(fd)))
                }),
            ),
            (
                "walk",
                Box::new(move |p: &str| {
                    let dir = File::open(&r3)?;
                    read(beneath::walk(dir.as_fd(), Path::new(p)).map(File::from))
                }),
            ),
        ]
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn opens_below_a_root_never_leave_it() {
        let (_dir, root, _outside) = tree();
        for (how, open) in opens(&root) {
            for inside in [
                "a/f",
                "rel_in",
                "a/b/up_in",
                "a/dir_in/f",
                "a/b/../f",
                "./a/./f",
            ] {
                assert_eq!(open(inside).unwrap(), "inside", "{how}: {inside}");
            }
            for out in [
                "abs_out",
                "rel_out",
                "../outside/secret",
                "a/../../outside/secret",
                "a/b/climb/outside/secret",
                // An absolute link is refused even when it points inside (as RESOLVE_BENEATH does).
                "abs_in",
            ] {
                let e = open(out).unwrap_err();
                assert_eq!(
                    e.raw_os_error(),
                    Some(beneath::ESCAPED),
                    "{how}: {out}: {e}"
                );
            }
            assert!(open("loop").is_err(), "{how}: a link to itself");
            assert!(open("missing").is_err(), "{how}");
            assert!(open("a/f/x").is_err(), "{how}: a file is no folder");
        }
    }

    /// A FIFO is refused, not waited on.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe.urdf");
        assert!(
            std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .unwrap()
                .success()
        );
        let file = open_beneath(dir.path(), Path::new("pipe.urdf")).unwrap();
        let e = check_regular(&file).unwrap_err();
        assert!(e.contains("not a regular file"), "{e}");
    }

    /// A thread swaps `root/f` between a file inside and a link to a file outside, as fast as it
    /// can, while reads below the root open it: a read either fails or returns what is inside,
    /// never the secret. Each way of opening reads until the file has changed 200 times under it.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_link_swapped_in_between_never_leads_out() {
        use std::sync::Arc;
        use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
        let (_dir, root, outside) = tree();
        let stop = Arc::new(AtomicBool::new(false));
        let flips = Arc::new(AtomicU64::new(0));
        let flipper = {
            let (root, secret) = (root.clone(), outside.join("secret"));
            let (stop, flips) = (stop.clone(), flips.clone());
            std::thread::spawn(move || {
                let (f, tmp) = (root.join("f"), root.join("f.tmp"));
                while !stop.load(Ordering::Relaxed) {
                    std::fs::write(&tmp, "inside").unwrap();
                    std::fs::rename(&tmp, &f).unwrap();
                    std::os::unix::fs::symlink(&secret, &tmp).unwrap();
                    std::fs::rename(&tmp, &f).unwrap();
                    flips.fetch_add(1, Ordering::Relaxed);
                }
            })
        };
        let (mut read_inside, mut refused) = (0u32, 0u32);
        for (how, open) in opens(&root) {
            let (from, started) = (flips.load(Ordering::Relaxed), std::time::Instant::now());
            let mut reads = 0;
            while reads < 1000 || flips.load(Ordering::Relaxed) - from < 200 {
                match open("f") {
                    Ok(text) => {
                        assert_eq!(text, "inside", "{how}: the swapped link was followed out");
                        read_inside += 1;
                    }
                    Err(_) => refused += 1,
                }
                reads += 1;
                assert!(
                    started.elapsed() < std::time::Duration::from_secs(120),
                    "{how}: the flipper is stuck"
                );
            }
        }
        stop.store(true, Ordering::Relaxed);
        flipper.join().unwrap();
        // The race was run: both outcomes happened.
        assert!(read_inside > 0 && refused > 0, "{read_inside} {refused}");
    }
}
