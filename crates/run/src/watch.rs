//! `assay watch DIR`: continuous evaluation. Every batch (a sub-folder of task specs) that lands
//! in DIR is evaluated once it has stopped changing; a batch whose tasks were evaluated before
//! (the same content hash) is recorded as skipped, not run again; each evaluated batch gets its
//! marginal text diversity against every batch evaluated before it; a corpus report accumulates.
//!
//! The coordinator keeps the history (every batch, skipped ones too, with its content hash) in
//! its job store: a local cluster's store persists in OUT/run across restarts of the watch, and
//! with `--coordinator` a lab's cluster does the same for everyone who submits to it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context;
use assay_proto::v1 as pb;
use assay_stats::diversity::{Marginal, marginal_diversity, text_diversity};
use serde::{Deserialize, Serialize};

/// The corpus report, `OUT/corpus.json`.
pub const CORPUS_JSON: &str = "corpus.json";
pub const CORPUS_MD: &str = "corpus.md";

#[derive(clap::Args)]
pub struct Args {
    /// The folder to watch: each sub-folder is one batch of task specs (.yaml, .yml, .json).
    pub dir: PathBuf,
    /// Output folder: corpus.json and corpus.md, batches/NAME/report.{json,md,html},
    /// artifacts/, and run/ (the local cluster's job store and logs, kept across restarts).
    #[arg(long, default_value = "assay-watch")]
    pub out: PathBuf,
    /// Submit to this running coordinator instead of starting a local cluster (its job store
    /// keeps the history; report.html pictures need --artifacts to be its artifact store).
    #[arg(long)]
    pub coordinator: Option<String>,
    /// The artifact store for report.html pictures (default: OUT/artifacts, the local one).
    #[arg(long)]
    pub artifacts: Option<PathBuf>,
    /// How often DIR is listed, in milliseconds. A batch is taken when two listings in a row
    /// see the same files, sizes and modification times (a copy in progress is not taken).
    #[arg(long, default_value_t = 1000)]
    pub poll_ms: u64,
    /// Stop after this many batches were handled (evaluated or skipped); default: run until
    /// SIGINT or SIGTERM.
    #[arg(long)]
    pub exit_after: Option<usize>,
    /// Embedding models for marginal diversity (and each batch's text diversity).
    #[arg(
        long = "marginal-models",
        value_delimiter = ',',
        default_value = "minilm"
    )]
    pub marginal_models: Vec<String>,
    #[command(flatten)]
    pub cluster: super::cluster::ClusterArgs,
    #[command(flatten)]
    pub batch: super::submit::BatchArgs,
}

/// One batch the watch handled.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Entry {
    /// The sub-folder's name.
    pub name: String,
    /// Files, sizes and modification times when it was taken.
    pub fingerprint: String,
    pub batch_id: String,
    /// SHA-256 of the batch's tasks (the coordinator's).
    pub content_hash: String,
    /// `evaluated`, `skipped` (a repeat of `duplicate_of`), or `failed` (with `error`).
    pub outcome: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duplicate_of: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub tasks: u32,
    pub invalid_tasks: u32,
    pub episodes: u32,
    pub successes: u32,
    /// Texts of the batch's valid tasks, as text diversity embeds them.
    pub texts: Vec<String>,
    /// Per embedding model: the batch's marginal diversity against every batch evaluated
    /// before it (None for the first batch, with nothing before it).
    pub marginal: BTreeMap<String, Option<Marginal>>,
    /// Per embedding model: text diversity of the corpus (every evaluated batch) after it.
    pub corpus_diversity: BTreeMap<String, Option<f64>>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub diversity_errors: BTreeMap<String, String>,
    pub finished_at_unix_ms: i64,
}

/// The corpus report: every batch in the order handled.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Corpus {
    pub models: Vec<String>,
    pub batches: Vec<Entry>,
}

