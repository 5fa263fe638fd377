//! The report's figures as standalone SVG strings, drawn with plotters: scene alignment against
//! completion (the paper's figure 4), grouped bar charts with optional 95 % intervals (figure 3,
//! Tables 1 and 3) and line charts (Table 2).
//!
//! Owns: drawing plain numbers. Never reads a report (the callers in [`crate::html`] pick the
//! numbers), never does IO. Every function accepts empty and degenerate input (no points, one
//! point, all values equal, non-finite values) and still returns a well-formed SVG; the same input
//! gives the same bytes.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use assay_stats::agreement::Estimate;
use assay_stats::calibration::Reliability;
use assay_stats::ranking::{Comparison, Ranking};

/// Series colours (matplotlib's tab10, as report.md's quality figure uses).
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// The colour of series `i`.
pub fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// The colour of series `i` as CSS (`#1f77b4`), for legends drawn in HTML.
pub fn colour_css(i: usize) -> String {
    let RGBColor(r, g, b) = colour(i);
    format!("#{r:02x}{g:02x}{b:02x}")
}

type Drawn = Result<(), Box<dyn std::error::Error>>;

/// Draws into a `w`×`h` SVG; a plotting error (none is expected) becomes an SVG that says so.
fn render(
    w: u32,
    h: u32,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Drawn,
) -> String {
    let mut out = String::new();
    let result = {
        let root = SVGBackend::with_string(&mut out, (w, h)).into_drawing_area();
        draw(&root).and_then(|()| root.present().map_err(Into::into))
    };
    match result {
        Ok(()) => out,
        Err(e) => {
            let msg = e
                .to_string()
                .replace('&', "&amp;")
                .replace('<', "&lt;")
                .replace('>', "&gt;");
            format!(
                "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\">\
                 <text x=\"10\" y=\"20\">figure not drawn: {msg}</text></svg>"
            )
        }
    }
}

/// A note in the middle of an empty plot.
fn note(root: &DrawingArea<SVGBackend<'_>, Shift>, text: &str) -> Drawn {
    let (w, h) = root.dim_in_pixel();
    root.draw(&Text::new(
        text.to_owned(),
        (w as i32 / 2 - 60, h as i32 / 2),
        ("sans-serif", 14).into_font().color(&BLACK.mix(0.6)),
    ))?;
    Ok(())
}

/// `lo..hi` covering `values` (and `include`), never empty, with a margin of `pad` of its span.
fn span(values: impl Iterator<Item = f64>, include: Option<f64>, pad: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.chain(include).filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        let d = if lo.abs() > 1e-12 {
            lo.abs() * 0.5
        } else {
            1.0
        };
        if include == Some(lo) {
            return (lo, lo + d);
        }
        return (lo - d, hi + d);
    }
    let m = (hi - lo) * pad;
    let lo = if include == Some(lo) { lo } else { lo - m };
    (lo, hi + m)
}

/// One (task, judge) of figure 4.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenePoint {
    pub group: String,
    /// Index of the judge (0 is drawn filled, the others as outlines).
    pub judge: usize,
    /// Mean scene alignment, 1–5.
    pub scene_alignment: f64,
    /// Mean completion, 0–10.
    pub completion: f64,
    /// The scores' spread in 0–1: see [`SPREAD_RULE`].
    pub spread: f64,
}

/// How figure 4's marker size encodes the variance of the scores, for its caption.
pub const SPREAD_RULE: &str = "marker radius = 3 + 12·√f px with f = (vSA/4 + vC/25)/2, the \
     variances of the task's scene-alignment and completion scores as fractions of the largest \
     their ranges allow (4 and 25); the area grows with the variance";

/// The spread `f` of [`SPREAD_RULE`] from the two sample variances (absent: 0).
pub fn spread(var_scene_alignment: Option<f64>, var_completion: Option<f64>) -> f64 {
    let f = |v: Option<f64>, max: f64| v.filter(|v| v.is_finite()).unwrap_or(0.0) / max;
    ((f(var_scene_alignment, 4.0) + f(var_completion, 25.0)) / 2.0).clamp(0.0, 1.0)
}

