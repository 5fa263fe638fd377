//! The report's presentation model: the tables both `report.md` and `report.html` show, built
//! once from the results ([`crate::tables`]) and written by two small renderers
//! ([`Table::markdown`] here, `html::table` for the page). A cell is a list of spans, so what a
//! cell means (code, a strong total, an undefined statistic and its reason) is decided once and
//! each format only decides how it looks.
//!
//! Owns: the model and the number formats every table shares. Never escapes for a format
//! (each renderer does), never aggregates.

use assay_stats::agreement::Estimate;
use assay_stats::stats::Proportion;

/// One piece of a cell.
#[derive(Debug, Clone, PartialEq)]
pub enum Span {
    Text(String),
    /// An identifier: a task id, a judge name, a predicate, a hash.
    Code(String),
    /// Emphasised (totals).
    Strong(String),
    /// A statistic with no value, with the reason.
    Undefined(String),
    /// A value that does not exist here (no trials, no fit): `–`.
    Missing,
    /// A line break inside the cell (HTML `<br>`, Markdown `; `).
    Break,
    /// A link to a task's own section in the page (HTML); its text elsewhere.
    TaskLink(String),
    /// A long name shown short: HTML gives the full one as the title, Markdown lists it under
    /// the table (see [`policy_label`]).
    Abbrev {
        short: String,
        full: String,
    },
}

/// A table cell: spans shown one after another.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Cell(pub Vec<Span>);

impl Cell {
    pub fn text(s: impl Into<String>) -> Self {
        Self(vec![Span::Text(s.into())])
    }
    pub fn code(s: impl Into<String>) -> Self {
        Self(vec![Span::Code(s.into())])
    }
    pub fn strong(s: impl Into<String>) -> Self {
        Self(vec![Span::Strong(s.into())])
    }
    pub fn missing() -> Self {
        Self(vec![Span::Missing])
    }
    /// `–` for an empty text.
    pub fn or_missing(s: &str) -> Self {
        if s.is_empty() {
            Self::missing()
        } else {
            Self::text(s)
        }
    }
    /// A policy's name, shortened when it has a label in `labels` or is a learned policy's spec
    /// ([`policy_label`]).
    pub fn policy(name: &str, labels: &[(String, String)]) -> Self {
        match policy_label(name, labels) {
            Some(short) => Self(vec![Span::Abbrev {
                short,
                full: name.to_owned(),
            }]),
            None => Self::text(name),
        }
    }
    /// Names, each with [`Cell::policy`], separated by commas.
    pub fn policies<'a>(
        names: impl IntoIterator<Item = &'a str>,
        labels: &[(String, String)],
    ) -> Self {
        let mut c = Self::default();
        for (i, name) in names.into_iter().enumerate() {
            if i > 0 {
                c = c.and(Span::Text(", ".into()));
            }
            c.0.extend(Self::policy(name, labels).0);
        }
        if c.0.is_empty() { Self::missing() } else { c }
    }
    /// Adds a span.
    pub fn and(mut self, span: Span) -> Self {
        self.0.push(span);
        self
    }
    /// The cell's text without any format (for tests and plain output).
    pub fn plain(&self) -> String {
        let mut out = String::new();
        for s in &self.0 {
            match s {
                Span::Text(t)
                | Span::Code(t)
                | Span::Strong(t)
                | Span::TaskLink(t)
                | Span::Abbrev { short: t, .. } => out.push_str(t),
                Span::Undefined(why) => {
                    out.push_str("undefined: ");
                    out.push_str(why);
                }
                Span::Missing => out.push('–'),
                Span::Break => out.push_str("; "),
            }
        }
        out
    }
}

impl From<String> for Cell {
    fn from(s: String) -> Self {
        Self::text(s)
    }
}

impl From<&str> for Cell {
    fn from(s: &str) -> Self {
        Self::text(s)
    }
}

/// A column: its title and whether its cells are numbers (right-aligned).
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub title: String,
    pub numeric: bool,
}

/// A row; a `total` row is shown emphasised (a table's last line over all groups).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Row {
    pub cells: Vec<Cell>,
    pub total: bool,
}

/// A table of the report.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    pub columns: Vec<Column>,
    pub rows: Vec<Row>,
}

impl Table {
    /// A table with these columns; a title starting with `#` is numeric (the `#` is dropped).
    pub fn new<S: AsRef<str>>(columns: impl IntoIterator<Item = S>) -> Self {
        Self {
            columns: columns
                .into_iter()
                .map(|c| {
                    let c = c.as_ref();
                    match c.strip_prefix('#') {
                        Some(title) => Column {
                            title: title.to_owned(),
                            numeric: true,
                        },
                        None => Column {
                            title: c.to_owned(),
                            numeric: false,
                        },
                    }
                })
                .collect(),
            rows: Vec::new(),
        }
    }

