//! The pictures every episode gets: views of the initial scene (for scene alignment), keyframes
//! over the rollout (for task completion), a contact sheet of both, optionally a video, and a
//! dynamics clip when the batch measures dynamics diversity.

use assay_model::clip::{ACTION_DIMS, Clip, ClipView, PROPRIO_DIMS};
use assay_model::episode::ClipCamera;
use assay_spec::scene::{SceneSnapshot, scene_views};
use assay_spec::spec::Camera;

use crate::image::{Rgb, contact_sheet};
use crate::video::Video;
use crate::{Outputs, RenderError, Renderer};

pub struct Imagery {
    pub views: Vec<(String, Rgb)>,
    pub keyframes: Vec<(u64, String, Rgb)>,
    pub sheet: Rgb,
}

/// Camera numbers of the scene views in frame headers (keyframes carry the index of their camera
/// in the task's camera list, which is small).
pub const VIEW_CAMERA_BASE: u32 = 1000;

/// Which picture of an episode is being drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shot {
    /// Scene view `i` of the initial scene (top, front, oblique left, oblique right).
    View(usize),
    /// A keyframe at this physics step, from the task's first camera.
    Keyframe(u64),
}

impl Shot {
    /// The camera number a frame header carries.
    pub fn camera(self) -> u32 {
        match self {
            Shot::View(i) => VIEW_CAMERA_BASE + i as u32,
            Shot::Keyframe(_) => 0,
        }
    }

    /// The physics step drawn (scene views show the state before the first policy step).
    pub fn step(self, initial_step: u64) -> u64 {
        match self {
            Shot::View(_) => initial_step,
            Shot::Keyframe(s) => s,
        }
    }
}

/// Renders the four scene views of `initial` and every keyframe from `keyframe_camera`, at
/// `width` × `height`; the contact sheet has the views on top and the keyframes below, at half size.
pub fn render_episode(
    r: &mut Renderer,
    initial: &SceneSnapshot,
    keyframes: &[(u64, SceneSnapshot)],
    keyframe_camera: &Camera,
    width: u32,
    height: u32,
) -> Result<Imagery, RenderError> {
    render_episode_with(
        initial,
        keyframes,
        keyframe_camera,
        width,
        height,
        &mut |_, scene, cam| Ok(Rgb::from_frame(&r.render_with(scene, cam, Outputs::RGB)?)),
    )
}

/// [`render_episode`] with the drawing left to `draw` (for example straight into a frame-bus
/// sample in shared memory, which subscribers on the node then read in place).
pub fn render_episode_with(
    initial: &SceneSnapshot,
    keyframes: &[(u64, SceneSnapshot)],
    keyframe_camera: &Camera,
    width: u32,
    height: u32,
    draw: &mut dyn FnMut(Shot, &SceneSnapshot, &Camera) -> Result<Rgb, RenderError>,
) -> Result<Imagery, RenderError> {
    let sized = |c: &Camera| Camera {
        width,
        height,
        ..c.clone()
    };
    let mut views = Vec::new();
    // The views show the scene as the task set it up: without the tool in the way.
    let scene = SceneSnapshot {
        tool: None,
        tool_rotation: None,
        fingers: Vec::new(),
        arm: Vec::new(),
        ..initial.clone()
    };
    for (i, cam) in scene_views().iter().enumerate() {
        views.push((cam.name.clone(), draw(Shot::View(i), &scene, &sized(cam))?));
    }
    let mut frames = Vec::new();
    for (step, scene) in keyframes {
        frames.push((
            *step,
            keyframe_camera.name.clone(),
            draw(Shot::Keyframe(*step), scene, &sized(keyframe_camera))?,
        ));
    }
    let thumbs: Vec<Rgb> = views
        .iter()
        .map(|(_, i)| i.halve(1))
        .chain(frames.iter().map(|(_, _, i)| i.halve(1)))
        .collect();
    Ok(Imagery {
        views,
        keyframes: frames,
        sheet: contact_sheet(&thumbs, 4),
    })
}

/// Frames per second of episode videos.
pub const VIDEO_FPS: u32 = 12;

