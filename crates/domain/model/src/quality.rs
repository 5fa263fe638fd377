//! Task quality as a judge sees it: what a judge is asked (scene alignment from the 4 views of
//! the initial scene, task completion from the 8 keyframes), how its answers are parsed, and
//! what one judge shard reports for one episode.
//!
//! The protocol follows appendix A.1 of the generative-simulation evaluation paper: each answer
//! ends in `Score: X`, scene alignment is scored 1–5 and completion 0–10, and every item is asked
//! k times (default 5) so that a report can give the mean and the variance of the answers.

use serde::{Deserialize, Serialize};

/// Repeats per item when a batch does not say.
pub const DEFAULT_REPEATS: u32 = 5;

/// The two questions a judge answers about an episode.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Item {
    /// Does the initial scene fit the task description? 1–5, from the 4 scene views.
    SceneAlignment,
    /// Did the rollout complete the task? 0–10, from the 8 keyframes.
    Completion,
}

impl Item {
    pub const ALL: [Item; 2] = [Item::SceneAlignment, Item::Completion];

    /// The inclusive range of a valid score.
    pub fn range(self) -> (f64, f64) {
        match self {
            Item::SceneAlignment => (1.0, 5.0),
            Item::Completion => (0.0, 10.0),
        }
    }

    /// Images the judge is shown.
    pub fn images(self) -> usize {
        match self {
            Item::SceneAlignment => 4,
            Item::Completion => 8,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Item::SceneAlignment => "scene_alignment",
            Item::Completion => "completion",
        }
    }
}

/// Parses a judge's answer strictly: exactly one line of the form `Score: X` (any case; X an
/// integer or a decimal; surrounding Markdown emphasis `*` or `_` and whitespace are allowed),
/// with X inside the item's range. Anything else is an error that says why.
pub fn parse_score(text: &str, item: Item) -> Result<f64, String> {
    let mut found: Vec<f64> = Vec::new();
    for line in text.lines() {
        let line = line.trim().trim_matches(|c| c == '*' || c == '_').trim();
        let Some(head) = line.get(..6) else { continue };
        if !head.eq_ignore_ascii_case("score:") {
            continue;
        }
        let value = line[6..]
            .trim()
            .trim_matches(|c| c == '*' || c == '_')
            .trim();
        let value = value.strip_suffix('.').unwrap_or(value);
        let is_number = !value.is_empty()
            && value.chars().all(|c| c.is_ascii_digit() || c == '.')
            && value.chars().filter(|c| *c == '.').count() <= 1
            && !value.starts_with('.')
            && !value.ends_with('.');
        if !is_number {
            return Err(format!("'Score:' is followed by {value:?}, not a number"));
        }
        found.push(value.parse().map_err(|e| format!("{value:?}: {e}"))?);
    }
    let (lo, hi) = item.range();
    match found.as_slice() {
        [] => Err("no line of the form 'Score: X'".into()),
        [x] if (lo..=hi).contains(x) => Ok(*x),
        [x] => Err(format!("score {x} is outside {lo}–{hi}")),
        _ => Err(format!(
            "{} lines of the form 'Score: X'; expected exactly one",
            found.len()
        )),
    }
}

/// Tokens, calls and money a judge spent.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Usage {
    /// Requests sent to a model (retries included; cache hits excluded).
    pub calls: u64,
    /// Answers served from the judge cache.
    pub cached: u64,
    pub tokens_in: u64,
    pub tokens_out: u64,
    /// From the judge's configured prices; 0 for a local or offline judge.
    pub cost_usd: f64,
}

impl Usage {
    pub fn add(&mut self, other: &Usage) {
        self.calls += other.calls;
        self.cached += other.cached;
        self.tokens_in += other.tokens_in;
        self.tokens_out += other.tokens_out;
        self.cost_usd += other.cost_usd;
    }
}

/// A repeat that gave no score.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ItemError {
    pub repeat: u32,
    pub error: String,
    /// The last answer's text, when there was one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw: Option<String>,
}