impl Corpus {
    /// The corpus report as Markdown.
    pub fn markdown(&self) -> String {
        let mut md = String::from("# Assay corpus: continuous evaluation\n\n");
        let evaluated = self
            .batches
            .iter()
            .filter(|b| b.outcome == "evaluated")
            .count();
        let tasks: u32 = self
            .batches
            .iter()
            .filter(|b| b.outcome == "evaluated")
            .map(|b| b.tasks)
            .sum();
        md.push_str(&format!(
            "{} batches seen: {evaluated} evaluated ({tasks} tasks), {} skipped as repeats, {} failed.\n\n",
            self.batches.len(),
            self.batches.iter().filter(|b| b.outcome == "skipped").count(),
            self.batches.iter().filter(|b| b.outcome == "failed").count(),
        ));
        md.push_str(
            "Marginal diversity: div(corpus before + batch) − div(corpus before), the paper's eq. 1 \
             on the task texts; positive means the batch widened the corpus.\n\n",
        );
        md.push_str("| # | batch | outcome | tasks | episodes | success |");
        for m in &self.models {
            md.push_str(&format!(" marginal ({m}) | corpus div ({m}) |"));
        }
        md.push_str("\n|---:|---|---|---:|---:|---:|");
        md.push_str(&"---:|---:|".repeat(self.models.len()));
        md.push('\n');
        for (i, b) in self.batches.iter().enumerate() {
            let outcome = match (&b.duplicate_of, &b.error) {
                (Some(d), _) => format!("skipped: repeats {d}"),
                (_, Some(e)) => format!("failed: {}", e.replace('|', "\\|").replace('\n', " ")),
                _ => format!("evaluated as `{}`", b.batch_id),
            };
            let success = if b.episodes > 0 {
                format!(
                    "{:.1} %",
                    100.0 * f64::from(b.successes) / f64::from(b.episodes)
                )
            } else {
                "–".into()
            };
            md.push_str(&format!(
                "| {} | {} | {outcome} | {} | {} | {success} |",
                i + 1,
                b.name.replace('|', "\\|"),
                b.tasks,
                b.episodes
            ));
            for m in &self.models {
                let marginal = match b.marginal.get(m) {
                    Some(Some(x)) => format!("{:+.3}", x.marginal),
                    Some(None) if b.outcome == "evaluated" => "first batch".into(),
                    _ => "–".into(),
                };
                let corpus = match b.corpus_diversity.get(m) {
                    Some(Some(d)) => format!("{d:.3}"),
                    _ => "–".into(),
                };
                md.push_str(&format!(" {marginal} | {corpus} |"));
            }
            md.push('\n');
        }
        md
    }
}

/// Files, sizes and modification times under `dir`, one per line, sorted.
fn fingerprint(dir: &Path) -> std::io::Result<String> {
    let mut lines = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d)? {
            let e = e?;
            let meta = e.metadata()?;
            if meta.is_dir() {
                stack.push(e.path());
                continue;
            }
            let modified = meta
                .modified()
                .unwrap_or(SystemTime::UNIX_EPOCH)
                .duration_since(SystemTime::UNIX_EPOCH)
                .unwrap_or_default()
                .as_nanos();
            lines.push(format!(
                "{} {} {modified}",
                e.path().strip_prefix(dir).unwrap_or(&e.path()).display(),
                meta.len()
            ));
        }
    }
    lines.sort();
    Ok(lines.join("\n"))
}

/// Sub-folders of `dir` (not hidden), sorted by name.
fn batch_folders(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let e = e?;
        let hidden = e.file_name().to_string_lossy().starts_with('.');
        if e.file_type()?.is_dir() && !hidden {
            out.push(e.path());
        }
    }
    out.sort();
    Ok(out)
}

fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

