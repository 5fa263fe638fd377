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

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::policy::{EpisodeContext, Policy, PolicyError, PolicyObservation};
use assay_model::world::{WorldError, WorldModelService, WorldStart};

/// The start of `clip`'s episode: its first frame and state, nothing after.
pub fn start_of(clip: &Clip, episode: &EpisodeContext) -> WorldStart {
    let frame = (clip.width * clip.height * 3) as usize;
    WorldStart {
        task_id: episode.task_id.clone(),
        seed: episode.seed,
        instruction: episode.instruction.clone(),
        width: clip.width,
        height: clip.height,
        rgb: clip.rgb[..frame].to_vec(),
        state: clip.proprio[..clip.proprio_dims as usize].to_vec(),
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
    let mut episode = world.reset(start)?;
    let frames = episode.step(actions)?;
    check_frames(&frames, actions.len(), start)?;
    Ok(frames.into_iter().map(|f| f.rgb).collect())
}

fn check_frames(
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
    Ok(())
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

/// What to stop a closed-loop rollout on.
pub struct Stop<'a> {
    /// Clip frames at most, the first (real) one included: the task's step budget.
    pub horizon: usize,
    /// The frame judge's probability that a frame shows the task done.
    pub judge: &'a dyn Fn(&[u8]) -> f64,
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
/// the frame and state the model gave last (the real ones first) and its actions drive the next
/// steps, one chunk at a time, until `stop` says so. A model that predicts no state hands the
/// policy the last state it had.
pub fn closed_loop(
    world: &dyn WorldModelService,
    start: &WorldStart,
    policy: &mut dyn Policy,
    episode: &EpisodeContext,
    stop: &Stop<'_>,
) -> Result<ClosedLoop, ImaginationError> {
    if start.state.len() != PROPRIO_DIMS {
        return Err(ImaginationError::World(WorldError::Refused(format!(
            "a start state of {} values, a policy in the world model is shown {PROPRIO_DIMS}",
            start.state.len()
        ))));
    }
    policy
        .reset(episode)
        .map_err(|e| ImaginationError::Policy(0, e))?;
    let mut world_episode = world.reset(start)?;
    let mut seen = (start.rgb.clone(), start.state.clone());
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
            let mut proprio = [0f32; PROPRIO_DIMS];
            proprio.copy_from_slice(&seen.1);
            let obs = PolicyObservation::legacy(
                t as u32,
                start.width,
                start.height,
                seen.0.clone(),
                proprio,
            );
            let answer = policy
                .act(&obs)
                .map_err(|e| ImaginationError::Policy(t, e))?;
            if answer.is_empty() || answer.iter().flatten().any(|x| !x.is_finite()) {
                return Err(ImaginationError::Policy(
                    t,
                    PolicyError::BadAnswer("an empty or non-finite chunk".into()),
                ));
            }
            chunk.extend(answer.iter().map(|a| a.to_vec()));
        }
        let action = chunk.pop_front().expect("a non-empty chunk");
        debug_assert_eq!(action.len(), ACTION_DIMS);
        let mut next = world_episode.step(&[action])?;
        check_frames(&next, 1, start)?;
        let f = next.pop().expect("one frame");
        if let Some(state) = f.state {
            if state.len() != PROPRIO_DIMS || state.iter().any(|v| !v.is_finite()) {
                return Err(ImaginationError::World(WorldError::BadAnswer(format!(
                    "a state of {} values, {PROPRIO_DIMS} finite ones were expected",
                    state.len()
                ))));
            }
            seen.1 = state;
        }
        t += 1;
        let p = (stop.judge)(&f.rgb);
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
            leak = Some(p);
        }
        seen.0 = f.rgb;
    }
    let (p_success, done_by_judge) = match verdict {
        Some(v) => v,
        // A budget of one frame: nothing was imagined; the judge reads the real first frame.
        None => ((stop.judge)(&start.rgb), false),
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
