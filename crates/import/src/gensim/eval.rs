//! The evaluator of GenSim task code: a small line-based reader of a Ravens task's `reset` that
//! knows the task API (`env.add_object`, `self.get_random_pose`, `self.fill_template`,
//! `self.add_goal`, `utils.apply`, `for` loops over literals and `range`). It never runs the code:
//! what it cannot read stays an unread expression that the mapping reports.
//!
//! Owns: reading. Never builds a spec (the parent module does, from what this returns).

use std::collections::BTreeMap;

use super::*;

#[derive(Debug, Clone, PartialEq)]
pub(super) enum Val {
    Num(f64),
    Str(String),
    Seq(Vec<Val>),
    /// A `get_random_pose` draw (index into `Eval::poses`).
    Pose(usize),
    /// `utils.apply(base, (0, 0, dz))`.
    Stack {
        base: usize,
        dz: f64,
    },
    /// An object returned by `env.add_object`.
    Obj(usize),
    Template {
        path: String,
        size: Vec<f64>,
    },
    Other(String),
}

#[derive(Debug, Clone)]
pub(super) struct AddObject {
    pub(super) urdf: Val,
    pub(super) pose: Option<usize>,
    pub(super) fixed: bool,
    pub(super) color: Option<String>,
}

#[derive(Debug, Clone, Default)]
pub(super) struct AddGoal {
    pub(super) kwargs: BTreeMap<String, Val>,
    pub(super) raw: BTreeMap<String, String>,
}

#[derive(Default)]
pub(super) struct Eval {
    pub(super) vars: BTreeMap<String, Val>,
    /// Sizes of the `get_random_pose` draws.
    pub(super) poses: Vec<Vec<f64>>,
    pub(super) objects: Vec<AddObject>,
    pub(super) goals: Vec<AddGoal>,
    /// Constructs that cannot be mapped: (field, reason, fatal).
    pub(super) unmappable: Vec<(String, String, bool)>,
}

/// Strips a `#` comment outside strings.
pub(super) fn strip_comment(line: &str) -> &str {
    let mut quote: Option<char> = None;
    for (i, c) in line.char_indices() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => {}
            None if c == '\'' || c == '"' => quote = Some(c),
            None if c == '#' => return &line[..i],
            None => {}
        }
    }
    line
}

/// Bracket depth change over `s` (outside strings).
pub(super) fn depth(s: &str) -> i32 {
    let mut d = 0;
    let mut quote: Option<char> = None;
    for c in s.chars() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => {}
            None => match c {
                '\'' | '"' => quote = Some(c),
                '(' | '[' | '{' => d += 1,
                ')' | ']' | '}' => d -= 1,
                _ => {}
            },
        }
    }
    d
}

/// Logical lines (brackets joined) with their indentation, comments stripped, blanks dropped.
pub(super) fn logical_lines(code: &str) -> Vec<(usize, String)> {
    let mut out: Vec<(usize, String)> = Vec::new();
    let mut open = 0;
    for raw in code.lines() {
        let line = strip_comment(raw);
        if line.trim().is_empty() {
            continue;
        }
        if open > 0 {
            let last = out.last_mut().expect("open line");
            last.1.push(' ');
            last.1.push_str(line.trim());
        } else {
            let indent = line.len() - line.trim_start().len();
            out.push((indent, line.trim().to_owned()));
        }
        open += depth(line);
    }
    out
}

/// Splits at top-level `sep` (outside brackets and strings).
pub(super) fn split_top(s: &str, sep: char) -> Vec<String> {
    let mut parts = Vec::new();
    let mut cur = String::new();
    let mut d = 0;
    let mut quote: Option<char> = None;
    for c in s.chars() {
        match quote {
            Some(q) => {
                if c == q {
                    quote = None;
                }
                cur.push(c);
            }
            None => {
                match c {
                    '\'' | '"' => quote = Some(c),
                    '(' | '[' | '{' => d += 1,
                    ')' | ']' | '}' => d -= 1,
                    _ => {}
                }
                if c == sep && d == 0 {
                    parts.push(std::mem::take(&mut cur));
                } else {
                    cur.push(c);
                }
            }
        }
    }
    if !cur.trim().is_empty() {
        parts.push(cur);
    }
    parts.into_iter().map(|p| p.trim().to_owned()).collect()
}