pub fn run(mut a: Args) -> anyhow::Result<ExitCode> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    anyhow::ensure!(a.dir.is_dir(), "{} is not a folder", a.dir.display());
    let rendering =
        a.cluster.render_workers > 0 || a.cluster.roles.split(',').any(|r| r.trim() == "render");
    if !a.cluster.no_judge && rendering && a.batch.judges.is_empty() {
        a.batch.judges.push(assay_judge::OFFLINE.into());
    }
    if a.batch.text_models.is_empty() {
        a.batch.text_models = a.marginal_models.clone();
    }
    let corpus_path = a.out.join(CORPUS_JSON);
    let mut corpus: Corpus = match std::fs::read_to_string(&corpus_path) {
        Ok(text) => serde_json::from_str(&text).with_context(|| {
            format!(
                "{} (move it away to start a new corpus)",
                corpus_path.display()
            )
        })?,
        Err(_) => Corpus::default(),
    };
    corpus.models = a.marginal_models.clone();
    let artifacts = a
        .artifacts
        .clone()
        .unwrap_or_else(|| a.out.join(assay_report::report::ARTIFACTS_LINK));
    let cluster = match &a.coordinator {
        Some(_) => None,
        None => Some(super::cluster::LocalCluster::start(
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
                training: true,
                trainer_capacity: None,
                asset_roots: crate::docs::asset_roots(
                    std::slice::from_ref(&a.dir),
                    &a.batch.asset_roots,
                )?,
            },
            &a.out.join("run"),
            &artifacts,
        )?),
    };
    let addr = match (&a.coordinator, &cluster) {
        (Some(c), _) => c.clone(),
        (None, Some(c)) => c.addr.clone(),
        (None, None) => unreachable!("a local cluster starts without --coordinator"),
    };
    // The local cluster's processes are started again when they die, as `assay eval` does.
    let mut cluster = cluster;
    let mut supervise = || -> anyhow::Result<()> {
        if let Some(c) = cluster.as_mut() {
            for line in c.supervise()? {
                eprintln!("{line}");
            }
        }
        Ok(())
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    {
        let stop = stop.clone();
        rt.spawn(async move {
            super::terminated().await;
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        });
    }
    let mut embedders = assay_trainer::embedders::Embedders::new(
        assay_trainer::embedders::Config::default(),
        assay_trainer::default_device(),
    );
    eprintln!(
        "watching {} (every {} ms); corpus report in {}",
        a.dir.display(),
        a.poll_ms,
        a.out.join(CORPUS_MD).display()
    );
    let mut pending: BTreeMap<PathBuf, String> = BTreeMap::new();
    let mut handled = 0usize;
    let result = (|| -> anyhow::Result<()> {
        loop {
            if stop.load(std::sync::atomic::Ordering::Relaxed)
                || a.exit_after.is_some_and(|n| handled >= n)
            {
                return Ok(());
            }
            supervise()?;
            for folder in batch_folders(&a.dir)? {
                let name = folder
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let Ok(print) = fingerprint(&folder) else {
                    continue;
                };
                if corpus
                    .batches
                    .iter()
                    .any(|b| b.name == name && b.fingerprint == print)
                {
                    continue;
                }
                // Taken only when two listings in a row agree (not while it is being copied).
                if pending.get(&folder) != Some(&print) {
                    pending.insert(folder, print);
                    continue;
                }
                pending.remove(&folder);
                let entry = handle(
                    &a,
                    &rt,
                    &addr,
                    &folder,
                    &name,
                    print,
                    &artifacts,
                    &corpus,
                    &mut embedders,
                    &mut supervise,
                    &stop,
                );
                eprintln!("{}", summary(&entry, &corpus.models));
                corpus.batches.push(entry);
                std::fs::write(&corpus_path, serde_json::to_string_pretty(&corpus)? + "\n")?;
                std::fs::write(a.out.join(CORPUS_MD), corpus.markdown())?;
                handled += 1;
                if a.exit_after.is_some_and(|n| handled >= n) {
                    return Ok(());
                }
            }
            std::thread::sleep(Duration::from_millis(a.poll_ms.max(50)));
        }
    })();
    if let Some(c) = cluster {
        c.stop();
    }
    result?;
    Ok(ExitCode::SUCCESS)
}

