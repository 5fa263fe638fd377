//! Structured captions of rendered scenes, and the built-in offline judge's scene-alignment score.
//!
//! A [`SceneCaption`] says what the four scene views of a task's initial state actually show: the
//! objects visible in the segmentation images, with the colour measured from their pixels, the
//! size and centre measured from back-projected depth, and a few relations between the measured
//! boxes. The render role builds it (`assay_render::caption`); this module owns the data, its
//! English wording ([`SceneCaption::to_text`]), the measurements that need no pixels (colour
//! naming, relations) and [`offline_alignment`], which compares a caption with a task's
//! description without any model.
//!
//! Owns: vocabulary, rubric and wording. Never renders, never reads files, never looks at the spec
//! beyond the primitive the renderer drew for each object ([`form_of`]).

use serde::{Deserialize, Serialize};

use assay_spec::spec::{COLORS, Shape};

/// What the scene views show, measured from their pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SceneCaption {
    /// The views captioned (top, front, oblique_left, oblique_right).
    pub views: Vec<String>,
    /// What the objects stand on: `table` or `ground`.
    pub surface: String,
    /// Every object of the scene, in scene order; those not visible in any view have
    /// `views_seen == 0` and are never described as seen.
    pub objects: Vec<CaptionObject>,
    pub relations: Vec<Relation>,
}

/// One object of the scene as the views show it. Everything but `segment` and `form` is measured
/// from the rendered pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CaptionObject {
    /// Segment id in the segmentation images (3 + the object's index in the scene).
    pub segment: u32,
    /// The primitive the renderer drew ([`form_of`]): box, cube, sphere, cylinder, container,
    /// mesh or articulated object.
    pub form: String,
    /// A palette colour name ([`name_colour`]), `unknown` when the object is not visible.
    pub colour: String,
    /// Mean of the best-lit pixels of the object's dominant colour.
    pub rgb: [u8; 3],
    /// Extent (m) in world x, y and z of the visible surface, over all views.
    pub size_m: [f64; 3],
    /// Centre (m, world) of that extent.
    pub centre: [f64; 3],
    /// Pixels of the object, summed over the views.
    pub pixels: u64,
    /// Views in which at least [`visible_pixels`] pixels of it are drawn.
    pub views_seen: u32,
    /// Its bottom is well below the surface, or it lies beside the table: it fell off.
    pub off_surface: bool,
    /// Its bottom is seen well above the surface with nothing measured under it.
    pub floating: bool,
}

/// `subject` is `on` / `in` / `next to` `object` (segment ids), from the measured boxes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Relation {
    pub subject: u32,
    pub relation: String,
    pub object: u32,
}

/// The offline judge's verdict on scene alignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct OfflineScore {
    /// In [1, 5], rounded to 2 decimals.
    pub score: f64,
    /// What matched and what did not, and how the score was made.
    pub rationale: String,
}

/// Fewest pixels (summed over a view) for an object to count as seen in it: 20 at 640 × 480,
/// scaled by the image's area, at least 1.
pub fn visible_pixels(width: u32, height: u32) -> u64 {
    let area = u64::from(width) * u64::from(height);
    (20 * area).div_ceil(640 * 480).max(1)
}

/// The primitive the renderer draws for `shape`: a box whose extents are within 25 % of each
/// other is a `cube`; an open-top box is a `container`; a URDF is an `articulated object`.
pub fn form_of(shape: &Shape) -> String {
    match shape {
        Shape::Box { half_extents } => {
            let max = half_extents.iter().copied().fold(f64::MIN, f64::max);
            let min = half_extents.iter().copied().fold(f64::MAX, f64::min);
            if min > 0.0 && max / min <= 1.25 {
                "cube"
            } else {
                "box"
            }
        }
        Shape::Sphere { .. } => "sphere",
        Shape::Cylinder { .. } => "cylinder",
        Shape::Container { .. } => "container",
        Shape::Mesh { .. } => "mesh",
        Shape::Urdf { .. } => "articulated object",
    }
    .to_owned()
}

// ---------------------------------------------------------------------------------------------
// Colour naming

/// Brightness of a surface facing the renderer's light squarely, relative to its albedo: the
/// renderer shades `albedo × (ambient + (1 − ambient) × |n · l|)` with ambient 0.35 and the light
/// from (0.35, 0.25, 1), so a top face gets 0.947 and a sphere's best-lit point 1.0.
pub const BEST_LIT: f64 = 0.95;

/// Chromaticity (r, g) of an RGB colour: shading scales all three channels alike, so it does not
/// change this.
fn chroma(rgb: [f64; 3]) -> Option<[f64; 2]> {
    let s = rgb[0] + rgb[1] + rgb[2];
    (s > 0.0).then(|| [rgb[0] / s, rgb[1] / s])
}

fn saturation(rgb: [f64; 3]) -> f64 {
    let max = rgb.iter().copied().fold(0.0, f64::max);
    let min = rgb.iter().copied().fold(f64::MAX, f64::min);
    if max <= 0.0 { 0.0 } else { (max - min) / max }
}

/// Index into [`COLORS`] of the chromatic colour (of `hues`: index and chromaticity) whose
/// chromaticity is nearest, or `None` for an achromatic pixel (nearest to grey, or too dark for
/// its hue to be read).
fn hue_class(rgb: [u8; 3], hues: &[(usize, [f64; 2])]) -> Option<usize> {
    let sum: u32 = rgb.iter().map(|&c| u32::from(c)).sum();
    if sum < 24 {
        return None;
    }
    let c = chroma(rgb.map(f64::from))?;
    let grey = 1.0 / 3.0;
    let mut best = (None, (c[0] - grey).powi(2) + (c[1] - grey).powi(2));
    for (i, h) in hues {
        let d = (c[0] - h[0]).powi(2) + (c[1] - h[1]).powi(2);
        if d < best.1 {
            best = (Some(*i), d);
        }
    }
    best.0
}

