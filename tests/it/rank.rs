//! `assay rank` as a user runs it, on the example ladder (5 policies, 3 tasks, real and a world
//! model).

use crate::common::{assay, ok};
use assay_stats::ranking::{Ranking, RankingConfig, parse_success_table, rank};

const LADDER: &str = "examples/rank/ladder.csv";

#[test]
fn rank_json_is_what_the_library_computes() {
    let out = ok(&assay(&[
        "rank",
        LADDER,
        "--json",
        "--resamples",
        "400",
        "--seed",
        "5",
    ]));
    let printed: Ranking = serde_json::from_str(&out).unwrap();
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/rank/ladder.csv"
    ))
    .unwrap();
    let expected = rank(
        &parse_success_table(&text).unwrap(),
        &RankingConfig {
            resamples: 400,
            seed: 5,
            ..RankingConfig::default()
        },
    )
    .unwrap();
    // The same text as the library's result serialised (parsing floats back from JSON may be
    // off by an ulp, so the text is compared, exactly).
    assert_eq!(
        out.trim_end(),
        serde_json::to_string_pretty(&expected).unwrap()
    );
    // And the numbers themselves (scipy 1.17.1, tests/python/ranking_reference.py; MMRV by hand).
    let c = &printed.comparisons[0];
    assert_eq!(c.proxy, "world-model");
    assert!((c.pearson.value.unwrap() - 0.864_879_156_219_262_6).abs() < 1e-12);
    assert!((c.spearman.value.unwrap() - 0.921_052_631_578_947_5).abs() < 1e-12);
    assert!((c.kendall.value.unwrap() - 0.888_888_888_888_888_8).abs() < 1e-12);
    assert!((c.mmrv.value.unwrap() - 0.7 / 15.0).abs() < 1e-12);
    // Field names as report.json will carry them.
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let p = &v["comparisons"][0]["policies"][0];
    for key in [
        "policy",
        "real",
        "proxy",
        "tasks",
        "real_trials",
        "proxy_trials",
    ] {
        assert!(p.get(key).is_some(), "{key} in {p}");
    }
    assert_eq!(v["comparisons"][0]["bootstrap"], "trials");
    assert!(v["comparisons"][0]["mmrv"]["ci95"].is_array());

    let md = ok(&assay(&["rank", LADDER, "--resamples", "200"]));
    assert!(
        md.contains("## Policy ranking: world-model against real"),
        "{md}"
    );
    assert!(md.contains("| Pearson r | 0.865 ["), "{md}");
}

#[test]
fn too_few_resamples_for_an_interval_are_refused() {
    for cmd in [
        vec!["rank", LADDER, "--resamples", "1"],
        vec![
            "agreement",
            "examples/agreement/paper-table5-completion.csv",
            "--resamples",
            "1",
        ],
    ] {
        let out = assay(&cmd);
        assert!(!out.status.success(), "{cmd:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("at least 40"), "{cmd:?}: {err}");
    }
}

#[test]
fn a_malformed_table_fails_naming_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "# a comment\ntask,policy,source,trials,successes\nlift,act,real,20,12\nlift,act,world-model,20,25\n",
    )
    .unwrap();
    let out = assay(&["rank", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.csv")
            && err.contains("line 4")
            && err.contains("column 5 'successes'")
            && err.contains("25 successes exceed 20 trials"),
        "{err}"
    );
    // A proxy that is not in the table.
    let out = assay(&["rank", LADDER, "--proxy", "cosmos"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("'cosmos'") && err.contains("world-model"),
        "{err}"
    );
}

#[test]
fn plot_writes_an_svg_to_a_file_or_a_folder() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plots/ladder.svg");
    ok(&assay(&[
        "rank",
        LADDER,
        "--resamples",
        "100",
        "--plot",
        file.to_str().unwrap(),
    ]));
    let svg = std::fs::read_to_string(&file).unwrap();
    assert!(
        svg.contains("<svg") && svg.contains("diffusion-400"),
        "{svg}"
    );
    assert!(svg.contains("r = 0.865"), "{svg}");

    let folder = dir.path().join("figures");
    let out = assay(&[
        "rank",
        LADDER,
        "--json",
        "--resamples",
        "100",
        "--plot",
        folder.to_str().unwrap(),
    ]);
    // The JSON on stdout stays parseable: the "wrote" line goes to stderr.
    let _: Ranking = serde_json::from_str(&ok(&out)).unwrap();
    let svg = std::fs::read_to_string(folder.join("rank-world-model.svg")).unwrap();
    assert!(svg.contains("<svg"));
}
