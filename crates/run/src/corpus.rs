//! The corpus report of `assay watch`: every batch folder handled (evaluated, skipped as a
//! repeat, or failed) with its marginal text diversity, as `corpus.json` and `corpus.md`, and
//! the line a terminal shows per batch.
//!
//! Owns: the corpus report's format. Never measures anything (`watch` does).

use std::collections::BTreeMap;

use assay_stats::diversity::Marginal;
use serde::{Deserialize, Serialize};

/// The corpus report, `OUT/corpus.json`.
pub const CORPUS_JSON: &str = "corpus.json";
pub const CORPUS_MD: &str = "corpus.md";

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

/// One line for a terminal.
pub fn summary(e: &Entry, models: &[String]) -> String {
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
