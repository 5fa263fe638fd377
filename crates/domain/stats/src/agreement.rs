//! Agreement between raters: a judge's scores against human ratings (the paper's figure 3), with
//! bootstrap intervals; and MMRV for policy rankings. A statistic that is undefined for its input
//! (a correlation of constant scores) is reported as undefined with the reason, never as 0 or NaN.

use serde::{Deserialize, Serialize};

use assay_spec::rng::Rng;

/// Pearson's r; `None` with fewer than 2 pairs or when either side is constant.
pub fn pearson(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    if n < 2 {
        return None;
    }
    let mean = |v: &[f64]| v[..n].iter().sum::<f64>() / n as f64;
    let (mx, my) = (mean(x), mean(y));
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (dx, dy) = (x[i] - mx, y[i] - my);
        sxy += dx * dy;
        sxx += dx * dx;
        syy += dy * dy;
    }
    // Relative to the scale of the data, so that rounding noise is not taken for spread.
    let scale = |m: f64| 1e-24 * (1.0 + m * m) * n as f64;
    if sxx <= scale(mx) || syy <= scale(my) {
        return None;
    }
    Some((sxy / (sxx * syy).sqrt()).clamp(-1.0, 1.0))
}

/// Mean absolute difference; `None` for no pairs.
pub fn mae(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    (n > 0).then(|| x.iter().zip(y).map(|(a, b)| (a - b).abs()).sum::<f64>() / n as f64)
}

/// Ranks from 1, ties sharing their average rank.
pub fn ranks(v: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut r = vec![0.0; v.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && v[order[j + 1]] == v[order[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0 + 1.0;
        for &k in &order[i..=j] {
            r[k] = avg;
        }
        i = j + 1;
    }
    r
}

/// Spearman's ρ: Pearson's r of the ranks.
pub fn spearman(x: &[f64], y: &[f64]) -> Option<f64> {
    pearson(&ranks(x), &ranks(y))
}

/// Kendall's τ-b (ties corrected); `None` when either side is all ties.
pub fn kendall(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len().min(y.len());
    let (mut concordant, mut discordant, mut tie_x, mut tie_y) = (0i64, 0i64, 0i64, 0i64);
    for i in 0..n {
        for j in i + 1..n {
            let (dx, dy) = (x[i] - x[j], y[i] - y[j]);
            match (dx == 0.0, dy == 0.0) {
                (true, true) => {}
                (true, false) => tie_x += 1,
                (false, true) => tie_y += 1,
                (false, false) if (dx > 0.0) == (dy > 0.0) => concordant += 1,
                _ => discordant += 1,
            }
        }
    }
    let nx = (concordant + discordant + tie_x) as f64;
    let ny = (concordant + discordant + tie_y) as f64;
    (nx > 0.0 && ny > 0.0).then(|| (concordant - discordant) as f64 / (nx * ny).sqrt())
}

/// MMRV as `../shared/DESIGN.md` pins it: for each policy i, the largest |real_i − real_j| over
/// the j that `sim` orders differently from `real` (strict comparisons, so a tie in real scores
/// costs nothing); the mean over i. The argument order is part of the definition.
pub fn mmrv(sim: &[f64], real: &[f64]) -> Option<f64> {
    let n = sim.len().min(real.len());
    if n == 0 {
        return None;
    }
    let total: f64 = (0..n)
        .map(|i| {
            (0..n)
                .filter(|&j| (sim[i] > sim[j]) != (real[i] > real[j]))
                .map(|j| (real[i] - real[j]).abs())
                .fold(0.0, f64::max)
        })
        .sum();
    Some(total / n as f64)
}

/// One statistic: its value and bootstrap 95 % interval, or why it is undefined.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Estimate {
    pub value: Option<f64>,
    /// Percentile interval over the bootstrap resamples where the statistic is defined; absent when
    /// fewer than 90 % of them are.
    pub ci95: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub undefined: Option<String>,
    /// Why a defined statistic has no interval.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_interval: Option<String>,
}

/// A judge against a reference (human ratings): the paper's figure 3 and more.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Agreement {
    pub n: usize,
    pub pearson: Estimate,
    pub mae: Estimate,
    pub r_over_mae: Estimate,
    pub spearman: Estimate,
    pub kendall: Estimate,
}

