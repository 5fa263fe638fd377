//! A batch's settings as a client gives them (`--seeds`, `--policy`, `--judge`, the diversity,
//! ranking and generalization plans…), shared by `assay eval`, `assay watch` and `assay submit`,
//! and the `SubmitBatchRequest` they make. Nested settings are JSON checked as the coordinator
//! would check them while the command line is read, before anything starts.
//!
//! Owns: the flags and the request. Never reads files or talks to a coordinator.

use std::path::PathBuf;

use assay_plan::TaskDocument;
use assay_proto::v1 as pb;

#[derive(clap::Args, Clone)]
pub struct BatchArgs {
    /// Render every episode's pictures (scene views, keyframes, caption, contact sheet) even
    /// without a judge; judges, dynamics budgets, a ranking and generalization imply it. A
    /// rendering batch runs on sim workers with a renderer, or on sim workers and render workers.
    #[arg(long, help_heading = "Batch")]
    pub render: bool,
    /// A folder the tasks may read asset files (URDF, meshes) from, besides the task paths
    /// themselves (repeatable; default: the working folder). A task whose asset root lies
    /// outside them is rejected.
    #[arg(long = "asset-root", value_name = "DIR", help_heading = "Batch")]
    pub asset_roots: Vec<std::path::PathBuf>,
    /// Seeds 0..N per task and policy.
    #[arg(long, default_value_t = 5, help_heading = "Batch")]
    pub seeds: u64,
    /// Explicit seeds (overrides --seeds).
    #[arg(long, value_delimiter = ',', help_heading = "Batch")]
    pub seed_list: Vec<u64>,
    /// Policies, repeatable: `oracle[:noise=M][,grasp=P][,sense=state|camera]` (the task's
    /// scripted plan; `grasp=P`: its grasps close in a share P of episodes),
    /// `openpi:url=ws://HOST:PORT` (an openpi server), `remote:url=http://HOST:PORT` (an
    /// assay.v1.Policy server), `torchscript:path=FILE.pt` (a TorchScript module),
    /// `diffusion:model=KEY` (a diffusion policy the cluster trained), `random[:speed=V]`
    /// (exploration episodes). docs/policies.md has each one's arguments and interface.
    #[arg(long = "policy", default_value = "oracle", help_heading = "Policies")]
    pub policies: Vec<String>,
    /// A name for the batch (shown in reports).
    #[arg(long, help_heading = "Batch")]
    pub name: Option<String>,
    /// Attempts per shard before it is recorded as failed (0: coordinator default).
    #[arg(long, default_value_t = 0, help_heading = "Batch")]
    pub max_attempts: u32,
    /// Judges that score every rendered episode (names from the judge workers' configuration;
    /// `offline` is built in). Repeat or separate with commas.
    #[arg(long = "judge", value_delimiter = ',', help_heading = "Judging")]
    pub judges: Vec<String>,
    /// Times each judge item (scene alignment, completion) is asked.
    #[arg(long, default_value_t = assay_model::quality::DEFAULT_REPEATS, help_heading = "Judging")]
    pub judge_repeats: u32,
    /// Stop making judge calls once this batch's judges have spent this many USD (0: no limit).
    #[arg(long, default_value_t = 0.0, help_heading = "Judging")]
    pub judge_budget_usd: f64,
    /// Text diversity of the task texts with these embedding models (built in: minilm, mpnet;
    /// others from the trainer workers' `[embedders.NAME]`). Comma-separated.
    #[arg(
        long = "text-models",
        value_delimiter = ',',
        help_heading = "Diversity"
    )]
    pub text_models: Vec<String>,
    /// Text embedded per source pipeline, `PIPELINE=TEMPLATE` with {name} and {description}
    /// (default: the paper's GenSim form for GenSim tasks, the description for others).
    #[arg(long = "text-template", value_parser = parse_template, help_heading = "Diversity")]
    pub text_templates: Vec<(String, String)>,
    /// Dynamics diversity: world models per task group trained on these episode budgets
    /// (e.g. 10,20,40), evaluated on the group's first max(budgets) episodes.
    #[arg(
        long = "dynamics-budgets",
        value_delimiter = ',',
        help_heading = "Diversity"
    )]
    pub dynamics_budgets: Vec<u32>,
    /// World-model settings as JSON (fields of assay-model DynamicsConfig, e.g. '{"steps": 2000}');
    /// in the configuration file a table (`[eval.world-model]`).
    #[arg(long = "world-model", value_parser = setting::<assay_model::dynamics::DynamicsConfig>, help_heading = "Diversity")]
    pub world_model: Option<String>,
    /// Rank the batch's policies with a world-model proxy trained on the episodes of these
    /// policies (repeatable or comma-separated; they must be among --policies and are not ranked
    /// themselves). A policy's own arguments stay with it: `oracle,random:speed=0.3,max_steps=600`
    /// is two policies.
    #[arg(long = "rank-train-policies", help_heading = "Ranking")]
    pub rank_train_policies: Vec<String>,
    /// Proxy settings as JSON (fields of assay-model ProxyConfig, e.g.
    /// '{"judge_steps": 600, "world_model": {"steps": 2000}}'); in the file `[eval.proxy]`.
    #[arg(
        long = "proxy",
        requires = "rank_train_policies",
        value_parser = setting::<assay_model::proxy::ProxyConfig>,
        help_heading = "Ranking"
    )]
    pub proxy: Option<String>,
    /// Rank a ladder of learned policies too (the world model ranks checkpoints, as the paper
    /// does): per task group, diffusion policies trained on the first N episodes of one policy
    /// and kept at several training steps, each run on the group's tasks and seeds. Optional JSON
    /// settings over the defaults (fields of assay-model LadderPlan, e.g. '{"train_policy":
    /// "oracle", "episodes": [10, 40], "checkpoints": [300, 1000, 3000], "max_steps": 6000}');
    /// in the file `[eval.rank-ladder]`.
    #[arg(
        long = "rank-ladder",
        num_args = 0..=1,
        default_missing_value = "{}",
        requires = "rank_train_policies",
        value_parser = setting::<assay_model::proxy::LadderPlan>,
        help_heading = "Ranking"
    )]
    pub rank_ladder: Option<String>,
    /// Rank only these task groups (comma-separated; default: every group of the batch). A
    /// ranking costs minutes per group, and a ladder spreads only in a group whose tasks one
    /// policy can learn.
    #[arg(
        long = "rank-groups",
        value_delimiter = ',',
        requires = "rank_train_policies",
        help_heading = "Ranking"
    )]
    pub rank_groups: Vec<String>,
    /// Generalization: train a diffusion policy per task group on its oracle episodes and run it
    /// on training and held-out variations. Optional JSON settings (fields of assay-model
    /// GeneralizationPlan, e.g. '{"episodes": 40, "held_out_seeds": 3, "config": {"steps": 3000}}');
    /// in the file `[eval.generalization]`.
    #[arg(
        long = "generalization",
        num_args = 0..=1,
        default_missing_value = "{}",
        value_parser = setting::<assay_model::generalization::GeneralizationPlan>,
        help_heading = "Generalization"
    )]
    pub generalization: Option<String>,
    /// The batch's share of the cluster beside other running batches: low, normal or high
    /// (weights 1, 4, 16; workers go to running batches in proportion). Default: normal
    /// (`assay watch`: low).
    #[arg(long, help_heading = "Sharing")]
    pub priority: Option<assay_model::job::Priority>,
    /// The most workers that may hold the batch's shards at once (0: no cap).
    #[arg(long, default_value_t = 0, help_heading = "Sharing")]
    pub max_workers: u32,
    /// Who submits, for the fair share between submitters (default: $ASSAY_SUBMITTER, else
    /// user@host).
    #[arg(long, help_heading = "Sharing")]
    pub submitter: Option<String>,
}