/// Names the colour of one object from its rendered pixels (any views, any shading).
///
/// Each pixel votes for the palette colour ([`COLORS`]) nearest in chromaticity, which shading
/// does not change, or for "achromatic"; the most voted wins. The colour reported is the mean of
/// the brightest tenth of the winning pixels; an achromatic object is `white`, `gray` or `black`
/// by that brightness over [`BEST_LIT`] (so it is read from its best-lit faces: an object seen
/// only from its dim sides reads darker than it is). Returns `("unknown", [0; 3])` for no pixels.
pub fn name_colour(pixels: &[[u8; 3]]) -> (String, [u8; 3]) {
    if pixels.is_empty() {
        return ("unknown".to_owned(), [0; 3]);
    }
    let hues: Vec<(usize, [f64; 2])> = COLORS
        .iter()
        .enumerate()
        .filter(|(_, (_, p))| saturation(*p) >= 0.1)
        .filter_map(|(i, (_, p))| chroma(*p).map(|c| (i, c)))
        .collect();
    let mut votes = vec![0u64; COLORS.len() + 1];
    let mut classes = Vec::with_capacity(pixels.len());
    // Neighbouring pixels of a face are mostly the same colour.
    let mut last = None;
    for &p in pixels {
        let c = match last {
            Some((q, c)) if q == p => c,
            _ => hue_class(p, &hues),
        };
        last = Some((p, c));
        votes[c.unwrap_or(COLORS.len())] += 1;
        classes.push(c);
    }
    let winner = (0..votes.len())
        .max_by_key(|&i| (votes[i], std::cmp::Reverse(i)))
        .filter(|&i| i < COLORS.len());
    // The brightest tenth of the winning pixels, from a histogram of r + g + b.
    let mut bins = vec![(0u64, [0u64; 3]); 766];
    let mut chosen = 0u64;
    for (p, _) in pixels.iter().zip(&classes).filter(|(_, c)| **c == winner) {
        let bin = &mut bins[p.iter().map(|&c| usize::from(c)).sum::<usize>()];
        bin.0 += 1;
        for (acc, c) in bin.1.iter_mut().zip(p) {
            *acc += u64::from(*c);
        }
        chosen += 1;
    }
    let (mut got, mut sum) = (0, [0u64; 3]);
    for (count, s) in bins.iter().rev() {
        if got >= chosen.div_ceil(10) {
            break;
        }
        got += count;
        for (acc, c) in sum.iter_mut().zip(s) {
            *acc += c;
        }
    }
    let mean: [u8; 3] = sum.map(|s| (s as f64 / got.max(1) as f64).round() as u8);
    let name = match winner {
        Some(i) => COLORS[i].0,
        None => {
            let albedo = f64::from(*mean.iter().max().unwrap_or(&0)) / 255.0 / BEST_LIT;
            if albedo >= 0.72 {
                "white"
            } else if albedo <= 0.3 {
                "black"
            } else {
                "gray"
            }
        }
    };
    (name.to_owned(), mean)
}

// ---------------------------------------------------------------------------------------------
// Relations

/// Tolerance (m) between a subject's bottom and a support's top for `on`.
pub const ON_TOLERANCE_M: f64 = 0.015;
/// Largest gap (m) between two footprints for `next to`.
pub const NEXT_TO_GAP_M: f64 = 0.05;

fn min_z(o: &CaptionObject) -> f64 {
    o.centre[2] - o.size_m[2] / 2.0
}

fn max_z(o: &CaptionObject) -> f64 {
    o.centre[2] + o.size_m[2] / 2.0
}

fn lo(o: &CaptionObject, k: usize) -> f64 {
    o.centre[k] - o.size_m[k] / 2.0
}

fn hi(o: &CaptionObject, k: usize) -> f64 {
    o.centre[k] + o.size_m[k] / 2.0
}

/// Distance between two footprints (axis-aligned xy boxes), 0 where they overlap.
fn footprint_gap(a: &CaptionObject, b: &CaptionObject) -> f64 {
    let d = |k| (lo(b, k) - hi(a, k)).max(lo(a, k) - hi(b, k)).max(0.0);
    f64::hypot(d(0), d(1))
}

fn centre_over(s: &CaptionObject, o: &CaptionObject, margin: f64) -> bool {
    (0..2).all(|k| s.centre[k] > lo(o, k) + margin && s.centre[k] < hi(o, k) - margin)
}

/// `in`: `o` is a container, `s`'s centre is over its footprint, `s` is narrower than it, and
/// `s`'s lowest visible point is below its rim (walls hide what is below the rim from the side
/// views, so up to 1 cm above it counts).
fn is_in(s: &CaptionObject, o: &CaptionObject) -> bool {
    o.form == "container"
        && centre_over(s, o, 0.005)
        && (0..2).all(|k| s.size_m[k] < o.size_m[k])
        && min_z(s) < max_z(o) + 0.01
        && min_z(s) > min_z(o) - 0.01
}

/// `on`: `s`'s centre is over `o`'s footprint and its bottom within [`ON_TOLERANCE_M`] of
/// `o`'s top.
fn is_on(s: &CaptionObject, o: &CaptionObject) -> bool {
    centre_over(s, o, 0.0)
        && (min_z(s) - max_z(o)).abs() < ON_TOLERANCE_M
        && s.centre[2] > o.centre[2]
}