/// The text between the outer parentheses of a call `f(...)`.
pub(super) fn call_args<'a>(s: &'a str, prefix: &str) -> Option<&'a str> {
    let rest = s.strip_prefix(prefix)?.strip_prefix('(')?;
    rest.strip_suffix(')')
}

/// Positional and keyword arguments.
pub(super) fn args(s: &str) -> (Vec<String>, BTreeMap<String, String>) {
    let mut pos = Vec::new();
    let mut kw = BTreeMap::new();
    for a in split_top(s, ',') {
        match a.split_once('=') {
            Some((k, v))
                if k.trim().chars().all(|c| c.is_alphanumeric() || c == '_')
                    && !v.starts_with('=') =>
            {
                kw.insert(k.trim().to_owned(), v.trim().to_owned());
            }
            _ => pos.push(a),
        }
    }
    (pos, kw)
}

pub(super) fn is_ident(s: &str) -> bool {
    !s.is_empty()
        && s.chars().all(|c| c.is_alphanumeric() || c == '_')
        && !s.starts_with(|c: char| c.is_ascii_digit())
}

impl Eval {
    pub(super) fn eval(&mut self, e: &str) -> Val {
        let e = e.trim();
        if let Some(s) = e
            .strip_prefix('\'')
            .and_then(|s| s.strip_suffix('\''))
            .or_else(|| e.strip_prefix('"').and_then(|s| s.strip_suffix('"')))
        {
            return Val::Str(s.to_owned());
        }
        if let Ok(x) = e.parse::<f64>() {
            return Val::Num(x);
        }
        if e == "np.pi" {
            return Val::Num(std::f64::consts::PI);
        }
        let div = split_top(e, '/');
        if div.len() == 2
            && let (Val::Num(a), Val::Num(b)) = (self.eval(&div[0]), self.eval(&div[1]))
        {
            return Val::Num(a / b);
        }
        if e.starts_with('(') && e.ends_with(')') && depth(&e[1..e.len() - 1]) == 0 {
            let inner = &e[1..e.len() - 1];
            let parts = split_top(inner, ',');
            if parts.len() == 1 && !inner.trim_end().ends_with(',') {
                return self.eval(&parts[0]);
            }
            return Val::Seq(parts.iter().map(|p| self.eval(p)).collect());
        }
        if e.starts_with('[') && e.ends_with(']') && depth(&e[1..e.len() - 1]) == 0 {
            let inner = &e[1..e.len() - 1];
            if let Some((expr, rest)) = inner.split_once(" for ")
                && let Some((var, iter)) = rest.split_once(" in ")
            {
                let items = self.iterate(iter);
                let saved = self.vars.get(var.trim()).cloned();
                let mut out = Vec::new();
                for it in items {
                    self.vars.insert(var.trim().to_owned(), it);
                    out.push(self.eval(expr));
                }
                match saved {
                    Some(v) => self.vars.insert(var.trim().to_owned(), v),
                    None => self.vars.remove(var.trim()),
                };
                return Val::Seq(out);
            }
            return Val::Seq(split_top(inner, ',').iter().map(|p| self.eval(p)).collect());
        }
        if let Some(a) = call_args(e, "utils.apply") {
            let parts = split_top(a, ',');
            if parts.len() == 2
                && let (Val::Pose(base), Val::Seq(off)) =
                    (self.eval(&parts[0]), self.eval(&parts[1]))
                && let Some(Val::Num(dz)) = off.get(2)
            {
                return Val::Stack { base, dz: *dz };
            }
            return Val::Other(e.into());
        }
        if let Some(inner) = e
            .strip_prefix("utils.COLORS[")
            .and_then(|s| s.strip_suffix(']'))
        {
            return self.eval(inner);
        }
        if let Some(a) = call_args(e, "self.get_random_pose") {
            let (pos, _) = args(a);
            let size = match pos.get(1).map(|s| self.eval(s)) {
                Some(Val::Seq(v)) => v
                    .iter()
                    .map(|x| if let Val::Num(n) = x { *n } else { 0.0 })
                    .collect(),
                _ => vec![0.04, 0.04, 0.04],
            };
            self.poses.push(size);
            return Val::Pose(self.poses.len() - 1);
        }
        if let Some(a) = call_args(e, "self.fill_template") {
            let (pos, _) = args(a);
            let path = match pos.first().map(|s| self.eval(s)) {
                Some(Val::Str(s)) => s,
                _ => String::new(),
            };
            let size = pos
                .get(1)
                .and_then(|d| {
                    let d = d.trim().strip_prefix('{')?.strip_suffix('}')?;
                    let (_, v) = d.split_once(':')?;
                    match self.eval(v) {
                        Val::Seq(v) => Some(
                            v.iter()
                                .map(|x| if let Val::Num(n) = x { *n } else { 0.0 })
                                .collect(),
                        ),
                        _ => None,
                    }
                })
                .unwrap_or_default();
            return Val::Template { path, size };
        }
        if let Some(a) = call_args(e, "env.add_object") {
            return self.add_object(a);
        }
        // A bound on unrolled loops: `range(4294967296)` would otherwise allocate 200 GB and
        // abort (found by core/tests/fuzz.rs); larger ranges stay unread expressions.
        if let Some(a) = call_args(e, "range")
            && let Val::Num(n) = self.eval(a)
            && n <= MAX_RANGE
        {
            return Val::Seq((0..n as usize).map(|i| Val::Num(i as f64)).collect());
        }
        for (prefix, what) in [
            (
                "self.make_ropes",
                "make_ropes: a deformable rope (a chain of small articulated blocks) is not representable in spec v1",
            ),
            (
                "self.make_piles",
                "make_piles: a pile of small particles is not representable in spec v1",
            ),
            (
                "self.make_kitting",
                "kitting shapes are not representable in spec v1",
            ),
        ] {
            if e.starts_with(prefix) {
                self.unmappable.push((
                    prefix.trim_start_matches("self.").into(),
                    what.into(),
                    true,
                ));
                return Val::Other(e.into());
            }
        }
        if e.starts_with("p.") {
            let field = e.split('(').next().unwrap_or(e).to_owned();
            if self.unmappable.iter().any(|(f, _, _)| *f == field) {
                return Val::Other(e.into());
            }
            self.unmappable.push((
                field,
                "direct PyBullet call (here: letting the scene settle), not part of spec v1".into(),
                false,
            ));
            return Val::Other(e.into());
        }
        if let Some(open) = e.find('[')
            && e.ends_with(']')
            && is_ident(&e[..open])
        {
            let base = self.eval(&e[..open]);
            let idx = self.eval(&e[open + 1..e.len() - 1]);
            if let (Val::Seq(v), Val::Num(i)) = (&base, idx)
                && let Some(x) = v.get(i as usize)
            {
                return x.clone();
            }
            return Val::Other(e.into());
        }
        if is_ident(e)
            && let Some(v) = self.vars.get(e)
        {
            return v.clone();
        }
        Val::Other(e.into())
    }

