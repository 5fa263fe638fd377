//! Text diversity of a set of tasks: equation (1) of the generative-simulation evaluation paper,
//! as DESIGN.md pins it.
//!
//! ```text
//! div = -(1/N) Σ_i log( (1/(N-1)) Σ_{j≠i} e_iᵀ e_j )
//! ```
//!
//! with every embedding L2-normalised first (so `e_iᵀ e_j` is a cosine), the diagonal dropped, a
//! mean per row, then the negative mean log. Duplicates are kept: they are data, and they lower
//! the diversity as they should. A row whose mean similarity is ≤ 0 has no logarithm: that is an
//! error naming the texts concerned, never a NaN or an infinity in a report.

/// Why a set of embeddings has no diversity value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiversityError {
    #[error("text diversity needs at least 2 texts, got {0}")]
    TooFew(usize),
    #[error("embedding {index} has {got} dimensions, the first has {expected}")]
    Dimensions {
        index: usize,
        expected: usize,
        got: usize,
    },
    #[error("embedding {index} ({text:?}) is zero or not finite: it has no direction")]
    Degenerate { index: usize, text: String },
    /// Rows whose mean cosine similarity to the others is ≤ 0, with their texts.
    #[error(
        "mean similarity ≤ 0 for {} text(s), so log is undefined (eq. 1): {}",
        .rows.len(),
        .rows.iter().map(|(i, t, m)| format!("#{i} {t:?} (mean {m:.4})")).collect::<Vec<_>>().join("; ")
    )]
    NonPositiveRow { rows: Vec<(usize, String, f64)> },
}

/// The diversity of `embeddings` (one per text; `texts` name them in errors and may be empty).
/// Computed in f64 whatever the embeddings' precision.
pub fn text_diversity(embeddings: &[Vec<f32>], texts: &[String]) -> Result<f64, DiversityError> {
    let n = embeddings.len();
    if n < 2 {
        return Err(DiversityError::TooFew(n));
    }
    let text = |i: usize| texts.get(i).cloned().unwrap_or_default();
    let dim = embeddings[0].len();
    let mut unit: Vec<Vec<f64>> = Vec::with_capacity(n);
    for (i, e) in embeddings.iter().enumerate() {
        if e.len() != dim {
            return Err(DiversityError::Dimensions {
                index: i,
                expected: dim,
                got: e.len(),
            });
        }
        let norm = e.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
        if !(norm.is_finite() && norm > 0.0) {
            return Err(DiversityError::Degenerate {
                index: i,
                text: text(i),
            });
        }
        unit.push(e.iter().map(|x| f64::from(*x) / norm).collect());
    }
    let mut logs = 0.0;
    let mut bad = Vec::new();
    for i in 0..n {
        let sum: f64 = (0..n)
            .filter(|&j| j != i)
            .map(|j| {
                unit[i]
                    .iter()
                    .zip(&unit[j])
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
            })
            .sum();
        let mean = sum / (n - 1) as f64;
        if mean > 0.0 {
            logs += mean.ln();
        } else {
            bad.push((i, text(i), mean));
        }
    }
    if !bad.is_empty() {
        return Err(DiversityError::NonPositiveRow { rows: bad });
    }
    Ok(-logs / n as f64)
}

/// The text of a task that is embedded for text diversity: `template` with `{name}` and
/// `{description}` replaced. Without a template, GenSim-style tasks use the form the paper used
/// for GenSim (`"Task: {name} \n Description: {description}"`), every other source the
/// description alone.
pub fn task_text(pipeline: &str, name: &str, description: &str, template: Option<&str>) -> String {
    let template = template.unwrap_or(if pipeline.eq_ignore_ascii_case("gensim") {
        GENSIM_TEMPLATE
    } else {
        "{description}"
    });
    template
        .replace("{name}", name)
        .replace("{description}", description)
}

/// The paper's text for GenSim tasks.
pub const GENSIM_TEMPLATE: &str = "Task: {name} \n Description: {description}";

/// One embedding model of a text-diversity table.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct EmbeddingModel {
    /// The configured name (`minilm`, `mpnet`, or a `[embedders.NAME]` of the configuration).
    pub name: String,
    /// What it is: the model folder's model, or the endpoint's model.
    pub model: String,
    pub dimensions: usize,
}

/// One row of the paper's Table 1: a group of texts and its diversity under each model (in the
/// order of [`TextDiversityTable::models`]); a model that could not score the group has its error
/// instead.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct TextDiversityRow {
    pub group: String,
    pub n: usize,
    pub div: Vec<Option<f64>>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<Option<String>>,
}

/// Text diversity of several groups under several models: the paper's Table 1.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct TextDiversityTable {
    pub models: Vec<EmbeddingModel>,
    pub rows: Vec<TextDiversityRow>,
}