fn marker_radius(spread: f64) -> i32 {
    let f = if spread.is_finite() {
        spread.clamp(0.0, 1.0)
    } else {
        0.0
    };
    (3.0 + 12.0 * f.sqrt()).round() as i32
}

/// Figure 4: scene alignment (x, 1–5) against completion (y, 0–10), one marker per point, its
/// size by [`SPREAD_RULE`], its colour by group (legend in order of first appearance).
pub fn scene_vs_completion(points: &[ScenePoint]) -> String {
    render(680, 520, |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "Scene alignment against task completion",
                ("sans-serif", 18),
            )
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(48)
            .build_cartesian_2d(0.75f64..5.25f64, -0.5f64..10.5f64)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(BLACK.mix(0.08))
            .x_labels(5)
            .y_labels(6)
            .x_desc("scene alignment (1–5)")
            .y_desc("task completion (0–10)")
            .axis_desc_style(("sans-serif", 14))
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        let valid: Vec<&ScenePoint> = points
            .iter()
            .filter(|p| p.scene_alignment.is_finite() && p.completion.is_finite())
            .collect();
        if valid.is_empty() {
            return note(root, "no judged tasks");
        }
        let mut groups: Vec<&str> = Vec::new();
        for p in &valid {
            if !groups.contains(&p.group.as_str()) {
                groups.push(&p.group);
            }
        }
        for (gi, g) in groups.iter().enumerate() {
            let c = colour(gi);
            chart
                .draw_series(valid.iter().filter(|p| p.group == *g).map(|p| {
                    let style = if p.judge == 0 {
                        c.mix(0.45).filled()
                    } else {
                        c.stroke_width(2)
                    };
                    Circle::new(
                        (
                            p.scene_alignment.clamp(1.0, 5.0),
                            p.completion.clamp(0.0, 10.0),
                        ),
                        marker_radius(p.spread),
                        style,
                    )
                }))?
                .label(g.to_string())
                .legend(move |(x, y)| Circle::new((x, y), 5, c.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 12))
            .draw()?;
        Ok(())
    })
}

/// One series of a bar chart: a value per category (None: undefined, drawn as "n/a") and,
/// optionally, a 95 % interval per category (`intervals` may be empty).
#[derive(Debug, Clone, PartialEq)]
pub struct Bars {
    pub name: String,
    pub values: Vec<Option<f64>>,
    pub intervals: Vec<Option<[f64; 2]>>,
}

/// A grouped bar chart: per category one bar per series.
#[derive(Debug, Clone, PartialEq)]
pub struct BarChart<'a> {
    pub title: &'a str,
    pub y_desc: &'a str,
    pub categories: &'a [String],
    pub series: &'a [Bars],
    /// Fixed y range (e.g. 0–1 for rates, −1–1 for correlations); None: fitted to the data and 0.
    pub y_range: Option<(f64, f64)>,
}

/// Width of the legend beside a bar chart, in pixels.
const LEGEND_WIDTH: u32 = 200;

