//! `assay diversity TEXTS`: text diversity (the paper's eq. 1) of groups of texts, one column per
//! embedding model (the paper's Table 1), and with `--base` the marginal diversity a new batch
//! adds to an existing corpus; measured by `assay_run::diversity`.

use std::path::PathBuf;
use std::process::ExitCode;

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

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let out = assay_run::diversity::measure(&assay_run::diversity::Measure {
        texts: &a.texts,
        models: &a.models,
        config: a.config.as_deref(),
        base: a.base.as_deref(),
        threads: a.threads,
    })?;
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        out!(
            "{}",
            assay_report::tables::text_diversity(&out.table).markdown()
        );
        if let Some(base) = &a.base {
            outln!("\nMarginal diversity against {}:\n", base.display());
            outln!(
                "| group | model | N corpus | N new | div corpus | div corpus + new | marginal |"
            );
            outln!("|---|---|---:|---:|---:|---:|---:|");
            for r in &out.marginal {
                match (&r.marginal, &r.error) {
                    (Some(m), _) => outln!(
                        "| {} | {} | {} | {} | {:.3} | {:.3} | {:+.3} |",
                        r.group,
                        r.model,
                        m.base_n,
                        m.new_n,
                        m.base_div,
                        m.union_div,
                        m.marginal
                    ),
                    (None, e) => outln!(
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
