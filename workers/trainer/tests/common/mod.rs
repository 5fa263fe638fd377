//! Clips and a policy at a 7-D, two-camera interface, for the tests of the world model at any
//! interface.
#![allow(dead_code)]

use assay_model::clip::Clip;

/// The interface of [`two_camera_clip`]: a 7-D end-effector-delta policy with a scene camera of
/// 32×32 and a wrist camera of 16×16, reading the tool's position, orientation and gripper.
pub const SEVEN: &str = "space=ee_delta,cameras=image:scene@32x32+wrist_image:wrist@16x16,\
                     state=ee_pos+ee_quat+gripper";

/// A `side`² grey frame with a `sq`² square of `color` at (x, y).
fn square(side: u32, sq: i32, x: i32, y: i32, color: [u8; 3]) -> Vec<u8> {
    let mut f = vec![100u8; (side * side * 3) as usize];
    for j in y.max(0)..(y + sq).min(side as i32) {
        for i in x.max(0)..(x + sq).min(side as i32) {
            let at = ((j as u32 * side + i as u32) * 3) as usize;
            f[at..at + 3].copy_from_slice(&color);
        }
    }
    f
}

/// A clip at [`SEVEN`]: the scene camera (32 px, the model's size) sees a red 4 px square move
/// by each action's (dx, dy) (1 px per 0.125); the wrist camera (16 px, drawn at 32 inside the
/// model), riding with the tool, sees a blue 2 px square move the other way at half the scale.
/// In the model's frames both are 4 px squares moving 2 px a step (a camera whose moving parts
/// are smaller learns slower, as both share one loss).
pub fn two_camera_clip(x: i32, y: i32, moves: &[(i32, i32)]) -> Clip {
    let (mut x, mut y) = (x, y);
    let (mut rgb, mut wrist, mut proprio, mut actions) = (vec![], vec![], vec![], vec![]);
    for t in 0..=moves.len() {
        rgb.extend(square(32, 4, x, y, [220, 30, 30]));
        wrist.extend(square(
            16,
            2,
            7 - (x - 12) / 2,
            7 - (y - 12) / 2,
            [30, 30, 220],
        ));
        proprio.extend([
            x as f32 / 16.0,
            y as f32 / 16.0,
            0.1,
            1.0,
            0.0,
            0.0,
            0.0,
            1.0,
        ]);
        let (dx, dy) = moves.get(t).copied().unwrap_or((0, 0));
        actions.extend([
            dx as f32 * 0.125,
            dy as f32 * 0.125,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ]);
        x = (x + dx).clamp(0, 28);
        y = (y + dy).clamp(0, 28);
    }
    Clip {
        height: 32,
        width: 32,
        interval_s: 0.1,
        proprio_dims: 8,
        action_dims: 7,
        rgb,
        proprio,
        actions,
        interface: SEVEN.into(),
        views: vec![assay_model::clip::ClipView {
            name: "wrist_image".into(),
            width: 16,
            height: 16,
            rgb: wrist,
        }],
        object_dims: 0,
        objects: Vec::new(),
    }
}

pub fn two_camera_episodes(seed: i32) -> Vec<Clip> {
    let dirs = [(2, 0), (-2, 0), (0, 2), (0, -2)];
    (0..16)
        .map(|i| {
            let a = dirs[(i + seed as usize) % 4];
            let b = if i % 2 == 0 { a } else { dirs[(i / 2 + 1) % 4] };
            let moves: Vec<(i32, i32)> = (0..8).map(|t| if t < 4 { a } else { b }).collect();
            two_camera_clip(
                10 + 2 * (i as i32 % 3),
                10 + 2 * ((i as i32 / 3) % 3),
                &moves,
            )
        })
        .collect()
}

/// Acts in [`SEVEN`]: always 0.25 to the right, in chunks of 2; keeps what it saw.
#[derive(Default)]
pub struct SevenRight {
    pub seen: Vec<assay_model::policy::PolicyObservation>,
}

impl assay_model::policy::Policy for SevenRight {
    fn reset(
        &mut self,
        _: &assay_model::policy::EpisodeContext,
    ) -> Result<(), assay_model::policy::PolicyError> {
        Ok(())
    }
    fn act_any(
        &mut self,
        obs: &assay_model::policy::PolicyObservation,
    ) -> Result<Vec<Vec<f32>>, assay_model::policy::PolicyError> {
        self.seen.push(obs.clone());
        Ok(vec![vec![0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]; 2])
    }
    fn interface(&self) -> assay_model::interface::Interface {
        assay_model::interface::Interface::parse_args(SEVEN).unwrap()
    }
}
