//! Rollouts in any world model ([`WorldModelService`]): replays of real actions (the frame
//! judge's imagined examples; the action test is `video_eval`'s) and a policy acting closed loop
//! (the ranked episodes).
//!
//! A ranked episode is imagined from what the world model is given at its start — the real first
//! frame and state, the instruction — and nothing else of the real episode: it runs until the
//! frame judge calls `done_frames` imagined frames in a row done (a predicted success) or the
//! task's step budget runs out (a predicted failure). Neither the real episode's length nor its
//! outcome can reach it: [`closed_loop`] is not given them. The leak ablation
//! ([`ClosedLoop::leak_at`]) reads the judge at the real length on purpose, beside the verdict.

use std::collections::VecDeque;

use assay_model::clip::{Clip, PROPRIO_DIMS};
use assay_model::interface::{Interface, NamedImage, StatePart};
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_model::world::{WorldError, WorldFrame, WorldModelService, WorldStart};

/// The start of `clip`'s episode: its first frames and state, nothing after.
pub fn start_of(clip: &Clip, episode: &EpisodeContext) -> WorldStart {
    start_at(
        clip,
        0,
        &episode.task_id,
        episode.seed,
        &episode.instruction,
    )
}

/// The interface `clip` was recorded at, each camera at the clip's size of it (the original
/// interface for a clip of the task camera; one that cannot be read too: the clip's check
/// refuses it first).
pub fn clip_interface(clip: &Clip) -> Interface {
    let mut sizes = vec![(clip.width, clip.height)];
    sizes.extend(clip.views.iter().map(|v| (v.width, v.height)));
    sized_interface(&clip.interface, &sizes)
}

/// The interface of `args` (`Interface::to_args`; one that cannot be read: the original) with
/// its cameras at `sizes`, in order.
pub fn sized_interface(args: &str, sizes: &[(u32, u32)]) -> Interface {
    let mut i = Interface::parse_args(args).unwrap_or_default();
    for (c, &(w, h)) in i.cameras.iter_mut().zip(sizes) {
        (c.width, c.height) = (w, h);
    }
    i
}

/// A start at frame `t` of `clip`: the frames of its cameras and its state there, at the clip's
/// interface (one that cannot be read gives the original: the clip's check refuses it first).
pub fn start_at(clip: &Clip, t: usize, task_id: &str, seed: u64, instruction: &str) -> WorldStart {
    let p = clip.proprio_dims as usize;
    WorldStart {
        task_id: task_id.to_owned(),
        seed,
        instruction: instruction.to_owned(),
        interface: clip_interface(clip),
        width: clip.width,
        height: clip.height,
        rgb: clip.frame(t).to_vec(),
        views: clip
            .views
            .iter()
            .map(|v| NamedImage {
                name: v.name.clone(),
                width: v.width,
                height: v.height,
                rgb: v.frame(t).to_vec(),
                depth: Vec::new(),
            })
            .collect(),
        state: clip.proprio[t * p..(t + 1) * p].to_vec(),
        objects: clip.objects_at(t).to_vec(),
    }
}

/// The clip's actions `0..T−1` (each leads to the next frame).
pub fn actions_of(clip: &Clip) -> Vec<Vec<f32>> {
    let d = clip.action_dims as usize;
    (0..clip.len().saturating_sub(1))
        .map(|t| clip.actions[t * d..(t + 1) * d].to_vec())
        .collect()
}

/// Frames `1..=actions.len()` imagined from `start` with `actions`, open loop.
pub fn replay(
    world: &dyn WorldModelService,
    start: &WorldStart,
    actions: &[Vec<f32>],
) -> Result<Vec<Vec<u8>>, WorldError> {
    Ok(replay_frames(world, start, actions)?
        .into_iter()
        .map(|f| f.rgb)
        .collect())
}

/// [`replay`] with all the model answers of each frame (its state and objects too).
pub fn replay_frames(
    world: &dyn WorldModelService,
    start: &WorldStart,
    actions: &[Vec<f32>],
) -> Result<Vec<WorldFrame>, WorldError> {
    let mut episode = world.reset(start)?;
    let frames = episode.step(actions)?;
    check_frames(&frames, actions.len(), start)?;
    Ok(frames)
}