/// Relations between the visible objects, from their measured boxes: `in` and `on` (one support
/// per subject, `in` first), then `next to` for each object's nearest neighbour at the same level
/// whose footprint is within [`NEXT_TO_GAP_M`] (each pair once, the lower segment as subject).
/// Kept few on purpose: boxes are axis-aligned and measured from the visible surface only.
pub fn relations(objects: &[CaptionObject]) -> Vec<Relation> {
    let visible: Vec<&CaptionObject> = objects.iter().filter(|o| o.views_seen > 0).collect();
    let rel = |s: &CaptionObject, r: &str, o: &CaptionObject| Relation {
        subject: s.segment,
        relation: r.to_owned(),
        object: o.segment,
    };
    let mut out = Vec::new();
    for s in &visible {
        let others = || visible.iter().filter(|o| o.segment != s.segment);
        if let Some(o) = others().find(|o| is_in(s, o)) {
            out.push(rel(s, "in", o));
        } else if let Some(o) = others().filter(|o| is_on(s, o)).min_by(|a, b| {
            (min_z(s) - max_z(a))
                .abs()
                .total_cmp(&(min_z(s) - max_z(b)).abs())
        }) {
            out.push(rel(s, "on", o));
        }
    }
    let stacked = |a: u32, b: u32| {
        out.iter()
            .any(|r| (r.subject == a && r.object == b) || (r.subject == b && r.object == a))
    };
    let mut near = Vec::new();
    for s in &visible {
        let nearest = visible
            .iter()
            .filter(|o| o.segment != s.segment && !stacked(s.segment, o.segment))
            .filter(|o| (min_z(s) - min_z(o)).abs() < 0.02)
            .map(|o| (footprint_gap(s, o), o))
            .filter(|(g, _)| *g < NEXT_TO_GAP_M)
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((_, o)) = nearest {
            let pair = (s.segment.min(o.segment), s.segment.max(o.segment));
            if !near.contains(&pair) {
                near.push(pair);
            }
        }
    }
    near.sort_unstable();
    out.extend(near.into_iter().map(|(a, b)| Relation {
        subject: a,
        relation: "next to".to_owned(),
        object: b,
    }));
    out
}

/// Whether the visible object `s` has something measured under it: a relation `on`/`in` as
/// subject, or another visible object whose footprint overlaps its own and whose top reaches
/// within 2 cm of its bottom.
pub fn supported(s: &CaptionObject, objects: &[CaptionObject], relations: &[Relation]) -> bool {
    relations
        .iter()
        .any(|r| r.subject == s.segment && r.relation != "next to")
        || objects.iter().any(|o| {
            o.segment != s.segment
                && o.views_seen > 0
                && footprint_gap(s, o) == 0.0
                && max_z(o) > min_z(s) - 0.02
                && o.centre[2] < s.centre[2]
        })
}

// ---------------------------------------------------------------------------------------------
// Wording

/// Bottom (m) below which a visible object counts as resting on the surface.
const RESTING_M: f64 = 0.015;

impl CaptionObject {
    fn visible(&self) -> bool {
        self.views_seen > 0
    }

    fn flat(&self) -> bool {
        matches!(self.form.as_str(), "box" | "cylinder")
            && self.size_m[2] < 0.3 * self.size_m[0].min(self.size_m[1])
    }

    /// "red cube", "brown flat box", "mesh".
    fn noun_phrase(&self) -> String {
        let mut words = Vec::new();
        if self.colour != "unknown" {
            words.push(self.colour.as_str());
        }
        if self.flat() {
            words.push("flat");
        }
        words.push(self.form.as_str());
        words.join(" ")
    }
}

fn cm(m: f64) -> String {
    let c = m * 100.0;
    if c >= 2.0 {
        format!("{c:.0}")
    } else {
        format!("{c:.1}")
    }
}

/// Metres to 2 decimals, without a "-0.00".
fn metres(v: f64) -> String {
    let s = format!("{v:.2}");
    if s == "-0.00" { "0.00".to_owned() } else { s }
}

fn article(phrase: &str) -> &'static str {
    if phrase.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    }
}

impl SceneCaption {
    /// "the red cube", or with its position where another visible object has the same phrase.
    fn refer(&self, segment: u32) -> String {
        let Some(o) = self.objects.iter().find(|o| o.segment == segment) else {
            return format!("object {segment}");
        };
        let phrase = o.noun_phrase();
        let twins = self
            .objects
            .iter()
            .filter(|x| x.visible() && x.noun_phrase() == phrase)
            .count();
        if twins > 1 {
            format!(
                "the {phrase} at ({}, {})",
                metres(o.centre[0]),
                metres(o.centre[1])
            )
        } else {
            format!("the {phrase}")
        }
    }

    /// One short English paragraph: each visible object (colour, form, size, position, where it
    /// rests), then the relations, then how many objects no view shows, e.g. "a red cube about
    /// 4 × 4 × 4 cm at (0.42, -0.12) on the table; a white container about 8 × 8 × 6 cm at
    /// (0.62, 0.08) on the table; the red cube is next to the white container." Never names an
    /// object by its spec id (ids often carry a colour word the pixels may contradict). This text
    /// is also what a two-stage caption + LLM judge sends to the LLM when the offline captioner
    /// is used.
    pub fn to_text(&self) -> String {
        let views = self.views.len();
        let mut clauses = Vec::new();
        for o in self.objects.iter().filter(|o| o.visible()) {
            let phrase = o.noun_phrase();
            let [x, y, z] = o.size_m;
            let mut c = format!(
                "{} {phrase} about {} × {} × {} cm at ({}, {})",
                article(&phrase),
                cm(x),
                cm(y),
                cm(z),
                metres(o.centre[0]),
                metres(o.centre[1])
            );
            let held = self
                .relations
                .iter()
                .any(|r| r.subject == o.segment && r.relation != "next to");
            if o.off_surface && self.surface == "table" {
                c.push_str(", fallen off the table");
            } else if o.off_surface {
                c.push_str(&format!(", below the {}", self.surface));
            } else if o.floating {
                c.push_str(&format!(
                    ", floating {} cm above the {}",
                    cm(min_z(o)),
                    self.surface
                ));
            } else if !held && min_z(o) < RESTING_M {
                c.push_str(&format!(" on the {}", self.surface));
            }
            if (o.views_seen as usize) < views {
                c.push_str(&format!(" (seen in {} of {views} views)", o.views_seen));
            }
            clauses.push(c);
        }
        let mut text = if clauses.is_empty() {
            format!("no object is visible in the {views} views")
        } else {
            clauses.join("; ")
        };
        for r in &self.relations {
            text.push_str(&format!(
                "; {} is {} {}",
                self.refer(r.subject),
                r.relation,
                self.refer(r.object)
            ));
        }
        text.push('.');
        let hidden = self.objects.iter().filter(|o| !o.visible()).count();
        match hidden {
            0 => {}
            1 => text.push_str(" 1 more object of the scene is not visible in any view."),
            n => text.push_str(&format!(
                " {n} more objects of the scene are not visible in any view."
            )),
        }
        text
    }
}

