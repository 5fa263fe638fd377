//! Generalization with the real cluster: `assay eval --generalization` trains a diffusion policy
//! per task group on the group's oracle episodes (trainer role), runs it in the simulator on the
//! variations it was trained on and on held-out seeds (sim + render roles, the policy acting on
//! 64×64 frames through the same path as every policy object), and reports both rates per group
//! with Wilson intervals — without mixing its episodes into the batch's own success tables.
#![cfg(feature = "trainer")]

use std::process::Command;

use crate::common::*;
use assay_report::report::Report;

#[test]
fn eval_trains_a_diffusion_policy_per_group_and_runs_it_on_held_out_variations() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(bin())
        .arg("eval")
        .args([
            "examples/tasks/placement/put-block-in-bowl.yaml",
            "examples/tasks/stacking/build-two-block-tower.yaml",
        ])
        .args([
            "--seeds",
            "2",
            "--no-judge",
            "--no-diversity",
            "--image-size",
            "160x120",
        ])
        .args([
            "--generalization",
            r#"{"episodes": 2, "held_out_seeds": 2, "max_steps": 600, "config": {"steps": 20}}"#,
        ])
        .arg("--out")
        .arg(dir.path())
        .arg("--quiet")
        .current_dir(repo())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let report: Report =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let r = &report.results;
    // The batch's own tables hold the oracle's 4 episodes only.
    assert_eq!(r.totals.episodes_planned, 4);
    assert_eq!(r.by_policy.len(), 1);
    let g = r.generalization.as_ref().expect("a generalization section");
    assert!(g.errors.is_empty(), "{:?}", g.errors);
    let mut groups: Vec<&str> = g.groups.iter().map(|x| x.group.as_str()).collect();
    groups.sort_unstable();
    assert_eq!(groups, ["placement", "stacking"]);
    for x in &g.groups {
        assert!(x.model.starts_with("policies/") && x.model.ends_with(".diffusion"));
        assert!(dir.path().join("artifacts").join(&x.model).is_file());
        assert_eq!((x.fit.clips, x.fit.steps), (2, 20));
        // Trained on the task's 2 seeds; run again there and on 2 held-out seeds.
        assert_eq!(x.train.trials, 2, "{x:?}");
        assert_eq!(x.held_out.trials, 2, "{x:?}");
        assert!(x.errors.is_empty() && x.pending == 0, "{x:?}");
    }
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("## Generalization"), "{md}");
    assert!(md.contains("| held-out variations |"), "{md}");
}