/// Refuses an answer of another number of frames than `asked`, or of frames not at the start's
/// cameras and sizes.
pub(crate) fn check_frames(
    frames: &[assay_model::world::WorldFrame],
    asked: usize,
    start: &WorldStart,
) -> Result<(), WorldError> {
    if frames.len() != asked {
        return Err(WorldError::BadAnswer(format!(
            "{} frame(s) for {asked} action(s)",
            frames.len()
        )));
    }
    let bytes = (start.width * start.height * 3) as usize;
    if let Some(f) = frames.iter().find(|f| f.rgb.len() != bytes) {
        return Err(WorldError::BadAnswer(format!(
            "a frame of {} bytes, {}x{} RGB is {bytes}",
            f.rgb.len(),
            start.width,
            start.height
        )));
    }
    for f in frames {
        if f.views.len() != start.views.len() {
            return Err(WorldError::BadAnswer(format!(
                "{} frame(s) of the cameras after the first, the interface has {}",
                f.views.len(),
                start.views.len()
            )));
        }
        for (v, want) in f.views.iter().zip(&start.views) {
            if v.len() != (want.width * want.height * 3) as usize {
                return Err(WorldError::BadAnswer(format!(
                    "a frame of camera '{}' of {} bytes, {}x{} RGB is {}",
                    want.name,
                    v.len(),
                    want.width,
                    want.height,
                    want.width * want.height * 3
                )));
            }
        }
    }
    Ok(())
}

/// A PNG of `rows` of RGB frames of `width`×`height`, side by side (rows of differing lengths
/// padded with black): a sheet of rollouts to look at, real and imagined.
pub fn sheet_png(rows: &[Vec<&[u8]>], width: usize, height: usize) -> Vec<u8> {
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    let (iw, ih) = (cols * width, rows.len() * height);
    let mut img = vec![0u8; iw * ih * 3];
    for (r, row) in rows.iter().enumerate() {
        for (c, f) in row.iter().enumerate() {
            for y in 0..height {
                let dst = ((r * height + y) * iw + c * width) * 3;
                img[dst..dst + width * 3].copy_from_slice(&f[y * width * 3..(y + 1) * width * 3]);
            }
        }
    }
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, iw as u32, ih as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().expect("png header to memory");
    w.write_image_data(&img).expect("png data to memory");
    w.finish().expect("png to memory");
    out
}

/// Mean squared error per pixel-channel, in [0, 1] units.
pub fn mse(a: &[u8], b: &[u8]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| {
            let d = (f64::from(*a) - f64::from(*b)) / 255.0;
            d * d
        })
        .sum::<f64>()
        / a.len().max(1) as f64
}

/// The probability that a state (the interface's state vector) and the scene objects' positions
/// (`WorldFrame::objects`) show the task done.
pub type ObjectsJudge<'a> = &'a dyn Fn(&[f32], &[f32]) -> f64;

/// What to stop a closed-loop rollout on.
pub struct Stop<'a> {
    /// Clip frames at most, the first (real) one included: the task's step budget.
    pub horizon: usize,
    /// The frame judge's probability that a frame shows the task done.
    pub judge: &'a dyn Fn(&[u8]) -> f64,
    /// When set, the verdict is this judge's, on the state and objects the world model predicts
    /// at each frame, instead of the frame judge's (a model that predicts no objects is an
    /// error). The leak ablation's frame is still read by the frame judge.
    pub objects: Option<ObjectsJudge<'a>>,
    pub threshold: f64,
    pub done_frames: usize,
    /// The leak ablation: also read the judge at this frame (the real episode's last).
    pub leak_at: Option<usize>,
}

/// A policy's rollout in the world model.
pub struct ClosedLoop {
    /// Imagined frames `1..`: up to the frame the verdict was taken at (the real first frame is
    /// the start's).
    pub frames: Vec<Vec<u8>>,
    /// The judge's probability on the frame the verdict was taken at.
    pub p_success: f64,
    pub done_by_judge: bool,
    /// The judge's probability on frame `leak_at` (or the last one, when the budget ended
    /// first).
    pub leak: Option<f64>,
}

