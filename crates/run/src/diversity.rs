//! `assay diversity TEXTS` as a library: text diversity (the paper's eq. 1) of groups of texts,
//! one column per embedding model (the paper's Table 1), and with a base corpus the marginal
//! diversity a new batch adds to it. Runs here, with libtorch (local models, through
//! `assay-trainer`'s embedders) or an endpoint.
//!
//! Owns: reading the groups and measuring them. Never prints.

use std::path::Path;

use anyhow::Context;
use assay_embed::{Config, Embedders};
use assay_stats::diversity::{Marginal, TextDiversityTable, marginal_diversity, parse_text_groups};
use serde::Serialize;

/// The marginal diversity of one group under one model (or why it could not be measured).
#[derive(Serialize)]
pub struct MarginalRow {
    pub group: String,
    pub model: String,
    #[serde(flatten)]
    pub marginal: Option<Marginal>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The table, and the marginal rows when a base corpus was given.
#[derive(Serialize)]
pub struct Output {
    #[serde(flatten)]
    pub table: TextDiversityTable,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub marginal: Vec<MarginalRow>,
}

/// What to measure.
pub struct Measure<'a> {
    /// YAML or JSON file mapping group names to lists of texts.
    pub texts: &'a Path,
    /// Embedding models (built in, or `[embedders.NAME]` of `config`).
    pub models: &'a [String],
    pub config: Option<&'a Path>,
    /// An existing corpus in the same form.
    pub base: Option<&'a Path>,
    /// libtorch threads (default: all cores).
    pub threads: Option<usize>,
}

fn read_groups(path: &Path) -> anyhow::Result<Vec<(String, Vec<String>)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse_text_groups(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Text diversity of every group under every model, and the marginal rows against the base.
pub fn measure(a: &Measure<'_>) -> anyhow::Result<Output> {
    let groups = read_groups(a.texts)?;
    let base = a.base.map(read_groups).transpose()?;
    let config = match a.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            Config::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => Config::default(),
    };
    if let Some(t) = a.threads {
        assay_trainer::set_threads(t);
    }
    let mut embedders = Embedders::on_default_device(config);
    let mut models = Vec::new();
    let mut embeddings = Vec::new();
    let mut marginal = Vec::new();
    for m in a.models {
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
    Ok(Output {
        table: TextDiversityTable::build(models, &groups, &embeddings),
        marginal,
    })
}
