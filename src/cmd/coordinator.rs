use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use assay_coordinator::CoordinatorConfig;

#[derive(clap::Args)]
pub struct Args {
    /// Address to listen on (port 0 picks a free port; see --addr-file).
    #[arg(long, env = "ASSAY_LISTEN", default_value = "127.0.0.1:7878")]
    pub listen: String,
    /// The SQLite job store; reopened on restart, unfinished shards carry on.
    #[arg(long, env = "ASSAY_STORE", default_value = "assay-jobs.db")]
    pub store: PathBuf,
    /// Artifact root (episodes and other files, content-addressed).
    #[arg(long, env = "ASSAY_ARTIFACTS", default_value = "assay-artifacts")]
    pub artifacts: PathBuf,
    /// Write the bound address (host:port and a newline) here once listening.
    #[arg(long)]
    pub addr_file: Option<PathBuf>,
    /// Lease lifetime without a heartbeat, in milliseconds.
    #[arg(long, env = "ASSAY_LEASE_TTL_MS", default_value_t = 15_000)]
    pub lease_ttl_ms: u64,
    /// Heartbeat interval asked of workers, in milliseconds.
    #[arg(long, env = "ASSAY_HEARTBEAT_MS", default_value_t = 3_000)]
    pub heartbeat_ms: u64,
    /// Attempts per shard before it is recorded as failed.
    #[arg(long, env = "ASSAY_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// Where the telemetry router (zenoh) listens: a zenoh endpoint (`tcp/10.0.0.5:7447` for a
    /// multi-node cluster), `loopback` for a free port on 127.0.0.1, or `off`.
    #[arg(long, env = "ASSAY_TELEMETRY", default_value = "loopback")]
    pub telemetry: String,
    /// Cluster name in telemetry key expressions (assay/<cluster>/...).
    #[arg(long, env = "ASSAY_CLUSTER", default_value = "local")]
    pub cluster: String,
    /// Where to serve Prometheus metrics (`GET /metrics`) and `GET /healthz`: an address
    /// (`0.0.0.0:9464`; port 0 picks a free port, written as line 3 of --addr-file), or `off`.
    #[arg(long, env = "ASSAY_METRICS_LISTEN", default_value = "off")]
    pub metrics_listen: String,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let artifacts = std::path::absolute(&a.artifacts).context("artifact root")?;
    let mut config = CoordinatorConfig::new(a.store.clone(), artifacts);
    config.lease_ttl = Duration::from_millis(a.lease_ttl_ms);
    config.heartbeat_interval = Duration::from_millis(a.heartbeat_ms);
    config.max_attempts = a.max_attempts.max(1);
    config.cluster = a.cluster.clone();
    config.keyring = assay_proto::auth::Keyring::from_env()
        .map_err(anyhow::Error::msg)?
        .map(std::sync::Arc::new);
    config.telemetry = match a.telemetry.as_str() {
        "off" => None,
        "loopback" => {
            Some(assay_telemetry::free_loopback_endpoint().context("choosing a telemetry port")?)
        }
        endpoint => Some(endpoint.to_owned()),
    };
    let telemetry_line = config.telemetry.clone().unwrap_or_else(|| "off".into());
    assay_run::rt::block_on(async move {
        let listener = tokio::net::TcpListener::bind(&a.listen)
            .await
            .with_context(|| format!("binding {}", a.listen))?;
        let addr = listener.local_addr()?;
        if !addr.ip().is_loopback() && config.keyring.is_none() {
            let warning = format!(
                "WARNING: listening on {addr}, beyond loopback, without a cluster token: anyone \
                 who can reach this address can submit batches and lease work. Set \
                 ASSAY_CLUSTER_TOKEN (or ASSAY_CLUSTER_TOKEN_FILE) here, and give each process \
                 the cluster token or its role's key (assay token derive --role worker)."
            );
            eprintln!("{warning}");
            tracing::warn!("{warning}");
        }
        let metrics = match a.metrics_listen.as_str() {
            "off" => None,
            at => Some(
                tokio::net::TcpListener::bind(at)
                    .await
                    .with_context(|| format!("binding the metrics address {at}"))?,
            ),
        };
        let metrics_line = match &metrics {
            Some(l) => l.local_addr()?.to_string(),
            None => "off".into(),
        };
        if let Some(f) = &a.addr_file {
            let tmp = f.with_extension("tmp");
            // Line 1: the gRPC address; line 2: the telemetry endpoint (or "off"); line 3: the
            // metrics address (or "off").
            std::fs::write(&tmp, format!("{addr}\n{telemetry_line}\n{metrics_line}\n"))?;
            std::fs::rename(&tmp, f)?;
        }
        assay_coordinator::serve(config, listener, metrics, assay_run::rt::terminated()).await?;
        Ok(ExitCode::SUCCESS)
    })
}
