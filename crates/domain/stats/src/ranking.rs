//! Ranking policies by a proxy of their success against their real success, as the
//! video-world-model policy-evaluation paper does (section III.A): per policy, R is the mean over
//! tasks of the real success rate ("average success rates across a representative set of tasks")
//! and R_S the same mean from the proxy (rollouts in a learned world model judged by a VLM, a
//! simulator, any cheaper evaluation). Pearson r, MMRV (as `../shared/DESIGN.md` pins it, called
//! `mmrv(proxy, real)`), Spearman ρ and Kendall τ-b compare the two vectors, each with a 95 %
//! percentile bootstrap interval. The statistics themselves are `crate::agreement`'s.
//!
//! Input is a success table, one row per (task, policy, source): `trials` and `successes`, or only a
//! success rate. A comparison uses the (task, policy) cells that both the real source and the proxy
//! have; every cell left out, and every policy left without a task, is listed with the reason.
//! When every cell has counts, a policy's mean is computed from exact fractions, so policies whose
//! successes add up to the same rate tie exactly (rounding does not break a tie in ρ, τ or MMRV).
//!
//! # What the bootstrap resamples
//!
//! It resamples what is uncertain in the table. A rate measured from `trials` rollouts is uncertain
//! because the rollouts are few, so when trials are known every cell's rate is drawn from its
//! Jeffreys posterior, Beta(successes + ½, failures + ½), independently on each side, and R and R_S
//! are recomputed over the same tasks ([`Bootstrap::Trials`]): the interval then says how much the
//! statistics could differ on the policies' true rates, for this task set. A posterior draw, rather
//! than the parametric bootstrap's Binomial(trials, observed rate), because the latter redraws a
//! cell seen at 0 or 1 as exactly 0 or 1 every time: 0 of 10 would count as certain, and a table
//! of mostly 0/10 cells would get an interval far narrower than its data warrant. Away from 0 and 1
//! the two spread alike (variances p(1 − p)/(n + 2) and p(1 − p)/n). The interval is then one for
//! the statistics on the policies' true rates, so an estimate at a boundary may lie outside it:
//! policies tied at 0/10 almost surely differ in truth, so MMRV's draws are above 0 even where the
//! table's MMRV is 0 (its upper bound is the one to read). When a side of the comparison
//! has cells with only a rate, that noise cannot be modelled; the tasks are resampled with
//! replacement instead (the same draw for both sides and every policy, so pairs stay paired), each
//! policy's means recomputed with the drawn multiplicities, and cells that do have counts are still
//! drawn from their posteriors ([`Bootstrap::Tasks`]): the interval then says how much the
//! statistics depend on which tasks were chosen, and needs at least 2 tasks (or a counted cell).
//! A resample where a policy draws none of its tasks leaves every statistic undefined for that
//! resample. Draws come from [`assay_spec::rng::Rng`] streams, one per (source, task, policy) cell and
//! one for the task draw, so that the result is the same for the same seed and table, and adding a
//! policy does not change the draws of another.
//!
//! A statistic that is undefined (fewer than 2 policies; a correlation of a constant vector) is
//! `None` with the reason, never 0 or NaN. Never does IO: the table comes in as text and the
//! Markdown and SVG go out as strings.

use std::collections::HashMap;
use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use crate::agreement::{
    BOOTSTRAP_RESAMPLES, Estimate, bootstrap_estimate, fields, kendall, mmrv, pearson, spearman,
};
use crate::draws::beta;
use crate::retest::{CountedCell, Retest, retest};
use assay_spec::rng::Rng;

/// One row of a success table: how often `policy` succeeded at `task` according to `source`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Cell {
    pub task: String,
    pub policy: String,
    pub source: String,
    /// Both or neither of `trials` and `successes` are given.
    pub trials: Option<u64>,
    pub successes: Option<u64>,
    /// `successes / trials` when counts are given, else the table's rate; in [0, 1].
    pub rate: f64,
}

/// What to compare.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RankingConfig {
    /// The source that is the ground truth (default `real`).
    pub real: String,
    /// The sources compared with it; empty: every other source, in order of first appearance.
    pub proxies: Vec<String>,
    /// Bootstrap resamples for the 95 % intervals.
    pub resamples: usize,
    /// Seed of the bootstrap streams.
    pub seed: u64,
}

impl Default for RankingConfig {
    fn default() -> Self {
        Self {
            real: "real".into(),
            proxies: Vec::new(),
            resamples: BOOTSTRAP_RESAMPLES,
            seed: 0,
        }
    }
}

/// Every proxy against the real source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Ranking {
    pub real: String,
    pub resamples: usize,
    pub seed: u64,
    pub comparisons: Vec<Comparison>,
}

/// One proxy against the real source, over the policies and tasks both have.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Comparison {
    pub proxy: String,
    pub real: String,
    /// Tasks with at least one policy in both sources, in order of first appearance.
    pub tasks: Vec<String>,
    /// In order of first appearance in the table.
    pub policies: Vec<PolicyPoint>,
    /// Cells and policies left out, with the reason.
    pub excluded: Vec<Excluded>,
    /// How the intervals were resampled.
    pub bootstrap: Bootstrap,
    pub pearson: Estimate,
    /// `mmrv(proxy, real)`; lower is better.
    pub mmrv: Estimate,
    pub spearman: Estimate,
    /// τ-b (ties corrected).
    pub kendall: Estimate,
    /// Calibration: the mean over policies of |R_S − R|, how far the proxy's success rates are
    /// from the real ones as rates a person reads (0 is perfect; an order can be right while
    /// every rate is off). Defined from one policy on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_mae: Option<Estimate>,
    /// What trial noise allows: Pearson r and MMRV of the real evaluation itself rerun in the
    /// proxy's place, on new seeds with the proxy's trial counts (`crate::retest`), the bar to
    /// read the proxy's figures against. Absent unless every cell on both sides has counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retest: Option<Retest>,
    /// Caveats worth reading next to the numbers.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// One policy's real and predicted success.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PolicyPoint {
    pub policy: String,
    /// R: mean over `tasks` of the real success rate.
    pub real: f64,
    /// R_S: mean over the same tasks of the proxy's success rate.
    pub proxy: f64,
    /// Tasks both sources have for this policy.
    pub tasks: usize,
    /// Real trials over those tasks; absent when a cell gave only a rate.
    pub real_trials: Option<u64>,
    pub proxy_trials: Option<u64>,
}

/// A cell (`task` set) or a whole policy (`task` null) left out of a comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Excluded {
    pub task: Option<String>,
    pub policy: String,
    pub reason: String,
}

/// How a comparison's bootstrap resampled (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Bootstrap {
    /// Every cell has counts: each cell's rate drawn from its Jeffreys posterior
    /// Beta(successes + ½, failures + ½); tasks fixed.
    Trials,
    /// Some cells have only a rate: tasks resampled with replacement; cells with counts also
    /// drawn from their posteriors.
    Tasks,
}

impl Bootstrap {
    pub fn describe(self) -> &'static str {
        match self {
            Bootstrap::Trials => {
                "every cell's rate drawn from its Jeffreys posterior Beta(successes + 1/2, \
                 failures + 1/2), tasks fixed"
            }
            Bootstrap::Tasks => {
                "tasks resampled with replacement (some cells give only a rate); cells with \
                 trials also drawn from their Jeffreys posteriors Beta(successes + 1/2, \
                 failures + 1/2)"
            }
        }
    }
}

/// Largest tolerated difference between a row's rate column and its successes / trials (a rate
/// rounded to two decimals).
const RATE_TOLERANCE: f64 = 0.005;

