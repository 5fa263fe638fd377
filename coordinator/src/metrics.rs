//! Prometheus metrics of a coordinator (`GET /metrics`, text exposition format 0.0.4).
//!
//! Everything is read from the job store when scraped, so the figures survive a coordinator
//! restart and never disagree with the store: queue depth and leases per role (what an
//! autoscaler scales worker pools on), shards by role and state, attempts beyond the first, shard
//! wall time as a histogram, judge tokens and cost per judge, batches by state, and the workers
//! connected now.
//!
//! Owns: the text a [`Snapshot`] renders to. Never runs SQL: the store fills the snapshot
//! (`Store::metrics`, `store/metrics.rs`, which owns the snapshot and its histogram buckets).

use std::fmt::Write as _;

use crate::store::shard_state;
pub use crate::store::{SHARD_SECONDS_BUCKETS, Snapshot};

/// Every role a shard can have, so a role with no shard yet still reports 0 (an autoscaler
/// reading a missing series sees "no data", not "empty queue").
const ROLES: &[&str] = &["sim", "render", "judge", "trainer"];

impl Snapshot {
    fn shards_in(&self, role: &str, state: &str) -> u64 {
        self.shards
            .get(&(role.to_owned(), state.to_owned()))
            .copied()
            .unwrap_or(0)
    }

    /// The text exposition format; `workers` is the number of worker sessions open now.
    pub fn render(&self, workers: u32) -> String {
        let mut roles: Vec<String> = ROLES.iter().map(|r| (*r).to_owned()).collect();
        for (role, _) in self.shards.keys() {
            if !roles.contains(role) {
                roles.push(role.clone());
            }
        }
        let mut out = String::new();
        let mut section = |name: &str, kind: &str, help: &str, body: String| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} {kind}");
            out.push_str(&body);
        };
        let mut body = String::new();
        for r in &roles {
            let _ = writeln!(
                body,
                "assay_queue_depth{{role=\"{}\"}} {}",
                label(r),
                self.shards_in(r, shard_state::QUEUED)
            );
        }
        section(
            "assay_queue_depth",
            "gauge",
            "Shards waiting for a worker of the role.",
            body,
        );
        let mut body = String::new();
        for r in &roles {
            let _ = writeln!(
                body,
                "assay_leases_active{{role=\"{}\"}} {}",
                label(r),
                self.shards_in(r, shard_state::LEASED)
            );
        }
        section(
            "assay_leases_active",
            "gauge",
            "Shards leased to a worker and not yet finished.",
            body,
        );
        let mut body = String::new();
        for r in &roles {
            for state in [
                shard_state::QUEUED,
                shard_state::LEASED,
                shard_state::DONE,
                shard_state::FAILED,
                shard_state::CANCELLED,
            ] {
                let _ = writeln!(
                    body,
                    "assay_shards{{role=\"{}\",state=\"{state}\"}} {}",
                    label(r),
                    self.shards_in(r, state)
                );
            }
        }
        section(
            "assay_shards",
            "gauge",
            "Shards in the job store by role and state.",
            body,
        );
        let mut body = String::new();
        for r in &roles {
            let _ = writeln!(
                body,
                "assay_shard_failures_total{{role=\"{}\"}} {}",
                label(r),
                self.shards_in(r, shard_state::FAILED)
            );
        }
        section(
            "assay_shard_failures_total",
            "counter",
            "Shards that failed after their last attempt.",
            body,
        );
        let mut body = String::new();
        for r in &roles {
            let _ = writeln!(
                body,
                "assay_shard_retries_total{{role=\"{}\"}} {}",
                label(r),
                self.retries.get(r).copied().unwrap_or(0)
            );
        }
        section(
            "assay_shard_retries_total",
            "counter",
            "Attempts beyond the first (lease expiries, errors retried, leases handed back).",
            body,
        );
        let mut body = String::new();
        for r in &roles {
            let empty = (vec![0; SHARD_SECONDS_BUCKETS.len()], 0, 0.0);
            let (buckets, count, sum) = self.shard_seconds.get(r).unwrap_or(&empty);
            for (bound, n) in SHARD_SECONDS_BUCKETS.iter().zip(buckets) {
                let _ = writeln!(
                    body,
                    "assay_shard_seconds_bucket{{role=\"{}\",le=\"{bound}\"}} {n}",
                    label(r)
                );
            }
            let _ = writeln!(
                body,
                "assay_shard_seconds_bucket{{role=\"{}\",le=\"+Inf\"}} {count}\n\
                 assay_shard_seconds_sum{{role=\"{}\"}} {sum}\n\
                 assay_shard_seconds_count{{role=\"{}\"}} {count}",
                label(r),
                label(r),
                label(r)
            );
        }
        section(
            "assay_shard_seconds",
            "histogram",
            "Wall time of finished shards, as the worker measured it.",
            body,
        );
        let mut calls = String::new();
        let mut tokens = String::new();
        let mut cost = String::new();
        for (judge, (n, cached, tin, tout, usd)) in &self.judges {
            let j = label(judge);
            let _ = writeln!(
                calls,
                "assay_judge_calls_total{{judge=\"{j}\",cached=\"false\"}} {n}\n\
                 assay_judge_calls_total{{judge=\"{j}\",cached=\"true\"}} {cached}"
            );
            let _ = writeln!(
                tokens,
                "assay_judge_tokens_total{{judge=\"{j}\",direction=\"in\"}} {tin}\n\
                 assay_judge_tokens_total{{judge=\"{j}\",direction=\"out\"}} {tout}"
            );
            let _ = writeln!(cost, "assay_judge_cost_usd_total{{judge=\"{j}\"}} {usd}");
        }
        section(
            "assay_judge_calls_total",
            "counter",
            "Judge requests sent to a model, and answers served from the judge cache.",
            calls,
        );
        section(
            "assay_judge_tokens_total",
            "counter",
            "Judge tokens, prompt (in) and answer (out).",
            tokens,
        );
        section(
            "assay_judge_cost_usd_total",
            "counter",
            "Judge spending from the configured prices (0 for local and offline judges).",
            cost,
        );
        let mut body = String::new();
        for (state, n) in &self.batches {
            let _ = writeln!(body, "assay_batches{{state=\"{}\"}} {n}", label(state));
        }
        section("assay_batches", "gauge", "Batches by state.", body);
        section(
            "assay_workers_connected",
            "gauge",
            "Worker sessions open now.",
            format!("assay_workers_connected {workers}\n"),
        );
        out
    }
}

