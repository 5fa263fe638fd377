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

#[cfg(test)]
mod tests {
    use super::*;

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