/// Runs `policy` (reset with `episode` first) inside `world` from `start`: at each step it sees
/// the frames and state the model gave last (the real ones first), at the start's interface (its
/// cameras by name, its state vector), and its actions — in the interface's action space, at
/// most the interface's execution horizon of each chunk — drive the next steps until `stop`
/// says so. A model that predicts no state hands the policy the last state it had.
pub fn closed_loop(
    world: &dyn WorldModelService,
    start: &WorldStart,
    policy: &mut dyn Policy,
    episode: &EpisodeContext,
    stop: &Stop<'_>,
) -> Result<ClosedLoop, ImaginationError> {
    let interface = &start.interface;
    let refuse = |msg: String| Err(ImaginationError::World(WorldError::Refused(msg)));
    let arm = episode.arm.as_deref();
    let state_dims = interface.state_dims(arm).unwrap_or(start.state.len());
    if start.state.len() != state_dims {
        return refuse(format!(
            "a start state of {} values, the interface's state ({}) has {state_dims}",
            start.state.len(),
            interface
                .state
                .iter()
                .map(|p| p.name())
                .collect::<Vec<_>>()
                .join("+")
        ));
    }
    if interface.cameras.len() != start.views.len() + 1 {
        return refuse(format!(
            "{} start frame(s) for the interface's {} camera(s)",
            start.views.len() + 1,
            interface.cameras.len()
        ));
    }
    let action_dims = match interface.action.dims(arm) {
        Ok(d) => d,
        Err(e) => return refuse(format!("action_space: {e}")),
    };
    // Where the original 4 floats of proprio sit in the state vector, when they do.
    let mut offset = 0;
    let (mut pos_at, mut holding_at) = (None, None);
    for part in &interface.state {
        match part {
            StatePart::EePos => pos_at = Some(offset),
            StatePart::Holding => holding_at = Some(offset),
            _ => {}
        }
        offset += part.dims(arm).unwrap_or(0);
    }
    let proprio = |state: &[f32]| {
        let mut p = [0f32; PROPRIO_DIMS];
        if let Some(i) = pos_at {
            p[..3].copy_from_slice(&state[i..i + 3]);
        }
        if let Some(i) = holding_at {
            p[3] = state[i];
        }
        p
    };
    policy
        .reset(episode)
        .map_err(|e| ImaginationError::Policy(0, e))?;
    let mut world_episode = world.reset(start)?;
    let mut seen_rgb = start.rgb.clone();
    let mut seen_views: Vec<Vec<u8>> = start.views.iter().map(|v| v.rgb.clone()).collect();
    let mut seen_state = start.state.clone();
    let mut chunk: VecDeque<Vec<f32>> = VecDeque::new();
    let mut frames = Vec::new();
    let mut verdict: Option<(f64, bool)> = None;
    let mut leak = None;
    let mut streak = 0usize;
    let last = stop.horizon.saturating_sub(1);
    let leak_at = stop.leak_at.map(|t| t.clamp(1, last.max(1)));
    let mut t = 0usize;
    while t < last && (verdict.is_none() || leak_at.is_some_and(|l| leak.is_none() && t < l)) {
        if chunk.is_empty() {
            let mut images = Vec::with_capacity(interface.cameras.len());
            for (i, c) in interface.cameras.iter().enumerate() {
                let (width, height) = start.camera_size(i);
                images.push(NamedImage {
                    name: c.name.clone(),
                    width,
                    height,
                    rgb: if i == 0 {
                        seen_rgb.clone()
                    } else {
                        seen_views[i - 1].clone()
                    },
                    depth: Vec::new(),
                });
            }
            let obs = PolicyObservation {
                step: t as u32,
                width: start.width,
                height: start.height,
                rgb: seen_rgb.clone(),
                proprio: proprio(&seen_state),
                images,
                state: seen_state.clone(),
            };
            let answer = policy
                .act_any(&obs)
                .map_err(|e| ImaginationError::Policy(t, e))?;
            if answer.is_empty() || answer.iter().flatten().any(|x| !x.is_finite()) {
                return Err(ImaginationError::Policy(
                    t,
                    PolicyError::BadAnswer("an empty or non-finite chunk".into()),
                ));
            }
            if let Some(a) = answer.iter().find(|a| a.len() != action_dims) {
                return Err(ImaginationError::Policy(
                    t,
                    PolicyError::BadAnswer(format!(
                        "an action of {} floats; the interface's {} takes {action_dims}",
                        a.len(),
                        interface.action
                    )),
                ));
            }
            let run = interface.execute.map_or(answer.len(), |h| h as usize);
            chunk.extend(answer.into_iter().take(run.max(1)));
        }
        let action = chunk.pop_front().expect("a non-empty chunk");
        let mut next = world_episode.step(&[action])?;
        check_frames(&next, 1, start)?;
        let f = next.pop().expect("one frame");
        if let Some(state) = f.state {
            if state.len() != state_dims || state.iter().any(|v| !v.is_finite()) {
                return Err(ImaginationError::World(WorldError::BadAnswer(format!(
                    "a state of {} values, {state_dims} finite ones were expected",
                    state.len()
                ))));
            }
            seen_state = state;
        }
        t += 1;
        let p = match stop.objects {
            Some(judge) if verdict.is_none() => match &f.objects {
                Some(objects) if objects.len() == start.objects.len() => {
                    judge(&seen_state, objects)
                }
                _ => {
                    return Err(ImaginationError::World(WorldError::BadAnswer(format!(
                        "no positions of the start's {} object values: the object judge needs \
                         a world model that predicts them",
                        start.objects.len()
                    ))));
                }
            },
            _ => (stop.judge)(&f.rgb),
        };
        if verdict.is_none() {
            streak = if p >= stop.threshold { streak + 1 } else { 0 };
            frames.push(f.rgb.clone());
            if streak >= stop.done_frames {
                verdict = Some((p, true));
            } else if t == last {
                verdict = Some((p, false));
            }
        }
        if leak_at == Some(t) {
            leak = Some(match stop.objects {
                Some(_) => (stop.judge)(&f.rgb),
                None => p,
            });
        }
        seen_rgb = f.rgb;
        seen_views = f.views;
    }
    let (p_success, done_by_judge) = match (verdict, stop.objects) {
        (Some(v), _) => v,
        // A budget of one frame: nothing was imagined; the judge reads the real first frame.
        (None, Some(judge)) => (judge(&start.state, &start.objects), false),
        (None, None) => ((stop.judge)(&start.rgb), false),
    };
    if stop.leak_at.is_some() && leak.is_none() {
        leak = Some(frames.last().map_or(p_success, |f| (stop.judge)(f)));
    }
    Ok(ClosedLoop {
        frames,
        p_success,
        done_by_judge,
        leak,
    })
}

