//! The Rust sentence embeddings equal Python sentence-transformers' on committed reference
//! vectors (made once by `scripts/embedding-references.py` with the Python library).
//!
//! Both built-in models are installed by `scripts/setup-models mpnet`, which the test script runs;
//! a test fails when its model is missing (a skipped mpnet check once hid a broken MPNet forward).

use std::path::PathBuf;

use assay_embed::models_dir;
use assay_embed::sentence::{Family, SentenceModel};
use serde::Deserialize;

#[derive(Deserialize)]
struct Reference {
    model: String,
    max_seq_length: usize,
    sentences: Vec<String>,
    tokens: Vec<usize>,
    input_ids: Vec<Vec<i64>>,
    vectors: Vec<Vec<f32>>,
}

fn reference(file: &str) -> Reference {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(file);
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(*x) * f64::from(*y))
        .sum();
    let na: f64 = a.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
    dot / (na * nb)
}

fn check(model: &SentenceModel, r: &Reference) {
    assert_eq!(model.max_seq_length(), r.max_seq_length);
    assert_eq!(
        model.token_ids(&r.sentences).unwrap(),
        r.input_ids,
        "token ids"
    );
    assert_eq!(model.token_counts(&r.sentences).unwrap(), r.tokens);
    // Batches of 8 after sorting by length, as a user's run would batch them; and one by one.
    for batch in [8, 1] {
        let got = model.encode(&r.sentences, batch).unwrap();
        assert_eq!(got.len(), r.vectors.len());
        let mut worst = (1.0f64, 0usize);
        let mut max_abs = 0f32;
        for (i, (g, want)) in got.iter().zip(&r.vectors).enumerate() {
            assert_eq!(g.len(), want.len());
            let c = cosine(g, want);
            if c < worst.0 {
                worst = (c, i);
            }
            for (x, y) in g.iter().zip(want) {
                max_abs = max_abs.max((x - y).abs());
            }
        }
        eprintln!(
            "{} batch {batch}: lowest cosine {:.9} (sentence {}), max abs diff {max_abs:.2e}",
            r.model, worst.0, worst.1
        );
        assert!(
            worst.0 >= 0.99999,
            "{}: sentence {} {:?} has cosine {} to the Python vector",
            r.model,
            worst.1,
            r.sentences[worst.1],
            worst.0
        );
    }
}

#[test]
fn minilm_matches_sentence_transformers() {
    let dir = models_dir().join("all-MiniLM-L6-v2");
    let model = SentenceModel::load(&dir, tch::Device::Cpu).unwrap_or_else(|e| {
        panic!("{e} (install it with scripts/setup-models)");
    });
    assert_eq!(model.family(), Family::Bert);
    assert_eq!(model.dimensions(), 384);
    check(&model, &reference("all-MiniLM-L6-v2-reference.json"));
}

#[test]
fn mpnet_matches_sentence_transformers() {
    let dir = models_dir().join("all-mpnet-base-v2");
    let model = SentenceModel::load(&dir, tch::Device::Cpu).unwrap_or_else(|e| {
        panic!("{e} (install it with scripts/setup-models mpnet)");
    });
    assert_eq!(model.family(), Family::MPNet);
    assert_eq!(model.dimensions(), 768);
    check(&model, &reference("all-mpnet-base-v2-reference.json"));
}

#[test]
fn a_folder_that_is_not_a_model_is_refused_with_the_file_and_reason() {
    let tmp = tempfile::tempdir().unwrap();
    let err = SentenceModel::load(tmp.path(), tch::Device::Cpu).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("config.json"), "{msg}");
    std::fs::write(
        tmp.path().join("config.json"),
        r#"{"model_type": "gpt2", "hidden_size": 8, "num_hidden_layers": 1, "num_attention_heads": 1}"#,
    )
    .unwrap();
    let msg = SentenceModel::load(tmp.path(), tch::Device::Cpu)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("model_type \"gpt2\" is not supported"),
        "{msg}"
    );
}
