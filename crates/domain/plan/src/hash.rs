//! The hash of a batch's content: the same tasks give the same hash, whatever their file names,
//! order or YAML formatting (continuous evaluation skips a batch whose content was evaluated).

use assay_spec::SpecError;
use assay_spec::hash::{batch_hash, sha256_hex};

use crate::documents::{PlannedTask, TaskDocument};

/// SHA-256 of a batch's tasks: the spec hashes of `tasks` and the SHA-256 of the documents that
/// did not become tasks (`invalid`), sorted, one per line.
pub fn content_hash(docs: &[TaskDocument], tasks: &[PlannedTask], invalid: &[SpecError]) -> String {
    let mut hashes: Vec<String> = tasks.iter().map(|t| t.info.spec_hash.clone()).collect();
    for d in docs {
        if invalid.iter().any(|e| e.origin == d.origin) {
            hashes.push(sha256_hex(d.content.as_bytes()));
        }
    }
    batch_hash(hashes.iter().map(String::as_str))
}
