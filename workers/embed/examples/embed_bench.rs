//! Sentences per second of the Rust sentence embeddings, in the form of
//! `bench/embeddings/python_bench.py` (run side by side by `scripts/bench-embeddings`).
//!   embed_bench --model-dir DIR --sentences FILE [--batch-size 32] [--repeat 1] [--threads 1]

use std::time::Instant;

use assay_embed::sentence::SentenceModel;

fn cpu_seconds() -> f64 {
    // utime + stime of this process, from /proc (clock ticks of 1/100 s on Linux).
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or_default();
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let get = |name: &str, default: &str| -> String {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
            .unwrap_or_else(|| default.to_owned())
    };
    let dir = get("--model-dir", "");
    let batch: usize = get("--batch-size", "32").parse().expect("--batch-size");
    let repeat: usize = get("--repeat", "1").parse().expect("--repeat");
    let threads: i32 = get("--threads", "1").parse().expect("--threads");
    let text = std::fs::read_to_string(get("--sentences", "bench/embeddings/corpus.txt"))
        .expect("reading the sentences");
    let sentences: Vec<String> = text.lines().map(str::to_owned).collect();
    tch::set_num_threads(threads);
    let model = SentenceModel::load(std::path::Path::new(&dir), tch::Device::Cpu)
        .unwrap_or_else(|e| panic!("{e}"));
    // Warm up once, as the Python side does.
    model
        .encode(&sentences[..batch.min(sentences.len())], batch)
        .expect("warm-up");
    let (t0, c0) = (Instant::now(), cpu_seconds());
    for _ in 0..repeat {
        model.encode(&sentences, batch).expect("encode");
    }
    let (secs, cpu) = (t0.elapsed().as_secs_f64(), cpu_seconds() - c0);
    let n = sentences.len() * repeat;
    println!(
        "{}",
        serde_json::json!({
            "engine": "assay (tch)",
            "model": std::path::Path::new(&dir).file_name().map(|f| f.to_string_lossy().into_owned()),
            "threads": threads,
            "batch_size": batch,
            "sentences": n,
            "seconds": secs,
            "cpu_seconds": cpu,
            "sentences_per_s": n as f64 / secs,
            "sentences_per_cpu_s": n as f64 / cpu.max(1e-9),
        })
    );
}