/// Who submits when not told: `$ASSAY_SUBMITTER`, else `$USER@<host name>`.
pub fn default_submitter() -> String {
    if let Ok(s) = std::env::var("ASSAY_SUBMITTER") {
        return s;
    }
    let user = std::env::var("USER").unwrap_or_else(|_| "unknown".into());
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_owned())
        .unwrap_or_default();
    if host.is_empty() {
        user
    } else {
        format!("{user}@{host}")
    }
}

/// A nested setting of a batch, with the coordinator's own check of it.
trait Setting: serde::de::DeserializeOwned {
    fn check(&self) -> Result<(), String> {
        Ok(())
    }
}

impl Setting for assay_model::dynamics::DynamicsConfig {}

impl Setting for assay_model::proxy::ProxyConfig {
    fn check(&self) -> Result<(), String> {
        self.validate()
    }
}

impl Setting for assay_model::proxy::LadderPlan {
    fn check(&self) -> Result<(), String> {
        self.validate()
    }
}

impl Setting for assay_model::generalization::GeneralizationPlan {
    fn check(&self) -> Result<(), String> {
        self.validate()
    }
}

/// A nested setting: JSON that must read as a `T` and pass its check (unknown fields, wrong
/// types and values the coordinator would refuse are refused here, before anything starts, with
/// the field's path and the reason), passed on as given.
fn setting<T: Setting>(s: &str) -> Result<String, String> {
    let mut de = serde_json::Deserializer::from_str(s);
    match serde_path_to_error::deserialize::<_, T>(&mut de) {
        Ok(t) => t.check().map(|()| s.to_owned()),
        Err(e) if e.path().iter().next().is_none() => Err(e.into_inner().to_string()),
        Err(e) => {
            let path = e.path().to_string();
            Err(format!("{path}: {}", e.into_inner()))
        }
    }
}

