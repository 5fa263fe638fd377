//! The artifact store on a filesystem: content-addressed files under a root that every worker of
//! a node (or, on a shared filesystem, of the cluster) sees.

use std::path::Path;

use sha2::{Digest, Sha256};

/// Stores `bytes` as `<root>/<kind>/<sha256>.<ext>` and returns that key. Writing the same bytes
/// again is harmless; concurrent writers never expose a partial file (write, then rename).
pub fn put(root: &Path, kind: &str, ext: &str, bytes: &[u8]) -> std::io::Result<String> {
    let key = format!("{kind}/{}.{ext}", hex(&Sha256::digest(bytes)));
    let path = root.join(&key);
    if !path.exists() {
        let dir = path.parent().expect("artifact keys have a folder");
        std::fs::create_dir_all(dir)?;
        let tmp = dir.join(format!(
            ".tmp-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::write(&tmp, bytes)?;
        std::fs::rename(&tmp, &path)?;
    }
    Ok(key)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn keys_are_content_hashes_and_rewrites_are_harmless() {
        let dir = tempfile::tempdir().unwrap();
        let a = super::put(dir.path(), "episodes", "arrow", b"hello").unwrap();
        assert_eq!(
            a,
            "episodes/2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824.arrow"
        );
        assert_eq!(
            super::put(dir.path(), "episodes", "arrow", b"hello").unwrap(),
            a
        );
        assert_eq!(std::fs::read(dir.path().join(&a)).unwrap(), b"hello");
    }
}