/// A grouped bar chart with error bars where intervals are given; its legend beside the plot, so
/// that no bar is hidden behind it however many series there are.
pub fn bar_chart(c: &BarChart<'_>) -> String {
    render(680 + LEGEND_WIDTH, 420, |whole| {
        whole.fill(&WHITE)?;
        let (plot, side) = whole.split_horizontally(680);
        let root = &plot;
        let n = c.categories.len().max(1);
        let (y0, y1) = c.y_range.unwrap_or_else(|| {
            let values = c.series.iter().flat_map(|s| {
                s.values
                    .iter()
                    .flatten()
                    .copied()
                    .chain(s.intervals.iter().flatten().flat_map(|i| i.iter().copied()))
            });
            span(values, Some(0.0), 0.1)
        });
        let mut chart = ChartBuilder::on(root)
            .caption(c.title, ("sans-serif", 18))
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(56)
            .build_cartesian_2d(0f64..n as f64, y0..y1)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .light_line_style(WHITE)
            .bold_line_style(BLACK.mix(0.08))
            .y_desc(c.y_desc)
            .axis_desc_style(("sans-serif", 14))
            .draw()?;
        // Category names under the axis, centred on their bars.
        let label_style =
            TextStyle::from(("sans-serif", 13).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
        chart.draw_series(c.categories.iter().enumerate().map(|(i, name)| {
            EmptyElement::at((i as f64 + 0.5, y0))
                + Text::new(name.clone(), (0, 8), label_style.clone())
        }))?;
        if c.categories.is_empty() || c.series.is_empty() {
            return note(root, "nothing to plot");
        }
        let k = c.series.len() as f64;
        let width = 0.8 / k;
        let base = 0f64.clamp(y0, y1);
        for (si, s) in c.series.iter().enumerate() {
            let col = colour(si);
            let left = |i: usize| i as f64 + 0.1 + si as f64 * width;
            let bars = s.values.iter().enumerate().take(n).filter_map(|(i, v)| {
                let v = (*v)?;
                v.is_finite().then(|| {
                    Rectangle::new(
                        [(left(i), base), (left(i) + width * 0.9, v.clamp(y0, y1))],
                        col.filled(),
                    )
                })
            });
            chart.draw_series(bars)?;
            let undefined = s
                .values
                .iter()
                .enumerate()
                .take(n)
                .filter(|(_, v)| !v.is_some_and(f64::is_finite))
                .map(|(i, _)| {
                    // Upright, standing on the base in its bar's place: side by side, the
                    // labels of neighbouring bars would run into each other.
                    Text::new(
                        "n/a",
                        (left(i) + width * 0.45, base),
                        ("sans-serif", 11)
                            .into_font()
                            .color(&col)
                            .transform(FontTransform::Rotate270)
                            .pos(Pos::new(HPos::Left, VPos::Center)),
                    )
                });
            chart.draw_series(undefined)?;
            let whiskers = s
                .intervals
                .iter()
                .enumerate()
                .take(n)
                .filter_map(|(i, iv)| {
                    let [lo, hi] = (*iv)?;
                    (lo.is_finite() && hi.is_finite()).then(|| {
                        let x = left(i) + width * 0.45;
                        let cap = width * 0.2;
                        let (lo, hi) = (lo.clamp(y0, y1), hi.clamp(y0, y1));
                        PathElement::new(
                            vec![
                                (x - cap, lo),
                                (x + cap, lo),
                                (x, lo),
                                (x, hi),
                                (x - cap, hi),
                                (x + cap, hi),
                            ],
                            BLACK.stroke_width(1),
                        )
                    })
                });
            chart.draw_series(whiskers)?;
        }
        for (si, s) in c.series.iter().enumerate() {
            let y = 48 + 20 * si as i32;
            side.draw(&Rectangle::new(
                [(4, y - 5), (14, y + 5)],
                colour(si).filled(),
            ))?;
            side.draw(&Text::new(
                s.name.clone(),
                (20, y - 7),
                ("sans-serif", 12).into_font(),
            ))?;
        }
        Ok(())
    })
}

/// One line of a line chart, its points in x order.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Lines with their points marked.
pub fn line_chart(title: &str, x_desc: &str, y_desc: &str, lines: &[Line]) -> String {
    render(680, 420, |root| {
        root.fill(&WHITE)?;
        let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
        let all: Vec<(f64, f64)> = lines
            .iter()
            .flat_map(|l| l.points.iter().filter(finite).copied())
            .collect();
        let (x0, x1) = span(all.iter().map(|p| p.0), None, 0.05);
        let (y0, y1) = span(all.iter().map(|p| p.1), Some(0.0), 0.1);
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 18))
            .margin(16)
            .x_label_area_size(44)
            .y_label_area_size(56)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(BLACK.mix(0.08))
            .x_desc(x_desc)
            .y_desc(y_desc)
            .axis_desc_style(("sans-serif", 14))
            .x_label_formatter(&|x| format!("{x}"))
            .draw()?;
        if all.is_empty() {
            return note(root, "nothing to plot");
        }
        for (i, l) in lines.iter().enumerate() {
            let col = colour(i);
            let pts: Vec<(f64, f64)> = l.points.iter().filter(finite).copied().collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), col.stroke_width(2)))?
                .label(l.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], col.stroke_width(2))
                });
            chart.draw_series(pts.into_iter().map(|p| Circle::new(p, 4, col.filled())))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 12))
            .draw()?;
        Ok(())
    })
}

