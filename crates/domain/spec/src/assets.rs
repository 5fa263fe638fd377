//! Files a task names (URDF documents, meshes), read with a size bound: a task cannot make a worker
//! read an unbounded file into memory, whether by naming a huge file or a device that never ends.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The folders this process may read asset files from, set once by the operator (a worker's
/// `--asset-root`); unset, asset files are confined only by each task's own asset root.
static ROOTS: OnceLock<Vec<PathBuf>> = OnceLock::new();

/// Confines every asset read of this process to `roots` (canonicalised here). Set once, at
/// start; a second call is an error.
pub fn set_roots(roots: &[PathBuf]) -> Result<(), String> {
    let canonical = roots
        .iter()
        .map(|r| {
            r.canonicalize()
                .map_err(|e| format!("asset root {}: {e}", r.display()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    ROOTS
        .set(canonical)
        .map_err(|_| "the asset roots are already set".to_owned())
}

/// Refuses `path` unless, symbolic links followed, it lies inside one of `roots` (canonical).
/// No roots: anything.
pub fn check_within(path: &Path, roots: &[PathBuf]) -> Result<(), String> {
    if roots.is_empty() {
        return Ok(());
    }
    let canonical = path.canonicalize().map_err(|e| e.to_string())?;
    if roots.iter().any(|r| canonical.starts_with(r)) {
        Ok(())
    } else {
        Err(format!(
            "{} is outside the asset roots the operator allowed ({})",
            canonical.display(),
            roots
                .iter()
                .map(|r| r.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    }
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
    check_within(path, ROOTS.get().map_or(&[], Vec::as_slice))
}

/// The largest asset file a worker reads.
pub const MAX_ASSET_BYTES: u64 = 256 * 1024 * 1024;

/// Reads `path`, refusing a file larger than [`MAX_ASSET_BYTES`]. The error is the reason only;
/// callers name the file and the field.
pub fn read(path: &Path) -> Result<Vec<u8>, String> {
    read_bounded(path, MAX_ASSET_BYTES)
}

/// [`read`] as UTF-8 text.
pub fn read_to_string(path: &Path) -> Result<String, String> {
    String::from_utf8(read(path)?).map_err(|_| "not UTF-8 text".to_owned())
}

fn too_large(max: u64) -> String {
    format!(
        "larger than the {} MiB an asset may be",
        max.div_ceil(1024 * 1024)
    )
}

fn read_bounded(path: &Path, max: u64) -> Result<Vec<u8>, String> {
    check_allowed(path)?;
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
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

#[cfg(test)]
mod tests {
    #[test]
    fn reads_are_confined_to_the_roots_links_followed() {
        let dir = tempfile::tempdir().unwrap();
        let (inside, outside) = (dir.path().join("in"), dir.path().join("out"));
        std::fs::create_dir_all(&inside).unwrap();
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(inside.join("a.obj"), "v 0 0 0").unwrap();
        std::fs::write(outside.join("b.obj"), "v 0 0 0").unwrap();
        let roots = [inside.canonicalize().unwrap()];
        super::check_within(&inside.join("a.obj"), &roots).unwrap();
        let e = super::check_within(&outside.join("b.obj"), &roots).unwrap_err();
        assert!(e.contains("outside the asset roots"), "{e}");
        assert!(super::check_within(&inside.join("../out/b.obj"), &roots).is_err());
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(outside.join("b.obj"), inside.join("link.obj")).unwrap();
            assert!(super::check_within(&inside.join("link.obj"), &roots).is_err());
        }
        super::check_within(&outside.join("b.obj"), &[]).unwrap();
    }

    use super::*;

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
        // A device whose length says nothing: refused once the bound is passed.
        let e = read_bounded(Path::new("/dev/zero"), 4096).unwrap_err();
        assert_eq!(e, "larger than the 1 MiB an asset may be");
        assert!(read(&dir.path().join("missing.obj")).is_err());
        std::fs::write(&small, [0xff, 0xfe]).unwrap();
        assert_eq!(read_to_string(&small).unwrap_err(), "not UTF-8 text");
    }
}