impl TextDiversityTable {
    /// The table of `groups` (name, texts) from each model's embeddings of the same texts
    /// (`embeddings[m][g][i]`: model m, group g, text i).
    pub fn build(
        models: Vec<EmbeddingModel>,
        groups: &[(String, Vec<String>)],
        embeddings: &[Vec<Vec<Vec<f32>>>],
    ) -> Self {
        let rows = groups
            .iter()
            .enumerate()
            .map(|(g, (group, texts))| {
                let results: Vec<Result<f64, DiversityError>> = embeddings
                    .iter()
                    .map(|per_model| text_diversity(&per_model[g], texts))
                    .collect();
                let errors: Vec<Option<String>> = results
                    .iter()
                    .map(|r| r.as_ref().err().map(ToString::to_string))
                    .collect();
                TextDiversityRow {
                    group: group.clone(),
                    n: texts.len(),
                    div: results.iter().map(|r| r.as_ref().ok().copied()).collect(),
                    errors: if errors.iter().all(Option::is_none) {
                        Vec::new()
                    } else {
                        errors
                    },
                }
            })
            .collect();
        Self { models, rows }
    }
}

/// Parses a YAML or JSON document mapping group names to lists of texts, keeping the file's
/// group order. Errors name the group and the entry.
pub fn parse_text_groups(text: &str) -> Result<Vec<(String, Vec<String>)>, String> {
    let doc: serde_yaml_ng::Value =
        serde_yaml_ng::from_str(text).map_err(|e| format!("not YAML or JSON: {e}"))?;
    let map = doc
        .as_mapping()
        .ok_or("expected a mapping from group names to lists of texts")?;
    let mut out = Vec::with_capacity(map.len());
    for (k, v) in map {
        let group = match k {
            serde_yaml_ng::Value::String(s) => s.clone(),
            serde_yaml_ng::Value::Number(n) => n.to_string(),
            other => return Err(format!("group name {other:?} is not a string")),
        };
        let list = v
            .as_sequence()
            .ok_or_else(|| format!("group {group:?}: expected a list of texts"))?;
        let mut texts = Vec::with_capacity(list.len());
        for (i, t) in list.iter().enumerate() {
            match t {
                serde_yaml_ng::Value::String(s) => texts.push(s.clone()),
                other => {
                    return Err(format!(
                        "group {group:?}, entry {i}: expected a text, found {other:?}"
                    ));
                }
            }
        }
        out.push((group, texts));
    }
    if out.is_empty() {
        return Err("no groups".into());
    }
    Ok(out)
}

/// How much a new batch of texts adds to an existing corpus: the diversity of the corpus, of the
/// corpus with the batch added, and the difference (positive: the batch makes the corpus more
/// diverse).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct Marginal {
    pub base_n: usize,
    pub new_n: usize,
    pub base_div: f64,
    pub union_div: f64,
    pub marginal: f64,
}

