//! `assay diversity TEXTS`: text diversity (the paper's eq. 1) of groups of texts, one column per
//! embedding model (the paper's Table 1), and with `--base` the marginal diversity a new batch
//! adds to an existing corpus. Runs here, with libtorch (local models) or an endpoint.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use assay_stats::diversity::{Marginal, TextDiversityTable, marginal_diversity, parse_text_groups};
use assay_trainer::embedders::{Config, Embedders};
use serde::Serialize;

#[derive(clap::Args)]
pub struct Args {
    /// YAML or JSON file mapping group names to lists of texts (`{stacking: ["...", ...], All:
    /// [...]}`). Groups are reported in file order; a group "All" is whatever the file calls it.
    pub texts: PathBuf,
    /// Embedding models, comma-separated: built-in `minilm` (all-MiniLM-L6-v2) and `mpnet`
    /// (all-mpnet-base-v2), or `[embedders.NAME]` of --config.
    #[arg(long, value_delimiter = ',', default_value = "minilm")]
    pub models: Vec<String>,
    /// Configuration file (TOML) with `[embedders.NAME]` entries.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// An existing corpus in the same form: report how much TEXTS adds to it, per group present
    /// in both (marginal diversity = div(corpus + new) - div(corpus)).
    #[arg(long)]
    pub base: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// libtorch threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

#[derive(Serialize)]
struct MarginalRow {
    group: String,
    model: String,
    #[serde(flatten)]
    marginal: Option<Marginal>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

#[derive(Serialize)]
struct Output {
    #[serde(flatten)]
    table: TextDiversityTable,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    marginal: Vec<MarginalRow>,
}

fn read_groups(path: &PathBuf) -> anyhow::Result<Vec<(String, Vec<String>)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse_text_groups(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let groups = read_groups(&a.texts)?;
    let base = a.base.as_ref().map(read_groups).transpose()?;
    let config = match &a.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            Config::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => Config::default(),
    };
    if let Some(t) = a.threads {
        tch::set_num_threads(t.max(1) as i32);
    }
    let mut embedders = Embedders::new(config, assay_trainer::default_device());
    let mut models = Vec::new();
    let mut embeddings = Vec::new();
    let mut marginal = Vec::new();
    for m in &a.models {
        let texts: Vec<&[String]> = groups.iter().map(|(_, t)| t.as_slice()).collect();
        let (d, per_group) = embedders.column(m, &texts)?;
        if let Some(base) = &base {
            for ((group, texts), new) in groups.iter().zip(&per_group) {
                let Some((_, base_texts)) = base.iter().find(|(g, _)| g == group) else {
                    continue;
                };
                let base_vecs = embedders.embed(m, base_texts)?;
                let r = marginal_diversity(&base_vecs, base_texts, new, texts);
                marginal.push(MarginalRow {
                    group: group.clone(),
                    model: m.clone(),
                    error: r.as_ref().err().map(ToString::to_string),
                    marginal: r.ok(),
                });
            }
        }
        models.push(d);
        embeddings.push(per_group);
    }
    let out = Output {
        table: TextDiversityTable::build(models, &groups, &embeddings),
        marginal,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print!(
            "{}",
            assay_report::tables::text_diversity(&out.table).markdown()
        );
        if base.is_some() {
            println!(
                "\nMarginal diversity against {}:\n",
                a.base.as_ref().unwrap().display()
            );
            println!(
                "| group | model | N corpus | N new | div corpus | div corpus + new | marginal |"
            );
            println!("|---|---|---:|---:|---:|---:|---:|");
            for r in &out.marginal {
                match (&r.marginal, &r.error) {
                    (Some(m), _) => println!(
                        "| {} | {} | {} | {} | {:.3} | {:.3} | {:+.3} |",
                        r.group, r.model, m.base_n, m.new_n, m.base_div, m.union_div, m.marginal
                    ),
                    (None, e) => println!(
                        "| {} | {} | | | | | error: {} |",
                        r.group,
                        r.model,
                        e.as_deref().unwrap_or_default()
                    ),
                }
            }
        }
    }
    let failed = out
        .table
        .rows
        .iter()
        .any(|r| r.div.iter().any(Option::is_none));
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