/// Bootstrap resamples used for the intervals.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

fn why_undefined(reference: &[f64], judge: &[f64]) -> String {
    let constant = |v: &[f64]| v.iter().all(|x| *x == v[0]);
    match (reference.len(), constant(reference), constant(judge)) {
        (n, _, _) if n < 2 => format!("needs at least 2 rated items, has {n}"),
        (_, true, true) => "both sides' scores are constant".into(),
        (_, true, false) => "the reference scores are constant".into(),
        (_, false, true) => "the judge's scores are constant".into(),
        _ => "the scores have no spread".into(),
    }
}

/// Fewest bootstrap resamples a 95 % percentile interval is drawn from: each 2.5 % tail then
/// holds at least one resample. Fewer gives an "interval" that can exclude its own estimate.
pub const MIN_RESAMPLES: usize = 40;

/// Refuses a resample count that cannot make a 95 % interval (0 means: no intervals).
pub fn check_resamples(n: usize) -> Result<usize, String> {
    if n == 0 || n >= MIN_RESAMPLES {
        Ok(n)
    } else {
        Err(format!(
            "{n} bootstrap resamples cannot make a 95 % interval: use at least {MIN_RESAMPLES} \
             (each 2.5 % tail then holds a resample), or 0 for no intervals"
        ))
    }
}

/// Agreement of `judge` with `reference` (paired by index), with percentile bootstrap intervals
/// over `resamples` resamples of the pairs drawn from a stream seeded by `seed`.
pub fn agreement(reference: &[f64], judge: &[f64], resamples: usize, seed: u64) -> Agreement {
    let n = reference.len().min(judge.len());
    let (reference, judge) = (&reference[..n], &judge[..n]);
    type Stat = fn(&[f64], &[f64]) -> Option<f64>;
    let ratio: Stat = |x, y| match (pearson(x, y), mae(x, y)) {
        (Some(r), Some(m)) if m > 0.0 => Some(r / m),
        _ => None,
    };
    let stats: [Stat; 5] = [pearson, mae, ratio, spearman, kendall];
    let mut samples: Vec<Vec<f64>> = vec![Vec::with_capacity(resamples); stats.len()];
    if n > 0 {
        let mut rng = Rng::new(seed, "agreement/bootstrap");
        let (mut x, mut y) = (vec![0.0; n], vec![0.0; n]);
        for _ in 0..resamples {
            for k in 0..n {
                let i = ((rng.unit() * n as f64) as usize).min(n - 1);
                x[k] = reference[i];
                y[k] = judge[i];
            }
            for (s, stat) in samples.iter_mut().zip(stats) {
                if let Some(v) = stat(&x, &y) {
                    s.push(v);
                }
            }
        }
    }
    let mut estimates = stats.iter().zip(samples).map(|(stat, s)| {
        bootstrap_estimate(stat(reference, judge), s, resamples, || {
            why_undefined(reference, judge)
        })
    });
    let mut next = || estimates.next().expect("five statistics");
    let (pearson, mae, r_over_mae, spearman, kendall) = (next(), next(), next(), next(), next());
    let mae = if n == 0 {
        Estimate {
            undefined: Some("no rated items".into()),
            ..mae
        }
    } else {
        mae
    };
    Agreement {
        n,
        pearson,
        mae,
        r_over_mae,
        spearman,
        kendall,
    }
}

