//! `assay agreement` as a user runs it, on the paper's table 5 (human vs model completion scores).

use std::process::Command;

fn assay(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_assay"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

#[test]
fn agreement_prints_the_papers_statistics_and_says_when_r_is_undefined() {
    let csv = "examples/agreement/paper-table5-completion.csv";
    let out = assay(&["agreement", csv, "--json", "--resamples", "300"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let t: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let row = |group: &str, judge: &str| {
        t["rows"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["group"] == group && r["judge"] == judge)
            .unwrap_or_else(|| panic!("{group} {judge}"))["agreement"]
            .clone()
    };
    // scipy: r = 0.55064, MAE = 1.18 for GPT-4 on RoboGen.
    let gpt4 = row("RoboGen", "GPT-4");
    assert!((gpt4["pearson"]["value"].as_f64().unwrap() - 0.550_637_369_643_261_4).abs() < 1e-9);
    assert!((gpt4["mae"]["value"].as_f64().unwrap() - 1.18).abs() < 1e-9);
    assert_eq!(gpt4["n"], 10);
    // LLava-1.5 answered 8 every time: r is undefined, reported as null with the reason.
    let llava = row("GenSim", "LLava-1.5");
    assert!(llava["pearson"]["value"].is_null());
    assert!(llava["r_over_mae"]["value"].is_null());
    assert!(
        llava["pearson"]["undefined"]
            .as_str()
            .unwrap()
            .contains("judge's scores are constant")
    );
    // Pooled over both datasets too.
    assert_eq!(
        t["rows"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|r| r["group"].is_null())
            .count(),
        3
    );

    let text = assay(&["agreement", csv, "--resamples", "300"]);
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(
        text.contains("r/MAE") && text.contains("Kendall tau"),
        "{text}"
    );
    assert!(text.contains("undefined"), "{text}");
}

#[test]
fn a_malformed_table_is_an_error_naming_the_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "task,human,gpt-4v\nOpen Laptop,3.6,3.96\nClose Window,3.1,three\n",
    )
    .unwrap();
    let out = assay(&["agreement", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("line 3") && err.contains("gpt-4v") && err.contains("three"),
        "{err}"
    );
}
