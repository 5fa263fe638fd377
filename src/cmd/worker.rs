//! `assay worker`: its arguments, turned into [`assay_worker::Options`]; the roles themselves are
//! `assay-worker`'s.

use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, env = "ASSAY_COORDINATOR", default_value = assay_run::client::DEFAULT_COORDINATOR)]
    pub coordinator: String,
    /// Comma-separated roles: sim, render, judge, trainer. With sim and render the episodes of a
    /// batch that renders get their scene views, keyframes, scene caption and contact sheet in
    /// this process; render alone draws the episodes sim-only workers simulated (and a policy
    /// that sees while it runs needs sim and render on one worker); judge scores rendered
    /// episodes with the judges a batch names; trainer fits the batch's models.
    #[arg(long, default_value = "sim", value_delimiter = ',')]
    pub roles: Vec<String>,
    /// Configuration file (TOML) naming the judges this worker can run (`[judges.<name>]`);
    /// the built-in `offline` judge needs none.
    #[arg(long, env = "ASSAY_CONFIG")]
    pub config: Option<std::path::PathBuf>,
    /// Size of rendered views and keyframes, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub image_size: (u32, u32),
    /// Also render a video of every episode (half the image size, 12 frames/s): MP4 when
    /// ffmpeg is installed, else an animated GIF.
    #[arg(long)]
    pub video: bool,
    /// Shards run at once.
    #[arg(long, env = "ASSAY_CAPACITY", default_value_t = 1)]
    pub capacity: u32,
    /// Node id (defaults to the host name).
    #[arg(long, env = "ASSAY_NODE_ID")]
    pub node_id: Option<String>,
    /// Worker id (defaults to <node>/<pid>).
    #[arg(long)]
    pub worker_id: Option<String>,
    /// MiB of drawn pictures and captions the render role keeps in memory, where the node's
    /// judges read them over shared memory (0: none; they read the artifact store).
    #[arg(long, default_value_t = 256)]
    pub keep_mib: usize,
    /// A folder tasks may read asset files (URDF, meshes) from (repeatable; in
    /// ASSAY_ASSET_ROOTS, colon-separated): this worker opens no asset file outside them,
    /// whatever a task says — a task's `source.asset_root` may only narrow them. None: the
    /// working folder.
    #[arg(
        long = "asset-root",
        value_name = "DIR",
        env = "ASSAY_ASSET_ROOTS",
        value_delimiter = ':'
    )]
    pub asset_roots: Vec<std::path::PathBuf>,
    /// An environment variable an openpi policy's `api_key_env` may name, its value sent to the
    /// server the policy string gives (repeatable; in ASSAY_POLICY_KEY_ENVS, comma-separated).
    /// Policy strings come with batches, from their submitters: no other variable is sent.
    #[arg(
        long = "policy-key-env",
        value_name = "VAR",
        env = "ASSAY_POLICY_KEY_ENVS",
        value_delimiter = ','
    )]
    pub policy_key_envs: Vec<String>,
}

pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or("expected WIDTHxHEIGHT, e.g. 640x480")?;
    let (w, h): (u32, u32) = (
        w.parse().map_err(|_| "bad width")?,
        h.parse().map_err(|_| "bad height")?,
    );
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        return Err("width and height must lie in 1..=8192".into());
    }
    Ok((w, h))
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let worker = assay_worker::Worker::new(assay_worker::Options {
        coordinator: a.coordinator,
        roles: a.roles,
        config: a.config,
        image_size: a.image_size,
        video: a.video,
        capacity: a.capacity,
        node_id: a.node_id,
        worker_id: a.worker_id,
        keep_mib: a.keep_mib,
        asset_roots: a.asset_roots,
        policy_key_envs: a.policy_key_envs,
    })?;
    assay_run::rt::block_on(async move { worker.serve(assay_run::rt::terminated()).await })?;
    Ok(ExitCode::SUCCESS)
}
