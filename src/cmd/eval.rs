//! `assay eval`: the embedded default. Starts a coordinator, N sim worker processes and a judge
//! worker on loopback, submits the batch, shows live progress, and writes report.json, report.md
//! and the quality figure.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use assay_proto::v1 as pb;
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

#[derive(clap::Args)]
pub struct Args {
    /// Task spec files or folders (walked for .yaml, .yml, .json); with --import, the
    /// generator's output trees.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Read PATHS as a generator's own output (gensim, robogen or bbsea): import them first,
    /// print the per-task mapping report and write it to OUT/import-report.json.
    #[arg(long, value_name = "PIPELINE")]
    pub import: Option<assay_import::Pipeline>,
    #[command(flatten)]
    pub cluster: super::cluster::ClusterArgs,
    /// No diversity (by default: text diversity with minilm, and with rendering, dynamics
    /// diversity at the profile's budgets, on a trainer worker).
    #[arg(
        long,
        conflicts_with_all = ["text_models", "dynamics_budgets"],
        help_heading = "Diversity"
    )]
    pub no_diversity: bool,
    /// The size of what is not set explicitly: `quick` — dynamics diversity from world models of
    /// 200 steps trained on 4 and 8 episodes per group (seconds per fit, curves from few
    /// episodes) — or `paper` — the paper's 10, 20 and 40 episodes, 2000 steps each (about 2½
    /// minutes per fit on one core). --dynamics-budgets and --world-model win over either.
    #[arg(long, value_enum, default_value = "quick", help_heading = "Diversity")]
    pub profile: Profile,
    /// Training shards the trainer worker runs at once (world-model fits use one CPU thread
    /// each; default: the number of CPUs).
    #[arg(long)]
    pub trainer_capacity: Option<u32>,
    /// Output folder: report.json, report.md, artifacts/, config.toml (this run's resolved
    /// settings: `--config OUT/config.toml` runs it again), and run/ (job store and process logs).
    /// Run the same command again to continue an interrupted run from its job store; a folder
    /// holding another batch, or one Assay did not make, is refused.
    #[arg(long, default_value = "assay-out", help_heading = "Output")]
    pub out: PathBuf,
    /// Start this batch in --out even if it holds another batch's run (its run/ is replaced) or
    /// was not made by Assay (nothing but what a run writes is touched).
    #[arg(long, help_heading = "Output")]
    pub force: bool,
    #[command(flatten)]
    pub batch: super::submit::BatchArgs,
    #[command(flatten)]
    pub human: super::report::HumanArgs,
    /// Exit non-zero if any task was invalid or any episode failed with an error.
    #[arg(long, help_heading = "Output")]
    pub strict: bool,
    /// No progress bar (logs a line per change instead).
    #[arg(long, help_heading = "Output")]
    pub quiet: bool,
}

/// How large the defaults of `assay eval` are (`--profile`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Profile {
    /// Minutes on a laptop.
    Quick,
    /// The papers' scale.
    Paper,
}

/// Dynamics budgets and world-model steps of the `quick` profile.
const QUICK_BUDGETS: [u32; 2] = [4, 8];
const QUICK_STEPS: u64 = 200;

