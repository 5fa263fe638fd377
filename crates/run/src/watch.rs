//! `assay watch DIR` as a library: continuous evaluation. Every batch (a sub-folder of task
//! specs) that lands in DIR is evaluated once it has stopped changing; a batch whose tasks were
//! evaluated before (the same content hash) is recorded as skipped, not run again; each evaluated
//! batch gets its marginal text diversity against every batch evaluated before it; a corpus
//! report accumulates.
//!
//! The coordinator keeps the history (every batch, skipped ones too, with its content hash) in
//! its job store: a local cluster's store persists in OUT/run across restarts of the watch, and
//! with `--coordinator` a lab's cluster does the same for everyone who submits to it.
//!
//! Owns: the watch loop and what it measures per batch (the corpus report is `corpus`).
//! Never prints (an [`Observer`] is told what happens).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use crate::batch::BatchArgs;
use crate::corpus::{CORPUS_JSON, CORPUS_MD, Corpus, Entry};
use crate::follow::{Event, Observer};
use crate::local::{ClusterArgs, LocalCluster};
use crate::{bundle, docs};
use anyhow::Context;
use assay_model::job::Priority;
use assay_proto::v1 as pb;
use assay_stats::diversity::{Marginal, marginal_diversity, text_diversity};

/// What `assay watch` watches and how (its flags).
#[derive(clap::Args)]
pub struct WatchArgs {
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
    pub cluster: ClusterArgs,
    #[command(flatten)]
    pub batch: BatchArgs,
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

/// The watch's resources: the cluster it submits to (a local one it keeps alive, or a running
/// coordinator), a runtime, the stop signal, and the embedding models of marginal diversity.
struct Watcher<'o> {
    a: WatchArgs,
    addr: String,
    cluster: Option<LocalCluster>,
    rt: std::sync::Arc<tokio::runtime::Runtime>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    artifacts: PathBuf,
    embedders: assay_embed::Embedders,
    observer: &'o mut dyn Observer,
}

/// Watches `a.dir` until stopped (SIGINT, SIGTERM) or `--exit-after` batches were handled.
pub fn run(mut a: WatchArgs, observer: &mut dyn Observer) -> anyhow::Result<()> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    anyhow::ensure!(a.dir.is_dir(), "{} is not a folder", a.dir.display());
    if !a.cluster.no_judge && a.cluster.rendering() && a.batch.judges.is_empty() {
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
    let mut w = Watcher::start(a, observer)?;
    let result = w.watch(&mut corpus, &corpus_path);
    if let Some(c) = w.cluster.take() {
        c.stop();
    }
    result
}

impl<'o> Watcher<'o> {
    /// Starts the local cluster (without `--coordinator`), the runtime and the signal handler.
    fn start(a: WatchArgs, observer: &'o mut dyn Observer) -> anyhow::Result<Self> {
        let artifacts = a
            .artifacts
            .clone()
            .unwrap_or_else(|| a.out.join(assay_report::report::ARTIFACTS_LINK));
        let cluster = match &a.coordinator {
            Some(_) => None,
            None => {
                let roots = docs::asset_roots(std::slice::from_ref(&a.dir), &a.batch.asset_roots)?;
                let roots = docs::worker_roots(&roots, &a.batch.policies);
                let plan = a
                    .cluster
                    .plan(&a.batch.judges, &a.batch.policies, true, None, roots);
                let cluster = LocalCluster::start(&plan, &a.out.join("run"), &artifacts)?;
                observer.event(Event::ClusterStarted {
                    description: &cluster.description,
                });
                Some(cluster)
            }
        };
        let addr = match (&a.coordinator, &cluster) {
            (Some(c), _) => c.clone(),
            (None, Some(c)) => c.addr.clone(),
            (None, None) => unreachable!("a local cluster starts without --coordinator"),
        };
        let rt = std::sync::Arc::new(crate::rt::runtime("assay-watch"));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        {
            let stop = stop.clone();
            rt.spawn(async move {
                crate::rt::terminated().await;
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
            });
        }
        let embedders = assay_embed::Embedders::on_default_device(assay_embed::Config::default());
        Ok(Self {
            a,
            addr,
            cluster,
            rt,
            stop,
            artifacts,
            embedders,
            observer,
        })
    }

