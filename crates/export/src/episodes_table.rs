//! The flat table of a batch's episodes, `episodes.parquet` beside every report: one row per
//! planned episode — its task, group, seed and policy, whether it completed and succeeded, its
//! steps, the episode file, the error of one that failed, and each judge's scores of it
//! (`<judge>.scene_alignment`, `<judge>.completion`: the mean over its repeats) — for pandas,
//! polars or DuckDB (`pd.read_parquet("out/episodes.parquet")`).
//!
//! Owns: the table's columns and their Parquet encoding (the CLI's `cmd::report` writes it).

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{ArrayRef, BooleanArray, Float64Array, RecordBatch, StringArray, UInt64Array};
use arrow_schema::{Field, Schema};

use assay_report::report::Results;

/// The table's file name, beside report.json.
pub const EPISODES_TABLE: &str = "episodes.parquet";

/// An episode: its task, seed and policy.
type EpisodeKey<'a> = (&'a str, u64, &'a str);
/// A judge's mean scene alignment and completion of one episode.
type Scores = (Option<f64>, Option<f64>);

/// The columns of one row.
#[derive(Default)]
struct Columns {
    task: Vec<String>,
    task_name: Vec<String>,
    group: Vec<String>,
    pipeline: Vec<String>,
    seed: Vec<u64>,
    policy: Vec<String>,
    completed: Vec<bool>,
    success: Vec<Option<bool>>,
    label_source: Vec<Option<String>>,
    steps: Vec<Option<u64>>,
    cutoff: Vec<Option<String>>,
    episode: Vec<Option<String>>,
    error: Vec<Option<String>>,
}

/// `results`' episodes as a Parquet file: completed episodes first, then failed ones, each in
/// task order. `episode` is the episode file's path relative to the report's folder
/// (`artifacts/episodes/<sha256>.arrow`).
pub fn episodes_parquet(results: &Results) -> Result<Vec<u8>, String> {
    let mut c = Columns::default();
    for t in &results.tasks {
        let task = |c: &mut Columns, seed: u64, policy: &str| {
            c.task.push(t.id.clone());
            c.task_name.push(t.name.clone());
            c.group.push(t.group.clone());
            c.pipeline.push(t.pipeline.clone());
            c.seed.push(seed);
            c.policy.push(policy.to_owned());
        };
        for e in &t.episodes {
            task(&mut c, e.seed, &e.policy);
            c.completed.push(true);
            c.success.push(Some(e.success));
            c.label_source.push(
                serde_json::to_value(e.label_source)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_owned)),
            );
            c.steps.push(Some(e.steps));
            c.cutoff.push(e.cutoff.clone());
            c.episode.push(Some(format!("artifacts/{}", e.artifact)));
            c.error.push(None);
        }
        for f in &t.failures {
            task(&mut c, f.seed, &f.policy);
            c.completed.push(false);
            c.success.push(None);
            c.label_source.push(None);
            c.steps.push(None);
            c.cutoff.push(None);
            c.episode.push(None);
            c.error.push(Some(if f.cancelled {
                "cancelled".to_owned()
            } else {
                f.error.clone()
            }));
        }
    }
    // Each judge's scores of each episode, by (task, seed, policy).
    let mut scores: Vec<(String, HashMap<EpisodeKey<'_>, Scores>)> = Vec::new();
    if let Some(q) = &results.quality {
        for j in &q.judges {
            let mut by_episode = HashMap::new();
            for t in q.tasks.iter().filter(|t| t.judge == j.judge) {
                for e in &t.episodes {
                    by_episode.insert(
                        (t.task_id.as_str(), e.seed, e.policy.as_str()),
                        (e.scene_alignment, e.completion),
                    );
                }
            }
            scores.push((j.judge.clone(), by_episode));
        }
    }
    let keys: Vec<(&str, u64, &str)> = c
        .task
        .iter()
        .zip(&c.seed)
        .zip(&c.policy)
        .map(|((t, s), p)| (t.as_str(), *s, p.as_str()))
        .collect();
    let mut judged: Vec<(String, ArrayRef)> = Vec::new();
    for (judge, by_episode) in &scores {
        let column = |pick: fn(&Scores) -> Option<f64>| -> ArrayRef {
            Arc::new(Float64Array::from(
                keys.iter()
                    .map(|k| by_episode.get(k).and_then(pick))
                    .collect::<Vec<_>>(),
            ))
        };
        judged.push((format!("{judge}.scene_alignment"), column(|s| s.0)));
        judged.push((format!("{judge}.completion"), column(|s| s.1)));
    }
    let text = |v: Vec<String>| Arc::new(StringArray::from(v)) as ArrayRef;
    let maybe_text = |v: Vec<Option<String>>| Arc::new(StringArray::from(v)) as ArrayRef;
    let columns: Vec<(&str, bool, ArrayRef)> = vec![
        ("task", false, text(c.task)),
        ("task_name", false, text(c.task_name)),
        ("group", false, text(c.group)),
        ("pipeline", false, text(c.pipeline)),
        ("seed", false, Arc::new(UInt64Array::from(c.seed))),
        ("policy", false, text(c.policy)),
        (
            "completed",
            false,
            Arc::new(BooleanArray::from(c.completed)),
        ),
        ("success", true, Arc::new(BooleanArray::from(c.success))),
        ("label_source", true, maybe_text(c.label_source)),
        ("steps", true, Arc::new(UInt64Array::from(c.steps))),
        ("cutoff", true, maybe_text(c.cutoff)),
        ("episode", true, maybe_text(c.episode)),
        ("error", true, maybe_text(c.error)),
    ];
    let columns = columns
        .into_iter()
        .chain(
            judged
                .iter()
                .map(|(name, a)| (name.as_str(), true, a.clone())),
        )
        .collect();
    to_parquet(columns, HashMap::new())
}

