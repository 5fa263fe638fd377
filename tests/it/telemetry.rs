//! Telemetry over zenoh between real processes: workers publish their statistics, the
//! coordinator its batches' progress, and `assay top` sees both.

use std::time::Duration;

use crate::common::*;

#[test]
fn assay_top_sees_every_worker_and_the_batch_through_the_coordinators_router() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(dir.path(), "127.0.0.1:0", &["--heartbeat-ms", "300"]);
    let announced = std::fs::read_to_string(dir.path().join("coordinator.addr")).unwrap();
    let endpoint = announced
        .lines()
        .nth(1)
        .expect("the telemetry endpoint on line 2")
        .to_owned();
    assert!(
        endpoint.starts_with("tcp/127.0.0.1:"),
        "loopback by default: {endpoint}"
    );
    let mut top = Proc::spawn(
        "top",
        &[
            "top",
            "--telemetry",
            &endpoint,
            "--json",
            "--duration",
            "10",
        ],
        dir.path(),
    );
    let _w0 = worker(dir.path(), &addr, 0, 1);
    let _w1 = worker(dir.path(), &addr, 1, 1);
    let batch = runtime().block_on(async {
        let sub = submit(&addr, &["examples/tasks/stacking"], 2).await;
        wait_for(&addr, &sub.batch_id, Duration::from_secs(120), finished).await;
        sub.batch_id
    });
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while top.child.try_wait().unwrap().is_none() {
        assert!(
            std::time::Instant::now() < deadline,
            "assay top did not stop:\n{}",
            top.log_text()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let samples: Vec<serde_json::Value> = top
        .log_text()
        .lines()
        .filter(|l| l.starts_with("{\"key\""))
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let key = |v: &serde_json::Value| v["key"].as_str().unwrap().to_owned();
    for w in ["test_worker-0", "test_worker-1"] {
        let k = format!("assay/local/workers/{w}/stats");
        let last = samples
            .iter()
            .rev()
            .find(|s| key(s) == k)
            .unwrap_or_else(|| panic!("no stats from {w}:\n{}", top.log_text()));
        assert_eq!(last["value"]["roles"], serde_json::json!(["sim"]));
    }
    let done: u64 = ["test_worker-0", "test_worker-1"]
        .iter()
        .filter_map(|w| {
            samples
                .iter()
                .rev()
                .find(|s| key(s) == format!("assay/local/workers/{w}/stats"))
        })
        .map(|s| s["value"]["episodes_done"].as_u64().unwrap())
        .sum();
    let progress = samples
        .iter()
        .rev()
        .find(|s| key(s) == format!("assay/local/batches/{batch}/progress"))
        .unwrap_or_else(|| panic!("no progress of {batch}:\n{}", top.log_text()));
    assert_eq!(progress["value"]["state"], "completed", "{progress}");
    assert_eq!(progress["value"]["done"], progress["value"]["total"]);
    assert_eq!(
        done,
        progress["value"]["total"].as_u64().unwrap(),
        "the workers' counts add up to the batch"
    );
}
