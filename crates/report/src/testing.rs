//! Builders of the records the report crate's tests aggregate (shared by `report`, `quality`
//! and `html`'s tests).

use assay_model::episode::{JudgeRecord, TaskInfo};
use assay_model::quality::{Item, ItemOutcome, JudgeOutcome, Usage};

/// A task of pipeline `assay` whose name is its id.
pub(crate) fn info(id: &str, group: &str) -> TaskInfo {
    TaskInfo {
        id: id.into(),
        name: id.into(),
        group: group.into(),
        pipeline: "assay".into(),
        origin: String::new(),
        spec_hash: "h".into(),
    }
}

/// Scores of one item, asked with its version-1 prompt.
pub(crate) fn item(item: Item, scores: &[f64]) -> ItemOutcome {
    ItemOutcome {
        item,
        prompt: format!("{}/v1", item.name()),
        scores: scores.to_vec(),
        errors: Vec::new(),
        unjudged: 0,
    }
}

/// A finished judge shard of the `oracle` episode (task, seed): scene-alignment scores `sa` and
/// completion scores `c`, by the offline judge's backend and model, spending nothing.
pub(crate) fn judged(judge: &str, task: &str, seed: u64, sa: &[f64], c: &[f64]) -> JudgeRecord {
    JudgeRecord {
        task_id: task.into(),
        seed,
        policy: "oracle".into(),
        judge: judge.into(),
        attempts: 1,
        outcome: Some(JudgeOutcome {
            judge: judge.into(),
            backend: "offline".into(),
            model: "caption".into(),
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            repeats: 2,
            items: vec![item(Item::SceneAlignment, sa), item(Item::Completion, c)],
            usage: Usage::default(),
            transcript: None,
        }),
        error: None,
        cancelled: false,
    }
}