/// `value` with the percentile 95 % interval of `samples`, its values in the resamples (of
/// `resamples` drawn) where it was defined; no interval when it is undefined in more than 10 % of
/// them. `undefined` says why when `value` is `None`.
pub(crate) fn bootstrap_estimate(
    value: Option<f64>,
    mut samples: Vec<f64>,
    resamples: usize,
    undefined: impl FnOnce() -> String,
) -> Estimate {
    let defined = samples.len();
    let ci95 = (value.is_some() && defined * 10 >= resamples * 9 && defined > 0).then(|| {
        samples.sort_by(f64::total_cmp);
        let last = samples.len() - 1;
        let at = |q: f64| samples[((q * last as f64).round() as usize).min(last)];
        [at(0.025), at(0.975)]
    });
    Estimate {
        value,
        undefined: value.is_none().then(undefined),
        no_interval: (value.is_some() && ci95.is_none()).then(|| {
            format!(
                "undefined in {} of {resamples} bootstrap resamples (scores nearly constant)",
                resamples - defined
            )
        }),
        ci95,
    }
}

/// Ratings read from a CSV table: one row per rated item, a reference column (human ratings) and
/// one column per judge; optionally a grouping column (dataset).
#[derive(Debug, Clone, PartialEq)]
pub struct Ratings {
    pub group_column: Option<String>,
    pub reference: String,
    pub judges: Vec<String>,
    pub rows: Vec<RatingRow>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RatingRow {
    pub line: usize,
    pub group: Option<String>,
    pub item: String,
    pub reference: Option<f64>,
    /// One per judge, `None` where the cell is empty.
    pub judges: Vec<Option<f64>>,
}

/// Splits one CSV line (RFC 4180 quoting within the line).
pub(crate) fn fields(line: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                chars.next();
                out.last_mut().expect("a field").push('"');
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(String::new()),
            _ => out.last_mut().expect("a field").push(c),
        }
    }
    out.into_iter().map(|f| f.trim().to_owned()).collect()
}

/// A score cell: a number, optionally followed by a parenthesised variance (`2.56(0.9)`, as the
/// paper's tables write the mean and variance of 5 runs); empty is missing.
fn score(cell: &str) -> Result<Option<f64>, String> {
    let number = cell.split('(').next().unwrap_or("").trim();
    if number.is_empty() {
        return Ok(None);
    }
    match number.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Some(v)),
        _ => Err(format!("'{cell}' is not a score")),
    }
}

/// Reads a ratings table. Lines starting with `#` are comments. `reference` names the reference
/// column (case-insensitive); the grouping column is `group` if given, else a column named
/// `dataset` or `group` if there is one; the item column is `task` or `item`, else the first
/// other column; every remaining column is a judge.
pub fn parse_ratings(text: &str, reference: &str, group: Option<&str>) -> Result<Ratings, String> {
    // Spreadsheets save CSV with a byte-order mark; it is not part of the first column's name.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (header_line, header) = lines.next().ok_or("the table is empty")?;
    let header = fields(header);
    let find = |name: &str| header.iter().position(|h| h.eq_ignore_ascii_case(name));
    let r = find(reference).ok_or_else(|| {
        format!(
            "line {header_line}: no reference column '{reference}' (columns: {})",
            header.join(", ")
        )
    })?;
    let g = match group {
        Some(name) => {
            Some(find(name).ok_or_else(|| format!("line {header_line}: no column '{name}'"))?)
        }
        None => find("dataset").or_else(|| find("group")),
    };
    let item = find("task")
        .or_else(|| find("item"))
        .filter(|i| Some(*i) != g && *i != r)
        .or_else(|| (0..header.len()).find(|i| Some(*i) != g && *i != r))
        .ok_or("the table needs an item column")?;
    let judge_cols: Vec<usize> = (0..header.len())
        .filter(|i| *i != r && *i != item && Some(*i) != g)
        .collect();
    if judge_cols.is_empty() {
        return Err(format!("line {header_line}: no judge columns"));
    }
    let mut rows = Vec::new();
    for (line, text) in lines {
        let f = fields(text);
        if f.len() != header.len() {
            return Err(format!(
                "line {line}: {} fields, the header has {}",
                f.len(),
                header.len()
            ));
        }
        let cell = |c: usize| {
            score(&f[c]).map_err(|e| format!("line {line}, column '{}': {e}", header[c]))
        };
        rows.push(RatingRow {
            line,
            group: g.map(|g| f[g].clone()),
            item: f[item].clone(),
            reference: cell(r)?,
            judges: judge_cols
                .iter()
                .map(|&c| cell(c))
                .collect::<Result<_, _>>()?,
        });
    }
    Ok(Ratings {
        group_column: g.map(|g| header[g].clone()),
        reference: header[r].clone(),
        judges: judge_cols.iter().map(|&c| header[c].clone()).collect(),
        rows,
    })
}

