//! Captions of the scene views: what the four views of a task's initial scene actually show,
//! measured from their pixels, for the built-in offline judge and for two-stage caption + LLM
//! judges ([`assay_model::caption`] owns the data, the wording and the score).
//!
//! Everything in a caption but an object's form comes from the rendered images: visibility from
//! the segment ids, colour from the RGB of the object's pixels, size and centre from its pixels
//! back-projected with their depth, resting or not from the same points. The snapshot only says
//! which primitive the renderer drew for a segment and what the scene's surface is.

use assay_model::caption::{
    CaptionObject, SceneCaption, form_of, name_colour, relations, supported, visible_pixels,
};
use assay_spec::scene::{
    EE_CAMERA, FIRST_OBJECT_SEGMENT, Observation, SEGMENT_BACKGROUND, SEGMENT_SURFACE,
    SceneSnapshot, camera_axes, scene_views,
};
use assay_spec::spec::{Camera, Surface, TABLE_CENTER, TABLE_HALF_EXTENTS};

use crate::{Frame, Outputs, RenderError, Renderer};

/// A bottom this far (m) below the surface's top means the object fell off.
const BELOW_SURFACE_M: f64 = 0.02;
/// A bottom seen this far (m) above the surface, with nothing under it, is floating.
const FLOATING_M: f64 = 0.025;

/// Renders the four scene views of `initial` ([`scene_views`], without the tool, as the episode
/// imagery shows them) at `width` × `height` with depth and segments, and captions what they
/// show ([`caption_frames`]).
pub fn caption_scene(
    r: &mut Renderer,
    initial: &SceneSnapshot,
    width: u32,
    height: u32,
) -> Result<SceneCaption, RenderError> {
    let scene = SceneSnapshot {
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
        ..initial.clone()
    };
    let mut frames = Vec::with_capacity(4);
    for camera in scene_views() {
        let camera = Camera {
            width,
            height,
            ..camera
        };
        let frame = r.render_with(&scene, &camera, Outputs::ALL)?;
        frames.push((camera.name.clone(), camera, frame));
    }
    Ok(caption_frames(&scene, &frames))
}

/// What the views show of one object, gathered pixel by pixel.
struct Seen {
    pixels: u64,
    in_view: u64,
    views_seen: u32,
    lo: [f64; 3],
    hi: [f64; 3],
    colours: Vec<[u8; 3]>,
    /// Lowest point, in a view that is not straight down, whose pixel below shows the surface
    /// or the background: how high the object's visible underside is.
    clear_bottom: f64,
}

impl Seen {
    fn new() -> Self {
        Seen {
            pixels: 0,
            in_view: 0,
            views_seen: 0,
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            colours: Vec::new(),
            clear_bottom: f64::INFINITY,
        }
    }
}

