//! The pictures every episode gets: views of the initial scene (for scene alignment), keyframes
//! over the rollout (for task completion), and a contact sheet of both.

use assay_core::scene::{SceneSnapshot, scene_views};
use assay_core::spec::Camera;

use crate::image::{Rgb, contact_sheet};
use crate::{Outputs, RenderError, Renderer};

pub struct Imagery {
    pub views: Vec<(String, Rgb)>,
    pub keyframes: Vec<(u64, String, Rgb)>,
    pub sheet: Rgb,
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
    let sized = |c: &Camera| Camera {
        width,
        height,
        ..c.clone()
    };
    let mut views = Vec::new();
    for cam in scene_views() {
        // The views show the scene as the task set it up: without the tool in the way.
        let scene = SceneSnapshot {
            tool: None,
            ..initial.clone()
        };
        views.push((
            cam.name.clone(),
            Rgb::from_frame(&r.render_with(&scene, &sized(&cam), Outputs::RGB)?),
        ));
    }
    let mut frames = Vec::new();
    for (step, scene) in keyframes {
        frames.push((
            *step,
            keyframe_camera.name.clone(),
            Rgb::from_frame(&r.render_with(scene, &sized(keyframe_camera), Outputs::RGB)?),
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