// ---------------------------------------------------------------------------------------------
// The offline judge

/// What a noun in a description can be drawn as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Cube,
    Block,
    /// "box": a solid box or a container.
    Box,
    Ball,
    Cylinder,
    /// Rods, pegs, pillars: cylinders or tall boxes.
    Rod,
    Container,
    /// Lids, drawers, laptops: URDFs, or boxes standing in for them.
    Articulated,
    /// Plates, boards, coasters: flat boxes or flat cylinders.
    Flat,
}

/// Nouns by what they can be drawn as.
const NOUNS: &[(Kind, &str)] = &[
    (Kind::Cube, "cube"),
    (Kind::Block, "block brick cuboid"),
    (Kind::Box, "box carton package"),
    (Kind::Ball, "ball sphere marble orb"),
    (Kind::Cylinder, "cylinder can bottle tube jar wheel"),
    (
        Kind::Rod,
        "peg rod pole stick dowel bar beam post pillar pier",
    ),
    (
        Kind::Container,
        "bowl container bin basket cup mug crate tray pot bucket pan dish fixture holder",
    ),
    (
        Kind::Articulated,
        "drawer cabinet door lid laptop microwave fridge refrigerator",
    ),
    (Kind::Articulated, "oven safe faucet lamp window toilet"),
    (
        Kind::Flat,
        "plate board slab tile pad mat coaster disk disc puck plank platform deck",
    ),
];

/// How well an object drawn as `form` fits a noun of `kind`: 1 fits, 0.8 roughly (a cube that is
/// not cubic), 0.6 cannot be told from the caption (a mesh or URDF could be anything), 0 no.
fn form_fit(kind: Kind, form: &str) -> f64 {
    use Kind::*;
    match (kind, form) {
        (_, "mesh") => 0.6,
        (Articulated, "articulated object") => 1.0,
        (_, "articulated object") => 0.6,
        (Cube, "cube") => 1.0,
        (Cube, "box") => 0.8,
        (Block | Box, "box" | "cube") => 1.0,
        (Box | Container, "container") => 1.0,
        (Ball, "sphere") => 1.0,
        (Cylinder | Rod, "cylinder") => 1.0,
        (Rod, "box") => 1.0,
        (Rod, "cube") => 0.6,
        (Articulated | Flat, "box" | "cube") => 1.0,
        (Articulated, "container") => 0.6,
        (Flat, "cylinder") => 1.0,
        _ => 0.0,
    }
}

/// Palette names and the words that mean them.
const COLOUR_WORDS: &[(&str, &str)] = &[
    ("red", "red crimson scarlet"),
    ("green", "green lime"),
    ("blue", "blue navy"),
    ("yellow", "yellow gold golden"),
    ("orange", "orange"),
    ("purple", "purple violet lilac lavender"),
    ("pink", "pink magenta"),
    ("cyan", "cyan teal turquoise aqua"),
    ("brown", "brown tan"),
    ("white", "white"),
    ("black", "black"),
    ("gray", "gray grey silver"),
];

/// Palette colours easily confused with each other under shading or naming habits.
const NEIGHBOURS: &[(&str, &str)] = &[
    ("red", "orange"),
    ("red", "pink"),
    ("red", "brown"),
    ("orange", "yellow"),
    ("orange", "brown"),
    ("purple", "pink"),
    ("purple", "blue"),
    ("blue", "cyan"),
    ("cyan", "green"),
    ("green", "yellow"),
    ("white", "gray"),
    ("gray", "black"),
];

/// Words skipped between a colour and its noun ("a small red block", "the light blue cube").
const ADJECTIVES: &str = "\
    small smaller smallest large larger largest big bigger biggest little tiny tall \
    taller short long thin thick flat wide narrow wooden plastic metal metallic square \
    round rectangular cylindrical empty open closed light dark bright pale heavy \
    colored coloured remaining same other another first second third last top bottom";

/// Nouns that are also common verbs or adjectives: nouns only after a determiner, number,
/// colour or adjective, or as plurals ("the can", not "the robot can").
const AMBIGUOUS: &str = "can safe pad pot pan dish board mat";

/// Words that make what follows a noun phrase.
const DETERMINERS: &str = "the a an this that these those each every its their all some";

const NUMBERS: &[(&str, usize)] = &[
    ("a", 1),
    ("an", 1),
    ("one", 1),
    ("single", 1),
    ("two", 2),
    ("both", 2),
    ("pair", 2),
    ("three", 3),
    ("four", 4),
    ("five", 5),
    ("six", 6),
    ("seven", 7),
    ("eight", 8),
    ("nine", 9),
    ("ten", 10),
];

/// A thing the description names, to be found among the visible objects.
#[derive(Debug, Clone)]
struct Mention {
    text: String,
    colour: Option<&'static str>,
    kind: Kind,
}