    pub(super) fn iterate(&mut self, e: &str) -> Vec<Val> {
        match self.eval(e) {
            Val::Seq(v) => v,
            _ => Vec::new(),
        }
    }

    pub(super) fn add_object(&mut self, a: &str) -> Val {
        let (pos, kw) = args(a);
        let urdf = pos
            .first()
            .map(|s| self.eval(s))
            .unwrap_or(Val::Other("".into()));
        let pose = match pos.get(1).map(|s| self.eval(s)) {
            Some(Val::Pose(p)) => Some(p),
            _ => None,
        };
        let category = pos
            .get(2)
            .or_else(|| kw.get("category"))
            .map(|s| self.eval(s));
        let fixed = matches!(category, Some(Val::Str(ref s)) if s == "fixed");
        let color = match kw.get("color").map(|s| self.eval(s)) {
            Some(Val::Str(s)) => Some(s),
            _ => None,
        };
        self.objects.push(AddObject {
            urdf,
            pose,
            fixed,
            color,
        });
        Val::Obj(self.objects.len() - 1)
    }

    pub(super) fn statement(&mut self, s: &str) {
        if let Some((lhs, rhs)) = s.split_once(" = ") {
            let lhs = lhs.trim();
            if is_ident(lhs) {
                let v = self.eval(rhs);
                self.vars.insert(lhs.to_owned(), v);
                return;
            }
            if let Some(attr) = lhs.strip_prefix("self.") {
                let v = self.eval(rhs);
                self.vars.insert(format!("self.{attr}"), v);
                return;
            }
            // Tuple targets (`objects, targets, matches = self.make_ropes(...)`).
            self.eval(rhs);
            return;
        }
        if let Some(a) = call_args(s, "self.add_goal") {
            let (_, kw) = args(a);
            let mut g = AddGoal::default();
            for (k, v) in &kw {
                let val = self.eval(v);
                g.kwargs.insert(k.clone(), val);
            }
            g.raw = kw;
            self.goals.push(g);
            return;
        }
        if let Some((target, arg)) = s.split_once(".append(")
            && is_ident(target)
        {
            let v = self.eval(arg.trim_end_matches(')'));
            if let Some(Val::Seq(list)) = self.vars.get_mut(target) {
                list.push(v);
            }
            return;
        }
        // Nothing is dropped silently: control flow the evaluator does not follow, and calls it
        // does not read, are listed (not fatal: the rest of the task may still import).
        let t = s.trim();
        if ["if ", "elif ", "while ", "with ", "try:", "else:"]
            .iter()
            .any(|k| t.starts_with(k))
        {
            self.unread(
                t,
                "control flow is not followed: the lines under it were read as if they ran",
            );
            return;
        }
        let v = self.eval(s);
        if matches!(v, Val::Other(_))
            && t.contains('(')
            && !t.starts_with("super()")
            // The base class's bookkeeping between episodes (language goals), no scene.
            && !t.starts_with("self.additional_reset()")
            && !t.starts_with("return")
        {
            self.unread(t, "a call the importer does not read");
        }
    }