fn parse_template(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(p, t)| (p.trim().to_owned(), t.to_owned()))
        .filter(|(p, _)| !p.is_empty())
        .ok_or_else(|| format!("expected PIPELINE=TEMPLATE, got {s:?}"))
}

impl BatchArgs {
    /// The `RankingPlan` JSON of `--rank-train-policies`, `--proxy` and `--rank-ladder` (empty:
    /// no ranking). Settings that are not JSON are passed on for the coordinator to reject with
    /// its reason.
    fn ranking_json(&self) -> String {
        if self.rank_train_policies.is_empty() {
            return String::new();
        }
        let mut plan =
            serde_json::json!({"train_policies": policy_list(&self.rank_train_policies)});
        for (key, text) in [("config", &self.proxy), ("ladder", &self.rank_ladder)] {
            match text
                .as_deref()
                .map(serde_json::from_str::<serde_json::Value>)
            {
                None => {}
                Some(Ok(v)) => plan[key] = v,
                Some(Err(_)) => return format!("{{\"{key}\": {}}}", text.as_deref().unwrap_or("")),
            }
        }
        if plan.get("config").is_none() {
            plan["config"] = serde_json::json!({});
        }
        if !self.rank_groups.is_empty() {
            plan["groups"] = serde_json::json!(self.rank_groups);
        }
        plan.to_string()
    }

    /// The batch's request: `tasks`, and the name given or `default_name`.
    pub fn request(&self, tasks: Vec<TaskDocument>, default_name: &str) -> pb::SubmitBatchRequest {
        let seeds = if self.seed_list.is_empty() {
            (0..self.seeds).collect()
        } else {
            self.seed_list.clone()
        };
        pb::SubmitBatchRequest {
            name: self.name.clone().unwrap_or_else(|| default_name.to_owned()),
            tasks: tasks.into_iter().map(pb::TaskDocument::from).collect(),
            policies: self
                .policies
                .iter()
                .map(|p| pb::PolicyRef { name: p.clone() })
                .collect(),
            seeds,
            max_attempts: self.max_attempts,
            judges: self.judges.clone(),
            judge_repeats: self.judge_repeats,
            judge_budget_usd: self.judge_budget_usd,
            text_models: self.text_models.clone(),
            dynamics_budgets: self.dynamics_budgets.clone(),
            dynamics_json: self.world_model.clone().unwrap_or_default(),
            text_templates: self.text_templates.iter().cloned().collect(),
            ranking_json: self.ranking_json(),
            generalization_json: self.generalization.clone().unwrap_or_default(),
            skip_if_evaluated: false,
            asset_roots: Vec::new(),
            render: self.render,
            priority: self.priority.unwrap_or_default().to_string(),
            max_workers: self.max_workers,
            submitter: self.submitter.clone().unwrap_or_else(default_submitter),
        }
    }
}

