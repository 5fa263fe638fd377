//! `assay eval`, the embedded default, as a library: a batch of task files (or a generator's
//! output, imported first) run end to end on a local cluster of real processes, its report
//! bundle written into the output folder.
//!
//! A run goes through phases, each a function: [`prepare`] (defaults, every check that can fail
//! before a process starts, the request), claiming the output folder and writing what it holds
//! before the batch (`config.toml`, the import's mapping), starting the local cluster, submitting
//! or resuming the batch and following it ([`crate::follow`]), and writing the report bundle.
//!
//! Owns: the run's defaults and checks, the order of its phases. Never prints (an
//! [`Observer`] is told what happens) or decides the exit code (the caller reads [`Outcome`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use assay_import::{Import, Pipeline};
use assay_plan::settings::{BatchSettings, check, check_groups, check_seeds};
use assay_plan::{TaskDocument, plan_tasks};
use assay_proto::v1 as pb;
use assay_report::report::{ARTIFACTS_LINK, Report};

use crate::batch::{BatchArgs, default_name};
use crate::bundle::HumanArgs;
use crate::follow::{Event, Observer};
use crate::local::{ClusterArgs, LocalCluster};
use crate::outdir::Claim;
use crate::{bundle, docs, imports, outdir};

/// What `assay eval` runs (its flags, but for how it prints and exits).
#[derive(clap::Args, Clone)]
pub struct EvalArgs {
    /// Task spec files or folders (walked for .yaml, .yml, .json); with --import, the
    /// generator's output trees.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Read PATHS as a generator's own output (gensim, robogen or bbsea): import them first,
    /// print the per-task mapping report and write it to OUT/import-report.json.
    #[arg(long, value_name = "PIPELINE")]
    pub import: Option<Pipeline>,
    #[command(flatten)]
    pub cluster: ClusterArgs,
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
    pub batch: BatchArgs,
    #[command(flatten)]
    pub human: HumanArgs,
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

/// How a run ended.
pub struct Outcome {
    /// The report as written into the output folder.
    pub report: Report,
    /// The batch's last status (none if the cluster gave up before the coordinator answered).
    pub last: Option<pb::BatchStatus>,
    /// Tasks the coordinator rejected.
    pub rejected: usize,
    /// Why the local cluster gave up before the batch ended, if it did.
    pub exited: Option<String>,
}

impl Outcome {
    /// Whether the batch completed, and, when `strict`, with no invalid task and no failed
    /// episode.
    pub fn succeeded(&self, strict: bool) -> bool {
        let Some(last) = self.last.as_ref().filter(|_| self.exited.is_none()) else {
            return false;
        };
        let completed = last.state == pb::BatchState::Completed as i32;
        let clean = self.rejected == 0 && last.shards_failed == 0;
        completed && (clean || !strict)
    }
}

/// A run checked and ready to start: nothing has been written yet.
struct Prepared {
    human: Option<assay_stats::agreement::AgreementTable>,
    imported: Imported,
    roots: Vec<PathBuf>,
    training: bool,
    req: pb::SubmitBatchRequest,
}

/// Runs the batch; `resolved` is the run's resolved configuration, written to OUT/config.toml
/// once the folder is claimed.
pub fn run(
    mut a: EvalArgs,
    resolved: Option<String>,
    observer: &mut dyn Observer,
) -> anyhow::Result<Outcome> {
    let prepared = prepare(&mut a)?;
    let claim = outdir::claim(&a.out, &outdir::batch_key(&prepared.req), a.force)?;
    if let Some(resolved) = resolved {
        let path = a.out.join("config.toml");
        std::fs::write(&path, resolved).with_context(|| format!("writing {}", path.display()))?;
    }
    write_imports(&a, &prepared.imported, observer)?;
    let run_dir = a.out.join("run");
    let plan = a.cluster.plan(
        &a.batch.judges,
        &a.batch.policies,
        prepared.training,
        a.trainer_capacity,
        docs::worker_roots(&prepared.roots, &a.batch.policies),
    );
    let mut cluster = LocalCluster::start(&plan, &run_dir, &a.out.join(ARTIFACTS_LINK))?;
    observer.event(Event::ClusterStarted {
        description: &cluster.description,
    });
    let work = (!a.batch.judges.is_empty(), prepared.training);
    let followed = crate::rt::block_on(submit_and_follow(
        &a.out,
        &claim,
        prepared.req,
        &mut cluster,
        work,
        observer,
    ));
    cluster.stop();
    let (followed, rejected) = followed?;
    let mut report = bundle::parse(&followed.report)?;
    if let Claim::Resume { batch_id } = &claim {
        report.run.events.push(format!(
            "went on with batch {batch_id} from the job store of an earlier run"
        ));
    }
    report.run.events.extend(followed.events);
    report.imports = import_summaries(&prepared.imported);
    let artifacts = a.out.join(ARTIFACTS_LINK);
    bundle::write(&a.out, &report, &artifacts, prepared.human.as_ref())?;
    let rejected = rejected.unwrap_or(report.results.invalid_tasks.len());
    Ok(Outcome {
        report,
        last: followed.last,
        rejected,
        exited: followed.exited,
    })
}

/// Reads (and imports) everything, applies the defaults and runs every check that can fail
/// before a process starts: the output folder is claimed only after.
fn prepare(a: &mut EvalArgs) -> anyhow::Result<Prepared> {
    // Read before anything starts: a bad ratings file fails now, not after the batch.
    let human = a.human.table()?;
    let (docs, imported) = documents(a)?;
    outdir::check_apart(&a.out, &a.paths)?;
    let rendering = a.cluster.rendering();
    apply_defaults(a, rendering)?;
    let training = check_work(a, rendering)?;
    check_judges(a)?;
    let roots = docs::asset_roots(&a.paths, &a.batch.asset_roots)?;
    let mut req = a.batch.request(docs, &default_name(&a.paths));
    req.asset_roots = docs::root_strings(&roots);
    req.render = rendering;
    check_settings(&req, &roots)?;
    Ok(Prepared {
        human,
        imported,
        roots,
        training,
        req,
    })
}

/// Each generator tree given and what its import made.
type Imported = Vec<(PathBuf, Import)>;

/// The batch's task documents: the files under the paths, or what their import made.
fn documents(a: &EvalArgs) -> anyhow::Result<(Vec<TaskDocument>, Imported)> {
    let Some(pipeline) = a.import else {
        return Ok((docs::collect(&a.paths)?, Vec::new()));
    };
    let mut docs = Vec::new();
    let mut imported = Vec::new();
    for path in &a.paths {
        let batch = imports::read(pipeline, path, None, None)?;
        docs.extend(imports::documents(&batch));
        imported.push((path.clone(), batch));
    }
    anyhow::ensure!(!docs.is_empty(), "no task could be imported");
    Ok((docs, imported))
}

/// The defaults of what is not set: the offline judge when episodes are rendered and judged,
/// text diversity with minilm, and dynamics diversity at the profile's budgets. Judges without
/// judging are refused.
fn apply_defaults(a: &mut EvalArgs, rendering: bool) -> anyhow::Result<()> {
    if a.cluster.no_judge || !rendering {
        if !a.batch.judges.is_empty() {
            anyhow::bail!("--judge needs rendered episodes: run with --roles sim,render");
        }
    } else if a.batch.judges.is_empty() {
        a.batch.judges.push(assay_judge::OFFLINE.into());
    }
    if a.no_diversity {
        return Ok(());
    }
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
    Ok(())
}

/// Refuses work that needs pictures without rendering, and training without a trainer role;
/// returns whether the batch trains anything.
fn check_work(a: &EvalArgs, rendering: bool) -> anyhow::Result<bool> {
    if !rendering {
        let b = &a.batch;
        let needs = [
            (
                "--dynamics-budgets needs rendered clips",
                !b.dynamics_budgets.is_empty(),
            ),
            (
                "--rank-ladder needs rendered clips",
                b.rank_ladder.is_some(),
            ),
            (
                "--rank-train-policies needs rendered clips",
                !b.rank_train_policies.is_empty(),
            ),
            (
                "--generalization needs rendered clips",
                b.generalization.is_some(),
            ),
        ];
        if let Some((what, _)) = needs.iter().find(|(_, asked)| *asked) {
            anyhow::bail!("{what}: run with --roles sim,render");
        }
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
    Ok(training)
}

/// Every judge named is in the configuration file (or is the built-in offline judge): failed
/// here, before anything starts, rather than in the judge worker's log.
fn check_judges(a: &EvalArgs) -> anyhow::Result<()> {
    let Some(path) = &a.cluster.config else {
        if let Some(j) = a.batch.judges.iter().find(|j| *j != assay_judge::OFFLINE) {
            anyhow::bail!("judge '{j}' needs a configuration file (--config) that defines it");
        }
        return Ok(());
    };
    let cfg = assay_judge::Config::load(path).map_err(anyhow::Error::msg)?;
    if let Some(j) = a.batch.judges.iter().find(|j| cfg.judge(j).is_none()) {
        anyhow::bail!(
            "judge '{j}' is not in {} (configured: {})",
            path.display(),
            cfg.names().join(", ")
        );
    }
    Ok(())
}

/// The coordinator's own check of the batch's settings, of its seeds against the held-out ones,
/// and of the groups its ranking and generalization name, before any process starts.
fn check_settings(req: &pb::SubmitBatchRequest, roots: &[PathBuf]) -> anyhow::Result<()> {
    let at = |e: assay_plan::SettingsError| anyhow::anyhow!("the batch's settings: {e}");
    let settings = check(&BatchSettings::from(req)).map_err(at)?;
    check_seeds(&settings, &req.seeds).map_err(at)?;
    let scoped = |groups: Option<&Vec<String>>| groups.is_some_and(|g| !g.is_empty());
    if scoped(settings.ranking.as_ref().map(|r| &r.groups))
        || scoped(settings.generalization.as_ref().map(|g| &g.groups))
    {
        let docs: Vec<TaskDocument> = req.tasks.iter().map(TaskDocument::from).collect();
        let (tasks, _) = plan_tasks(&docs, roots);
        let groups: Vec<&str> = tasks.iter().map(|t| t.info.group.as_str()).collect();
        check_groups(&settings, &groups).map_err(at)?;
    }
    Ok(())
}

/// Each import's specs and mapping report: the first in the output folder, the others in
/// `import-K/` beside it.
fn write_imports(
    a: &EvalArgs,
    imported: &[(PathBuf, Import)],
    observer: &mut dyn Observer,
) -> anyhow::Result<()> {
    for (k, (path, batch)) in imported.iter().enumerate() {
        let pipeline = a.import.expect("imported with a pipeline");
        let dir = match k {
            0 => a.out.clone(),
            _ => a.out.join(format!("import-{k}")),
        };
        imports::write(batch, &dir)?;
        observer.event(Event::Imported {
            pipeline,
            path,
            import: batch,
            folder: &dir,
        });
    }
    Ok(())
}

/// What the report says of each import.
fn import_summaries(imported: &[(PathBuf, Import)]) -> Vec<assay_report::report::ImportSummary> {
    imported
        .iter()
        .enumerate()
        .map(|(k, (path, batch))| {
            let file = match k {
                0 => "import-report.json".to_string(),
                _ => format!("import-{k}/import-report.json"),
            };
            imports::summary(batch, path, &file)
        })
        .collect()
}

/// Submits the batch (or goes on with the one of the job store) and follows it; returns how
/// following ended and, for a submission, how many tasks were rejected.
async fn submit_and_follow(
    out: &Path,
    claim: &Claim,
    req: pb::SubmitBatchRequest,
    cluster: &mut LocalCluster,
    work: (bool, bool),
    observer: &mut dyn Observer,
) -> anyhow::Result<(crate::follow::Followed, Option<usize>)> {
    let addr = cluster.addr.clone();
    let mut c = crate::client::connect(&addr).await?;
    let (batch_id, rejected) = match claim {
        Claim::Resume { batch_id } => {
            let run_dir = out.join("run");
            observer.event(Event::Resumed {
                batch_id,
                run_dir: &run_dir,
            });
            (batch_id.clone(), None)
        }
        Claim::Fresh => {
            let r = crate::client::submit(&mut c, req).await?;
            outdir::submitted(out, &r.batch_id)?;
            observer.event(Event::Submitted { response: &r });
            (r.batch_id, Some(r.rejected.len()))
        }
    };
    let followed = crate::follow::follow(&addr, c, &batch_id, cluster, work, observer).await?;
    Ok((followed, rejected))
}
