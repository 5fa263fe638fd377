//! What connected workers can do, and the work that waits for a capability none of them offers.
//!
//! Owns: the registry of connected workers' capabilities and the "waiting" lines `assay status`
//! and `assay top` show. Never leases (the store matches needs to capabilities in one query).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Mutex;

/// The capabilities of each connected worker session.
#[derive(Default)]
pub struct Registry {
    sessions: Mutex<BTreeMap<u64, Vec<String>>>,
    next: std::sync::atomic::AtomicU64,
}

impl Registry {
    /// Records a session's capabilities; the returned id removes them when it ends.
    pub fn join(&self, capabilities: Vec<String>) -> u64 {
        let id = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.sessions
            .lock()
            .expect("registry")
            .insert(id, capabilities);
        id
    }

    pub fn leave(&self, id: u64) {
        self.sessions.lock().expect("registry").remove(&id);
    }

    /// The capabilities of every connected worker.
    pub fn offered(&self) -> Vec<Vec<String>> {
        self.sessions
            .lock()
            .expect("registry")
            .values()
            .cloned()
            .collect()
    }
}

/// A worker's capabilities as it declared them, or its roles for a worker that declares none.
pub fn capabilities(declared: &[String], roles: &[String]) -> Vec<String> {
    let mut caps: BTreeSet<String> = declared.iter().cloned().collect();
    caps.extend(roles.iter().cloned());
    caps.into_iter().collect()
}

/// One line per group of queued shards whose needs no connected worker offers all of: what is
/// missing, and how to offer it.
pub fn waiting(queued: &[(Vec<String>, u32)], offered: &[Vec<String>]) -> Vec<String> {
    let mut lines = Vec::new();
    for (needs, n) in queued {
        if offered
            .iter()
            .any(|caps| needs.iter().all(|need| caps.contains(need)))
        {
            continue;
        }
        let shards = if *n == 1 {
            "shard needs"
        } else {
            "shards need"
        };
        let missing: Vec<&str> = needs
            .iter()
            .filter(|need| !offered.iter().any(|caps| caps.contains(need)))
            .map(String::as_str)
            .collect();
        let line = if missing.is_empty() {
            format!(
                "{n} {shards} {} on one worker: no connected worker offers them together ({})",
                needs.join(" and "),
                hint(needs)
            )
        } else {
            format!(
                "{n} {shards} {}: no connected worker offers it ({})",
                missing.join(" and "),
                hint(&missing.iter().map(|m| m.to_string()).collect::<Vec<_>>())
            )
        };
        lines.push(line);
    }
    lines
}

fn hint(needs: &[String]) -> String {
    let roles: Vec<&str> = needs
        .iter()
        .filter(|n| ["sim", "render", "judge", "trainer"].contains(&n.as_str()))
        .map(String::as_str)
        .collect();
    let judges: Vec<&str> = needs
        .iter()
        .filter_map(|n| n.strip_prefix("judge:"))
        .collect();
    let mut parts = Vec::new();
    if !roles.is_empty() {
        parts.push(format!("start a worker with --roles {}", roles.join(",")));
    }
    if !judges.is_empty() {
        parts.push(format!(
            "configure [judges.{}] on a judge worker",
            judges.join("], [judges.")
        ));
    }
    if parts.is_empty() {
        parts.push(format!("no worker declares {}", needs.join(", ")));
    }
    parts.join("; ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(s: &[&str]) -> Vec<String> {
        s.iter().map(|x| x.to_string()).collect()
    }

    #[test]
    fn work_waits_only_for_what_no_worker_offers_and_says_how_to_offer_it() {
        let queued = vec![
            (v(&["render"]), 4),
            (v(&["sim"]), 2),
            (v(&["sim", "render"]), 1),
            (v(&["judge", "judge:vlm"]), 3),
        ];
        let offered = vec![v(&["sim"]), v(&["judge", "judge:offline"])];
        assert_eq!(
            waiting(&queued, &offered),
            vec![
                "4 shards need render: no connected worker offers it (start a worker with --roles render)",
                "1 shard needs render: no connected worker offers it (start a worker with --roles render)",
                "3 shards need judge:vlm: no connected worker offers it (configure [judges.vlm] on a judge worker)",
            ]
        );
        let offered = vec![v(&["sim"]), v(&["render"])];
        assert_eq!(
            waiting(&queued[2..3], &offered),
            vec![
                "1 shard needs sim and render on one worker: no connected worker offers them together (start a worker with --roles sim,render)"
            ]
        );
        assert!(waiting(&queued[..2], &[v(&["sim", "render"])]).is_empty());
    }
}
