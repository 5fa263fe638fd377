//! Content hashes.

use sha2::{Digest, Sha256};

/// SHA-256 of `bytes`, lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// The hash of a set of tasks by their spec hashes: SHA-256 of the hashes sorted, one per line
/// (a report's `provenance.batch_hash`, a batch's content hash).
pub fn batch_hash<'a>(spec_hashes: impl IntoIterator<Item = &'a str>) -> String {
    let mut hashes: Vec<&str> = spec_hashes.into_iter().collect();
    hashes.sort_unstable();
    let mut text = String::new();
    for h in hashes {
        text.push_str(h);
        text.push('\n');
    }
    sha256_hex(text.as_bytes())
}