/// One line for a terminal.
fn summary(e: &Entry, models: &[String]) -> String {
    match e.outcome.as_str() {
        "skipped" => format!(
            "{}: skipped, the same tasks were evaluated in {} (content {})",
            e.name,
            e.duplicate_of.as_deref().unwrap_or("?"),
            &e.content_hash[..e.content_hash.len().min(12)]
        ),
        "evaluated" => {
            let marginal: Vec<String> = models
                .iter()
                .map(|m| match e.marginal.get(m) {
                    Some(Some(x)) => format!(
                        "{m} {:+.3} ({} tasks before, {:.3} → {:.3})",
                        x.marginal, x.base_n, x.base_div, x.union_div
                    ),
                    _ => match e.diversity_errors.get(m) {
                        Some(err) => format!("{m}: {err}"),
                        None => format!("{m}: first batch"),
                    },
                })
                .collect();
            format!(
                "{}: evaluated as {}: {} tasks, {}/{} episodes succeeded; marginal diversity: {}",
                e.name,
                e.batch_id,
                e.tasks,
                e.successes,
                e.episodes,
                marginal.join("; ")
            )
        }
        _ => format!(
            "{}: failed: {}",
            e.name,
            e.error.as_deref().unwrap_or_default()
        ),
    }
}

/// Submits one batch folder, waits for it, writes its reports and measures its marginal
/// diversity. Errors become a `failed` entry: the watch goes on with the next batch.
#[allow(clippy::too_many_arguments)]
fn handle(
    a: &Args,
    rt: &tokio::runtime::Runtime,
    addr: &str,
    folder: &Path,
    name: &str,
    print: String,
    artifacts: &Path,
    corpus: &Corpus,
    embedders: &mut assay_trainer::embedders::Embedders,
    supervise: &mut dyn FnMut() -> anyhow::Result<()>,
    stop: &std::sync::atomic::AtomicBool,
) -> Entry {
    let mut entry = Entry {
        name: name.to_owned(),
        fingerprint: print,
        batch_id: String::new(),
        content_hash: String::new(),
        outcome: "failed".into(),
        duplicate_of: None,
        error: None,
        tasks: 0,
        invalid_tasks: 0,
        episodes: 0,
        successes: 0,
        texts: Vec::new(),
        marginal: BTreeMap::new(),
        corpus_diversity: BTreeMap::new(),
        diversity_errors: BTreeMap::new(),
        finished_at_unix_ms: 0,
    };
    if let Err(e) = evaluate(
        a, rt, addr, folder, name, artifacts, corpus, embedders, supervise, stop, &mut entry,
    ) {
        entry.outcome = "failed".into();
        entry.error = Some(format!("{e:#}"));
    }
    entry.finished_at_unix_ms = now_ms();
    entry
}

