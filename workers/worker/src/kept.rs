//! Artifacts read where they are: from the memory of the process of this node that made them
//! (the render role keeps its pictures, captions and clips, `assay_framebus::cache`), over
//! iceoryx2, checked against their content addresses; else from the artifact store, where each
//! was written before its shard was reported.
//!
//! Owns: the reader a judge or trainer shard opens on its own thread, and the counts of what came
//! from where. Never keeps anything itself (the render role does).

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use crate::telemetry::Counters;

/// How long a reader waits for the node's keepers to answer one request.
const ANSWER: Duration = Duration::from_millis(500);

/// A reader of this node's kept artifacts. Not `Send`: iceoryx2 ports belong to the thread that
/// made them, so each shard opens its own.
pub(crate) struct NodeArtifacts {
    reader: Option<(
        assay_framebus::cache::ArtifactReader,
        assay_framebus::FrameBus,
    )>,
}

impl NodeArtifacts {
    /// Opens a reader; without shared memory every read goes to the artifact store.
    pub(crate) fn open() -> Self {
        static READERS: AtomicU64 = AtomicU64::new(0);
        let name = format!(
            "assay-reader-{}-{}",
            std::process::id(),
            READERS.fetch_add(1, Ordering::Relaxed)
        );
        let reader =
            assay_framebus::FrameBus::open(&name).and_then(|bus| Ok((bus.artifact_reader()?, bus)));
        match reader {
            Ok(r) => Self { reader: Some(r) },
            Err(e) => {
                tracing::debug!(error = %e, "no shared memory: reading the artifact store");
                Self { reader: None }
            }
        }
    }

    /// The bytes of `key` if a process of this node keeps them.
    pub(crate) fn kept(&self, key: &str) -> Option<Vec<u8>> {
        let (reader, _) = self.reader.as_ref()?;
        match reader.fetch(key, ANSWER) {
            Ok(found) => found,
            Err(e) => {
                tracing::debug!(error = %e, key, "shared memory read failed");
                None
            }
        }
    }

    /// The bytes of `key`: kept on this node, else from the artifact store under `root`;
    /// counted in `counters` by where they came from.
    // Only the trainer role reads whole artifacts through the node (a build without it has no
    // caller).
    #[cfg_attr(not(feature = "trainer"), expect(dead_code))]
    pub(crate) fn read(
        &self,
        root: &Path,
        key: &str,
        counters: &Counters,
    ) -> std::io::Result<Vec<u8>> {
        if let Some(bytes) = self.kept(key) {
            counters.frames_shared.fetch_add(1, Ordering::Relaxed);
            return Ok(bytes);
        }
        // A key from a shard is opened below the store's folder, never beside it.
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(
            &mut assay_spec::assets::open_beneath(root, Path::new(key))?,
            &mut bytes,
        )?;
        counters.frames_stored.fetch_add(1, Ordering::Relaxed);
        Ok(bytes)
    }
}