    /// Lists a line of task code the evaluator did not read, once.
    pub(super) fn unread(&mut self, line: &str, reason: &str) {
        let short: String = line.chars().take(60).collect();
        let field = format!("code `{short}`");
        if !self.unmappable.iter().any(|(f, _, _)| *f == field) {
            self.unmappable.push((field, reason.into(), false));
        }
    }

    pub(super) fn block(&mut self, lines: &[(usize, String)]) {
        let mut i = 0;
        while i < lines.len() {
            let (indent, text) = &lines[i];
            let body_end = lines[i + 1..]
                .iter()
                .position(|(k, _)| k <= indent)
                .map_or(lines.len(), |p| i + 1 + p);
            if let Some(head) = text.strip_prefix("for ").and_then(|t| t.strip_suffix(':')) {
                if let Some((var, iter)) = head.split_once(" in ") {
                    let items = self.iterate(iter);
                    for it in items {
                        self.vars.insert(var.trim().to_owned(), it);
                        self.block(&lines[i + 1..body_end]);
                    }
                }
                i = body_end;
                continue;
            }
            self.statement(text);
            i += 1;
        }
    }
}

/// The body of `def name(...)`: the lines indented deeper than the `def`.
pub(super) fn method<'a>(lines: &'a [(usize, String)], name: &str) -> &'a [(usize, String)] {
    let Some(start) = lines
        .iter()
        .position(|(_, t)| t.starts_with(&format!("def {name}(")))
    else {
        return &[];
    };
    let indent = lines[start].0;
    let end = lines[start + 1..]
        .iter()
        .position(|(k, _)| *k <= indent)
        .map_or(lines.len(), |p| start + 1 + p);
    &lines[start + 1..end]
}
