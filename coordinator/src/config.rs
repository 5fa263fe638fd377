//! Coordinator configuration.

use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct CoordinatorConfig {
    /// The SQLite job store (created if missing; reopened after a restart).
    pub store_path: PathBuf,
    /// Artifact root announced to workers.
    pub artifact_root: PathBuf,
    /// How long a lease lives without a heartbeat.
    pub lease_ttl: Duration,
    pub heartbeat_interval: Duration,
    /// Attempts per shard before it is recorded as failed (batches may override).
    pub max_attempts: u32,
    /// The zenoh endpoint the telemetry router listens on (and announces to workers); None: off.
    pub telemetry: Option<String>,
    /// Cluster name in telemetry key expressions.
    pub cluster: String,
    /// The credentials calls must carry, and which role each grants (None: calls are not
    /// checked). Re-read every `credentials_refresh` when some come from files.
    pub keyring: Option<std::sync::Arc<assay_proto::auth::Keyring>>,
    /// How often the keyring's files are read again (a rotated Secret is taken this soon).
    pub credentials_refresh: Duration,
}

impl CoordinatorConfig {
    pub fn new(store_path: PathBuf, artifact_root: PathBuf) -> Self {
        Self {
            store_path,
            artifact_root,
            lease_ttl: Duration::from_secs(15),
            heartbeat_interval: Duration::from_secs(3),
            max_attempts: 3,
            telemetry: None,
            cluster: "local".into(),
            keyring: None,
            credentials_refresh: Duration::from_secs(2),
        }
    }
}