/// [`Marginal`] of `new` against `base` (embeddings and texts of each, from one model).
pub fn marginal_diversity(
    base: &[Vec<f32>],
    base_texts: &[String],
    new: &[Vec<f32>],
    new_texts: &[String],
) -> Result<Marginal, DiversityError> {
    let base_div = text_diversity(base, base_texts)?;
    let all: Vec<Vec<f32>> = base.iter().chain(new).cloned().collect();
    let texts: Vec<String> = base_texts.iter().chain(new_texts).cloned().collect();
    let union_div = text_diversity(&all, &texts)?;
    Ok(Marginal {
        base_n: base.len(),
        new_n: new.len(),
        base_div,
        union_div,
        marginal: union_div - base_div,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_text_follows_the_source() {
        assert_eq!(
            task_text("gensim", "stack-blocks", "stack them", None),
            "Task: stack-blocks \n Description: stack them"
        );
        assert_eq!(
            task_text("robogen", "open", "open the drawer", None),
            "open the drawer"
        );
        assert_eq!(
            task_text("bbsea", "n", "d", Some("{name}: {description}")),
            "n: d"
        );
    }

    #[test]
    fn text_groups_keep_file_order_and_name_bad_entries() {
        let g = parse_text_groups("zeta: [a, b]\nAll: [a, b, c]\nalpha: []\n").unwrap();
        let names: Vec<&str> = g.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["zeta", "All", "alpha"]);
        assert_eq!(g[1].1.len(), 3);
        let j = parse_text_groups(r#"{"b": ["x"], "a": ["y", "z"]}"#).unwrap();
        assert_eq!(j[0].0, "b");
        let e = parse_text_groups("g: [ok, 3]").unwrap_err();
        assert!(e.contains("group \"g\", entry 1"), "{e}");
        assert!(parse_text_groups("- a").unwrap_err().contains("mapping"));
    }

    #[test]
    fn marginal_is_the_union_minus_the_base() {
        let at = |deg: f64| vec![deg.to_radians().cos() as f32, deg.to_radians().sin() as f32];
        let base = vec![at(0.0), at(0.0)];
        let t = |n: usize| vec![String::new(); n];
        // Two identical texts: mean similarity 1, diversity 0. Adding one at 60 degrees: the
        // hand-computed 0.422837 of the eq. (1) tests below.
        let m = marginal_diversity(&base, &t(2), &[at(60.0)], &t(1)).unwrap();
        assert!(m.base_div.abs() < 1e-9);
        assert!((m.union_div - 0.422837).abs() < 1e-6, "{}", m.union_div);
        assert!((m.marginal - m.union_div).abs() < 1e-12);
        assert_eq!((m.base_n, m.new_n), (2, 1));
        // A duplicate of the corpus adds nothing... but lowers nothing either here: still 0.
        let d = marginal_diversity(&base, &t(2), &[at(0.0)], &t(1)).unwrap();
        assert!(d.marginal.abs() < 1e-9);
    }

    #[test]
    fn table_keeps_errors_per_model() {
        let groups = vec![
            ("a".to_owned(), vec!["x".to_owned(), "y".to_owned()]),
            ("b".to_owned(), vec!["z".to_owned()]),
        ];
        let model = |name: &str| EmbeddingModel {
            name: name.into(),
            model: name.into(),
            dimensions: 2,
        };
        let e = vec![vec![
            vec![vec![1.0, 0.0], vec![0.5, 0.5]],
            vec![vec![1.0, 0.0]],
        ]];
        let t = TextDiversityTable::build(vec![model("m")], &groups, &e);
        assert_eq!(t.rows[0].n, 2);
        assert!(t.rows[0].div[0].unwrap() > 0.0);
        assert_eq!(t.rows[1].div[0], None);
        assert!(
            t.rows[1].errors[0]
                .as_deref()
                .unwrap()
                .contains("at least 2")
        );
    }

    fn at(deg: f64) -> Vec<f32> {
        let r = deg.to_radians();
        vec![r.cos() as f32, r.sin() as f32]
    }

    #[test]
    fn two_texts_at_sixty_degrees() {
        // cos 60° = 0.5 on both rows: div = -ln 0.5 = ln 2.
        let d = text_diversity(&[at(0.0), at(60.0)], &[]).unwrap();
        assert!((d - std::f64::consts::LN_2).abs() < 1e-6, "{d}");
    }

    #[test]
    fn duplicates_are_kept_and_lower_diversity() {
        // a = b = 0°, c = 60°: rows a, b: (1 + 0.5)/2 = 0.75; row c: (0.5 + 0.5)/2 = 0.5.
        // div = -(2 ln 0.75 + ln 0.5)/3 = 0.422837…
        let d = text_diversity(&[at(0.0), at(0.0), at(60.0)], &[]).unwrap();
        let expected = -(2.0 * 0.75f64.ln() + 0.5f64.ln()) / 3.0;
        assert!((d - expected).abs() < 1e-6, "{d} vs {expected}");
        assert!((expected - 0.422_837).abs() < 1e-6);
        assert!(d < text_diversity(&[at(0.0), at(60.0)], &[]).unwrap());
        // Identical texts: every similarity is 1, log 1 = 0.
        let same = text_diversity(&[at(10.0), at(10.0), at(10.0)], &[]).unwrap();
        assert!(same.abs() < 1e-9, "{same}");
    }

    #[test]
    fn embeddings_are_normalised_first() {
        let scaled = vec![vec![3.0, 0.0], vec![0.5, 0.5 * 3f32.sqrt()]];
        let d = text_diversity(&scaled, &[]).unwrap();
        assert!((d - std::f64::consts::LN_2).abs() < 1e-6, "{d}");
    }

    #[test]
    fn a_row_mean_at_or_below_zero_is_an_error_naming_the_texts() {
        let texts: Vec<String> = ["stack the blocks", "open the drawer", "push the ball"]
            .map(String::from)
            .to_vec();
        // 0°, 90°, 180°: row 0: (0 + -1)/2 < 0; row 1: (0 + 0)/2 = 0; row 2: (-1 + 0)/2 < 0.
        let (e, n, w) = (vec![1.0, 0.0], vec![0.0, 1.0], vec![-1.0, 0.0]);
        let err = text_diversity(&[e.clone(), n.clone(), w], &texts).unwrap_err();
        match &err {
            DiversityError::NonPositiveRow { rows } => {
                assert_eq!(rows.iter().map(|r| r.0).collect::<Vec<_>>(), [0, 1, 2]);
            }
            other => panic!("{other:?}"),
        }
        let msg = err.to_string();
        assert!(msg.contains("\"open the drawer\" (mean 0.0000)"), "{msg}");
        assert!(msg.contains("log is undefined"), "{msg}");
        // Orthogonal pair: mean exactly 0, an error too, never +inf.
        assert!(text_diversity(&[e, n], &[]).is_err());
    }

    #[test]
    fn malformed_inputs_are_errors() {
        assert_eq!(
            text_diversity(&[at(0.0)], &[]),
            Err(DiversityError::TooFew(1))
        );
        assert!(matches!(
            text_diversity(&[at(0.0), vec![1.0, 0.0, 0.0]], &[]),
            Err(DiversityError::Dimensions { index: 1, .. })
        ));
        assert!(matches!(
            text_diversity(&[at(0.0), vec![0.0, 0.0]], &["x".into(), "empty".into()]),
            Err(DiversityError::Degenerate { index: 1, .. })
        ));
        assert!(matches!(
            text_diversity(&[at(0.0), vec![f32::NAN, 1.0]], &[]),
            Err(DiversityError::Degenerate { index: 1, .. })
        ));
    }
}
