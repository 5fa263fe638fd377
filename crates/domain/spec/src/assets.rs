//! Files a task names (URDF documents, meshes), read with a size bound: a task cannot make a worker
//! read an unbounded file into memory, whether by naming a huge file or a device that never ends.

use std::io::Read;
use std::path::Path;

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