/// Reads a success table: CSV with a header naming `task`, `policy`, `source` and either `trials` +
/// `successes` or a rate column (`success_rate`, `rate` or `success`), case-insensitive, in any
/// order; other columns are ignored. Quoted fields, `#` comment lines and blank lines are allowed.
/// A row may give counts, a rate, or both (they must agree to within 0.005). Errors name the line,
/// the column and the reason.
pub fn parse_success_table(text: &str) -> Result<Vec<Cell>, String> {
    // Spreadsheets save CSV with a byte-order mark; it is not part of the first column's name.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (header_line, header) = lines.next().ok_or("the table is empty (no header line)")?;
    let header = fields(header);
    let listed = || header.join(", ");
    let find = |names: &[&str]| -> Vec<usize> {
        (0..header.len())
            .filter(|&i| names.iter().any(|n| header[i].eq_ignore_ascii_case(n)))
            .collect()
    };
    let one = |names: &[&str]| -> Result<Option<usize>, String> {
        match find(names).as_slice() {
            [] => Ok(None),
            [c] => Ok(Some(*c)),
            [a, b, ..] => Err(format!(
                "line {header_line}: columns {} '{}' and {} '{}' both give the {}",
                a + 1,
                header[*a],
                b + 1,
                header[*b],
                names[0]
            )),
        }
    };
    let need = |name: &str| -> Result<usize, String> {
        one(&[name])?.ok_or_else(|| {
            format!(
                "line {header_line}: no '{name}' column (columns: {})",
                listed()
            )
        })
    };
    let (task_c, policy_c, source_c) = (need("task")?, need("policy")?, need("source")?);
    let trials_c = one(&["trials"])?;
    let successes_c = one(&["successes"])?;
    let rate_c = one(&["success_rate", "rate", "success"])?;
    match (trials_c, successes_c, rate_c) {
        (Some(_), None, _) => {
            return Err(format!(
                "line {header_line}: a 'trials' column needs a 'successes' column"
            ));
        }
        (None, Some(_), _) => {
            return Err(format!(
                "line {header_line}: a 'successes' column needs a 'trials' column"
            ));
        }
        (None, None, None) => {
            return Err(format!(
                "line {header_line}: no 'trials' and 'successes' columns and no 'success_rate' \
                 column (columns: {})",
                listed()
            ));
        }
        _ => {}
    }

    let mut cells = Vec::new();
    let mut first_line: HashMap<(String, String, String), usize> = HashMap::new();
    for (line, text) in lines {
        let f = fields(text);
        if f.len() != header.len() {
            return Err(format!(
                "line {line}: {} fields, the header (line {header_line}) has {}",
                f.len(),
                header.len()
            ));
        }
        let at =
            |c: usize, why: String| format!("line {line}, column {} '{}': {why}", c + 1, header[c]);
        let name = |c: usize| -> Result<String, String> {
            if f[c].is_empty() {
                Err(at(c, "empty".into()))
            } else {
                Ok(f[c].clone())
            }
        };
        let count = |c: Option<usize>| -> Result<Option<u64>, String> {
            let Some(c) = c else { return Ok(None) };
            if f[c].is_empty() {
                return Ok(None);
            }
            f[c].parse::<u64>()
                .map(Some)
                .map_err(|_| at(c, format!("'{}' is not a whole number", f[c])))
        };
        let (task, policy, source) = (name(task_c)?, name(policy_c)?, name(source_c)?);
        let trials = count(trials_c)?;
        let successes = count(successes_c)?;
        let rate = match rate_c {
            Some(c) if !f[c].is_empty() => {
                let v = match f[c].parse::<f64>() {
                    Ok(v) if v.is_finite() => v,
                    _ => return Err(at(c, format!("'{}' is not a number", f[c]))),
                };
                if !(0.0..=1.0).contains(&v) {
                    let hint = if v > 1.0 && v.fract() == 0.0 {
                        " (a count of successes goes in a 'successes' column, with 'trials')"
                    } else {
                        ""
                    };
                    return Err(at(c, format!("{} is outside [0, 1]{hint}", f[c])));
                }
                Some(v)
            }
            _ => None,
        };
        let rate = match (trials, successes, trials_c, successes_c) {
            (Some(0), _, Some(c), _) => {
                return Err(at(c, "0 trials: a cell needs at least one".into()));
            }
            (Some(n), Some(k), _, Some(c)) if k > n => {
                return Err(at(c, format!("{k} successes exceed {n} trials")));
            }
            (Some(n), Some(k), _, _) => {
                let counted = k as f64 / n as f64;
                if let (Some(r), Some(c)) = (rate, rate_c)
                    && (r - counted).abs() > RATE_TOLERANCE
                {
                    return Err(at(
                        c,
                        format!("{r} disagrees with successes / trials = {k}/{n} = {counted:.3}"),
                    ));
                }
                counted
            }
            (Some(_), None, _, Some(c)) => {
                return Err(at(c, "empty, but the row gives trials".into()));
            }
            (None, Some(_), Some(c), _) => {
                return Err(at(c, "empty, but the row gives successes".into()));
            }
            _ => rate.ok_or_else(|| {
                let empty: Vec<String> = [trials_c, successes_c, rate_c]
                    .into_iter()
                    .flatten()
                    .map(|c| format!("{} '{}'", c + 1, header[c]))
                    .collect();
                format!(
                    "line {line}, columns {}: all empty (a row needs trials and successes, or a \
                     success rate)",
                    empty.join(", ")
                )
            })?,
        };
        let key = (task.clone(), policy.clone(), source.clone());
        if let Some(first) = first_line.insert(key, line) {
            return Err(format!(
                "line {line}, columns 'task', 'policy', 'source': a second row for task '{task}', \
                 policy '{policy}', source '{source}' (the first is on line {first})"
            ));
        }
        cells.push(Cell {
            task,
            policy,
            source,
            trials,
            successes,
            rate,
        });
    }
    if cells.is_empty() {
        return Err(format!("line {header_line}: a header and no rows"));
    }
    Ok(cells)
}