/// A video of `states` from `camera` at `width` × `height` ([`VIDEO_FPS`]).
pub fn render_video(
    r: &mut Renderer,
    states: &[(u64, SceneSnapshot)],
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<Video, RenderError> {
    let cam = Camera {
        width,
        height,
        ..camera.clone()
    };
    let mut frames = Vec::with_capacity(states.len());
    for (_, scene) in states {
        frames.push(Rgb::from_frame(&r.render_with(
            scene,
            &cam,
            Outputs::RGB,
        )?));
    }
    crate::video::encode(&frames, VIDEO_FPS).map_err(RenderError::Video)
}

/// The objects' section of a clip of `scenes` ([`Clip::objects`]): each object's position, in
/// the scenes' order. None (0 dims) when the scenes do not all hold the same objects in the same
/// order, or more than a clip holds.
fn object_positions(scenes: &[SceneSnapshot]) -> (u32, Vec<f32>) {
    let Some(first) = scenes.first() else {
        return (0, Vec::new());
    };
    let same = |s: &SceneSnapshot| {
        s.objects.len() == first.objects.len()
            && s.objects
                .iter()
                .zip(&first.objects)
                .all(|(a, b)| a.id == b.id)
    };
    let dims = 3 * first.objects.len();
    if dims == 0 || dims > assay_model::clip::MAX_OBJECT_DIMS || !scenes.iter().all(same) {
        return (0, Vec::new());
    }
    let objects = scenes
        .iter()
        .flat_map(|s| s.objects.iter().flat_map(|o| o.position))
        .collect();
    (dims as u32, objects)
}

/// The largest dynamics clip frame drawn (pixels square).
pub const MAX_CLIP_SIZE: u32 = 1024;

/// A dynamics clip ([`Clip`]): `scenes` drawn from `camera` at `size` × `size` RGB (colour only,
/// one reused render target), with `proprio` and `actions` per frame as the sim role measured
/// them ([`assay_model::clip::PROPRIO_DIMS`] and [`assay_model::clip::ACTION_DIMS`] values per
/// scene) and `interval_s` between frames.
pub fn render_clip(
    r: &mut Renderer,
    scenes: &[SceneSnapshot],
    camera: &Camera,
    size: u32,
    interval_s: f32,
    proprio: Vec<f32>,
    actions: Vec<f32>,
) -> Result<Clip, RenderError> {
    let bad = |reason: String| RenderError::Scene {
        path: "clip".into(),
        reason,
    };
    if size == 0 || size > MAX_CLIP_SIZE {
        return Err(bad(format!(
            "clip frames of {size} pixels square (1..={MAX_CLIP_SIZE})"
        )));
    }
    let cam = Camera {
        width: size,
        height: size,
        ..camera.clone()
    };
    let (object_dims, objects) = object_positions(scenes);
    let pixels = (size * size) as usize;
    let mut rgba = vec![0u8; pixels * 4];
    let mut rgb = Vec::with_capacity(scenes.len() * pixels * 3);
    for scene in scenes {
        r.render_rgba_into(scene, &cam, &mut rgba)?;
        rgb.extend(rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
    }
    let clip = Clip {
        height: size,
        width: size,
        interval_s,
        proprio_dims: PROPRIO_DIMS as u32,
        action_dims: ACTION_DIMS as u32,
        rgb,
        proprio,
        actions,
        interface: String::new(),
        views: Vec::new(),
        object_dims,
        objects,
    };
    clip.validate().map_err(|e| bad(e.to_string()))?;
    Ok(clip)
}

/// A dynamics clip at a policy's interface (`interface`, `Interface::to_args`): `scenes` drawn
/// from each of `cameras` as placed at that frame and at its own size, the first camera as the
/// clip's frames and the others as its views, with the interface's state vector (`state`) and
/// actions (`actions`) per frame and `interval_s` between frames.
pub fn render_clip_at(
    r: &mut Renderer,
    scenes: &[SceneSnapshot],
    cameras: &[ClipCamera],
    interval_s: f32,
    state: Vec<f32>,
    actions: Vec<f32>,
    interface: &str,
) -> Result<Clip, RenderError> {
    let bad = |reason: String| RenderError::Scene {
        path: "clip".into(),
        reason,
    };
    let t = scenes.len();
    if cameras.is_empty() || cameras.iter().any(|c| c.frames.len() != t) {
        return Err(bad(format!(
            "a clip at an interface needs each camera placed at each of its {t} frames"
        )));
    }
    let dims = |n: usize, what: &str| match n.checked_div(t) {
        Some(d) if d * t == n && d > 0 => Ok(d as u32),
        _ => Err(bad(format!("{n} {what} values for {t} frames"))),
    };
    let (state_dims, action_dims) = (dims(state.len(), "state")?, dims(actions.len(), "action")?);
    let mut drawn = Vec::with_capacity(cameras.len());
    for c in cameras {
        let (w, h) = (c.frames[0].width, c.frames[0].height);
        if w == 0 || h == 0 || w.max(h) > MAX_CLIP_SIZE {
            return Err(bad(format!(
                "camera '{}': frames of {w}x{h} pixels (1..={MAX_CLIP_SIZE})",
                c.name
            )));
        }
        let mut rgba = vec![0u8; (w * h * 4) as usize];
        let mut rgb = Vec::with_capacity(t * (w * h * 3) as usize);
        for (scene, camera) in scenes.iter().zip(&c.frames) {
            r.render_rgba_into(scene, camera, &mut rgba)?;
            rgb.extend(rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
        }
        drawn.push(ClipView {
            name: c.name.clone(),
            width: w,
            height: h,
            rgb,
        });
    }
    let first = drawn.remove(0);
    let (object_dims, objects) = object_positions(scenes);
    let clip = Clip {
        height: first.height,
        width: first.width,
        interval_s,
        proprio_dims: state_dims,
        action_dims,
        rgb: first.rgb,
        proprio: state,
        actions,
        interface: interface.to_owned(),
        views: drawn,
        object_dims,
        objects,
    };
    clip.validate().map_err(|e| bad(e.to_string()))?;
    Ok(clip)
}
