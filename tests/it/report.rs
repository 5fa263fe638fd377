//! The report files of a tiny fixed batch run by `assay eval`: report.json against its committed
//! JSON Schema (checked by an independent validator, Python's `jsonschema`), and report.md
//! against a golden file.

use std::path::Path;
use std::process::Command;

use crate::common::*;
use assay_report::report::Report;

const TINY: &str = "tests/fixtures/report/tiny";
const GOLDEN: &str = "tests/fixtures/report/golden-report.md";

/// The test suite's Python (with `jsonschema`, from tests/python/requirements.txt).
fn python() -> String {
    std::env::var("ASSAY_TEST_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Validates `instance` against `schema` with Python's jsonschema (Draft 2020-12): the errors,
/// one per line, empty when valid.
fn validate(schema: &Path, instance: &Path) -> String {
    let script = r#"
import json, sys
import jsonschema
schema = json.load(open(sys.argv[1]))
jsonschema.Draft202012Validator.check_schema(schema)
v = jsonschema.Draft202012Validator(schema)
for e in v.iter_errors(json.load(open(sys.argv[2]))):
    print(f"{e.json_path}: {e.message[:200]}")
"#;
    let out = Command::new(python())
        .args(["-c", script])
        .arg(schema)
        .arg(instance)
        .output()
        .expect("python");
    assert!(
        out.status.success(),
        "the validator did not run (scripts/test installs jsonschema; or set ASSAY_TEST_PYTHON): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn a_tiny_batch_gives_a_report_json_that_matches_its_schema_and_the_golden_report_md() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let run = Command::new(bin())
        .args([
            "eval",
            TINY,
            "--roles",
            "sim",
            "--no-diversity",
            "--seeds",
            "2",
            "--policy",
            "oracle",
            "--policy",
            "oracle:noise=0.08",
            "--workers",
            "1",
            "--quiet",
            "--out",
        ])
        .arg(&out)
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );

    // report.json: valid against the committed schema, at the current version, with provenance.
    let schema = repo().join(assay_report::report::SCHEMA_FILE);
    let json = out.join("report.json");
    let errors = validate(&schema, &json);
    assert!(
        errors.is_empty(),
        "report.json against its schema:\n{errors}"
    );
    let r: Report = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(r.report_version, assay_report::report::REPORT_VERSION);
    let p = &r.provenance;
    assert!(p.assay_version.starts_with("assay-coordinator "), "{p:?}");
    assert_eq!(p.config_hash.len(), 64, "{p:?}");
    assert_eq!(p.seeds, [0, 1]);
    assert_eq!(
        p.spec_hashes.keys().collect::<Vec<_>>(),
        ["small-put-block-in-bowl", "small-stack-two-blocks"]
    );
    assert_eq!(
        p.batch_hash,
        assay_report::report::batch_hash(p.spec_hashes.values().map(String::as_str))
    );
    assert!(p.code_versions.contains_key("rapier3d"), "{p:?}");
    // The validator does reject a report that breaks the schema.
    let mut broken: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    broken["results"]["totals"]
        .as_object_mut()
        .unwrap()
        .remove("episodes_planned");
    broken["results"]["tasks"][0]["success"]["trials"] = "four".into();
    let bad = dir.path().join("broken.json");
    std::fs::write(&bad, broken.to_string()).unwrap();
    let errors = validate(&schema, &bad);
    assert!(
        errors.contains("episodes_planned") && errors.contains("four"),
        "{errors}"
    );

    // report.md: everything above the Run section depends only on the batch and the code.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let (fixed, run_part) = md.split_once("\n## Run\n").expect("a Run section");
    assert!(
        run_part.contains("| batch |") && run_part.contains("\n## Provenance\n"),
        "{run_part}"
    );
    let golden_path = repo().join(GOLDEN);
    if std::env::var_os("ASSAY_UPDATE_GOLDEN").is_some() {
        std::fs::write(&golden_path, fixed).unwrap();
    }
    let golden = std::fs::read_to_string(&golden_path).unwrap_or_default();
    assert!(
        fixed == golden,
        "report.md differs from {GOLDEN} (if the change is intended, run this test again with \
         ASSAY_UPDATE_GOLDEN=1 and review the diff):\n--- got ---\n{fixed}"
    );
}

/// `assay report --from B/report.json` writes beside its input (never into the working folder),
/// an `ASSAY_OUT` meant for another command changes nothing, and a folder holding another
/// batch's report is refused unless `--force`.
#[test]
fn report_from_a_file_writes_beside_it_and_replaces_no_other_batch() {
    let dir = tempfile::tempdir().unwrap();
    let report = |batch: &str| {
        let results = assay_report::report::build_results("b", &[], &[0], &[], &[], &[]);
        Report {
            report_version: assay_report::report::REPORT_VERSION,
            results,
            run: assay_report::report::RunInfo {
                batch_id: batch.into(),
                ..Default::default()
            },
            provenance: Default::default(),
            imports: Vec::new(),
        }
    };
    let (a, b) = (dir.path().join("A"), dir.path().join("B"));
    for (d, id) in [(&a, "b00001"), (&b, "b00002")] {
        std::fs::create_dir_all(d).unwrap();
        std::fs::write(
            d.join("report.json"),
            serde_json::to_string(&report(id)).unwrap(),
        )
        .unwrap();
    }
    let a_before = std::fs::read(a.join("report.json")).unwrap();
    let run = |args: &[&str]| {
        Command::new(bin())
            .args(args)
            .env("ASSAY_OUT", &a)
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let o = run(&["report", "--from", "B/report.json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(b.join("report.md").is_file() && b.join("report.html").is_file());
    assert!(
        !dir.path().join("report.md").exists(),
        "nothing in the working folder"
    );
    assert!(!a.join("report.md").exists(), "ASSAY_OUT is not report's");
    let o = run(&["report", "--from", "B/report.json", "--out", "A"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("report of batch b00001, not b00002"), "{err}");
    assert_eq!(std::fs::read(a.join("report.json")).unwrap(), a_before);
    let o = run(&["report", "--from", "B/report.json", "--out", "A", "--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
