//! Operating a cluster: the coordinator's Prometheus metrics scraped while a batch runs.

mod common;

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use common::*;

const STACKING: &str = "examples/tasks/stacking";

/// `GET path` on `addr` over plain HTTP/1.0: (status line, body).
fn http_get(addr: &str, path: &str) -> (String, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut raw = String::new();
    s.read_to_string(&mut raw).unwrap();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((&raw, ""));
    (
        head.lines().next().unwrap_or_default().to_owned(),
        body.to_owned(),
    )
}

/// The value of the sample `series` (name with labels, exactly as exposed).
fn sample(text: &str, series: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(series)?.strip_prefix(' '))
        .unwrap_or_else(|| panic!("no sample {series} in\n{text}"))
        .trim()
        .parse()
        .unwrap()
}

#[test]
fn metrics_are_scraped_while_a_batch_runs() {
    let dir = tempfile::tempdir().unwrap();
    let (_coord, addr) = coordinator(
        dir.path(),
        "127.0.0.1:0",
        &["--metrics-listen", "127.0.0.1:0"],
    );
    let announced = std::fs::read_to_string(dir.path().join("coordinator.addr")).unwrap();
    let metrics = announced.lines().nth(2).unwrap().trim().to_owned();
    assert_ne!(metrics, "off");
    let (status, body) = http_get(&metrics, "/healthz");
    assert!(status.contains("200"), "{status}");
    assert_eq!(body, "ok\n");
    let (_, before) = http_get(&metrics, "/metrics");
    assert_eq!(sample(&before, "assay_queue_depth{role=\"sim\"}"), 0.0);
    assert_eq!(sample(&before, "assay_workers_connected"), 0.0);

    let _w = worker(dir.path(), &addr, 0, 1);
    runtime().block_on(async {
        let sub = submit(&addr, &[STACKING], 3).await;
        let planned = sub.accepted_tasks as f64 * 3.0;
        // Scrape while the batch runs: shards queued behind the one worker, one leased, some
        // done, and the figures adding up at every scrape.
        let deadline = Instant::now() + Duration::from_secs(300);
        let (mut saw_queue, mut saw_lease, mut saw_progress) = (false, false, false);
        loop {
            let (status, text) = http_get(&metrics, "/metrics");
            assert!(status.contains("200"), "{status}");
            let queued = sample(&text, "assay_queue_depth{role=\"sim\"}");
            let leased = sample(&text, "assay_leases_active{role=\"sim\"}");
            let done = sample(&text, "assay_shards{role=\"sim\",state=\"done\"}");
            assert_eq!(queued + leased + done, planned, "{text}");
            assert!(
                leased <= 1.0,
                "one worker of capacity 1 holds {leased} leases"
            );
            assert_eq!(
                sample(&text, "assay_shard_seconds_count{role=\"sim\"}"),
                done
            );
            saw_queue |= queued > 0.0;
            saw_lease |= leased == 1.0
                && sample(&text, "assay_workers_connected") == 1.0
                && sample(&text, "assay_batches{state=\"running\"}") == 1.0;
            saw_progress |= done > 0.0 && done < planned;
            if done == planned {
                break;
            }
            assert!(Instant::now() < deadline, "batch did not finish:\n{text}");
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
        assert!(
            saw_queue && saw_lease && saw_progress,
            "queue {saw_queue}, lease {saw_lease}, progress {saw_progress}"
        );
        wait_for(&addr, &sub.batch_id, Duration::from_secs(30), finished).await;
        let (_, after) = http_get(&metrics, "/metrics");
        assert_eq!(sample(&after, "assay_queue_depth{role=\"sim\"}"), 0.0);
        assert_eq!(sample(&after, "assay_batches{state=\"completed\"}"), 1.0);
        assert_eq!(
            sample(
                &after,
                "assay_shard_seconds_bucket{role=\"sim\",le=\"+Inf\"}"
            ),
            planned
        );
        assert_eq!(
            sample(&after, "assay_shard_failures_total{role=\"sim\"}"),
            0.0
        );
        // Histogram buckets are cumulative and end at the count.
        let buckets: Vec<f64> = after
            .lines()
            .filter(|l| l.starts_with("assay_shard_seconds_bucket{role=\"sim\""))
            .map(|l| l.rsplit(' ').next().unwrap().parse().unwrap())
            .collect();
        assert!(buckets.windows(2).all(|w| w[0] <= w[1]), "{buckets:?}");
    });
}