/// The correlation plot of `ranking`'s comparison `comparison` as a standalone SVG: the proxy's
/// predicted success against real success, one point per policy (policies at the same place
/// share it) with the 95 % Wilson intervals of both rates where their trials are known, each
/// point's labels beside it clear of the other labels and points, the y = x diagonal, r and MMRV
/// in the title. Panics if `comparison` is out of range.
pub fn ranking(ranking: &Ranking, comparison: usize) -> String {
    ranking_labelled(ranking, comparison, &[])
}

/// [`ranking`] with each policy that has one of `labels` (policy name, label; a ladder's
/// policies, [`crate::ranking::RankingResults::labels`]) named by it.
pub fn ranking_labelled(
    ranking: &Ranking,
    comparison: usize,
    labels: &[(String, String)],
) -> String {
    let c = &ranking.comparisons[comparison];
    let mut out = String::new();
    draw_ranking(c, labels, &mut out).expect("plotters draws into a String, which cannot fail");
    out
}

/// How far the unit square's axes reach beyond 0 and 1: a rate of 0 or 1 and its interval are
/// drawn clear of the axis lines, not over them.
const UNIT_PAD: f64 = 0.04;

/// A chart of the unit square drawn on `root`: its title, mesh and axes' descriptions, and the
/// dashed y = x diagonal (the ranking's and the reliability diagram's frame).
fn unit_square<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
) -> Result<
    ChartContext<
        'a,
        SVGBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    Box<dyn std::error::Error>,
> {
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 18))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(56)
        .build_cartesian_2d(-UNIT_PAD..1.0 + UNIT_PAD, -UNIT_PAD..1.0 + UNIT_PAD)?;
    chart
        .configure_mesh()
        .x_labels(6)
        .y_labels(6)
        .light_line_style(WHITE)
        .bold_line_style(BLACK.mix(0.08))
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style(("sans-serif", 14))
        .draw()?;
    chart.draw_series(DashedLineSeries::new(
        [(0.0, 0.0), (1.0, 1.0)],
        6,
        4,
        BLACK.mix(0.45).stroke_width(1),
    ))?;
    Ok(chart)
}

fn short(e: &Estimate) -> String {
    e.value
        .map_or_else(|| "undefined".to_owned(), |v| format!("{v:.3}"))
}

/// A policy's point of a ranking plot: its place, the 95 % Wilson intervals of its two rates
/// (from their trials, pooled over its tasks; none for a rate without trials) and the labels of
/// every policy drawn at that place.
struct RankPoint {
    real: f64,
    proxy: f64,
    real_ci: Option<[f64; 2]>,
    proxy_ci: Option<[f64; 2]>,
    labels: Vec<String>,
}

/// The Wilson interval of a rate measured from `trials` (`None`: no trials known).
fn rate_interval(rate: f64, trials: Option<u64>) -> Option<[f64; 2]> {
    let n = trials.filter(|&n| n > 0)?;
    if !rate.is_finite() {
        return None;
    }
    let k = (rate.clamp(0.0, 1.0) * n as f64).round() as u64;
    Some(assay_stats::stats::wilson(k, n, 1.96))
}

/// The policies of `c` as points, those at the same place (to 1e-9) sharing one point.
fn rank_points(c: &Comparison, labels: &[(String, String)]) -> Vec<RankPoint> {
    let mut points: Vec<RankPoint> = Vec::new();
    for p in &c.policies {
        let label =
            crate::view::policy_label(&p.policy, labels).unwrap_or_else(|| p.policy.clone());
        match points
            .iter_mut()
            .find(|q| (q.real - p.real).abs() < 1e-9 && (q.proxy - p.proxy).abs() < 1e-9)
        {
            Some(q) => q.labels.push(label),
            None => points.push(RankPoint {
                real: p.real,
                proxy: p.proxy,
                real_ci: rate_interval(p.real, p.real_trials),
                proxy_ci: rate_interval(p.proxy, p.proxy_trials),
                labels: vec![label],
            }),
        }
    }
    points
}