#[allow(clippy::too_many_arguments)]
fn evaluate(
    a: &Args,
    rt: &tokio::runtime::Runtime,
    addr: &str,
    folder: &Path,
    name: &str,
    artifacts: &Path,
    corpus: &Corpus,
    embedders: &mut assay_trainer::embedders::Embedders,
    supervise: &mut dyn FnMut() -> anyhow::Result<()>,
    stop: &std::sync::atomic::AtomicBool,
    entry: &mut Entry,
) -> anyhow::Result<()> {
    let docs = crate::docs::collect(&[folder.to_path_buf()])?;
    let roots = crate::docs::asset_roots(std::slice::from_ref(&a.dir), &a.batch.asset_roots)?;
    let (planned, _) = assay_coordinator::service::plan_tasks(&docs, &roots);
    let templates = a.batch.text_templates.iter().cloned().collect();
    let texts = assay_coordinator::service::text_groups(&planned, &templates)
        .map_err(|s| anyhow::anyhow!("{}", s.message()))?
        .pop()
        .map(|(_, all)| all)
        .unwrap_or_default();
    let mut req = a.batch.request(docs, name);
    req.asset_roots = crate::docs::root_strings(&roots);
    req.skip_if_evaluated = true;
    req.render =
        a.cluster.render_workers > 0 || a.cluster.roles.split(',').any(|r| r.trim() == "render");
    let (response, status) = rt.block_on(async {
        let mut c = super::client(addr).await?;
        let r = c.submit_batch(req).await?.into_inner();
        super::print_rejected(&r.rejected);
        if !r.duplicate_of.is_empty() {
            return anyhow::Ok((r, None));
        }
        let started = Instant::now();
        // Set while the coordinator cannot be reached (a local one is started again).
        let mut lost_since: Option<Instant> = None;
        loop {
            supervise()?;
            let st = match c
                .get_batch(pb::GetBatchRequest {
                    batch_id: r.batch_id.clone(),
                })
                .await
            {
                Ok(st) => {
                    lost_since = None;
                    st.into_inner()
                }
                Err(e) => {
                    let since = *lost_since.get_or_insert_with(Instant::now);
                    if since.elapsed() > Duration::from_secs(120) {
                        anyhow::bail!(
                            "lost the coordinator while batch {} ran: {}",
                            r.batch_id,
                            e.message()
                        );
                    }
                    tokio::time::sleep(Duration::from_millis(500)).await;
                    if let Ok(again) = super::client(addr).await {
                        c = again;
                    }
                    continue;
                }
            };
            if st.state != pb::BatchState::Running as i32 {
                return Ok((r, Some(st)));
            }
            if stop.load(std::sync::atomic::Ordering::Relaxed) {
                anyhow::bail!(
                    "stopped while batch {} ran (on a running coordinator it carries on)",
                    r.batch_id
                );
            }
            if started.elapsed() > Duration::from_secs(10) && st.workers_connected == 0 {
                tracing::warn!(batch = %r.batch_id, "no worker is connected to the coordinator");
            }
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
    })?;
    entry.batch_id = response.batch_id.clone();
    entry.content_hash = response.content_hash.clone();
    entry.tasks = response.accepted_tasks;
    entry.invalid_tasks = response.rejected.len() as u32;
    let Some(status) = status else {
        entry.outcome = "skipped".into();
        entry.duplicate_of = Some(response.duplicate_of);
        return Ok(());
    };
    entry.episodes = status.shards_done;
    entry.successes = status.successes;
    let report = rt.block_on(async {
        let mut c = super::client(addr).await?;
        anyhow::Ok(
            c.get_report(pb::GetReportRequest {
                batch_id: response.batch_id.clone(),
            })
            .await?
            .into_inner(),
        )
    })?;
    let report = super::report::parse(&report)?;
    super::report::write(&a.out.join("batches").join(name), &report, artifacts, None)?;
    entry.outcome = "evaluated".into();
    // Marginal diversity against every batch evaluated before this one.
    let base: Vec<String> = corpus
        .batches
        .iter()
        .filter(|b| b.outcome == "evaluated")
        .flat_map(|b| b.texts.iter().cloned())
        .collect();
    for m in &a.marginal_models {
        let measured = (|| -> anyhow::Result<(Option<Marginal>, f64)> {
            let new = embedders.embed(m, &texts)?;
            if base.is_empty() {
                return Ok((None, text_diversity(&new, &texts)?));
            }
            let old = embedders.embed(m, &base)?;
            let x = marginal_diversity(&old, &base, &new, &texts)?;
            let union = x.union_div;
            Ok((Some(x), union))
        })();
        match measured {
            Ok((x, union)) => {
                entry.marginal.insert(m.clone(), x);
                entry.corpus_diversity.insert(m.clone(), Some(union));
            }
            Err(e) => {
                entry.marginal.insert(m.clone(), None);
                entry.corpus_diversity.insert(m.clone(), None);
                entry.diversity_errors.insert(m.clone(), format!("{e:#}"));
            }
        }
    }
    entry.texts = texts;
    Ok(())
}