fn colour_word(w: &str) -> Option<&'static str> {
    COLOUR_WORDS
        .iter()
        .find(|(_, words)| words.split(' ').any(|x| x == w))
        .map(|(c, _)| *c)
}

/// The noun's kind and whether the word was plural.
fn noun(w: &str) -> Option<(Kind, bool)> {
    let find = |w: &str| {
        NOUNS
            .iter()
            .find(|(_, words)| words.split(' ').any(|x| x == w))
            .map(|(k, _)| *k)
    };
    if let Some(k) = find(w) {
        return Some((k, false));
    }
    for suffix in ["es", "s"] {
        if let Some(stem) = w.strip_suffix(suffix)
            && let Some(k) = find(stem)
        {
            return Some((k, true));
        }
    }
    None
}

/// Cubes and blocks are one family: "a three-block tower of red, green and blue cubes".
fn family(k: Kind) -> Kind {
    match k {
        Kind::Cube => Kind::Block,
        k => k,
    }
}

/// One noun phrase of a description, before it is counted out into mentions.
struct Phrase<'a> {
    noun: &'a str,
    kind: Kind,
    plural: bool,
    number: Option<usize>,
    /// "a", "another": a new thing, never refined away.
    indefinite: bool,
    /// (word as written, palette name).
    colours: Vec<(&'a str, &'static str)>,
}

fn is_number(w: &str) -> Option<usize> {
    NUMBERS
        .iter()
        .find(|(k, _)| *k == w)
        .map(|(_, n)| *n)
        .or_else(|| w.parse::<usize>().ok().filter(|n| (1..=10).contains(n)))
}

/// The things `description` names. Each known noun with the colour words before it ("red and
/// blue blocks" is one red and one blue block) counts as its number ("three-block tower": 3), or
/// 2 for a bare plural. A noun right before another known noun only modifies it ("box lid");
/// "one" after a colour repeats the previous kind ("the blue one"). A later phrase without an
/// indefinite article whose kind and colours agree with an earlier one is that one again ("the
/// white box … the box"). Colourless phrases, unless indefinite ("a cube"), are then refined by
/// the coloured ones of the same kind ("each ball … the red, green and blue balls" is three
/// balls, not four).
fn mentions(description: &str) -> Vec<Mention> {
    let lower = description.to_lowercase();
    let words: Vec<&str> = lower
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .collect();
    let is_adjective = |w: &str| ADJECTIVES.split_whitespace().any(|a| a == w);
    let mut phrases: Vec<Phrase<'_>> = Vec::new();
    for (i, &w) in words.iter().enumerate() {
        let prev = i.checked_sub(1).map(|j| words[j]);
        let (kind, plural) = match noun(w) {
            Some(n) => n,
            None if matches!(w, "one" | "ones") && prev.and_then(colour_word).is_some() => {
                match phrases.last() {
                    Some(p) => (p.kind, w == "ones"),
                    None => continue,
                }
            }
            None => continue,
        };
        if words.get(i + 1).is_some_and(|n| noun(n).is_some()) {
            continue;
        }
        let after_modifier = prev.is_some_and(|b| {
            DETERMINERS.split(' ').any(|d| d == b)
                || colour_word(b).is_some()
                || is_adjective(b)
                || is_number(b).is_some()
        });
        if !plural && AMBIGUOUS.split(' ').any(|a| a == w) && !after_modifier {
            continue;
        }
        let (mut colours, mut number, mut indefinite) = (Vec::new(), None, false);
        for &b in words[..i].iter().rev() {
            if let Some(c) = colour_word(b) {
                colours.insert(0, (b, c));
            } else if b == "and" || b == "or" {
                if colours.is_empty() {
                    break;
                }
            } else if is_adjective(b) {
                indefinite |= matches!(b, "another" | "other" | "second" | "third");
            } else if let Some(n) = is_number(b) {
                if matches!(b, "a" | "an") {
                    // "a three-block tower" is three blocks; "a cube" is one more cube.
                    indefinite |= number.is_none();
                    number.get_or_insert(n);
                    break;
                }
                number.get_or_insert(n);
            } else {
                break;
            }
        }
        let agrees = |p: &Phrase<'_>, c: Option<&str>| {
            family(p.kind) == family(kind) && c.is_none_or(|c| p.colours.iter().any(|x| x.1 == c))
        };
        let seen_before = if colours.is_empty() {
            phrases.iter().any(|p| agrees(p, None))
        } else {
            colours
                .iter()
                .all(|(_, c)| phrases.iter().any(|p| agrees(p, Some(c))))
        };
        if !indefinite && (number.is_none() || plural) && seen_before {
            continue;
        }
        phrases.push(Phrase {
            noun: w,
            kind,
            plural,
            number,
            indefinite,
            colours,
        });
    }
    let count = |p: &Phrase<'_>| p.number.unwrap_or(if p.plural { 2 } else { 1 });
    // Mentions per colour of a coloured phrase.
    let each = |p: &Phrase<'_>| if p.colours.len() > 1 { 1 } else { count(p) };
    let mut out = Vec::new();
    for p in &phrases {
        if p.colours.is_empty() {
            let coloured: usize = phrases
                .iter()
                .filter(|q| !p.indefinite && family(q.kind) == family(p.kind))
                .map(|q| q.colours.len() * each(q))
                .sum();
            for _ in 0..count(p).saturating_sub(coloured) {
                out.push(Mention {
                    text: p.noun.to_owned(),
                    colour: None,
                    kind: p.kind,
                });
            }
        } else {
            for (word, colour) in &p.colours {
                for _ in 0..each(p) {
                    out.push(Mention {
                        text: format!("{word} {}", p.noun),
                        colour: Some(colour),
                        kind: p.kind,
                    });
                }
            }
        }
    }
    out
}

fn neighbours(a: &str, b: &str) -> bool {
    NEIGHBOURS
        .iter()
        .any(|(x, y)| (*x == a && *y == b) || (*x == b && *y == a))
}