    pub fn row(&mut self, cells: Vec<Cell>) {
        debug_assert_eq!(cells.len(), self.columns.len(), "a row per column");
        self.rows.push(Row {
            cells,
            total: false,
        });
    }

    pub fn total(&mut self, cells: Vec<Cell>) {
        debug_assert_eq!(cells.len(), self.columns.len(), "a row per column");
        self.rows.push(Row { cells, total: true });
    }

    /// As a GitHub-flavoured Markdown table, ending with a newline.
    pub fn markdown(&self) -> String {
        let mut out = String::from("|");
        for c in &self.columns {
            out.push(' ');
            out.push_str(&md_text(&c.title));
            out.push_str(" |");
        }
        out.push_str("\n|");
        for c in &self.columns {
            out.push_str(if c.numeric { "---:|" } else { "---|" });
        }
        out.push('\n');
        for r in &self.rows {
            out.push('|');
            for c in &r.cells {
                out.push(' ');
                out.push_str(&md_cell(c, r.total));
                out.push_str(" |");
            }
            out.push('\n');
        }
        out
    }
}

/// Markdown text in a table: pipes escaped, one line.
pub fn md_text(s: &str) -> String {
    s.replace('|', "\\|").replace(['\n', '\r'], " ")
}

/// A cell as Markdown; the spans of a total row are emphasised.
pub fn md_cell(c: &Cell, total: bool) -> String {
    let mut out = String::new();
    for s in &c.0 {
        match s {
            Span::Text(t) if total && !t.trim().is_empty() => {
                out.push_str(&format!("**{}**", md_text(t)))
            }
            Span::Text(t) => out.push_str(&md_text(t)),
            Span::Code(t) | Span::TaskLink(t) => {
                out.push_str(&format!("`{}`", md_text(t).replace('`', "'")))
            }
            Span::Strong(t) => out.push_str(&format!("**{}**", md_text(t))),
            Span::Abbrev { short, .. } => out.push_str(&md_text(short)),
            Span::Undefined(why) => out.push_str(&format!("undefined: {}", md_text(why))),
            Span::Missing => out.push('–'),
            Span::Break => out.push_str("; "),
        }
    }
    out
}

/// A learned policy's spec shortened for tables and plots: `diffusion:model=policies/<sha>.
/// diffusion,max_steps=6000` reads `diffusion 3fa9c2d1` (its kind and the model file's first 8
/// characters). None for any other name, which is shown as it is.
pub fn short_policy(name: &str) -> Option<String> {
    let (kind, params) = name.split_once(':')?;
    let model = params.split(',').find_map(|p| p.strip_prefix("model="))?;
    let file = model.rsplit('/').next().unwrap_or(model);
    let stem = file.split('.').next().unwrap_or(file);
    let short: String = stem.chars().take(8).collect();
    let shorter = format!("{kind} {short}");
    (!short.is_empty() && shorter.len() < name.len()).then_some(shorter)
}

/// A policy's name as the tables and plots show it: its label in `labels` (policy name, label)
/// when it has one (a ladder's policy reads `diffusion 10 ep @ 300`, see
/// [`crate::ranking::RankingResults::labels`]), else [`short_policy`]'s. None for a name shown
/// as it is.
pub fn policy_label(name: &str, labels: &[(String, String)]) -> Option<String> {
    labels
        .iter()
        .find(|(policy, _)| policy == name)
        .map(|(_, label)| label.clone())
        .or_else(|| short_policy(name))
}

/// Where `name` stands in the order of `labels` (a ladder's policies by episodes and step), for
/// sorting: None, first, for a policy without a label.
pub fn label_rank(name: &str, labels: &[(String, String)]) -> Option<usize> {
    labels.iter().position(|(policy, _)| policy == name)
}

/// The abbreviations of a table's cells, each once, in order of appearance: (short, full).
pub fn abbreviations<'a>(tables: impl IntoIterator<Item = &'a Table>) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    for t in tables {
        for s in t.rows.iter().flat_map(|r| &r.cells).flat_map(|c| &c.0) {
            if let Span::Abbrev { short, full } = s
                && !out.iter().any(|(_, f)| f == full)
            {
                out.push((short.clone(), full.clone()));
            }
        }
    }
    out
}