/// One item (scene alignment or completion) of one episode, asked `repeats` times.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ItemOutcome {
    pub item: Item,
    /// The prompt template's name and version, e.g. `completion/v1`.
    pub prompt: String,
    /// One per repeat that gave a valid score, in repeat order.
    pub scores: Vec<f64>,
    pub errors: Vec<ItemError>,
    /// Repeats never asked because the batch's judge budget was spent.
    #[serde(default)]
    pub unjudged: u32,
}

/// What one judge shard reports for one episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct JudgeOutcome {
    /// The judge's name in the configuration (`offline`, `gpt-4o`, ...).
    pub judge: String,
    /// `offline`, `openai` or `caption+llm`.
    pub backend: String,
    /// The model(s) behind the judge, e.g. `gpt-4o` or `llava-1.6 → gpt-4`.
    pub model: String,
    pub task_id: String,
    pub seed: u64,
    pub policy: String,
    pub repeats: u32,
    pub items: Vec<ItemOutcome>,
    pub usage: Usage,
    /// Content address of the transcript (every prompt and raw answer) in the artifact store.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transcript: Option<String>,
}

impl JudgeOutcome {
    pub fn item(&self, item: Item) -> Option<&ItemOutcome> {
        self.items.iter().find(|i| i.item == item)
    }
}

/// Mean and sample variance (n − 1, as the paper's tables: five answers 0, 0, 0, 0, 4 give
/// 0.80 (3.20)) of some scores; variance is absent below two scores, mean below one.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ScoreStats {
    pub n: u64,
    pub mean: Option<f64>,
    pub variance: Option<f64>,
}

impl ScoreStats {
    pub fn of(scores: &[f64]) -> Self {
        let n = scores.len();
        if n == 0 {
            return Self::default();
        }
        let mean = scores.iter().sum::<f64>() / n as f64;
        let variance = (n > 1)
            .then(|| scores.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64);
        Self {
            n: n as u64,
            mean: Some(mean),
            variance,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_strictly() {
        let ok = |t: &str, i| parse_score(t, i).unwrap();
        assert_eq!(ok("Score: 4", Item::SceneAlignment), 4.0);
        assert_eq!(
            ok("The scene fits.\nscore: 3.5\n", Item::SceneAlignment),
            3.5
        );
        assert_eq!(ok("**Score: 7**", Item::Completion), 7.0);
        assert_eq!(ok("**Score:** 10.", Item::Completion), 10.0);
        assert_eq!(ok("Score: 0", Item::Completion), 0.0);
        let err = |t: &str, i| parse_score(t, i).unwrap_err();
        assert!(err("I would say four", Item::SceneAlignment).contains("no line"));
        assert!(err("Score: 0", Item::SceneAlignment).contains("outside 1–5"));
        assert!(err("Score: 11", Item::Completion).contains("outside 0–10"));
        assert!(err("Score: -1", Item::Completion).contains("not a number"));
        assert!(err("Score: 4/5", Item::SceneAlignment).contains("not a number"));
        assert!(err("Score: about 4", Item::SceneAlignment).contains("not a number"));
        assert!(err("Score: 3\nScore: 4", Item::SceneAlignment).contains("exactly one"));
        assert!(err("Score:", Item::SceneAlignment).contains("not a number"));
    }

    #[test]
    fn variance_is_the_sample_variance_of_the_papers_tables() {
        let s = ScoreStats::of(&[0.0, 0.0, 0.0, 0.0, 4.0]);
        assert_eq!(s.mean, Some(0.8));
        assert!((s.variance.unwrap() - 3.2).abs() < 1e-12);
        let s = ScoreStats::of(&[0.0, 0.0, 0.0, 4.0, 4.0]);
        assert!((s.variance.unwrap() - 4.8).abs() < 1e-12);
        assert_eq!(ScoreStats::of(&[3.0]).variance, None);
        assert_eq!(ScoreStats::of(&[]).mean, None);
    }
}