/// How well visible object `o` answers mention `m`, in [0, 1], with a note when not fully.
fn quality(m: &Mention, o: &CaptionObject) -> (f64, Option<&'static str>) {
    let form = form_fit(m.kind, &o.form);
    let (colour, colour_note) = match m.colour {
        None => (1.0, None),
        Some(c) if c == o.colour => (1.0, None),
        Some(c) if neighbours(c, &o.colour) => (0.6, Some("colour close")),
        Some(_) => (0.3, Some("colour differs")),
    };
    let (mut q, mut note) = if form > 0.0 {
        let note = colour_note.or(if form < 0.8 {
            Some("kind not verifiable")
        } else if form < 1.0 {
            Some("shape close")
        } else {
            None
        });
        (form * colour, note)
    } else if m.colour.is_some() && colour == 1.0 {
        (0.3, Some("colour matches, shape differs"))
    } else {
        (0.0, None)
    };
    if o.off_surface || o.floating {
        q *= 0.5;
        note = Some(if o.off_surface {
            "fell off the surface"
        } else {
            "floating"
        });
    }
    (q, note)
}

/// Score of a description with no recognisable object mention.
pub const NEUTRAL_SCORE: f64 = 3.0;

/// The built-in offline judge's scene alignment (1–5): does the caption of what the four views
/// show contain what the task's description names?
///
/// Reads only the description and the caption (measured colours, primitive forms, sizes,
/// positions, visibility, plausibility); never the spec, so a spec that says "red" but renders
/// grey is caught.
///
/// Rubric, deterministic:
/// 1. **Mentions.** The description's object nouns, from a fixed vocabulary (block/cube/brick,
///    box, ball/sphere, cylinder/can/peg/rod, bowl/container/bin/basket/cup/crate/tray,
///    lid/drawer/cabinet/laptop…, plate/board/coaster…), each with the colour words before it
///    (synonyms: grey = gray, violet = purple, teal = cyan, …); plurals count as their number, or
///    2; a repeated reference counts once ("the white box … the box"), and a colourless phrase
///    is refined by coloured ones of its kind ("each ball … the red and blue balls" is two).
///    Other words (zones, areas, lines, "objects") are not counted either way.
/// 2. **Matching.** Each mention against each visible object: 1 when form and colour fit; the
///    colour of a neighbouring hue (red/orange, blue/cyan, white/gray…) × 0.6, another colour
///    × 0.3; a cube that is not cubic × 0.8; a mesh or URDF, whose kind the caption cannot tell,
///    × 0.6; the right colour on the wrong form 0.3; an object that fell off or floats × 0.5.
///    Pairs are assigned greedily, best first (coloured mentions first among equals), one
///    object per mention. `M` = mean over mentions.
/// 3. **Scene.** `V` = share of the scene's objects visible in some view; `P` = share of the
///    visible ones resting plausibly (not fallen off, not floating); `C` = context objects
///    beyond the mentions (the paper's rubric rewards "items that may appear near the task"),
///    min(n, 2) / 2.
/// 4. **Score** = 1 + 4 · M · (0.80 + 0.10 P + 0.05 V + 0.05 C): 1 when nothing named is
///    visible, 4.8 when everything named is visible and the scene is plausible, 5 with context.
///    Without any mention: [`NEUTRAL_SCORE`].
///
/// Cannot judge: what a mesh or URDF depicts beyond its colour, zones and markings (not
/// rendered), textures and realism, size words ("small", "large"), or the relations the
/// description asks for (they describe the goal, not the initial scene).
pub fn offline_alignment(description: &str, caption: &SceneCaption) -> OfflineScore {
    let wanted = mentions(description);
    let visible: Vec<&CaptionObject> = caption.objects.iter().filter(|o| o.visible()).collect();
    let total = caption.objects.len();
    let plausible = visible
        .iter()
        .filter(|o| !o.off_surface && !o.floating)
        .count();
    let scene = format!(
        "visible: {} of {total} scene objects; resting plausibly: {plausible} of {}",
        visible.len(),
        visible.len()
    );
    if wanted.is_empty() {
        return OfflineScore {
            score: NEUTRAL_SCORE,
            rationale: format!(
                "no object the offline judge recognises is named in the description, so the \
                 caption cannot be compared with it: neutral score {NEUTRAL_SCORE:.2}; {scene}."
            ),
        };
    }
    let mut pairs = Vec::new();
    for (mi, m) in wanted.iter().enumerate() {
        for (oi, o) in visible.iter().enumerate() {
            let (q, note) = quality(m, o);
            if q > 0.0 {
                pairs.push((q, mi, oi, note));
            }
        }
    }
    // Best first; at equal quality a coloured mention before a colourless one ("balls … the
    // black ball": the black ball gets the black sphere), then in order.
    let plain = |mi: usize| wanted[mi].colour.is_none();
    pairs.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(plain(a.1).cmp(&plain(b.1)))
            .then(a.1.cmp(&b.1))
            .then(a.2.cmp(&b.2))
    });
    let mut by_mention: Vec<Option<(f64, usize, Option<&str>)>> = vec![None; wanted.len()];
    let mut taken = vec![false; visible.len()];
    for (q, mi, oi, note) in pairs {
        if by_mention[mi].is_none() && !taken[oi] {
            by_mention[mi] = Some((q, oi, note));
            taken[oi] = true;
        }
    }
    let m = by_mention.iter().flatten().map(|(q, _, _)| q).sum::<f64>() / wanted.len() as f64;
    let v = if total == 0 {
        0.0
    } else {
        visible.len() as f64 / total as f64
    };
    let p = if visible.is_empty() {
        0.0
    } else {
        plausible as f64 / visible.len() as f64
    };
    let extra = taken.iter().filter(|t| !**t).count();
    let c = extra.min(2) as f64 / 2.0;
    let raw = m * (0.80 + 0.10 * p + 0.05 * v + 0.05 * c);
    let score = ((1.0 + 4.0 * raw) * 100.0).round() / 100.0;
    let matched: Vec<String> = wanted
        .iter()
        .zip(&by_mention)
        .map(|(w, got)| match got {
            Some((q, oi, note)) => format!(
                "'{}' → {} ({q:.2}{})",
                w.text,
                caption.refer(visible[*oi].segment),
                note.map(|n| format!(", {n}")).unwrap_or_default()
            ),
            None => format!("'{}' → nothing visible fits (0.00)", w.text),
        })
        .collect();
    let found = by_mention.iter().filter(|x| x.is_some()).count();
    OfflineScore {
        score,
        rationale: format!(
            "{found} of {} named objects found: {}; {scene}; context objects beyond those named: \
             {extra}. Score {score:.2} = 1 + 4 × M {m:.2} × (0.80 + 0.10 × P {p:.2} + 0.05 × V \
             {v:.2} + 0.05 × C {c:.2}).",
            wanted.len(),
            matched.join("; ")
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(
        segment: u32,
        form: &str,
        colour: &str,
        centre: [f64; 3],
        size: [f64; 3],
    ) -> CaptionObject {
        CaptionObject {
            segment,
            form: form.into(),
            colour: colour.into(),
            rgb: [0; 3],
            size_m: size,
            centre,
            pixels: 500,
            views_seen: 4,
            off_surface: false,
            floating: false,
        }
    }

    fn caption(objects: Vec<CaptionObject>) -> SceneCaption {
        let relations = relations(&objects);
        SceneCaption {
            views: ["top", "front", "oblique_left", "oblique_right"]
                .map(String::from)
                .to_vec(),
            surface: "table".into(),
            objects,
            relations,
        }
    }

    /// The bbsea "red cube into the white box, then the lid" scene as the views show it.
    fn cube_box_lid() -> SceneCaption {
        caption(vec![
            obj(3, "cube", "red", [0.42, -0.12, 0.02], [0.04, 0.04, 0.04]),
            obj(
                4,
                "container",
                "white",
                [0.62, 0.08, 0.03],
                [0.08, 0.08, 0.06],
            ),
            obj(5, "box", "brown", [0.42, 0.16, 0.005], [0.086, 0.086, 0.01]),
        ])
    }

    const BBSEA: &str = "put the red cube into the white box and cover the box with the lid";

    fn kinds(d: &str) -> Vec<(String, Option<&'static str>)> {
        mentions(d)
            .into_iter()
            .map(|m| (m.text, m.colour))
            .collect()
    }

    #[test]
    fn mentions_follow_colours_numbers_and_references() {
        assert_eq!(
            kinds(BBSEA),
            vec![
                ("red cube".into(), Some("red")),
                ("white box".into(), Some("white")),
                ("lid".into(), None)
            ]
        );
        assert_eq!(kinds("stack three small grey blocks").len(), 3);
        assert_eq!(
            kinds("put the red and violet balls in a bowl"),
            vec![
                ("red balls".into(), Some("red")),
                ("violet balls".into(), Some("purple")),
                ("bowl".into(), None)
            ]
        );
        assert_eq!(
            kinds("stack the green cube on the red one, then the red cube on a cube").len(),
            3
        );
        assert_eq!(kinds("remove the box lid").len(), 1);
        assert_eq!(
            kinds("the robot can drop the can into the bin"),
            vec![("can".into(), None), ("bin".into(), None)]
        );
        assert!(kinds("push the pile into the yellow zone").is_empty());
    }

    #[test]
    fn everything_named_visible_scores_high() {
        let s = offline_alignment(BBSEA, &cube_box_lid());
        assert_eq!(s.score, 4.8, "{}", s.rationale);
        assert!(
            s.rationale.contains("3 of 3 named objects found"),
            "{}",
            s.rationale
        );
        assert!(
            s.rationale
                .contains("'white box' → the white container (1.00)")
        );
        // A context object beyond those named adds the last bit.
        let mut c = cube_box_lid();
        c.objects.push(obj(
            6,
            "sphere",
            "blue",
            [0.3, 0.3, 0.02],
            [0.04, 0.04, 0.04],
        ));
        let s = offline_alignment(BBSEA, &c);
        assert_eq!(s.score, 4.9, "{}", s.rationale);
    }

    #[test]
    fn colour_mismatch_scores_lower() {
        let full = offline_alignment(BBSEA, &cube_box_lid()).score;
        let s = offline_alignment(
            "put the green cube into the white box and cover the box with the lid",
            &cube_box_lid(),
        );
        assert!(s.score < full - 0.5, "{} {}", s.score, s.rationale);
        assert!(s.score > 3.0, "{}", s.rationale);
        assert!(s.rationale.contains("colour differs"), "{}", s.rationale);
        // A neighbouring hue costs less than a wrong one.
        let near = offline_alignment(
            "put the orange cube into the white box and cover the box with the lid",
            &cube_box_lid(),
        );
        assert!(
            near.score > s.score && near.score < full,
            "{}",
            near.rationale
        );
    }

    #[test]
    fn missing_objects_score_lower_and_nothing_scores_one() {
        let mut c = cube_box_lid();
        c.objects[1].views_seen = 0;
        c.relations = relations(&c.objects);
        let s = offline_alignment(BBSEA, &c);
        assert!(s.score < 3.9, "{}", s.rationale);
        assert!(
            s.rationale.contains("'white box' → nothing visible fits"),
            "{}",
            s.rationale
        );
        let s = offline_alignment("put the green ball into the yellow bowl", &cube_box_lid());
        assert!(s.score <= 2.0, "{}", s.rationale);
        let none = offline_alignment("put the green ball into the blue bin", &caption(vec![]));
        assert_eq!(none.score, 1.0, "{}", none.rationale);
    }

    #[test]
    fn coloured_mentions_pick_first_among_equals() {
        let c = caption(vec![
            obj(3, "sphere", "red", [0.3, -0.2, 0.02], [0.04, 0.04, 0.04]),
            obj(4, "sphere", "black", [0.5, 0.2, 0.02], [0.04, 0.04, 0.04]),
        ]);
        let s = offline_alignment("among several balls, pick up the black ball", &c);
        assert_eq!(s.score, 4.8, "{}", s.rationale);
        assert!(
            s.rationale
                .contains("'black ball' → the black sphere (1.00)")
        );
    }

    #[test]
    fn no_mentions_is_neutral() {
        let s = offline_alignment("do the thing with the stuff", &cube_box_lid());
        assert_eq!(s.score, NEUTRAL_SCORE);
        assert!(
            s.rationale.contains("cannot be compared"),
            "{}",
            s.rationale
        );
    }

    #[test]
    fn fallen_or_floating_objects_score_lower() {
        let full = offline_alignment(BBSEA, &cube_box_lid()).score;
        let mut c = cube_box_lid();
        c.objects[0].off_surface = true;
        c.objects[0].centre = [0.42, -0.85, -0.3];
        c.relations = relations(&c.objects);
        let s = offline_alignment(BBSEA, &c);
        assert!(s.score < full - 0.5, "{}", s.rationale);
        assert!(s.rationale.contains("fell off"), "{}", s.rationale);
        assert!(
            c.to_text()
                .contains("red cube about 4 × 4 × 4 cm at (0.42, -0.85), fallen off the table")
        );
        let mut c = cube_box_lid();
        c.objects[2].floating = true;
        let s = offline_alignment(BBSEA, &c);
        assert!(s.score < full - 0.5, "{}", s.rationale);
    }

    #[test]
    fn text_describes_what_is_seen() {
        let mut c = cube_box_lid();
        // The cube moved into the container: its bottom sits on the container's floor.
        c.objects[0].centre = [0.62, 0.08, 0.03];
        c.objects[0].size_m = [0.04, 0.04, 0.04];
        c.objects[2].views_seen = 1;
        c.objects.push(CaptionObject {
            views_seen: 0,
            ..obj(6, "sphere", "unknown", [0.0; 3], [0.0; 3])
        });
        c.relations = relations(&c.objects);
        assert_eq!(
            c.to_text(),
            "a red cube about 4 × 4 × 4 cm at (0.62, 0.08); \
             a white container about 8 × 8 × 6 cm at (0.62, 0.08) on the table; \
             a brown flat box about 9 × 9 × 1.0 cm at (0.42, 0.16) on the table \
             (seen in 1 of 4 views); \
             the red cube is in the white container. \
             1 more object of the scene is not visible in any view."
        );
        assert_eq!(
            caption(vec![]).to_text(),
            "no object is visible in the 4 views."
        );
    }

    #[test]
    fn relations_on_in_and_next_to() {
        let c = caption(vec![
            obj(3, "cube", "red", [0.5, 0.0, 0.02], [0.04, 0.04, 0.04]),
            obj(4, "cube", "green", [0.5, 0.0, 0.06], [0.04, 0.04, 0.04]),
            obj(5, "sphere", "blue", [0.5, 0.05, 0.02], [0.04, 0.04, 0.04]),
            obj(6, "container", "white", [0.8, 0.0, 0.03], [0.1, 0.1, 0.06]),
            obj(7, "box", "brown", [0.8, 0.0, 0.065], [0.11, 0.11, 0.01]),
        ]);
        let r: Vec<(u32, &str, u32)> = c
            .relations
            .iter()
            .map(|r| (r.subject, r.relation.as_str(), r.object))
            .collect();
        assert_eq!(r, vec![(4, "on", 3), (7, "on", 6), (3, "next to", 5)]);
        let t = c.to_text();
        assert!(t.contains("the green cube is on the red cube"), "{t}");
        assert!(
            t.contains("the brown flat box is on the white container"),
            "{t}"
        );
    }

    /// What the renderer draws: palette albedo × (0.35 + 0.65 |n · l|), 8 bits, no gamma.
    fn shaded(c: [f64; 3], k: f64) -> [u8; 3] {
        c.map(|x| (x * k * 255.0).round() as u8)
    }

    #[test]
    fn every_palette_colour_is_named_back_under_shading() {
        let l = {
            let v = [0.35f64, 0.25, 1.0];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / n)
        };
        let k = |n: usize| 0.35 + 0.65 * l[n].abs();
        for (name, c) in COLORS {
            // A box from above: mostly its top face, some of two sides.
            let mut px = vec![shaded(*c, k(2)); 300];
            px.extend(vec![shaded(*c, k(0)); 60]);
            px.extend(vec![shaded(*c, k(1)); 60]);
            let (got, rgb) = name_colour(&px);
            assert_eq!(got, *name, "{name} measured {rgb:?}");
            // Its sides alone keep the hue (achromatic ones need the top).
            if saturation(*c) > 0.1 {
                assert_eq!(name_colour(&[shaded(*c, k(1)); 20]).0, *name);
            }
        }
        assert_eq!(name_colour(&[]).0, "unknown");
    }

    #[test]
    fn forms_from_shapes() {
        let b = |h: [f64; 3]| form_of(&Shape::Box { half_extents: h });
        assert_eq!(b([0.02, 0.02, 0.02]), "cube");
        assert_eq!(b([0.043, 0.043, 0.005]), "box");
        assert_eq!(form_of(&Shape::Sphere { radius: 0.02 }), "sphere");
        assert_eq!(visible_pixels(640, 480), 20);
        assert_eq!(visible_pixels(320, 240), 5);
    }
}