#[derive(Debug, thiserror::Error)]
pub enum ImaginationError {
    #[error("imagined step {0}: {1}")]
    Policy(usize, PolicyError),
    #[error("{0}")]
    World(#[from] WorldError),
}

#[cfg(test)]
mod tests {
    use super::sheet_png;

    fn decode(png_bytes: &[u8]) -> (u32, u32, Vec<u8>) {
        let mut reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        (info.width, info.height, buf)
    }

    #[test]
    fn a_sheet_lays_frames_out_in_rows_and_pads_short_rows_with_black() {
        // 2×1 frames: a red and a green one in the first row, one blue frame in the second.
        let red = [255, 0, 0, 255, 0, 0];
        let green = [0, 255, 0, 0, 255, 0];
        let blue = [0, 0, 255, 0, 0, 255];
        let rows = vec![vec![&red[..], &green[..]], vec![&blue[..]]];
        let (w, h, rgb) = decode(&sheet_png(&rows, 2, 1));
        assert_eq!((w, h), (4, 2));
        let mut want = Vec::new();
        want.extend(red);
        want.extend(green);
        want.extend(blue);
        want.extend([0; 6]);
        assert_eq!(rgb, want);
        // One frame alone is that frame.
        let (w, h, rgb) = decode(&sheet_png(&[vec![&green[..]]], 2, 1));
        assert_eq!((w, h, rgb), (2, 1, green.to_vec()));
    }
}