/// Checks what the parser guarantees, for cells built another way.
fn check(cells: &[Cell]) -> Result<(), String> {
    let mut seen = HashMap::new();
    for (i, c) in cells.iter().enumerate() {
        let what = format!(
            "cell {i} (task '{}', policy '{}', source '{}')",
            c.task, c.policy, c.source
        );
        if let Some(first) = seen.insert((&c.task, &c.policy, &c.source), i) {
            return Err(format!("{what}: the same as cell {first}"));
        }
        if !(0.0..=1.0).contains(&c.rate) {
            return Err(format!("{what}: rate {} is outside [0, 1]", c.rate));
        }
        match (c.trials, c.successes) {
            (Some(0), _) => return Err(format!("{what}: 0 trials")),
            (Some(n), Some(k)) if k > n => {
                return Err(format!("{what}: {k} successes exceed {n} trials"));
            }
            (Some(_), None) | (None, Some(_)) => {
                return Err(format!("{what}: trials and successes go together"));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Compares every proxy source with the real one (see the module documentation). Errors when the
/// real source or a named proxy has no rows, or when there is nothing to compare with.
pub fn rank(cells: &[Cell], cfg: &RankingConfig) -> Result<Ranking, String> {
    crate::agreement::check_resamples(cfg.resamples)?;
    check(cells)?;
    let mut sources: Vec<&str> = Vec::new();
    for c in cells {
        if !sources.contains(&c.source.as_str()) {
            sources.push(&c.source);
        }
    }
    let listed = sources.join(", ");
    if !sources.contains(&cfg.real.as_str()) {
        return Err(format!(
            "no rows with source '{}' (the ground truth; sources in the table: {listed})",
            cfg.real
        ));
    }
    let mut proxies: Vec<&str> = Vec::new();
    if cfg.proxies.is_empty() {
        proxies.extend(sources.iter().filter(|s| **s != cfg.real));
    } else {
        for p in &cfg.proxies {
            if *p == cfg.real {
                return Err(format!("'{p}' is the real source, not a proxy"));
            }
            if !sources.contains(&p.as_str()) {
                return Err(format!(
                    "no rows with source '{p}' (sources in the table: {listed})"
                ));
            }
            if !proxies.contains(&p.as_str()) {
                proxies.push(p);
            }
        }
    }
    if proxies.is_empty() {
        return Err(format!(
            "no source to compare with '{}' (sources in the table: {listed})",
            cfg.real
        ));
    }
    Ok(Ranking {
        real: cfg.real.clone(),
        resamples: cfg.resamples,
        seed: cfg.seed,
        comparisons: proxies
            .into_iter()
            .map(|p| compare(cells, &cfg.real, p, cfg.resamples, cfg.seed))
            .collect(),
    })
}

/// A success rate as the table gives it.
#[derive(Debug, Clone, Copy)]
enum Rate {
    Counted { successes: u64, trials: u64 },
    Given(f64),
}

impl Rate {
    fn of(c: &Cell) -> Self {
        match (c.successes, c.trials) {
            (Some(successes), Some(trials)) => Rate::Counted { successes, trials },
            _ => Rate::Given(c.rate),
        }
    }

    fn value(self) -> f64 {
        match self {
            Rate::Counted { successes, trials } => successes as f64 / trials as f64,
            Rate::Given(r) => r,
        }
    }

    /// This rate drawn from its Jeffreys posterior, Beta(successes + ½, failures + ½); a given
    /// rate stays.
    fn redraw(self, rng: &mut Rng) -> Self {
        match self {
            Rate::Counted { successes, trials } if trials > 0 => Rate::Given(beta(
                rng,
                successes as f64 + 0.5,
                (trials - successes) as f64 + 0.5,
            )),
            other => other,
        }
    }

    /// Whether redrawing can change it.
    fn varies(self) -> bool {
        matches!(self, Rate::Counted { trials, .. } if trials > 0)
    }
}

fn gcd(mut a: u128, mut b: u128) -> u128 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// The mean of `rates`, each counted `weight` times; `None` when the weights add up to 0. Exact
/// (a reduced fraction, then one division) when every rate has counts, so that equal means are
/// equal floats; otherwise, or if the fraction would overflow, summed in order.
fn mean(rates: impl Iterator<Item = (u64, Rate)>) -> Option<f64> {
    let (mut num, mut den) = (Some(0u128), Some(1u128));
    let (mut sum, mut weights) = (0.0, 0u64);
    for (w, r) in rates {
        if w == 0 {
            continue;
        }
        weights += w;
        sum += w as f64 * r.value();
        (num, den) = match (num, den, r) {
            (Some(n), Some(d), Rate::Counted { successes, trials }) => {
                let t = u128::from(trials);
                let add = u128::from(w)
                    .checked_mul(u128::from(successes))
                    .and_then(|x| x.checked_mul(d));
                match (n.checked_mul(t).zip(add), d.checked_mul(t)) {
                    (Some((a, b)), Some(d)) => match a.checked_add(b) {
                        Some(n) => {
                            let g = gcd(n, d).max(1);
                            (Some(n / g), Some(d / g))
                        }
                        None => (None, None),
                    },
                    _ => (None, None),
                }
            }
            _ => (None, None),
        };
    }
    if weights == 0 {
        return None;
    }
    match (num, den.and_then(|d| d.checked_mul(u128::from(weights)))) {
        (Some(n), Some(d)) => {
            let g = gcd(n, d).max(1);
            Some((n / g) as f64 / (d / g) as f64)
        }
        _ => Some(sum / weights as f64),
    }
}

fn stream(seed: u64, source: &str, task: &str, policy: &str) -> Rng {
    Rng::new(
        seed,
        &format!("ranking\u{1f}{source}\u{1f}{task}\u{1f}{policy}"),
    )
}

/// One policy's cells present on both sides: (task index, real, proxy).
struct Row {
    policy: String,
    cells: Vec<(usize, Rate, Rate)>,
}

type Stat = fn(&[f64], &[f64]) -> Option<f64>;

/// Mean absolute difference of the proxy's and the real rates (`Comparison::calibration_mae`).
fn calibration_mae(proxy: &[f64], real: &[f64]) -> Option<f64> {
    (!real.is_empty()).then(|| {
        proxy
            .iter()
            .zip(real)
            .map(|(p, r)| (p - r).abs())
            .sum::<f64>()
            / real.len() as f64
    })
}

/// The four statistics on (proxy, real), in `Comparison`'s order. MMRV needs 2 policies too.
const STATS: [Stat; 4] = [
    pearson,
    |proxy, real| {
        if real.len() < 2 {
            None
        } else {
            mmrv(proxy, real)
        }
    },
    spearman,
    kendall,
];

fn compare(cells: &[Cell], real: &str, proxy: &str, resamples: usize, seed: u64) -> Comparison {
    let index: HashMap<(&str, &str, &str), &Cell> = cells
        .iter()
        .map(|c| ((c.source.as_str(), c.task.as_str(), c.policy.as_str()), c))
        .collect();
    let (mut policies, mut all_tasks): (Vec<&str>, Vec<&str>) = (Vec::new(), Vec::new());
    for c in cells
        .iter()
        .filter(|c| c.source == real || c.source == proxy)
    {
        if !policies.contains(&c.policy.as_str()) {
            policies.push(&c.policy);
        }
        if !all_tasks.contains(&c.task.as_str()) {
            all_tasks.push(&c.task);
        }
    }
    let mut excluded = Vec::new();
    let mut rows: Vec<Row> = Vec::new();
    for &policy in &policies {
        let mut row = Row {
            policy: policy.to_owned(),
            cells: Vec::new(),
        };
        for (t, &task) in all_tasks.iter().enumerate() {
            match (
                index.get(&(real, task, policy)),
                index.get(&(proxy, task, policy)),
            ) {
                (Some(r), Some(p)) => row.cells.push((t, Rate::of(r), Rate::of(p))),
                (Some(_), None) => excluded.push(Excluded {
                    task: Some(task.to_owned()),
                    policy: policy.to_owned(),
                    reason: format!("no '{proxy}' row"),
                }),
                (None, Some(_)) => excluded.push(Excluded {
                    task: Some(task.to_owned()),
                    policy: policy.to_owned(),
                    reason: format!("no '{real}' row"),
                }),
                (None, None) => {}
            }
        }
        if row.cells.is_empty() {
            excluded.push(Excluded {
                task: None,
                policy: policy.to_owned(),
                reason: format!("no task with both a '{real}' and a '{proxy}' row"),
            });
        } else {
            rows.push(row);
        }
    }

    // Task indices from here on count only the tasks some policy has on both sides.
    let mut tasks: Vec<&str> = Vec::new();
    let mut renumber = vec![usize::MAX; all_tasks.len()];
    for (t, task) in all_tasks.iter().enumerate() {
        if rows.iter().any(|r| r.cells.iter().any(|c| c.0 == t)) {
            renumber[t] = tasks.len();
            tasks.push(task);
        }
    }
    for row in &mut rows {
        for c in &mut row.cells {
            c.0 = renumber[c.0];
        }
    }

    let point = |row: &Row| -> PolicyPoint {
        let trials = |side: fn(&(usize, Rate, Rate)) -> Rate| -> Option<u64> {
            row.cells
                .iter()
                .map(|c| match side(c) {
                    Rate::Counted { trials, .. } => Some(trials),
                    Rate::Given(_) => None,
                })
                .sum()
        };
        PolicyPoint {
            policy: row.policy.clone(),
            real: mean(row.cells.iter().map(|c| (1, c.1))).expect("a policy with tasks"),
            proxy: mean(row.cells.iter().map(|c| (1, c.2))).expect("a policy with tasks"),
            tasks: row.cells.len(),
            real_trials: trials(|c| c.1),
            proxy_trials: trials(|c| c.2),
        }
    };
    let points: Vec<PolicyPoint> = rows.iter().map(point).collect();
    let real_v: Vec<f64> = points.iter().map(|p| p.real).collect();
    let proxy_v: Vec<f64> = points.iter().map(|p| p.proxy).collect();

    let counted = |r: Rate| matches!(r, Rate::Counted { .. });
    let method = if rows
        .iter()
        .all(|r| r.cells.iter().all(|c| counted(c.1) && counted(c.2)))
    {
        Bootstrap::Trials
    } else {
        Bootstrap::Tasks
    };
    // A counted cell always varies (its posterior has spread, even at 0 or 1), so only a table of
    // rates on a single task has nothing to resample.
    let counted_spread = rows
        .iter()
        .any(|r| r.cells.iter().any(|c| c.1.varies() || c.2.varies()));
    let nothing_to_resample = (method == Bootstrap::Tasks && tasks.len() < 2 && !counted_spread)
        .then(|| {
            format!(
                "{} task, so resampling tasks never differs: no interval",
                tasks.len()
            )
        });

    let mut samples: Vec<Vec<f64>> = vec![Vec::with_capacity(resamples); STATS.len()];
    let mut mae_samples: Vec<f64> = Vec::with_capacity(resamples);
    // Resamples where a policy drew none of its tasks (only with different task sets).
    let mut incomplete = 0usize;
    if !rows.is_empty() && nothing_to_resample.is_none() {
        let mut streams: Vec<Vec<(Rng, Rng)>> = rows
            .iter()
            .map(|r| {
                r.cells
                    .iter()
                    .map(|&(t, _, _)| {
                        (
                            stream(seed, real, tasks[t], &r.policy),
                            stream(seed, proxy, tasks[t], &r.policy),
                        )
                    })
                    .collect()
            })
            .collect();
        let mut task_rng = Rng::new(
            seed,
            &format!("ranking\u{1f}{real}\u{1f}{proxy}\u{1f}tasks"),
        );
        let n = tasks.len();
        let mut weights = vec![1u64; n];
        let (mut x, mut y) = (vec![0.0; rows.len()], vec![0.0; rows.len()]);
        for _ in 0..resamples {
            if method == Bootstrap::Tasks {
                weights.fill(0);
                for _ in 0..n {
                    weights[((task_rng.unit() * n as f64) as usize).min(n - 1)] += 1;
                }
            }
            let mut complete = true;
            for (i, (row, rngs)) in rows.iter().zip(&mut streams).enumerate() {
                let drawn: Vec<(usize, Rate, Rate)> = row
                    .cells
                    .iter()
                    .zip(rngs.iter_mut())
                    .map(|(&(t, r, p), (rr, pr))| (t, r.redraw(rr), p.redraw(pr)))
                    .collect();
                match (
                    mean(drawn.iter().map(|c| (weights[c.0], c.1))),
                    mean(drawn.iter().map(|c| (weights[c.0], c.2))),
                ) {
                    (Some(r), Some(p)) => (y[i], x[i]) = (r, p),
                    _ => complete = false,
                }
            }
            if !complete {
                incomplete += 1;
                continue;
            }
            for (s, stat) in samples.iter_mut().zip(STATS) {
                if let Some(v) = stat(&x, &y) {
                    s.push(v);
                }
            }
            mae_samples.extend(calibration_mae(&x, &y));
        }
    }

    let constant = |v: &[f64]| v.iter().all(|x| *x == v[0]);
    let why = |correlation: bool| -> String {
        match rows.len() {
            0 => format!("no policy has a task with both a '{real}' and a '{proxy}' row"),
            n if n < 2 => format!("needs at least 2 policies, has {n}"),
            _ if !correlation => "undefined".into(),
            _ => match (constant(&real_v), constant(&proxy_v)) {
                (true, true) => {
                    format!("every policy has the same success rate in '{real}' and in '{proxy}'")
                }
                (true, false) => format!("every policy has the same '{real}' success rate"),
                (false, true) => format!("every policy has the same '{proxy}' success rate"),
                _ => "the success rates have no spread".into(),
            },
        }
    };
    // A defined estimate without an interval says why: no resamples, nothing to resample, or in
    // how many resamples it was undefined and for which reasons (the shared message assumes
    // scores).
    let explain_interval = |e: &mut Estimate, undefined_in: usize| {
        if e.value.is_none() {
            return;
        }
        let reason = if resamples == 0 {
            Some("no bootstrap resamples were drawn".to_owned())
        } else if nothing_to_resample.is_some() {
            nothing_to_resample.clone()
        } else {
            e.no_interval.is_some().then(|| {
                let mut why =
                    format!("undefined in {undefined_in} of {resamples} bootstrap resamples");
                if incomplete > 0 {
                    let _ = write!(
                        why,
                        "; in {incomplete} of them a policy drew none of its tasks \
                         (policies have different task sets)"
                    );
                }
                if undefined_in > incomplete {
                    let _ = write!(
                        why,
                        "; in {} every policy's resampled rate was the same",
                        undefined_in - incomplete
                    );
                }
                why
            })
        };
        if let Some(reason) = reason {
            e.ci95 = None;
            e.no_interval = Some(reason);
        }
    };
    let mut estimates = STATS.iter().zip(samples).enumerate().map(|(k, (stat, s))| {
        let undefined_in = resamples - s.len();
        let mut e = bootstrap_estimate(stat(&proxy_v, &real_v), s, resamples, || why(k != 1));
        explain_interval(&mut e, undefined_in);
        e
    });
    let mut next = || estimates.next().expect("four statistics");
    let (pearson, mmrv, spearman, kendall) = (next(), next(), next(), next());
    let calibration_mae = (!rows.is_empty()).then(|| {
        let undefined_in = resamples - mae_samples.len();
        let mut e = bootstrap_estimate(
            calibration_mae(&proxy_v, &real_v),
            mae_samples,
            resamples,
            || "no policy".to_owned(),
        );
        explain_interval(&mut e, undefined_in);
        e
    });

    let mut notes = Vec::new();
    if points.iter().any(|p| p.tasks != points[0].tasks) {
        notes.push(
            "policies are averaged over different numbers of tasks (cells missing on one side \
             are left out): compare their rates with care"
                .to_owned(),
        );
    }
    Comparison {
        proxy: proxy.to_owned(),
        real: real.to_owned(),
        tasks: tasks.iter().map(|t| (*t).to_owned()).collect(),
        policies: points,
        excluded,
        bootstrap: method,
        pearson,
        mmrv,
        spearman,
        kendall,
        calibration_mae,
        retest: retest_of(&rows, &tasks, real, resamples, seed),
        notes,
    }
}

/// The rows' retest (`crate::retest`) when every cell on both sides has counts.
fn retest_of(
    rows: &[Row],
    tasks: &[&str],
    real: &str,
    resamples: usize,
    seed: u64,
) -> Option<Retest> {
    let counted: Option<Vec<(&str, Vec<CountedCell<'_>>)>> = rows
        .iter()
        .map(|row| {
            let cells = row.cells.iter().map(|&(t, r, p)| match (r, p) {
                (
                    Rate::Counted { successes, trials },
                    Rate::Counted {
                        trials: proxy_trials,
                        ..
                    },
                ) => Some(CountedCell {
                    task: tasks[t],
                    successes,
                    trials,
                    proxy_trials,
                }),
                _ => None,
            });
            Some((row.policy.as_str(), cells.collect::<Option<Vec<_>>>()?))
        })
        .collect();
    retest(&counted?, real, resamples, seed)
}

impl Comparison {
    /// The four statistics with their names as tables print them.
    pub fn statistics(&self) -> [(&'static str, &Estimate); 4] {
        [
            ("Pearson r", &self.pearson),
            ("MMRV (lower is better)", &self.mmrv),
            ("Spearman ρ", &self.spearman),
            ("Kendall τ-b", &self.kendall),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(task: &str, policy: &str, source: &str, successes: u64, trials: u64) -> Cell {
        Cell {
            task: task.into(),
            policy: policy.into(),
            source: source.into(),
            trials: Some(trials),
            successes: Some(successes),
            rate: successes as f64 / trials as f64,
        }
    }

    fn rated(task: &str, policy: &str, source: &str, rate: f64) -> Cell {
        Cell {
            task: task.into(),
            policy: policy.into(),
            source: source.into(),
            trials: None,
            successes: None,
            rate,
        }
    }

    fn cfg(resamples: usize, seed: u64) -> RankingConfig {
        RankingConfig {
            resamples,
            seed,
            ..RankingConfig::default()
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    /// One task per policy, rates given: R = R_S = the rates themselves.
    fn vectors(proxy: &[f64], real: &[f64]) -> Vec<Cell> {
        let mut cells = Vec::new();
        for (i, (p, r)) in proxy.iter().zip(real).enumerate() {
            cells.push(rated("t", &format!("p{i}"), "real", *r));
            cells.push(rated("t", &format!("p{i}"), "sim", *p));
        }
        cells
    }

    fn mmrv_of(proxy: &[f64], real: &[f64]) -> f64 {
        let r = rank(&vectors(proxy, real), &cfg(0, 0)).unwrap();
        r.comparisons[0].mmrv.value.unwrap()
    }

    #[test]
    fn calibration_is_the_mean_distance_of_the_rates_whatever_the_order() {
        let calibration = |proxy: &[f64], real: &[f64]| {
            let r = rank(&vectors(proxy, real), &cfg(0, 0)).unwrap();
            r.comparisons[0].calibration_mae.clone().unwrap()
        };
        // Ordered perfectly, yet every rate 0.3 too high: Pearson 1, calibration 0.3.
        let e = calibration(&[0.5, 0.7, 0.9], &[0.2, 0.4, 0.6]);
        assert!((e.value.unwrap() - 0.3).abs() < 1e-12, "{e:?}");
        // |0.1 − 0.2| and |0.9 − 0.6|: 0.2. One policy is enough.
        assert!((calibration(&[0.1, 0.9], &[0.2, 0.6]).value.unwrap() - 0.2).abs() < 1e-12);
        assert_eq!(calibration(&[0.4], &[0.4]).value, Some(0.0));
        // With counted trials the bootstrap gives it an interval around the value.
        let a = rank(&ladder(), &cfg(1000, 7)).unwrap();
        let e = a.comparisons[0].calibration_mae.clone().unwrap();
        let [lo, hi] = e.ci95.unwrap();
        assert!(
            lo <= e.value.unwrap() && e.value.unwrap() <= hi && lo < hi,
            "{e:?}"
        );
    }

    #[test]
    fn mmrv_on_hand_computed_rankings() {
        let real = [0.2, 0.4, 0.8];
        // Perfect: the proxy orders every pair as real does (its scale does not matter).
        assert_eq!(mmrv_of(&[0.1, 0.5, 0.9], &real), 0.0);
        // Reversed: every pair violated. i=0: max(|0.2−0.4|, |0.2−0.8|) = 0.6; i=1: max(0.2, 0.4)
        // = 0.4; i=2: max(0.6, 0.4) = 0.6. Mean (0.6 + 0.4 + 0.6) / 3 = 0.5333…
        assert!(close(mmrv_of(&[0.9, 0.5, 0.1], &real), 1.6 / 3.0));
        // Tie in the proxy: proxy = [0.5, 0.5, 0.9]. Pair (0, 1): proxy 0 > 1 false, real 0.2 >
        // 0.4 false: agree; proxy 1 > 0 false, real 0.4 > 0.2 true: violation for i=1, |0.4−0.2|
        // = 0.2. Every other pair agrees. MMRV = (0 + 0.2 + 0) / 3 = 0.0667.
        assert!(close(mmrv_of(&[0.5, 0.5, 0.9], &real), 0.2 / 3.0));
        // Tie in real: real = [0.4, 0.4, 0.8], proxy = [0.3, 0.6, 0.9]. Pair (0, 1): real ties, so
        // real_i > real_j is false both ways; proxy 1 > 0 true ≠ false: a violation for i=1 that
        // costs |0.4 − 0.4| = 0. Every other pair agrees: MMRV = 0.
        assert_eq!(mmrv_of(&[0.3, 0.6, 0.9], &[0.4, 0.4, 0.8]), 0.0);
        // Ties on both sides, and a big miss: real = [0.1, 0.5, 0.5, 0.9], proxy = [0.6, 0.6,
        // 0.2, 0.9]. i=0: j=1 (proxy tie, real 0.1 < 0.5: false = false, agree), j=2 (proxy 0.6
        // > 0.2 true, real 0.1 > 0.5 false: violation |0.1−0.5| = 0.4), j=3 agree → 0.4.
        // i=1: j=0 (proxy tie: false; real 0.5 > 0.1 true: violation 0.4), j=2 (true vs real tie
        // false: violation 0), j=3 agree → 0.4. i=2: j=0 (0.2 > 0.6 false, 0.5 > 0.1 true:
        // violation 0.4), j=1 (false, false: agree), j=3 agree → 0.4. i=3: agrees with all → 0.
        // MMRV = (0.4 + 0.4 + 0.4 + 0) / 4 = 0.3.
        assert!(close(
            mmrv_of(&[0.6, 0.6, 0.2, 0.9], &[0.1, 0.5, 0.5, 0.9]),
            0.3
        ));
        // The argument order is the definition's: swapping the sides changes the result.
        assert!(close(
            mmrv_of(&[0.4, 0.4, 0.8], &[0.3, 0.6, 0.9]),
            0.3 / 3.0
        ));
    }

    /// scipy 1.17.1 (`tests/python/ranking_reference.py examples/rank/ladder.csv`, run with
    /// ~/.cache/assay/st-venv/bin/python): per policy R (real) and R_S (world-model), then Pearson
    /// r, Spearman ρ, Kendall τ-b of (R_S, R), and MMRV(R_S, R) from the script's own loop.
    const LADDER: &[(&str, f64, f64)] = &[
        ("diffusion-400", 0.8266666666666667, 0.7833333333333333),
        ("diffusion-100", 0.7, 0.6666666666666666),
        ("act", 0.6, 0.6166666666666667),
        ("bc-rnn", 0.6, 0.55),
        ("bc-mlp", 0.36666666666666664, 0.55),
    ];
    const LADDER_PEARSON: f64 = 0.8648791562192626;
    const LADDER_SPEARMAN: f64 = 0.9210526315789475;
    const LADDER_KENDALL: f64 = 0.8888888888888888;
    const LADDER_MMRV: f64 = 0.04666666666666667;

    fn ladder() -> Vec<Cell> {
        parse_success_table(include_str!("../../../../examples/rank/ladder.csv")).unwrap()
    }

    #[test]
    fn the_ladder_agrees_with_scipy_and_the_hand_computed_mmrv() {
        let r = rank(&ladder(), &cfg(300, 1)).unwrap();
        assert_eq!(r.comparisons.len(), 1);
        let c = &r.comparisons[0];
        assert_eq!((c.proxy.as_str(), c.real.as_str()), ("world-model", "real"));
        assert_eq!(c.tasks, ["lift", "can", "square"]);
        assert!(c.excluded.is_empty() && c.notes.is_empty());
        assert_eq!(c.bootstrap, Bootstrap::Trials);
        assert_eq!(c.policies.len(), LADDER.len());
        for (p, (name, real, proxy)) in c.policies.iter().zip(LADDER) {
            assert_eq!(p.policy, *name);
            // Exact: the ties (act = bc-rnn in real, bc-rnn = bc-mlp in the world model) are
            // bit-for-bit ties.
            assert_eq!((p.real, p.proxy), (*real, *proxy), "{name}");
            assert_eq!(
                (p.tasks, p.real_trials, p.proxy_trials),
                (3, Some(150), Some(60))
            );
        }
        let near = |e: &Estimate, v: f64, what: &str| {
            let x = e.value.unwrap();
            assert!((x - v).abs() < 1e-12, "{what}: {x} vs {v}");
        };
        near(&c.pearson, LADDER_PEARSON, "pearson");
        near(&c.spearman, LADDER_SPEARMAN, "spearman");
        near(&c.kendall, LADDER_KENDALL, "kendall");
        // By hand: real = [0.827, 0.7, 0.6, 0.6, 0.367], proxy = [0.783, 0.667, 0.617, 0.55,
        // 0.55]. act/bc-rnn: proxy act > bc-rnn, real tie → a violation costing 0. bc-rnn/bc-mlp:
        // proxy tie, so for i = bc-rnn "proxy greater" is false while real 0.6 > 0.367 is true →
        // a violation costing 0.6 − 0.3667 = 0.2333 (for i = bc-mlp both are false: none).
        // MMRV = 0.2333 / 5 = 0.04667.
        near(&c.mmrv, LADDER_MMRV, "mmrv");
        near(&c.mmrv, (0.6 - 55.0 / 150.0) / 5.0, "mmrv by hand");
    }

    #[test]
    fn bootstrap_intervals_contain_the_estimate_and_repeat_for_a_seed() {
        let cells = ladder();
        let a = rank(&cells, &cfg(1000, 7)).unwrap();
        for (name, e) in a.comparisons[0].statistics() {
            let v = e.value.unwrap();
            let [lo, hi] = e.ci95.unwrap_or_else(|| panic!("{name}: {e:?}"));
            assert!(lo <= v && v <= hi, "{name}: {lo} {v} {hi}");
            assert!(lo < hi, "{name}: the trials' noise shows: {lo} {hi}");
        }
        assert_eq!(a, rank(&cells, &cfg(1000, 7)).unwrap());
        assert_ne!(a, rank(&cells, &cfg(1000, 8)).unwrap());
        // Adding a policy does not change another's draws: its stream is its own. (The statistics
        // change, but a policy's point estimate and the seed's streams do not.)
        let mut more = cells.clone();
        more.push(cell("lift", "new", "real", 10, 50));
        more.push(cell("lift", "new", "world-model", 3, 20));
        let b = rank(&more, &cfg(1000, 7)).unwrap();
        assert_eq!(
            b.comparisons[0].policies[..5],
            a.comparisons[0].policies[..]
        );
        assert_eq!(
            b.comparisons[0].notes.len(),
            1,
            "different task counts are noted"
        );
    }

    #[test]
    fn more_trials_narrow_the_interval() {
        let scaled = |k: u64| -> Vec<Cell> {
            ladder()
                .into_iter()
                .map(|c| {
                    let (s, n) = (c.successes.unwrap(), c.trials.unwrap());
                    cell(&c.task, &c.policy, &c.source, s * k, n * k)
                })
                .collect()
        };
        let width = |k: u64| {
            let r = rank(&scaled(k), &cfg(1000, 3)).unwrap();
            let [lo, hi] = r.comparisons[0].pearson.ci95.unwrap();
            assert!(close(
                r.comparisons[0].pearson.value.unwrap(),
                LADDER_PEARSON
            ));
            hi - lo
        };
        assert!(width(10) < width(1) / 2.0, "{} {}", width(10), width(1));
    }

    #[test]
    fn beta_draws_have_the_beta_mean_and_variance() {
        // Jeffreys posteriors of 0/10, 3/10, 10/10 and 1/1000, and Beta(½, ½) itself.
        for (a, b) in [
            (0.5, 10.5),
            (3.5, 7.5),
            (10.5, 0.5),
            (1.5, 999.5),
            (0.5, 0.5),
        ] {
            let mut rng = Rng::new(11, "beta");
            let n = 40_000;
            let draws: Vec<f64> = (0..n).map(|_| beta(&mut rng, a, b)).collect();
            assert!(draws.iter().all(|x| (0.0..=1.0).contains(x)));
            let m = draws.iter().sum::<f64>() / n as f64;
            let v = draws.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64;
            let (em, ev) = (a / (a + b), a * b / ((a + b).powi(2) * (a + b + 1.0)));
            assert!(
                (m - em).abs() < 4.0 * (ev / n as f64).sqrt(),
                "Beta({a}, {b}): mean {m} vs {em}"
            );
            assert!(
                (v / ev - 1.0).abs() < 0.06,
                "Beta({a}, {b}): variance {v} vs {ev}"
            );
        }
    }

    #[test]
    fn a_cell_at_zero_or_one_is_uncertain_too() {
        // Three of four policies at 0/10 in the simulator, as the demo's ladder: the parametric
        // bootstrap redrew them as 0 every time and so treated them as exact. A posterior draw
        // does not: the interval is defined and wider than with the same rates measured 10 times
        // as often.
        let table = |k: u64| {
            let mut cells = Vec::new();
            for (i, (real, proxy)) in [(0, 2), (0, 3), (0, 5), (5, 9)].into_iter().enumerate() {
                cells.push(cell("t", &format!("p{i}"), "real", real * k, 10 * k));
                cells.push(cell("t", &format!("p{i}"), "sim", proxy * k, 10 * k));
            }
            cells
        };
        let pearson = |k: u64| {
            let c = rank(&table(k), &cfg(2000, 5))
                .unwrap()
                .comparisons
                .remove(0);
            assert_eq!(c.bootstrap, Bootstrap::Trials);
            let v = c.pearson.value.unwrap();
            let [lo, hi] = c.pearson.ci95.unwrap();
            assert!(lo < v && v <= hi, "{lo} {v} {hi}");
            (lo, hi)
        };
        let (lo10, hi10) = pearson(1);
        let (lo100, hi100) = pearson(10);
        assert!(
            lo10 < lo100 && hi100 - lo100 < hi10 - lo10,
            "{lo10} {lo100}"
        );
    }

    #[test]
    fn rates_only_resample_tasks() {
        let mut cells = Vec::new();
        for (i, (real, proxy)) in [
            ([0.9, 0.8, 0.7], [0.8, 0.9, 0.6]),
            ([0.6, 0.5, 0.7], [0.5, 0.6, 0.4]),
            ([0.4, 0.2, 0.3], [0.3, 0.3, 0.2]),
            ([0.1, 0.3, 0.2], [0.2, 0.1, 0.3]),
        ]
        .iter()
        .enumerate()
        {
            for (t, task) in ["a", "b", "c"].iter().enumerate() {
                cells.push(rated(task, &format!("p{i}"), "real", real[t]));
                cells.push(rated(task, &format!("p{i}"), "sim", proxy[t]));
            }
        }
        let r = rank(&cells, &cfg(500, 2)).unwrap();
        let c = &r.comparisons[0];
        assert_eq!(c.bootstrap, Bootstrap::Tasks);
        assert_eq!(c.policies[0].real_trials, None);
        let [lo, hi] = c.pearson.ci95.unwrap();
        let v = c.pearson.value.unwrap();
        assert!(lo <= v && v <= hi && lo < hi, "{lo} {v} {hi}");
        // One task: resampling tasks cannot show anything, and the result says so.
        let one: Vec<Cell> = cells.iter().filter(|c| c.task == "a").cloned().collect();
        let c = rank(&one, &cfg(500, 2)).unwrap().comparisons.remove(0);
        assert!(c.pearson.value.is_some() && c.pearson.ci95.is_none());
        assert!(c.pearson.no_interval.unwrap().contains("1 task"));
        // A policy with one of two tasks draws none of them in about a quarter of the resamples:
        // too many for an interval, and the reason says so.
        let uneven: Vec<Cell> = cells
            .iter()
            .filter(|c| c.task != "c" && !(c.policy == "p1" && c.task == "b" && c.source == "sim"))
            .cloned()
            .collect();
        let c = rank(&uneven, &cfg(400, 2)).unwrap().comparisons.remove(0);
        let why = c.mmrv.no_interval.unwrap();
        assert!(why.contains("a policy drew none of its tasks"), "{why}");
        assert_eq!(c.excluded.len(), 1);
        // Every rate 0 or 1 with counts: the posteriors still spread, so there is an interval.
        // With two policies Pearson is ±1 in every draw (here always +1: 5/5 and 0/5 never swap
        // in 100 draws); the calibration's distance is not.
        let sure = vec![
            cell("a", "x", "real", 5, 5),
            cell("a", "x", "sim", 4, 4),
            cell("a", "y", "real", 0, 5),
            cell("a", "y", "sim", 0, 4),
        ];
        let c = rank(&sure, &cfg(100, 0)).unwrap().comparisons.remove(0);
        assert_eq!(c.bootstrap, Bootstrap::Trials);
        assert_eq!(c.pearson.value, Some(1.0));
        let [lo, hi] = c.pearson.ci95.unwrap();
        assert!(close(lo, 1.0) && close(hi, 1.0), "{lo} {hi}");
        let [lo, hi] = c.calibration_mae.unwrap().ci95.unwrap();
        assert!(0.0 < lo && lo < hi, "{lo} {hi}");
    }

    #[test]
    fn undefined_statistics_say_why_and_two_policies_still_compute() {
        // Constant real success: the correlations are undefined; MMRV is 0 (no real margin).
        let r = rank(&vectors(&[0.2, 0.5, 0.9], &[0.5, 0.5, 0.5]), &cfg(100, 0)).unwrap();
        let c = &r.comparisons[0];
        for e in [&c.pearson, &c.spearman, &c.kendall] {
            assert_eq!(e.value, None);
            assert_eq!(e.ci95, None);
            assert!(
                e.undefined.as_deref().unwrap().contains("same 'real'"),
                "{e:?}"
            );
        }
        assert_eq!(c.mmrv.value, Some(0.0));
        // Constant proxy.
        let r = rank(&vectors(&[0.3, 0.3], &[0.1, 0.9]), &cfg(100, 0)).unwrap();
        let e = &r.comparisons[0].pearson;
        assert!(
            e.undefined.as_deref().unwrap().contains("same 'sim'"),
            "{e:?}"
        );
        // Two policies: everything is defined.
        let r = rank(&vectors(&[0.2, 0.6], &[0.1, 0.9]), &cfg(100, 0)).unwrap();
        let c = &r.comparisons[0];
        assert_eq!(c.pearson.value, Some(1.0));
        assert_eq!(c.spearman.value, Some(1.0));
        assert_eq!(c.kendall.value, Some(1.0));
        assert_eq!(c.mmrv.value, Some(0.0));
        // One policy: nothing is.
        let r = rank(&vectors(&[0.2], &[0.1]), &cfg(100, 0)).unwrap();
        for (name, e) in r.comparisons[0].statistics() {
            assert_eq!(e.value, None, "{name}");
            assert!(
                e.undefined
                    .as_deref()
                    .unwrap()
                    .contains("at least 2 policies")
            );
        }
        let json = serde_json::to_value(&r).unwrap();
        assert!(json["comparisons"][0]["pearson"]["value"].is_null());
    }

    #[test]
    fn cells_missing_on_one_side_are_left_out_and_listed() {
        let cells = parse_success_table(
            "task,policy,source,trials,successes\n\
             a,p1,real,10,9\nb,p1,real,10,7\na,p1,sim,10,8\n\
             a,p2,real,10,5\nb,p2,real,10,4\na,p2,sim,10,6\nb,p2,sim,10,3\n\
             c,p3,real,10,2\nd,p3,sim,10,1\n\
             a,p4,real,10,1\nb,p4,real,10,2\na,p4,sim,10,2\nb,p4,sim,10,1\n",
        )
        .unwrap();
        let c = rank(&cells, &cfg(50, 0)).unwrap().comparisons.remove(0);
        let names: Vec<&str> = c.policies.iter().map(|p| p.policy.as_str()).collect();
        assert_eq!(names, ["p1", "p2", "p4"]);
        assert_eq!(c.tasks, ["a", "b"]);
        let got: Vec<(Option<&str>, &str, &str)> = c
            .excluded
            .iter()
            .map(|x| (x.task.as_deref(), x.policy.as_str(), x.reason.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (Some("b"), "p1", "no 'sim' row"),
                (Some("c"), "p3", "no 'sim' row"),
                (Some("d"), "p3", "no 'real' row"),
                (None, "p3", "no task with both a 'real' and a 'sim' row"),
            ]
        );
        // p1 is averaged over task a only: 9/10 real, 8/10 predicted.
        assert_eq!(
            (c.policies[0].real, c.policies[0].proxy, c.policies[0].tasks),
            (0.9, 0.8, 1)
        );
        assert_eq!(c.policies[0].real_trials, Some(10));
        assert_eq!(c.notes.len(), 1);
        let left_out: Vec<(Option<&str>, &str, &str)> = c
            .excluded
            .iter()
            .map(|x| (x.task.as_deref(), x.policy.as_str(), x.reason.as_str()))
            .collect();
        assert!(
            left_out
                .iter()
                .any(|x| x.0 == Some("b") && x.1 == "p1" && x.2.contains("no 'sim' row")),
            "{left_out:?}"
        );
        assert!(
            left_out
                .iter()
                .any(|x| x.0.is_none() && x.1 == "p3" && x.2.contains("no task with both")),
            "{left_out:?}"
        );
    }

    #[test]
    fn proxies_are_chosen_and_checked() {
        let mut cells = ladder();
        cells.extend(
            ladder()
                .into_iter()
                .filter(|c| c.source == "world-model")
                .map(|c| Cell {
                    source: "simpler".into(),
                    ..c
                }),
        );
        let all = rank(&cells, &cfg(40, 0)).unwrap();
        let names: Vec<&str> = all.comparisons.iter().map(|c| c.proxy.as_str()).collect();
        assert_eq!(names, ["world-model", "simpler"]);
        let one = RankingConfig {
            proxies: vec!["simpler".into()],
            ..cfg(40, 0)
        };
        assert_eq!(rank(&cells, &one).unwrap().comparisons.len(), 1);
        let missing = RankingConfig {
            proxies: vec!["cosmos".into()],
            ..cfg(40, 0)
        };
        let e = rank(&cells, &missing).unwrap_err();
        assert!(e.contains("'cosmos'") && e.contains("world-model"), "{e}");
        let e = rank(
            &cells,
            &RankingConfig {
                real: "truth".into(),
                ..cfg(40, 0)
            },
        )
        .unwrap_err();
        assert!(e.contains("no rows with source 'truth'"), "{e}");
        let only_real: Vec<Cell> = cells.into_iter().filter(|c| c.source == "real").collect();
        assert!(
            rank(&only_real, &cfg(40, 0))
                .unwrap_err()
                .contains("no source to compare")
        );
    }

    #[test]
    fn parse_errors_name_the_line_and_the_column() {
        let head = "task,policy,source,trials,successes\n";
        let fails = |body: &str, want: &[&str]| {
            let e = parse_success_table(&format!("{head}{body}")).unwrap_err();
            for w in want {
                assert!(e.contains(w), "{e:?} should contain {w:?}");
            }
        };
        fails(
            "a,p,real,10,12\n",
            &[
                "line 2",
                "column 5 'successes'",
                "12 successes exceed 10 trials",
            ],
        );
        fails(
            "a,p,real,10,3\nb,p,real,0,0\n",
            &["line 3", "column 4 'trials'", "0 trials"],
        );
        fails(
            "a,p,real,ten,3\n",
            &["line 2", "column 4 'trials'", "'ten' is not a whole number"],
        );
        fails("a,p,real,10,-1\n", &["line 2", "column 5", "'-1'"]);
        fails(
            "a,p,real,10,3\n\n# note\na,p,real,10,4\n",
            &["line 5", "second row", "line 2"],
        );
        fails("a,,real,10,3\n", &["line 2", "column 2 'policy'", "empty"]);
        fails("a,p,real,10\n", &["line 2", "4 fields", "has 5"]);
        fails(
            "a,p,real,10,\n",
            &["line 2", "column 5 'successes'", "empty"],
        );
        let e = parse_success_table("task,policy,source,trials,successes,rate\na,p,real,,,\n")
            .unwrap_err();
        assert!(
            e.contains("line 2, columns 4 'trials', 5 'successes', 6 'rate': all empty"),
            "{e}"
        );
        let e = parse_success_table("task,policy,trials,successes\na,p,1,1\n").unwrap_err();
        assert!(
            e.contains("line 1") && e.contains("no 'source' column"),
            "{e}"
        );
        let e = parse_success_table("task,policy,source,trials\na,p,real,1\n").unwrap_err();
        assert!(e.contains("line 1") && e.contains("'successes'"), "{e}");
        let e = parse_success_table("task,policy,source\na,p,real\n").unwrap_err();
        assert!(e.contains("success_rate"), "{e}");
        let rates = "task,policy,source,success_rate\n";
        let e = parse_success_table(&format!("{rates}a,p,real,1.5\n")).unwrap_err();
        assert!(
            e.contains("line 2, column 4 'success_rate': 1.5 is outside [0, 1]"),
            "{e}"
        );
        let e = parse_success_table(&format!("{rates}a,p,real,85%\n")).unwrap_err();
        assert!(
            e.contains("line 2, column 4") && e.contains("not a number"),
            "{e}"
        );
        let e = parse_success_table("task,policy,source,success\na,p,real,7\n").unwrap_err();
        assert!(
            e.contains("'successes' column"),
            "a count in a rate column: {e}"
        );
        let e =
            parse_success_table("task,policy,source,trials,successes,rate\na,p,real,10,6,0.9\n")
                .unwrap_err();
        assert!(e.contains("column 6 'rate'") && e.contains("6/10"), "{e}");
        let e = parse_success_table("task,policy,source,rate,success\n").unwrap_err();
        assert!(e.contains("both give"), "{e}");
        assert!(
            parse_success_table("# nothing\n")
                .unwrap_err()
                .contains("empty")
        );
    }

    #[test]
    fn tables_may_quote_comment_and_mix_counts_with_rates() {
        let cells = parse_success_table(
            "# a comment\n\n Task , Policy,SOURCE,trials,successes,rate,notes\n\
             \"open, then close\",\"pi \"\"0\"\"\",real,20,15,0.75,x\n\
             \"open, then close\",\"pi \"\"0\"\"\",wm,,,0.7,\n\
             lift,pi1,real,4,1,,\n",
        )
        .unwrap();
        assert_eq!(cells.len(), 3);
        assert_eq!(cells[0].task, "open, then close");
        assert_eq!(cells[0].policy, "pi \"0\"");
        assert_eq!(
            (cells[0].trials, cells[0].successes, cells[0].rate),
            (Some(20), Some(15), 0.75)
        );
        assert_eq!((cells[1].trials, cells[1].rate), (None, 0.7));
        assert_eq!(cells[2].rate, 0.25);
    }

    #[test]
    fn a_byte_order_mark_is_not_part_of_the_first_column() {
        let table = "task,policy,source,success_rate\r\nlift,pi,real,0.5\r\n";
        let plain = parse_success_table(table).unwrap();
        let marked = parse_success_table(&format!("\u{feff}{table}")).unwrap();
        assert_eq!(plain, marked);
        assert_eq!(marked[0].task, "lift");
    }

    #[test]
    fn equal_fractions_tie_exactly() {
        // 0.1 + 0.2 + 0.3 differs from 0.3 + 0.2 + 0.1 in floating point; as fractions they are
        // the same, so the two policies tie.
        let cells = vec![
            cell("a", "x", "real", 1, 10),
            cell("b", "x", "real", 2, 10),
            cell("c", "x", "real", 3, 10),
            cell("a", "y", "real", 3, 10),
            cell("b", "y", "real", 2, 10),
            cell("c", "y", "real", 1, 10),
            cell("a", "x", "sim", 1, 2),
            cell("b", "x", "sim", 1, 2),
            cell("c", "x", "sim", 1, 2),
            cell("a", "y", "sim", 1, 4),
            cell("b", "y", "sim", 1, 4),
            cell("c", "y", "sim", 1, 4),
        ];
        assert_ne!(0.1 + 0.2 + 0.3, 0.3 + 0.2 + 0.1);
        let c = rank(&cells, &cfg(0, 0)).unwrap().comparisons.remove(0);
        assert_eq!(c.policies[0].real, c.policies[1].real);
        assert_eq!(c.policies[0].real, 0.2);
        // Real ties, so MMRV pays nothing; the correlations are undefined (constant real).
        assert_eq!(c.mmrv.value, Some(0.0));
        assert!(c.pearson.value.is_none());
        assert_eq!(
            c.mmrv.no_interval.as_deref(),
            Some("no bootstrap resamples were drawn")
        );
    }

    #[test]
    fn too_few_resamples_for_an_interval_are_refused() {
        let cells = ladder();
        for n in [1, 2, 39] {
            let e = rank(&cells, &cfg(n, 0)).unwrap_err();
            assert!(e.contains("at least 40"), "{n}: {e}");
        }
        assert!(rank(&cells, &cfg(0, 0)).is_ok(), "0: no intervals");
        assert!(rank(&cells, &cfg(40, 0)).is_ok());
    }
}