/// Pixels per character of the plot's 12-px labels (an upper estimate for sans-serif).
const LABEL_CHAR_PX: i32 = 7;
const LABEL_LINE_PX: i32 = 15;

/// Top-left corners for labels `(width, height)` in pixels beside the points at `at`, so that no
/// label overlaps another or any point's marker and each stays inside `area` (left, top, right,
/// bottom): of the places right of and left of its point, above or below it, the first free one;
/// failing those, the first free one further down or up; failing all, right of its point, moved
/// inside.
fn place_labels(
    at: &[(i32, i32)],
    sizes: &[(i32, i32)],
    area: (i32, i32, i32, i32),
) -> Vec<(i32, i32)> {
    let (left, top, right, bottom) = area;
    // The markers (radius 5) are in the way from the start.
    let mut placed: Vec<(i32, i32, i32, i32)> =
        at.iter().map(|&(x, y)| (x - 6, y - 6, 12, 12)).collect();
    let mut out = Vec::with_capacity(at.len());
    for (&(x, y), &(w, h)) in at.iter().zip(sizes) {
        let near = [
            (x + 8, y - h - 2),
            (x + 8, y + 4),
            (x - 8 - w, y - h - 2),
            (x - 8 - w, y + 4),
        ];
        let further = (1..40).flat_map(|k| {
            let d = k * LABEL_LINE_PX;
            [
                (x + 8, y + 4 + d),
                (x + 8, y - h - 2 - d),
                (x - 8 - w, y + 4 + d),
                (x - 8 - w, y - h - 2 - d),
            ]
        });
        let inside =
            |(lx, ly): (i32, i32)| (lx.min(right - w).max(left), ly.min(bottom - h).max(top));
        let free = |(lx, ly): (i32, i32)| {
            lx >= left
                && lx + w <= right
                && ly >= top
                && ly + h <= bottom
                && placed.iter().all(|&(px, py, pw, ph)| {
                    lx + w <= px || px + pw <= lx || ly + h <= py || py + ph <= ly
                })
        };
        let spot = near
            .into_iter()
            .chain(further)
            .find(|&c| free(c))
            .unwrap_or_else(|| inside(near[0]));
        placed.push((spot.0, spot.1, w, h));
        out.push(spot);
    }
    out
}

fn draw_ranking(
    c: &Comparison,
    labels: &[(String, String)],
    out: &mut String,
) -> Result<(), Box<dyn std::error::Error>> {
    let title = format!(
        "{} against {}: r = {}, MMRV = {}",
        crate::ranking::source_title(&c.proxy),
        c.real,
        short(&c.pearson),
        short(&c.mmrv)
    );
    let root = SVGBackend::with_string(out, (600, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = unit_square(
        &root,
        &title,
        &format!("real success R ({})", c.real),
        &format!("predicted success R_S ({})", c.proxy),
    )?;
    chart.draw_series(std::iter::once(Text::new(
        "y = x",
        (0.86, 0.93),
        ("sans-serif", 12).into_font().color(&BLACK.mix(0.6)),
    )))?;
    let blue = RGBColor(31, 119, 180);
    let points = rank_points(c, labels);
    // The 95 % intervals of both rates, behind the points.
    let bars = blue.mix(0.45).stroke_width(1);
    for p in &points {
        if let Some([lo, hi]) = p.proxy_ci {
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(p.real, lo), (p.real, hi)],
                bars,
            )))?;
        }
        if let Some([lo, hi]) = p.real_ci {
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(lo, p.proxy), (hi, p.proxy)],
                bars,
            )))?;
        }
    }
    chart.draw_series(
        points
            .iter()
            .map(|p| Circle::new((p.real, p.proxy), 5, blue.filled())),
    )?;
    // Each point's label beside it, clear of the others' and inside the plot.
    let (xs, ys) = chart.plotting_area().get_pixel_range();
    let area = (xs.start, ys.start, xs.end, ys.end);
    let at: Vec<(i32, i32)> = points
        .iter()
        .map(|p| chart.backend_coord(&(p.real, p.proxy)))
        .collect();
    // Policies sharing a point: one line each.
    let sizes: Vec<(i32, i32)> = points
        .iter()
        .map(|p| {
            let widest = p.labels.iter().map(|l| l.chars().count()).max();
            (
                widest.unwrap_or(0) as i32 * LABEL_CHAR_PX,
                p.labels.len() as i32 * LABEL_LINE_PX,
            )
        })
        .collect();
    let style =
        TextStyle::from(("sans-serif", 12).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    for (p, (x, y)) in points.iter().zip(place_labels(&at, &sizes, area)) {
        for (k, line) in p.labels.iter().enumerate() {
            root.draw(&Text::new(
                line.clone(),
                (x, y + k as i32 * LABEL_LINE_PX),
                style.clone(),
            ))?;
        }
    }
    root.present()?;
    Ok(())
}

