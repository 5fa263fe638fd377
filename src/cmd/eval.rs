//! `assay eval`: the embedded default. Starts a coordinator and N sim worker processes on
//! loopback, submits the batch, shows live progress, and writes report.json and report.md.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use assay_proto::v1 as pb;
use indicatif::{ProgressBar, ProgressStyle};

use crate::proc::{ChildProc, wait_for_file};

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders (walked for .yaml, .yml, .json).
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Sim worker processes to start.
    #[arg(long, default_value_t = 2)]
    pub workers: u32,
    /// Shards each worker runs at once.
    #[arg(long, default_value_t = 1)]
    pub capacity: u32,
    /// Worker roles: sim,render (pictures of every episode) or sim (physics only, faster).
    #[arg(long, default_value = "sim,render")]
    pub roles: String,
    /// Size of rendered views and keyframes, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480")]
    pub image_size: String,
    /// Output folder: report.json, report.md, artifacts/, and run/ (job store and process logs).
    #[arg(long, default_value = "assay-out")]
    pub out: PathBuf,
    #[command(flatten)]
    pub batch: super::submit::BatchArgs,
    /// Exit non-zero if any task was invalid or any episode failed with an error.
    #[arg(long)]
    pub strict: bool,
    /// No progress bar (logs a line per change instead).
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let docs = crate::docs::collect(&a.paths)?;
    let run_dir = a.out.join("run");
    // Each eval starts from an empty job store: the report covers this run only.
    let _ = std::fs::remove_dir_all(&run_dir);
    std::fs::create_dir_all(&run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    let addr_file = run_dir.join("coordinator.addr");
    let s = |p: PathBuf| p.display().to_string();
    let mut coordinator = ChildProc::spawn(
        "coordinator",
        &[
            "coordinator".into(),
            "--listen".into(),
            "127.0.0.1:0".into(),
            "--store".into(),
            s(run_dir.join("jobs.db")),
            "--artifacts".into(),
            s(a.out.join("artifacts")),
            "--addr-file".into(),
            s(addr_file.clone()),
        ],
        &run_dir.join("coordinator.log"),
    )?;
    let addr = format!(
        "http://{}",
        wait_for_file(&addr_file, Duration::from_secs(30), &mut coordinator)?
    );
    let mut workers = Vec::new();
    for i in 0..a.workers.max(1) {
        workers.push(ChildProc::spawn(
            &format!("worker {i}"),
            &[
                "worker".into(),
                "--coordinator".into(),
                addr.clone(),
                "--roles".into(),
                a.roles.clone(),
                "--image-size".into(),
                a.image_size.clone(),
                "--capacity".into(),
                a.capacity.to_string(),
                "--node-id".into(),
                "local".into(),
                "--worker-id".into(),
                format!("local/worker-{i}"),
            ],
            &run_dir.join(format!("worker-{i}.log")),
        )?);
    }
    eprintln!(
        "local cluster: coordinator at {addr}, {} sim workers; logs in {}",
        workers.len(),
        run_dir.display()
    );

    let req = a
        .batch
        .request(docs, &super::submit::default_name(&a.paths));
    let quiet = a.quiet;
    let outcome = super::block_on(async {
        let mut c = super::client(&addr).await?;
        let r = c.submit_batch(req).await?.into_inner();
        super::print_rejected(&r.rejected);
        eprintln!(
            "batch {}: {} tasks accepted, {} rejected, {} episodes",
            r.batch_id,
            r.accepted_tasks,
            r.rejected.len(),
            r.shards
        );
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(u64::from(r.shards))
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} episodes  {msg}",
            )
            .expect("progress template"),
        );
        let mut stream = c
            .watch_batch(pb::GetBatchRequest {
                batch_id: r.batch_id.clone(),
            })
            .await?
            .into_inner();
        let mut last = None;
        while let Some(st) = stream.message().await? {
            let finished = st.shards_done + st.shards_failed + st.shards_cancelled;
            bar.set_position(u64::from(finished));
            bar.set_message(format!(
                "{} ok, {} failed, {} running, {} workers",
                st.successes, st.shards_failed, st.shards_running, st.workers_connected
            ));
            if quiet {
                eprintln!("{}", super::status::line(&st));
            }
            last = Some(st);
        }
        bar.finish();
        let report = c
            .get_report(pb::GetReportRequest {
                batch_id: r.batch_id.clone(),
            })
            .await?
            .into_inner();
        anyhow::Ok((last, report, r.rejected.len()))
    });
    for w in &mut workers {
        w.stop(Duration::from_secs(5));
    }
    coordinator.stop(Duration::from_secs(5));
    let (last, report, rejected) = outcome?;
    super::report::write(&a.out, &report)?;
    let last = last.context("no status from the coordinator")?;
    eprintln!(
        "{}: {}/{} episodes completed, {} succeeded, {} failed; report in {}",
        super::state_name(last.state),
        last.shards_done,
        last.shards_total,
        last.successes,
        last.shards_failed,
        a.out.join("report.md").display()
    );
    let completed = last.state == pb::BatchState::Completed as i32;
    let clean = rejected == 0 && last.shards_failed == 0;
    Ok(if completed && (clean || !a.strict) {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