/// Two decimals, never `-0.00`.
pub fn num2(v: f64) -> String {
    let s = format!("{v:.2}");
    if s == "-0.00" { "0.00".into() } else { s }
}

/// A success rate with its count and Wilson interval: `80 % (4/5) [38, 96]`; `–` without
/// trials.
pub fn proportion(p: &Proportion) -> Cell {
    match (p.rate, p.ci95) {
        (Some(r), Some([lo, hi])) => Cell::text(format!(
            "{:.0} % ({}/{}) [{:.0}, {:.0}]",
            r * 100.0,
            p.successes,
            p.trials,
            lo * 100.0,
            hi * 100.0
        )),
        (Some(r), None) => Cell::text(format!("{:.0} % ({}/{})", r * 100.0, p.successes, p.trials)),
        _ => Cell::missing(),
    }
}

/// An estimate with its 95 % interval (`0.812 [0.501, 0.934]`), the value alone with why it has
/// no interval, or undefined with the reason — never 0 or NaN.
pub fn estimate(e: &Estimate) -> Cell {
    match e.value {
        Some(v) if v.is_finite() => match (e.ci95, &e.no_interval) {
            (Some([lo, hi]), _) => Cell::text(format!("{v:.3} [{lo:.3}, {hi:.3}]")),
            (None, Some(why)) => Cell::text(format!("{v:.3} (no interval: {why})")),
            (None, None) => Cell::text(format!("{v:.3}")),
        },
        _ => Cell(vec![Span::Undefined(
            e.undefined.clone().unwrap_or_else(|| "no value".into()),
        )]),
    }
}

/// `3.50 (var 0.25, n 4)`, `–` where absent.
pub fn score(mean: Option<f64>, variance: Option<f64>, n: u64) -> Cell {
    match mean {
        Some(m) => Cell::text(format!(
            "{} (var {}, n {n})",
            num2(m),
            variance.map_or("–".into(), num2)
        )),
        None => Cell::missing(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_tables_escape_and_align() {
        let mut t = Table::new(["name", "#n"]);
        t.row(vec![
            Cell::code("a|b").and(Span::Text(" x\ny".into())),
            "1".into(),
        ]);
        t.total(vec![Cell::text("all"), Cell::missing()]);
        assert_eq!(
            t.markdown(),
            "| name | n |\n|---|---:|\n| `a\\|b` x y | 1 |\n| **all** | – |\n"
        );
    }

    #[test]
    fn learned_policies_read_short_and_keep_their_full_name() {
        let full = "diffusion:model=policies/3fa9c2d1e8b74a60.diffusion,max_steps=6000";
        assert_eq!(short_policy(full).as_deref(), Some("diffusion 3fa9c2d1"));
        assert_eq!(short_policy("oracle:noise=0.03"), None);
        assert_eq!(short_policy("diffusion-400"), None);
        let mut t = Table::new(["policy"]);
        t.row(vec![Cell::policies([full, "oracle", full], &[])]);
        assert_eq!(
            t.rows[0].cells[0].plain(),
            "diffusion 3fa9c2d1, oracle, diffusion 3fa9c2d1"
        );
        assert_eq!(
            abbreviations([&t]),
            [("diffusion 3fa9c2d1".to_owned(), full.to_owned())]
        );
        // A label (a ladder policy's episodes and step) comes before the shortened name.
        let labels = [(full.to_owned(), "diffusion 10 ep @ 300".to_owned())];
        assert_eq!(
            policy_label(full, &labels).as_deref(),
            Some("diffusion 10 ep @ 300")
        );
        assert_eq!(policy_label("oracle", &labels), None);
        let mut t = Table::new(["policy"]);
        t.row(vec![Cell::policies([full, "oracle"], &labels)]);
        assert_eq!(t.rows[0].cells[0].plain(), "diffusion 10 ep @ 300, oracle");
        assert_eq!(
            abbreviations([&t]),
            [("diffusion 10 ep @ 300".to_owned(), full.to_owned())]
        );
    }

    #[test]
    fn numbers_have_one_format() {
        assert_eq!(num2(-0.001), "0.00");
        let p = Proportion::new(4, 5);
        assert!(proportion(&p).plain().starts_with("80 % (4/5) ["));
        assert_eq!(proportion(&Proportion::new(0, 0)).plain(), "–");
        let e = Estimate {
            value: None,
            ci95: None,
            undefined: Some("needs 2".into()),
            no_interval: None,
        };
        assert_eq!(estimate(&e).plain(), "undefined: needs 2");
        assert_eq!(score(Some(3.5), None, 2).plain(), "3.50 (var –, n 2)");
    }
}