/// Runs the batch. `resolved` is the run's resolved configuration (`crate::config::resolved`),
/// written to OUT/config.toml once the folder is claimed.
pub fn run(mut a: Args, resolved: Option<String>) -> anyhow::Result<ExitCode> {
    // Read before anything starts: a bad ratings file fails now, not after the batch.
    let human = a.human.table()?;
    // Read (and import) everything first: the output folder is claimed before anything is
    // written into it.
    let mut imported = Vec::new();
    let docs = match a.import {
        None => crate::docs::collect(&a.paths)?,
        Some(pipeline) => {
            let mut docs = Vec::new();
            for path in &a.paths {
                let batch = super::import::read(pipeline, path, None)?;
                docs.extend(super::import::documents(&batch));
                imported.push((path.clone(), batch));
            }
            anyhow::ensure!(!docs.is_empty(), "no task could be imported");
            docs
        }
    };
    crate::outdir::check_apart(&a.out, &a.paths)?;
    let rendering =
        a.cluster.render_workers > 0 || a.cluster.roles.split(',').any(|r| r.trim() == "render");
    if a.cluster.no_judge || !rendering {
        if !a.batch.judges.is_empty() {
            anyhow::bail!("--judge needs rendered episodes: run with --roles sim,render");
        }
    } else if a.batch.judges.is_empty() {
        a.batch.judges.push(assay_judge::OFFLINE.into());
    }
    if !a.no_diversity {
        if a.batch.text_models.is_empty() {
            a.batch.text_models.push("minilm".into());
        }
        if a.batch.dynamics_budgets.is_empty() && rendering {
            match a.profile {
                Profile::Quick => {
                    a.batch.dynamics_budgets = QUICK_BUDGETS.to_vec();
                    if a.batch.world_model.is_none() {
                        a.batch.world_model = Some(format!("{{\"steps\": {QUICK_STEPS}}}"));
                    }
                }
                Profile::Paper => {
                    a.batch.dynamics_budgets = assay_model::dynamics::DEFAULT_BUDGETS.to_vec();
                }
            }
        }
    }
    if !a.batch.dynamics_budgets.is_empty() && !rendering {
        anyhow::bail!("--dynamics-budgets needs rendered clips: run with --roles sim,render");
    }
    if a.batch.rank_ladder.is_some() && !rendering {
        anyhow::bail!("--rank-ladder needs rendered clips: run with --roles sim,render");
    }
    if !a.batch.rank_train_policies.is_empty() && !rendering {
        anyhow::bail!("--rank-train-policies needs rendered clips: run with --roles sim,render");
    }
    if a.batch.generalization.is_some() && !rendering {
        anyhow::bail!("--generalization needs rendered clips: run with --roles sim,render");
    }
    let training = !a.batch.text_models.is_empty()
        || !a.batch.dynamics_budgets.is_empty()
        || !a.batch.rank_train_policies.is_empty()
        || a.batch.generalization.is_some();
    if training && !cfg!(feature = "trainer") {
        anyhow::bail!(
            "this build has no trainer role (built without the `trainer` feature): run with --no-diversity"
        );
    }
    if let Some(path) = &a.cluster.config {
        // Fail here, before anything starts, rather than in the judge worker's log.
        let cfg = assay_judge::Config::load(path).map_err(anyhow::Error::msg)?;
        for j in &a.batch.judges {
            if cfg.judge(j).is_none() {
                anyhow::bail!(
                    "judge '{j}' is not in {} (configured: {})",
                    path.display(),
                    cfg.names().join(", ")
                );
            }
        }
    } else if let Some(j) = a.batch.judges.iter().find(|j| *j != assay_judge::OFFLINE) {
        anyhow::bail!("judge '{j}' needs a configuration file (--config) that defines it");
    }
    let roots = crate::docs::asset_roots(&a.paths, &a.batch.asset_roots)?;
    let mut req = a
        .batch
        .request(docs, &super::submit::default_name(&a.paths));
    req.asset_roots = crate::docs::root_strings(&roots);
    req.render = rendering;
    // The coordinator's own check of the batch's settings, before any process starts.
    let settings = assay_coordinator::settings::check(&req)
        .map_err(|e| anyhow::anyhow!("the batch's settings: {e}"))?;
    if settings
        .ranking
        .as_ref()
        .is_some_and(|r| !r.groups.is_empty())
        || settings
            .generalization
            .as_ref()
            .is_some_and(|g| !g.groups.is_empty())
    {
        let (tasks, _) = assay_coordinator::service::plan_tasks(&req.tasks, &roots);
        let groups: Vec<&str> = tasks.iter().map(|t| t.info.group.as_str()).collect();
        assay_coordinator::settings::check_groups(&settings, &groups)
            .map_err(|e| anyhow::anyhow!("the batch's settings: {e}"))?;
    }
    let claim = crate::outdir::claim(&a.out, &crate::outdir::batch_key(&req), a.force)?;
    if let Some(resolved) = resolved {
        let path = a.out.join("config.toml");
        std::fs::write(&path, resolved).with_context(|| format!("writing {}", path.display()))?;
    }
    for (k, (path, batch)) in imported.iter().enumerate() {
        let pipeline = a.import.expect("imported with a pipeline");
        print!("{}", batch.report());
        let dir = match k {
            0 => a.out.clone(),
            _ => a.out.join(format!("import-{k}")),
        };
        super::import::write(batch, &dir)?;
        println!(
            "imported {} of {} {pipeline} task(s) from {} ({} not imported; mapping in {})",
            batch.specs().len(),
            batch.tasks.len(),
            path.display(),
            super::import::failed(batch),
            dir.join("import-report.json").display()
        );
    }
    let run_dir = a.out.join("run");
    let mut cluster = super::cluster::LocalCluster::start(
        &super::cluster::Plan {
            workers: a.cluster.workers,
            capacity: a.cluster.capacity,
            roles: a.cluster.roles.clone(),
            render_workers: a.cluster.render_workers,
            image_size: a.cluster.image_size.clone(),
            video: a.cluster.video,
            config: a.cluster.config.clone(),
            judges: a.batch.judges.clone(),
            judge_capacity: a.cluster.judge_capacity,
            training,
            trainer_capacity: a.trainer_capacity,
            asset_roots: roots.clone(),
        },
        &run_dir,
        &a.out.join(assay_report::report::ARTIFACTS_LINK),
    )?;
    let addr = cluster.addr.clone();
    let telemetry = cluster.telemetry.clone();

    let quiet = a.quiet;
    let (has_judges, has_training) = (!a.batch.judges.is_empty(), training);
    let out = a.out.clone();
    // A local process that dies (a crash, the OOM killer) is started again (a few times, with
    // backoff); one that keeps dying stops the watch, and the report of what finished is still
    // written.
    let mut events: Vec<String> = Vec::new();
    let outcome = super::block_on(async {
        let mut c = super::client(&addr).await?;
        let (batch_id, rejected) = match &claim {
            crate::outdir::Claim::Resume { batch_id } => {
                eprintln!(
                    "batch {batch_id}: going on from the job store in {} (finished episodes are \
                     kept)",
                    run_dir.display()
                );
                (batch_id.clone(), None)
            }
            crate::outdir::Claim::Fresh => {
                let r = c.submit_batch(req).await?.into_inner();
                crate::outdir::submitted(&out, &r.batch_id)?;
                super::print_rejected(&r.rejected);
                eprintln!(
                    "batch {}: {} tasks accepted, {} rejected, {} episodes",
                    r.batch_id,
                    r.accepted_tasks,
                    r.rejected.len(),
                    r.shards
                );
                (r.batch_id, Some(r.rejected.len()))
            }
        };
        // One bar per kind of work the batch has, each with its own ETA: episodes, judging,
        // training.
        let bars = if quiet {
            MultiProgress::with_draw_target(ProgressDrawTarget::hidden())
        } else {
            MultiProgress::new()
        };
        let style =
            |template: &str| ProgressStyle::with_template(template).expect("progress template");
        let bar = bars.add(ProgressBar::new(0));
        bar.set_style(style(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} episodes, eta {eta}  {msg}",
        ));
        let judging = ProgressBar::new(0);
        judging.set_style(style(
            "  judging      {bar:40} {pos}/{len} episodes judged, eta {eta}  {msg}",
        ));
        let training_bar = ProgressBar::new(0);
        training_bar.set_style(style(
            "  training     {bar:40} {pos}/{len} trainer jobs, eta {eta}  {msg}",
        ));
        // Shown from the start when the batch will have such work, in this order.
        if has_judges {
            bars.add(judging.clone());
        }
        if has_training {
            bars.add(training_bar.clone());
        }
        // Cluster-wide rates from the workers' telemetry, shown beside the progress.
        let rates = std::sync::Arc::new(std::sync::Mutex::new(std::collections::HashMap::<
            String,
            (f64, f64),
        >::new()));
        let viewer = match &telemetry {
            Some(endpoint) => {
                // The local cluster's processes inherit this process's token, if any.
                let password = assay_proto::auth::Token::from_env()
                    .ok()
                    .flatten()
                    .map(|t| t.derive("zenoh"));
                assay_telemetry::open_client(endpoint, password.as_deref())
                    .await
                    .ok()
            }
            None => None,
        };
        let mut listener = None;
        if let Some(session) = &viewer
            && let Ok(sub) = assay_telemetry::ClusterSubscriber::new(session, "local").await
        {
            let rates = rates.clone();
            listener = Some(tokio::spawn(async move {
                while let Some((key, v)) = sub.next().await {
                    if key.ends_with("/stats")
                        && let Ok(s) = serde_json::from_value::<assay_telemetry::WorkerStats>(v)
                    {
                        rates
                            .lock()
                            .expect("rates")
                            .insert(s.worker, (s.physics_steps_per_s, s.frames_per_s));
                    }
                }
            }));
        }
        let mut stream = c
            .watch_batch(pb::GetBatchRequest {
                batch_id: batch_id.clone(),
            })
            .await?
            .into_inner();
        let mut last = None;
        let mut exited = None;
        // Set while the coordinator is unreachable (it died and is being started again).
        let mut lost: Option<tonic::Status> = None;
        let mut lost_since = std::time::Instant::now();
        let mut check = tokio::time::interval(Duration::from_secs(1));
        loop {
            let next = if lost.is_none() {
                tokio::select! {
                    st = stream.message() => Some(st),
                    _ = check.tick() => None,
                }
            } else {
                check.tick().await;
                None
            };
            match cluster.supervise() {
                Ok(lines) => {
                    for l in lines {
                        bars.suspend(|| eprintln!("{l}"));
                        events.push(l);
                    }
                }
                Err(e) => {
                    exited = Some(e.to_string());
                    break;
                }
            }
            let st = match next {
                Some(Ok(Some(st))) => st,
                Some(Ok(None)) => break,
                Some(Err(e)) => {
                    lost = Some(e);
                    lost_since = std::time::Instant::now();
                    continue;
                }
                None => {
                    if let Some(e) = &lost {
                        // Back on the same address: watch the batch again.
                        let again = async {
                            let mut c2 = super::client(&addr).await?;
                            let s2 = c2
                                .watch_batch(pb::GetBatchRequest {
                                    batch_id: batch_id.clone(),
                                })
                                .await?
                                .into_inner();
                            anyhow::Ok((c2, s2))
                        };
                        match again.await {
                            Ok((c2, s2)) => {
                                (c, stream) = (c2, s2);
                                lost = None;
                            }
                            Err(_) if lost_since.elapsed() < Duration::from_secs(120) => {}
                            Err(e2) => anyhow::bail!(
                                "lost the local coordinator ({}) and could not reach it again \
                                 ({e2}); run the same command again to go on from the job store",
                                e.message()
                            ),
                        }
                    }
                    continue;
                }
            };
            let finished = st.shards_done + st.shards_failed + st.shards_cancelled;
            bar.set_length(u64::from(st.shards_total));
            bar.set_position(u64::from(finished));
            let (steps, frames) = rates
                .lock()
                .expect("rates")
                .values()
                .fold((0.0, 0.0), |a, r| (a.0 + r.0, a.1 + r.1));
            if st.judge_total > 0 {
                judging.set_length(u64::from(st.judge_total));
                judging.set_position(u64::from(st.judge_done + st.judge_failed));
                judging.set_message(format!("{} failed", st.judge_failed));
            }
            if st.trainer_total > 0 {
                training_bar.set_length(u64::from(st.trainer_total));
                training_bar.set_position(u64::from(st.trainer_done + st.trainer_failed));
                training_bar.set_message(format!("{} failed", st.trainer_failed));
            }
            bar.set_message(format!(
                "{} ok, {} failed, {} running, {} workers, {:.0} steps/s, {:.0} frames/s",
                st.successes,
                st.shards_failed,
                st.shards_running,
                st.workers_connected,
                steps,
                frames
            ));
            if quiet {
                eprintln!("{}", super::status::line(&st));
            }
            last = Some(st);
        }
        bar.finish();
        if has_judges {
            judging.finish();
        }
        if has_training {
            training_bar.finish();
        }
        if let Some(l) = listener {
            l.abort();
        }
        if let Some(v) = viewer {
            assay_telemetry::close(v).await;
        }
        let report = c
            .get_report(pb::GetReportRequest {
                batch_id: batch_id.clone(),
            })
            .await;
        let report = match (report, &exited) {
            (Ok(r), _) => r.into_inner(),
            (Err(e), Some(why)) => anyhow::bail!(
                "{why}, and no report could be fetched ({e}); run the same command again to go \
                 on from the job store"
            ),
            (Err(e), None) => return Err(e.into()),
        };
        anyhow::Ok((last, report, rejected, exited))
    });
    cluster.stop();
    let (last, report, rejected, exited) = outcome?;
    let mut parsed = super::report::parse(&report)?;
    if let crate::outdir::Claim::Resume { batch_id } = &claim {
        parsed.run.events.push(format!(
            "went on with batch {batch_id} from the job store of an earlier run"
        ));
    }
    parsed.run.events.extend(events);
    parsed.imports = imported
        .iter()
        .enumerate()
        .map(|(k, (path, batch))| {
            let file = match k {
                0 => "import-report.json".to_string(),
                _ => format!("import-{k}/import-report.json"),
            };
            super::import::summary(batch, path, &file)
        })
        .collect();
    super::report::write(
        &a.out,
        &parsed,
        &a.out.join(assay_report::report::ARTIFACTS_LINK),
        human.as_ref(),
    )?;
    for line in super::report::ranking_lines(&parsed) {
        println!("{line}");
    }
    if let (Some(why), None) = (&exited, &last) {
        eprintln!(
            "{why}: the report holds what finished; run the same command again to go on from \
             the job store"
        );
        return Ok(ExitCode::FAILURE);
    }
    let last = last.context("no status from the coordinator")?;
    eprintln!(
        "{}: {}/{} episodes completed, {} succeeded, {} failed; report in {} (and report.md, report.json)",
        super::state_name(last.state),
        last.shards_done,
        last.shards_total,
        last.successes,
        last.shards_failed,
        a.out.join("report.html").display()
    );
    if let Some(why) = exited {
        eprintln!(
            "{why}: the report holds what finished; run the same command again to go on from \
             the job store"
        );
        return Ok(ExitCode::FAILURE);
    }
    let completed = last.state == pb::BatchState::Completed as i32;
    let rejected = rejected.unwrap_or(parsed.results.invalid_tasks.len());
    let clean = rejected == 0 && last.shards_failed == 0;
    Ok(if completed && (clean || !a.strict) {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