/// `columns` (name, nullable, values) as one Parquet file, `metadata` on its schema.
pub fn to_parquet(
    columns: Vec<(&str, bool, ArrayRef)>,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, String> {
    let schema = Arc::new(
        Schema::new(
            columns
                .iter()
                .map(|(name, nullable, a)| Field::new(*name, a.data_type().clone(), *nullable))
                .collect::<Vec<_>>(),
        )
        .with_metadata(metadata),
    );
    let batch = RecordBatch::try_new(
        schema.clone(),
        columns.into_iter().map(|(_, _, a)| a).collect(),
    )
    .map_err(|e| e.to_string())?;
    let mut bytes = Vec::new();
    let mut writer = parquet::arrow::ArrowWriter::try_new(&mut bytes, schema, None)
        .map_err(|e| e.to_string())?;
    writer.write(&batch).map_err(|e| e.to_string())?;
    writer.close().map_err(|e| e.to_string())?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use assay_model::episode::{ShardRecord, TaskInfo};
    use assay_report::report::build_results;

    use super::*;

    #[test]
    fn a_failed_episode_is_a_row_too() {
        let failed = ShardRecord {
            task_id: "a".into(),
            seed: 3,
            policy: "oracle".into(),
            judge: String::new(),
            attempts: 3,
            outcome: None,
            error: Some("boom".into()),
            cancelled: false,
        };
        let task = TaskInfo {
            id: "a".into(),
            name: "a".into(),
            group: "g".into(),
            pipeline: "assay".into(),
            origin: String::new(),
            spec_hash: "h".into(),
        };
        let results = build_results("x", &["oracle".into()], &[3], &[task], &[failed], &[]);
        let bytes = episodes_parquet(&results).unwrap();
        assert_eq!(
            (&bytes[..4], &bytes[bytes.len() - 4..]),
            (&b"PAR1"[..], &b"PAR1"[..])
        );
    }
}