/// Agreement of every judge with the reference, per group and over all rows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct AgreementTable {
    pub reference: String,
    pub group_column: Option<String>,
    pub resamples: usize,
    pub rows: Vec<AgreementRow>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct AgreementRow {
    /// The group, or `None` for all rows together.
    pub group: Option<String>,
    pub judge: String,
    pub agreement: Agreement,
}

impl Ratings {
    /// Each judge against the reference, per group (in order of appearance) and then over all rows;
    /// a row missing either score is left out of that judge's pairs.
    pub fn agreement(&self, resamples: usize, seed: u64) -> AgreementTable {
        let mut groups: Vec<Option<String>> = Vec::new();
        for r in &self.rows {
            if r.group.is_some() && !groups.contains(&r.group) {
                groups.push(r.group.clone());
            }
        }
        groups.push(None);
        let mut rows = Vec::new();
        for g in &groups {
            for (j, judge) in self.judges.iter().enumerate() {
                let (x, y): (Vec<f64>, Vec<f64>) = self
                    .rows
                    .iter()
                    .filter(|r| g.is_none() || &r.group == g)
                    .filter_map(|r| Some((r.reference?, r.judges[j]?)))
                    .unzip();
                rows.push(AgreementRow {
                    group: g.clone(),
                    judge: judge.clone(),
                    agreement: agreement(&x, &y, resamples, seed),
                });
            }
        }
        AgreementTable {
            reference: self.reference.clone(),
            group_column: self.group_column.clone(),
            resamples,
            rows,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// scipy 1.17.1 (`tests/python/agreement_reference.py`) on the paper's tables: dataset, model,
    /// n, Pearson r, MAE, r/MAE, Spearman ρ, Kendall τ-b.
    type Expected = (
        &'static str,
        &'static str,
        usize,
        Option<f64>,
        f64,
        Option<f64>,
        Option<f64>,
        Option<f64>,
    );
    const TABLE4: &[Expected] = &[
        (
            "GenSim",
            "GPT-4+Blip2",
            10,
            Some(0.0018250792782161002),
            0.8419999999999999,
            Some(0.0021675525869549886),
            Some(-0.31098139099274313),
            Some(-0.20459830184114206),
        ),
        (
            "GenSim",
            "Cambrian",
            10,
            Some(0.7605448244345618),
            2.425,
            Some(0.3136267317255925),
            Some(0.6418214174789838),
            Some(0.5443310539518174),
        ),
        (
            "GenSim",
            "LLava",
            10,
            Some(-0.2329879318681195),
            1.115,
            Some(-0.20895778642880672),
            Some(-0.2335496832484569),
            Some(-0.1807753815155468),
        ),
        (
            "GenSim",
            "GPT-4v",
            10,
            Some(0.5163448270491295),
            0.45299999999999996,
            Some(1.1398340552960917),
            Some(0.2727272727272727),
            Some(0.19999999999999998),
        ),
        (
            "GenSim",
            "GPT-4+LLava",
            10,
            Some(-0.29276036456613813),
            2.1949999999999994,
            Some(-0.13337602030347984),
            Some(-0.24003717444980285),
            Some(-0.20452399702596544),
        ),
        (
            "GenSim",
            "GPT-4+Cambrian",
            10,
            Some(-0.3284612674466703),
            1.739,
            Some(-0.18887939473644066),
            Some(-0.3446561747421316),
            Some(-0.395777167602761),
        ),
        (
            "RoboGen",
            "GPT-4+Blip2",
            10,
            Some(0.4449887098087766),
            0.7750000000000001,
            Some(0.5741789803984213),
            Some(0.473902240270431),
            Some(0.3492151478847891),
        ),
        (
            "RoboGen",
            "Cambrian",
            10,
            Some(0.06722051244415155),
            2.375,
            Some(0.028303373660695387),
            Some(0.05326236412913074),
            Some(0.027607881518711637),
        ),
        (
            "RoboGen",
            "LLava",
            10,
            Some(-0.7153329540925248),
            0.43500000000000005,
            Some(-1.6444435726264937),
            Some(-0.5303300858899106),
            Some(-0.46852128566581824),
        ),
        (
            "RoboGen",
            "GPT-4v",
            10,
            Some(0.08762211461517484),
            0.42699999999999994,
            Some(0.2052040154922128),
            Some(0.19937791451169073),
            Some(0.14458880781356395),
        ),
        (
            "RoboGen",
            "GPT-4+LLava",
            10,
            Some(0.5332917024410913),
            0.9570000000000001,
            Some(0.5572536075664485),
            Some(0.6230559828490335),
            Some(0.4819626927118799),
        ),
        (
            "RoboGen",
            "GPT-4+Cambrian",
            10,
            Some(0.37157778545301834),
            1.0530000000000002,
            Some(0.3528753897939395),
            Some(0.5489204808235123),
            Some(0.35010942629624875),
        ),
    ];
    const TABLE5: &[Expected] = &[
        (
            "GenSim",
            "Cambrian-8B",
            9,
            Some(0.5820430034724432),
            7.533333333333333,
            Some(0.07726234559368715),
            Some(0.7201440432144051),
            Some(0.6425396041156862),
        ),
        (
            "GenSim",
            "LLava-1.5",
            9,
            None,
            1.2444444444444442,
            None,
            None,
            None,
        ),
        (
            "GenSim",
            "GPT-4",
            9,
            Some(0.30799756652261123),
            2.99,
            Some(0.10300921957277967),
            Some(0.30125786715206027),
            Some(0.253546276418555),
        ),
        (
            "RoboGen",
            "Cambrian-8B",
            10,
            None,
            7.380000000000001,
            None,
            None,
            None,
        ),
        (
            "RoboGen",
            "LLava-1.5",
            10,
            None,
            1.1400000000000001,
            None,
            None,
            None,
        ),
        (
            "RoboGen",
            "GPT-4",
            10,
            Some(0.5506373696432614),
            1.1800000000000002,
            Some(0.4666418386807299),
            Some(0.4969512195121952),
            Some(0.29545454545454547),
        ),
    ];

    fn check(csv: &str, expected: &[Expected]) {
        let ratings = parse_ratings(csv, "human", None).unwrap();
        assert_eq!(ratings.group_column.as_deref(), Some("dataset"));
        let table = ratings.agreement(200, 7);
        let close = |a: Option<f64>, b: Option<f64>, what: &str| match (a, b) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 1e-9, "{what}: {a} vs scipy {b}"),
            (None, None) => {}
            _ => panic!("{what}: {a:?} vs scipy {b:?}"),
        };
        for (dataset, model, n, r, m, ratio, rho, tau) in expected {
            let row = table
                .rows
                .iter()
                .find(|x| x.group.as_deref() == Some(dataset) && x.judge == *model)
                .unwrap_or_else(|| panic!("{dataset} {model}"));
            let a = &row.agreement;
            let what = format!("{dataset} {model}");
            assert_eq!(a.n, *n, "{what}");
            close(a.pearson.value, *r, &format!("{what} r"));
            close(a.mae.value, Some(*m), &format!("{what} MAE"));
            close(a.r_over_mae.value, *ratio, &format!("{what} r/MAE"));
            close(a.spearman.value, *rho, &format!("{what} rho"));
            close(a.kendall.value, *tau, &format!("{what} tau"));
            if r.is_none() {
                let why = a.pearson.undefined.as_deref().unwrap_or("");
                assert!(why.contains("constant"), "{what}: {why}");
                assert!(a.pearson.ci95.is_none());
            } else if let Some([lo, hi]) = a.pearson.ci95 {
                assert!(lo <= hi && (-1.0..=1.0).contains(&lo) && (-1.0..=1.0).contains(&hi));
            } else {
                // Nearly constant scores (LLava's 3.00 on 8 of 10 GenSim tasks): many resamples
                // are constant, and the result says so rather than inventing an interval.
                let why = a.pearson.no_interval.as_deref().expect("a reason");
                assert!(why.contains("resamples"), "{what}: {why}");
            }
        }
    }

