//! What the command line prints of a cluster's answers: a batch's status line, a state's name,
//! the tasks a coordinator rejected, a report's ranking in a line per comparison.
//!
//! Everything a command prints on stdout goes through `out!` and `outln!`: a reader that closed
//! the pipe early (`assay import … | head`) makes what follows be discarded, not a panic. The
//! command still does its work (an import still writes its specs) and exits with its own status;
//! a command that only prints until stopped (`assay top`, `assay status --watch`) asks
//! [`stdout_closed`] and ends. (Restoring SIGPIPE's default would instead kill the process on any
//! closed pipe, the sandboxed importers' and policy servers' included.)

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

use assay_proto::v1 as pb;

static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);

/// `print!` that discards its output once stdout's reader has gone (see the module's note).
macro_rules! out {
    ($($arg:tt)*) => { $crate::print::stdout(format_args!($($arg)*)) };
}

/// `println!` that discards its output once stdout's reader has gone (see the module's note).
macro_rules! outln {
    () => { $crate::print::stdout(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::print::stdout(format_args!("{}\n", format_args!($($arg)*))) };
}

/// Writes to stdout; a closed pipe is remembered and what follows dropped, any other error
/// panics as `print!` does.
pub fn stdout(args: std::fmt::Arguments<'_>) {
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_fmt(args) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            STDOUT_CLOSED.store(true, Ordering::Relaxed);
        } else {
            panic!("failed printing to stdout: {e}");
        }
    }
}

/// Whether stdout's reader has gone (a write found the pipe closed).
pub fn stdout_closed() -> bool {
    STDOUT_CLOSED.load(Ordering::Relaxed)
}

/// The name of a batch state.
pub fn state_name(state: i32) -> &'static str {
    match pb::BatchState::try_from(state).unwrap_or(pb::BatchState::Unspecified) {
        pb::BatchState::Running => "running",
        pb::BatchState::Completed => "completed",
        pb::BatchState::Cancelled => "cancelled",
        pb::BatchState::Skipped => "skipped",
        pb::BatchState::Unspecified => "unknown",
    }
}

/// Prints the task errors a coordinator reported for a submission.
pub fn rejected(rejected: &[pb::SpecError]) {
    for e in rejected {
        let task = if e.task_id.is_empty() {
            "<no id>"
        } else {
            &e.task_id
        };
        let path = if e.path.is_empty() {
            "<document>"
        } else {
            &e.path
        };
        eprintln!("invalid task {task} ({}): {path}: {}", e.origin, e.reason);
    }
}

/// One batch's status on a line (and the work no connected worker can take on lines of their
/// own).
pub fn status_line(s: &pb::BatchStatus) -> String {
    if !s.duplicate_of.is_empty() {
        return format!(
            "{}  {:<9}  repeats {} (content {})  {}",
            s.batch_id,
            state_name(s.state),
            s.duplicate_of,
            s.content_hash.get(..12).unwrap_or(&s.content_hash),
            s.name
        );
    }
    let judged = if s.judge_total > 0 {
        format!(
            "  {}/{} judged (${:.4})",
            s.judge_done + s.judge_failed,
            s.judge_total,
            s.judge_cost_usd
        )
    } else {
        String::new()
    };
    let judged = if s.trainer_total > 0 {
        format!(
            "{judged}  {}/{} trained",
            s.trainer_done + s.trainer_failed,
            s.trainer_total
        )
    } else {
        judged
    };
    // Work no connected worker can take, on lines of their own.
    let mut waiting: String = s
        .waiting
        .iter()
        .map(|w| format!("\n  waiting: {w}"))
        .collect();
    if s.state == pb::BatchState::Running as i32 && !s.priority.is_empty() {
        waiting.push_str("\n  share: ");
        waiting.push_str(&share_line(
            &s.priority,
            s.workers_holding,
            s.fair_share,
            s.holds,
        ));
        if s.max_workers > 0 {
            waiting.push_str(&format!(", at most {} workers", s.max_workers));
        }
    }
    format!(
        "{}  {:<9}  {}/{} done  {} ok  {} failed  {} running  {} queued  {} cancelled  {} invalid tasks{judged}  {} workers  {}{waiting}",
        s.batch_id,
        state_name(s.state),
        s.shards_done + s.shards_failed + s.shards_cancelled,
        s.shards_total,
        s.successes,
        s.shards_failed,
        s.shards_running,
        s.shards_queued,
        s.shards_cancelled,
        s.invalid_tasks,
        s.workers_connected,
        s.name
    )
}

/// A batch's share of the cluster, as `status` and `top` show it.
pub fn share_line(priority: &str, workers: u32, fair_share: f64, holds: f64) -> String {
    format!(
        "{priority} priority, {workers} worker{} holding its shards, {:.0}% of the leases held (fair share {:.0}%)",
        if workers == 1 { "" } else { "s" },
        holds * 100.0,
        fair_share * 100.0
    )
}

/// One line per ranking comparison of `report` (for a terminal), empty without a ranking.
pub fn ranking_lines(report: &assay_report::report::Report) -> Vec<String> {
    let Some(ranking) = report
        .results
        .ranking
        .as_ref()
        .and_then(|k| k.ranking.as_ref())
    else {
        return Vec::new();
    };
    let est = |e: &assay_stats::agreement::Estimate| match (e.value, e.ci95) {
        (Some(v), Some([lo, hi])) => format!("{v:.3} [{lo:.3}, {hi:.3}]"),
        (Some(v), None) => format!("{v:.3}"),
        (None, _) => "undefined".into(),
    };
    ranking
        .comparisons
        .iter()
        .map(|c| {
            format!(
                "policy ranking, {} against {} ({} policies): Pearson r {}, MMRV {}, Spearman {}, Kendall {}",
                c.proxy,
                c.real,
                c.policies.len(),
                est(&c.pearson),
                est(&c.mmrv),
                est(&c.spearman),
                est(&c.kendall)
            )
        })
        .collect()
}

/// An error and its causes on one line, as anyhow's `{:#}` prints them, but a cause that says
/// exactly what the one before it said is left out: hyper's connect errors repeat themselves
/// ("transport error: tcp connect error: tcp connect error: Connection refused").
pub fn error_chain(e: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if parts.last() != Some(&text) {
            parts.push(text);
        }
    }
    parts.join(": ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Cause {
        text: &'static str,
        source: Option<Box<Cause>>,
    }

    impl std::fmt::Display for Cause {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(self.text)
        }
    }

    impl std::error::Error for Cause {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            self.source
                .as_deref()
                .map(|c| c as &(dyn std::error::Error + 'static))
        }
    }

    fn cause(text: &'static str, source: Option<Cause>) -> Cause {
        Cause {
            text,
            source: source.map(Box::new),
        }
    }

    #[test]
    fn an_error_chain_says_each_cause_once() {
        let refused = cause("Connection refused (os error 111)", None);
        let e = anyhow::Error::new(cause(
            "transport error",
            Some(cause(
                "tcp connect error",
                Some(cause("tcp connect error", Some(refused))),
            )),
        ))
        .context("no coordinator at http://127.0.0.1:7878");
        assert_eq!(
            error_chain(&e),
            "no coordinator at http://127.0.0.1:7878: transport error: tcp connect error: \
             Connection refused (os error 111)"
        );
        // The same words further apart are two causes, kept.
        let e = anyhow::Error::new(cause("a", Some(cause("b", Some(cause("a", None))))));
        assert_eq!(error_chain(&e), "a: b: a");
    }
}