/// A label value with `\`, `"` and newlines escaped, as the exposition format asks.
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_store_reports_zero_for_every_role() {
        let s = Snapshot::default();
        let text = s.render(0);
        for role in ROLES {
            assert!(text.contains(&format!("assay_queue_depth{{role=\"{role}\"}} 0")));
            assert!(text.contains(&format!(
                "assay_shard_seconds_bucket{{role=\"{role}\",le=\"+Inf\"}} 0"
            )));
        }
        assert!(text.contains("assay_workers_connected 0"));
        // Every family is announced once, with its type.
        for family in [
            "assay_queue_depth",
            "assay_shard_seconds",
            "assay_judge_tokens_total",
        ] {
            assert_eq!(
                text.matches(&format!("# TYPE {family} ")).count(),
                1,
                "{family}"
            );
        }
    }

    #[test]
    fn histogram_buckets_are_cumulative_and_labels_escaped() {
        let mut s = Snapshot::default();
        s.shard_seconds.insert("sim".into(), {
            let mut b = vec![0; SHARD_SECONDS_BUCKETS.len()];
            for secs in [0.05, 0.7, 20.0] {
                for (n, bound) in b.iter_mut().zip(SHARD_SECONDS_BUCKETS) {
                    *n += u64::from(secs <= *bound);
                }
            }
            (b, 3, 20.75)
        });
        s.judges.insert("a\"b".into(), (3, 1, 100, 20, 0.5));
        let text = s.render(2);
        assert!(text.contains("assay_shard_seconds_bucket{role=\"sim\",le=\"0.1\"} 1"));
        assert!(text.contains("assay_shard_seconds_bucket{role=\"sim\",le=\"1\"} 2"));
        assert!(text.contains("assay_shard_seconds_bucket{role=\"sim\",le=\"30\"} 3"));
        assert!(text.contains("assay_shard_seconds_count{role=\"sim\"} 3"));
        assert!(text.contains("assay_judge_tokens_total{judge=\"a\\\"b\",direction=\"in\"} 100"));
        assert!(text.contains("assay_workers_connected 2"));
    }
}