/// A reliability diagram as a standalone SVG: per series (label, diagram), each bin's observed
/// rate against its mean predicted probability with its 95 % interval, the points joined, the
/// marker's area growing with the bin's predictions; the y = x diagonal; each series' ECE in the
/// legend.
pub fn reliability(title: &str, series: &[(&str, &Reliability)]) -> String {
    render(600, 560, |root| {
        root.fill(&WHITE)?;
        let mut chart = unit_square(
            root,
            title,
            "predicted probability of success (bin mean)",
            "observed success rate (simulator)",
        )?;
        if series.iter().all(|(_, r)| r.bins.is_empty()) {
            return note(root, "no predictions");
        }
        for (i, (label, r)) in series.iter().enumerate() {
            let c = colour(i);
            let points: Vec<(f64, f64)> = r
                .bins
                .iter()
                .filter_map(|b| Some((b.mean_predicted, b.observed.rate?)))
                .collect();
            let ece = r
                .ece
                .map_or_else(|| "undefined".to_owned(), |e| format!("{e:.3}"));
            chart
                .draw_series(LineSeries::new(points, c.stroke_width(2)))?
                .label(format!("{label} (ECE {ece}, {} episodes)", r.predictions))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
            for b in &r.bins {
                let (Some(rate), Some([lo, hi])) = (b.observed.rate, b.observed.ci95) else {
                    continue;
                };
                let x = b.mean_predicted;
                chart.draw_series(std::iter::once(PathElement::new(
                    [(x, lo), (x, hi)],
                    c.mix(0.6).stroke_width(1),
                )))?;
                let radius = 3 + (2.0 * (b.observed.trials as f64).sqrt()).round() as i32;
                chart.draw_series(std::iter::once(Circle::new(
                    (x, rate),
                    radius.min(14),
                    c.mix(0.8).filled(),
                )))?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 12))
            .draw()?;
        Ok(())
    })
}