/// The name of a batch given none: what its task paths are called, joined by ` + ` — a task
/// file's stem, a folder's name (`put-block-in-bowl + robomimic` for
/// `examples/tasks/placement/put-block-in-bowl.yaml examples/tasks/robomimic`); the path as
/// written when it has no name of its own (`.`, `/`). Reports are titled by it.
pub fn default_name(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| {
            let named = p.canonicalize().unwrap_or_else(|_| p.clone());
            let task_file = assay_spec::spec::Format::from_path(&p.display().to_string()).is_some();
            let name = if task_file {
                named.file_stem()
            } else {
                named.file_name()
            };
            name.map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        })
        .collect::<Vec<_>>()
        .join(" + ")
}

/// Policies given comma-separated: each value split at its commas, a piece that is an argument
/// (`key=value`, no `:` before its `=`) kept with the policy before it. A policy's arguments are
/// comma-separated too (`random:speed=0.3,max_steps=600`), and a policy's name never holds `=`.
fn policy_list(values: &[String]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for piece in values.iter().flat_map(|v| v.split(',')) {
        let argument = piece
            .find('=')
            .is_some_and(|eq| piece.find(':').is_none_or(|colon| eq < colon));
        match out.last_mut() {
            Some(last) if argument => {
                last.push(',');
                last.push_str(piece);
            }
            _ => out.push(piece.to_owned()),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        batch: BatchArgs,
    }

    fn ranking(args: &[&str]) -> serde_json::Value {
        let cli =
            Cli::try_parse_from(std::iter::once("assay").chain(args.iter().copied())).unwrap();
        serde_json::from_str(&cli.batch.ranking_json()).unwrap()
    }

    #[test]
    fn a_batch_given_no_name_is_named_by_its_task_files_and_folders() {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path().join("robomimic");
        std::fs::create_dir(&folder).unwrap();
        let file = dir.path().join("put-block-in-bowl.yaml");
        std::fs::write(&file, "id: x\n").unwrap();
        assert_eq!(
            default_name(&[file, folder.join(".")]),
            "put-block-in-bowl + robomimic"
        );
        assert_eq!(default_name(&[PathBuf::from("/")]), "/");
    }

    #[test]
    fn rank_ladder_takes_optional_json_and_needs_training_policies() {
        let plan = ranking(&["--rank-train-policies", "oracle", "--rank-ladder"]);
        assert_eq!(plan["ladder"], serde_json::json!({}));
        let plan: assay_model::proxy::RankingPlan = serde_json::from_value(plan).unwrap();
        assert_eq!(plan.ladder, Some(Default::default()));
        let plan = ranking(&[
            "--rank-train-policies",
            "oracle",
            "--proxy",
            r#"{"judge_steps": 5}"#,
            r#"--rank-ladder={"episodes": [4]}"#,
        ]);
        assert_eq!(plan["ladder"]["episodes"], serde_json::json!([4]));
        assert_eq!(plan["config"]["judge_steps"], 5);
        assert!(
            ranking(&["--rank-train-policies", "oracle"])
                .get("ladder")
                .is_none()
        );
        assert!(Cli::try_parse_from(["assay", "--rank-ladder"]).is_err());
    }

    #[test]
    fn training_policies_keep_their_own_arguments() {
        let plan = ranking(&[
            "--rank-train-policies",
            "oracle,random:speed=0.3,max_steps=600,oracle:noise=0.02",
            "--rank-train-policies",
            "openpi:url=ws://127.0.0.1:8000,remote:url=http://127.0.0.1:9000",
        ]);
        assert_eq!(
            plan["train_policies"],
            serde_json::json!([
                "oracle",
                "random:speed=0.3,max_steps=600",
                "oracle:noise=0.02",
                "openpi:url=ws://127.0.0.1:8000",
                "remote:url=http://127.0.0.1:9000",
            ])
        );
    }
}