    fn stopped(&self) -> bool {
        self.stop.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The local cluster's processes are started again when they die, as `assay eval` does.
    fn supervise(&mut self) -> anyhow::Result<()> {
        if let Some(c) = self.cluster.as_mut() {
            for line in c.supervise()? {
                self.observer.event(Event::Process { line: &line });
            }
        }
        Ok(())
    }

    /// Lists the folder every `--poll-ms` and handles each batch folder that stopped changing
    /// and was not handled before, writing the corpus report after each.
    fn watch(&mut self, corpus: &mut Corpus, corpus_path: &Path) -> anyhow::Result<()> {
        let corpus_md = self.a.out.join(CORPUS_MD);
        self.observer.event(Event::Watching {
            dir: &self.a.dir,
            poll_ms: self.a.poll_ms,
            corpus: &corpus_md,
        });
        let mut pending: BTreeMap<PathBuf, String> = BTreeMap::new();
        let mut handled = 0usize;
        let done = |handled: usize, a: &WatchArgs| a.exit_after.is_some_and(|n| handled >= n);
        loop {
            if self.stopped() || done(handled, &self.a) {
                return Ok(());
            }
            self.supervise()?;
            for folder in batch_folders(&self.a.dir)? {
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
                let entry = self.handle(&folder, &name, print, corpus);
                self.observer.event(Event::Handled {
                    entry: &entry,
                    models: &corpus.models,
                });
                corpus.batches.push(entry);
                std::fs::write(corpus_path, serde_json::to_string_pretty(&*corpus)? + "\n")?;
                std::fs::write(&corpus_md, corpus.markdown())?;
                handled += 1;
                if done(handled, &self.a) {
                    return Ok(());
                }
            }
            std::thread::sleep(Duration::from_millis(self.a.poll_ms.max(50)));
        }
    }

    /// Submits one batch folder, waits for it, writes its reports and measures its marginal
    /// diversity. Errors become a `failed` entry: the watch goes on with the next batch.
    fn handle(&mut self, folder: &Path, name: &str, print: String, corpus: &Corpus) -> Entry {
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
        if let Err(e) = self.evaluate(folder, name, corpus, &mut entry) {
            entry.outcome = "failed".into();
            entry.error = Some(format!("{e:#}"));
        }
        entry.finished_at_unix_ms = now_ms();
        entry
    }

    fn evaluate(
        &mut self,
        folder: &Path,
        name: &str,
        corpus: &Corpus,
        entry: &mut Entry,
    ) -> anyhow::Result<()> {
        let docs = docs::collect(&[folder.to_path_buf()])?;
        let roots =
            docs::asset_roots(std::slice::from_ref(&self.a.dir), &self.a.batch.asset_roots)?;
        let (planned, _) = assay_plan::plan_tasks(&docs, &roots);
        let templates = self.a.batch.text_templates.iter().cloned().collect();
        let texts = assay_plan::texts::all_texts(&planned, &templates)?;
        let mut req = self.a.batch.request(docs, name);
        req.asset_roots = docs::root_strings(&roots);
        req.skip_if_evaluated = true;
        // Continuous evaluation yields to a person's batch unless told otherwise.
        req.priority = self.a.batch.priority.unwrap_or(Priority::Low).to_string();
        req.render = self.a.cluster.rendering();
        let (response, status) = self.submit_and_wait(req)?;
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
        let report = self.rt.block_on(async {
            let mut c = crate::client::connect(&self.addr).await?;
            anyhow::Ok(
                c.get_report(pb::GetReportRequest {
                    batch_id: response.batch_id.clone(),
                })
                .await?
                .into_inner(),
            )
        })?;
        let report = bundle::parse(&report)?;
        let folder = self.a.out.join("batches").join(name);
        bundle::write(&folder, &report, &self.artifacts, None)?;
        entry.outcome = "evaluated".into();
        self.marginal(corpus, &texts, entry);
        entry.texts = texts;
        Ok(())
    }

    /// Submits the batch and polls it until it is final; a skipped repeat has no status.
    fn submit_and_wait(
        &mut self,
        req: pb::SubmitBatchRequest,
    ) -> anyhow::Result<(pb::SubmitBatchResponse, Option<pb::BatchStatus>)> {
        let rt = self.rt.clone();
        rt.block_on(async {
            let mut c = crate::client::connect(&self.addr).await?;
            let r = crate::client::submit(&mut c, req).await?;
            self.observer.event(Event::Rejected {
                errors: &r.rejected,
            });
            if !r.duplicate_of.is_empty() {
                return anyhow::Ok((r, None));
            }
            let status = self.wait(&mut c, &r.batch_id).await?;
            Ok((r, Some(status)))
        })
    }

    /// Polls `batch_id` until it is no longer running; a coordinator that cannot be reached is
    /// tried again for two minutes (a local one is being started again).
    async fn wait(
        &mut self,
        c: &mut crate::client::Client,
        batch_id: &str,
    ) -> anyhow::Result<pb::BatchStatus> {
        let started = Instant::now();
        let mut lost_since: Option<Instant> = None;
        loop {
            self.supervise()?;
            let asked = c
                .get_batch(pb::GetBatchRequest {
                    batch_id: batch_id.to_owned(),
                })
                .await;
            let st = match asked {
                Ok(st) => {
                    lost_since = None;
                    st.into_inner()
                }
                Err(e) => {
                    let since = *lost_since.get_or_insert_with(Instant::now);
                    if since.elapsed() > Duration::from_secs(120) {
                        anyhow::bail!(
                            "lost the coordinator while batch {batch_id} ran: {}",
                            e.message()
                        );
                    }
                    tokio::time::sleep(Duration::from_millis(500)).await;
                    if let Ok(again) = crate::client::connect(&self.addr).await {
                        *c = again;
                    }
                    continue;
                }
            };
            if st.state != pb::BatchState::Running as i32 {
                return Ok(st);
            }
            if self.stopped() {
                anyhow::bail!(
                    "stopped while batch {batch_id} ran (on a running coordinator it carries on)"
                );
            }
            if started.elapsed() > Duration::from_secs(10) && st.workers_connected == 0 {
                tracing::warn!(batch = %batch_id, "no worker is connected to the coordinator");
            }
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
    }

    /// Marginal diversity against every batch evaluated before this one, per model.
    fn marginal(&mut self, corpus: &Corpus, texts: &[String], entry: &mut Entry) {
        let base: Vec<String> = corpus
            .batches
            .iter()
            .filter(|b| b.outcome == "evaluated")
            .flat_map(|b| b.texts.iter().cloned())
            .collect();
        for m in &self.a.marginal_models {
            let measured = (|| -> anyhow::Result<(Option<Marginal>, f64)> {
                let new = self.embedders.embed(m, texts)?;
                if base.is_empty() {
                    return Ok((None, text_diversity(&new, texts)?));
                }
                let old = self.embedders.embed(m, &base)?;
                let x = marginal_diversity(&old, &base, &new, texts)?;
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
    }
}