/// The ranking's reliability figure ([`reliability`]) over every ranked episode: the curves of
/// `r` without a group, raw and calibrated; `None` without predictions.
pub fn ranking_reliability(r: &crate::ranking::RankingResults) -> Option<String> {
    let series: Vec<(&str, &Reliability)> = r
        .reliability
        .iter()
        .filter(|c| c.group.is_none())
        .map(|c| (c.source.as_str(), &c.reliability))
        .collect();
    (!series.is_empty())
        .then(|| reliability("Reliability on the ranked episodes (frame judge)", &series))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn well_formed(svg: &str) {
        assert!(svg.contains("<svg"), "{svg}");
        assert!(svg.trim_end().ends_with("</svg>"), "{svg}");
        assert!(!svg.contains("NaN") && !svg.contains("inf"), "{svg}");
        assert!(!svg.contains("figure not drawn"), "{svg}");
    }

    fn point(group: &str, judge: usize, sa: f64, c: f64, spread: f64) -> ScenePoint {
        ScenePoint {
            group: group.into(),
            judge,
            scene_alignment: sa,
            completion: c,
            spread,
        }
    }

    #[test]
    fn scene_figure_handles_empty_single_and_odd_points() {
        well_formed(&scene_vs_completion(&[]));
        well_formed(&scene_vs_completion(&[point("g", 0, 3.0, 5.0, 0.0)]));
        let many = [
            point("a", 0, 1.0, 0.0, 0.0),
            point("a", 1, 5.0, 10.0, 1.0),
            point("b", 0, 9.0, -3.0, 7.0),
            point("<b>", 1, f64::NAN, 2.0, f64::NAN),
        ];
        let svg = scene_vs_completion(&many);
        well_formed(&svg);
        assert!(svg.contains("&lt;b&gt;") || !svg.contains("<b>"));
        assert_eq!(svg, scene_vs_completion(&many));
        // Bigger variance, bigger marker.
        assert!(marker_radius(spread(Some(4.0), Some(25.0))) > marker_radius(spread(None, None)));
    }

    #[test]
    fn bar_chart_handles_degenerate_input() {
        let cats = vec!["x".to_owned(), "y".to_owned()];
        for values in [
            vec![],
            vec![Some(0.0), Some(0.0)],
            vec![None, Some(f64::NAN)],
        ] {
            let series = [Bars {
                name: "s".into(),
                values,
                intervals: vec![Some([0.1, 0.9]), None],
            }];
            for y_range in [None, Some((0.0, 1.0))] {
                well_formed(&bar_chart(&BarChart {
                    title: "t",
                    y_desc: "y",
                    categories: &cats,
                    series: &series,
                    y_range,
                }));
            }
        }
        well_formed(&bar_chart(&BarChart {
            title: "t",
            y_desc: "y",
            categories: &[],
            series: &[],
            y_range: None,
        }));
    }

    #[test]
    fn line_chart_handles_degenerate_input() {
        well_formed(&line_chart("t", "x", "y", &[]));
        let one = [Line {
            name: "a".into(),
            points: vec![(10.0, 2.0)],
        }];
        well_formed(&line_chart("t", "x", "y", &one));
        let flat = [
            Line {
                name: "a".into(),
                points: vec![(10.0, 2.0), (20.0, 2.0), (40.0, f64::NAN)],
            },
            Line {
                name: "b".into(),
                points: vec![],
            },
        ];
        well_formed(&line_chart("t", "x", "y", &flat));
    }

    #[test]
    fn the_reliability_diagram_handles_empty_and_degenerate_input() {
        use assay_stats::calibration::reliability;
        let empty = reliability(&[], 5);
        let svg = super::reliability("none", &[("world-model", &empty)]);
        well_formed(&svg);
        assert!(svg.contains("no predictions"), "{svg}");
        // Every prediction in one bin, every outcome the same (an interval of zero width).
        let one = reliability(&[(1.0, true), (0.99, true), (0.95, true)], 5);
        let spread = reliability(&[(0.1, false), (0.5, true), (0.9, true), (0.3, false)], 5);
        let svg = super::reliability("two", &[("a", &one), ("b", &spread)]);
        well_formed(&svg);
        assert!(svg.contains("ECE 0.020, 3 episodes"), "{svg}");
        assert_eq!(
            svg,
            super::reliability("two", &[("a", &one), ("b", &spread)]),
            "the same input gives the same bytes"
        );
    }

    /// Crowded points (a row along the top edge, a column at the left, one shared by three
    /// policies): every label inside the plot, clear of every other label and every marker.
    #[test]
    fn ranking_labels_keep_clear_of_each_other_and_of_the_markers() {
        let area = (60, 40, 580, 500);
        let mut at: Vec<(i32, i32)> = (0..5).map(|k| (60 + 40 * k, 40)).collect();
        at.extend((0..5).map(|k| (60, 480 - 30 * k)));
        at.push((300, 300));
        let mut sizes = vec![(150, 15); at.len()];
        sizes[10] = (230, 45);
        let spots = super::place_labels(&at, &sizes, area);
        let boxes: Vec<(i32, i32, i32, i32)> = spots
            .iter()
            .zip(&sizes)
            .map(|(&(x, y), &(w, h))| (x, y, w, h))
            .collect();
        let apart = |a: (i32, i32, i32, i32), b: (i32, i32, i32, i32)| {
            a.0 + a.2 <= b.0 || b.0 + b.2 <= a.0 || a.1 + a.3 <= b.1 || b.1 + b.3 <= a.1
        };
        for (i, &b) in boxes.iter().enumerate() {
            assert!(
                b.0 >= area.0 && b.0 + b.2 <= area.2 && b.1 >= area.1 && b.1 + b.3 <= area.3,
                "label {i} at {b:?} leaves the plot"
            );
            for (j, &o) in boxes.iter().enumerate().skip(i + 1) {
                assert!(apart(b, o), "labels {i} {b:?} and {j} {o:?} overlap");
            }
            for (j, &(x, y)) in at.iter().enumerate() {
                assert!(
                    apart(b, (x - 5, y - 5, 10, 10)),
                    "label {i} covers point {j}"
                );
            }
        }
        // Beside its own point where there is room.
        assert_eq!(spots[10], (308, 300 - 45 - 2));
    }

    /// Policies at the same place share one marker, their labels on lines of their own; each
    /// rate measured from trials has its 95 % interval.
    #[test]
    fn policies_at_one_place_share_a_marker_and_rates_have_intervals() {
        let cells = assay_stats::ranking::parse_success_table(
            "task,policy,source,trials,successes\n\
             t,a,real,10,0\nt,b,real,10,0\nt,c,real,10,5\n\
             t,a,wm,10,10\nt,b,wm,10,10\nt,c,wm,10,4\n",
        )
        .unwrap();
        let r = assay_stats::ranking::rank(
            &cells,
            &assay_stats::ranking::RankingConfig {
                resamples: 0,
                ..Default::default()
            },
        )
        .unwrap();
        let svg = ranking(&r, 0);
        well_formed(&svg);
        assert_eq!(svg.matches("<circle").count(), 2, "{svg}");
        assert!(
            ["a", "b", "c"]
                .iter()
                .all(|l| svg.contains(&format!(">\n{l}\n</text>"))),
            "{svg}"
        );
        let c = rank_points(&r.comparisons[0], &[]);
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].labels, ["a", "b"]);
        let [lo, hi] = c[1].real_ci.unwrap();
        assert!(lo < 0.5 && hi > 0.5 && lo > 0.2 && hi < 0.8, "{lo} {hi}");
        assert_eq!(c[0].proxy_ci.unwrap()[1], 1.0);
    }

    #[test]
    fn the_ranking_plot_shows_the_comparison() {
        // The ladder of assay-stats' ranking tests (examples/rank/ladder.csv).
        const POLICIES: [&str; 5] = ["diffusion-400", "diffusion-100", "act", "bc-rnn", "bc-mlp"];
        let cells = assay_stats::ranking::parse_success_table(include_str!(
            "../../../examples/rank/ladder.csv"
        ))
        .unwrap();
        let cfg = assay_stats::ranking::RankingConfig {
            resamples: 200,
            seed: 0,
            ..Default::default()
        };
        let r = assay_stats::ranking::rank(&cells, &cfg).unwrap();
        let svg = ranking(&r, 0);
        assert!(svg.starts_with("<svg"), "{}", &svg[..80.min(svg.len())]);
        assert!(svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<circle").count(), 5);
        assert!(
            svg.contains("world-model against real: r = 0.865, MMRV = 0.047"),
            "{svg}"
        );
        for p in POLICIES {
            assert!(svg.contains(p), "{p}");
        }
        assert!(svg.contains("y = x"));
        assert_eq!(
            svg,
            ranking(&assay_stats::ranking::rank(&cells, &cfg).unwrap(), 0)
        );
    }
}