    #[test]
    fn the_papers_tables_agree_with_scipy() {
        check(
            include_str!("../../../../examples/agreement/paper-table4-scene-alignment.csv"),
            TABLE4,
        );
        check(
            include_str!("../../../../examples/agreement/paper-table5-completion.csv"),
            TABLE5,
        );
    }

    #[test]
    fn bootstrap_intervals_cover_the_estimate_and_shrink_with_more_data() {
        let x: Vec<f64> = (0..40).map(|i| f64::from(i % 10)).collect();
        let y: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, v)| v + if i % 3 == 0 { 1.5 } else { -0.5 })
            .collect();
        let small = agreement(&x[..10], &y[..10], 1000, 1);
        let large = agreement(&x, &y, 1000, 1);
        for a in [&small, &large] {
            let r = a.pearson.value.unwrap();
            let [lo, hi] = a.pearson.ci95.unwrap();
            assert!(lo <= r && r <= hi, "{lo} {r} {hi}");
        }
        let width = |a: &Agreement| {
            let [lo, hi] = a.mae.ci95.unwrap();
            hi - lo
        };
        assert!(width(&large) < width(&small));
        // Same seed, same intervals.
        assert_eq!(agreement(&x, &y, 500, 3), agreement(&x, &y, 500, 3));
    }

    #[test]
    fn mmrv_follows_the_pinned_definition() {
        // Perfect ranking: no violation.
        assert_eq!(mmrv(&[0.1, 0.5, 0.9], &[0.2, 0.4, 0.8]), Some(0.0));
        // sim swaps policies 0 and 1: each of them pays |0.4 − 0.2|; policy 2 pays nothing.
        let m = mmrv(&[0.5, 0.1, 0.9], &[0.2, 0.4, 0.8]).unwrap();
        assert!((m - 0.4 / 3.0).abs() < 1e-12);
        // Argument order matters: a tie in the first argument is a violation, in the second not.
        assert_eq!(mmrv(&[0.3, 0.3], &[0.1, 0.9]), Some(0.4));
        assert_eq!(mmrv(&[0.1, 0.9], &[0.3, 0.3]), Some(0.0));
    }

    #[test]
    fn a_byte_order_mark_is_not_part_of_the_first_column() {
        // The reference column first, so a mark left in its name would lose it.
        let table = "human,task,gpt\r\n3,a,4\r\n2,b,2\r\n";
        let plain = parse_ratings(table, "human", None).unwrap();
        let marked = parse_ratings(&format!("\u{feff}{table}"), "human", None).unwrap();
        assert_eq!(plain, marked);
        assert_eq!(marked.reference, "human");
    }

    #[test]
    fn malformed_tables_are_named_by_line_and_column() {
        let e = parse_ratings("task,human,gpt\na,3,4\nb,x,2\n", "human", None).unwrap_err();
        assert!(e.contains("line 3") && e.contains("'human'"), "{e}");
        let e = parse_ratings("task,human,gpt\na,3\n", "human", None).unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        let e = parse_ratings("task,people,gpt\na,3,4\n", "human", None).unwrap_err();
        assert!(e.contains("no reference column"), "{e}");
        // Quoted fields, empty cells (left out), comments.
        let r = parse_ratings(
            "# a comment\ntask,human,gpt\n\"Open, then close\",3,\nb,4,4.5(0.1)\n",
            "human",
            None,
        )
        .unwrap();
        assert_eq!(r.rows[0].item, "Open, then close");
        assert_eq!(r.rows[0].judges, vec![None]);
        assert_eq!(r.rows[1].judges, vec![Some(4.5)]);
        assert_eq!(r.agreement(10, 0).rows[0].agreement.n, 1);
    }
}