/// Captions already rendered frames: (view name, camera, frame with RGBA, depth and segments).
/// Frames of the end-effector camera (whose eye follows the tool) and frames without depth or
/// segments are skipped; a camera's size is taken from its frame.
///
/// Per object: visible in a view with at least [`visible_pixels`] pixels; colour named from all
/// its pixels ([`name_colour`]); extent from its back-projected pixel centres (in a view looking
/// straight down each grown by half a pixel's footprint, so a top face is not measured short);
/// fallen off when its bottom is more than 2 cm below the surface or its centre beside the
/// table; floating when its underside, seen against the surface or background from a side view,
/// is more than 2.5 cm up and nothing measured is under it ([`supported`]). Relations come from
/// [`relations`]. One pass over each frame's pixels.
///
/// What it cannot see: the underside of anything (a side view's lowest visible point is the
/// bottom), parts hidden in every view (sizes are of the visible surface), and colours of faces
/// never lit squarely (an achromatic object seen only from its sides reads darker).
pub fn caption_frames(scene: &SceneSnapshot, frames: &[(String, Camera, Frame)]) -> SceneCaption {
    let n = scene.objects.len();
    let mut seen: Vec<Seen> = (0..n).map(|_| Seen::new()).collect();
    let mut views = Vec::new();
    for (name, camera, f) in frames {
        let (w, h) = (f.width, f.height);
        let count = w as usize * h as usize;
        if camera.name == EE_CAMERA || f.depth.len() != count || f.segments.len() != count {
            continue;
        }
        views.push(name.clone());
        let camera = Camera {
            width: w,
            height: h,
            ..camera.clone()
        };
        let axes = camera_axes(camera.eye, camera.target);
        // Views that look straight down see no undersides.
        let side = axes[2][2] > -0.99;
        // Pixel centres fall short of an edge by half a pixel on average: a view looking straight
        // down grows each point by half a pixel's footprint in x and y (exact for the top faces
        // it mostly sees). Side views are not grown: most of what they see is at a slant, where
        // growing would overshoot, and the z of a top face is exact from any view.
        let t = if side {
            0.0
        } else {
            (camera.fovy_deg.to_radians() / 2.0).tan() / f64::from(h)
        };
        let pad: [f64; 3] = std::array::from_fn(|k| t * (axes[0][k].abs() + axes[1][k].abs()));
        let un = Observation {
            camera,
            depth: Vec::new(),
            segments: Vec::new(),
        }
        .unprojection();
        let rgb = f.rgba.len() == count * 4;
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let seg = f.segments[i];
                let Some(k) = seg.checked_sub(FIRST_OBJECT_SEGMENT).map(|k| k as usize) else {
                    continue;
                };
                if k >= n {
                    continue;
                }
                let d = f.depth[i];
                let Some(p) = un.point(x, y, d) else {
                    continue;
                };
                let s = &mut seen[k];
                s.pixels += 1;
                s.in_view += 1;
                for a in 0..3 {
                    let e = pad[a] * f64::from(d);
                    s.lo[a] = s.lo[a].min(p[a] - e);
                    s.hi[a] = s.hi[a].max(p[a] + e);
                }
                if rgb {
                    s.colours
                        .push([f.rgba[4 * i], f.rgba[4 * i + 1], f.rgba[4 * i + 2]]);
                }
                if side && y + 1 < h {
                    let below = f.segments[i + w as usize];
                    if below == SEGMENT_SURFACE || below == SEGMENT_BACKGROUND {
                        s.clear_bottom = s.clear_bottom.min(p[2]);
                    }
                }
            }
        }
        let threshold = visible_pixels(w, h);
        for s in &mut seen {
            if s.in_view >= threshold {
                s.views_seen += 1;
            }
            s.in_view = 0;
        }
    }
    let mut objects: Vec<CaptionObject> = scene
        .objects
        .iter()
        .zip(&seen)
        .enumerate()
        .map(|(i, (o, s))| {
            let visible = s.views_seen > 0;
            let (colour, rgb) = if visible {
                name_colour(&s.colours)
            } else {
                ("unknown".to_owned(), [0; 3])
            };
            let (size_m, centre) = if s.pixels > 0 {
                (
                    std::array::from_fn(|a| s.hi[a] - s.lo[a]),
                    std::array::from_fn(|a| (s.hi[a] + s.lo[a]) / 2.0),
                )
            } else {
                ([0.0; 3], [0.0; 3])
            };
            let beside_table = scene.surface == Surface::Table
                && (0..2).any(|a| (centre[a] - TABLE_CENTER[a]).abs() > TABLE_HALF_EXTENTS[a]);
            CaptionObject {
                segment: FIRST_OBJECT_SEGMENT + i as u32,
                form: form_of(&o.shape),
                colour,
                rgb,
                size_m,
                centre,
                pixels: s.pixels,
                views_seen: s.views_seen,
                off_surface: visible && (s.lo[2] < -BELOW_SURFACE_M || beside_table),
                floating: false,
            }
        })
        .collect();
    let relations = relations(&objects);
    let floating: Vec<bool> = objects
        .iter()
        .zip(&seen)
        .map(|(o, s)| {
            o.views_seen > 0
                && !o.off_surface
                && s.clear_bottom > FLOATING_M
                && s.clear_bottom.is_finite()
                && !supported(o, &objects, &relations)
        })
        .collect();
    for (o, f) in objects.iter_mut().zip(floating) {
        o.floating = f;
    }
    SceneCaption {
        views,
        surface: match scene.surface {
            Surface::Table => "table",
            Surface::Ground => "ground",
        }
        .to_owned(),
        objects,
        relations,
    }
}
