//! A world model the proxy imagines in, whatever it is: Assay's RSSM in the trainer, or any
//! lab's model behind the `assay.v1.WorldModel` gRPC service (`proto/assay/v1/world_model.proto`;
//! the client is `assay_policy::world_model`). One imagined episode is a session: reset with
//! the first real frame, the state and the instruction, then stepped with chunks of actions,
//! each answered with the next frames (and, when the model predicts it, the next state).

use thiserror::Error;

use crate::interface::{CameraRequest, Interface};

/// The start of one imagined episode.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldStart {
    pub task_id: String,
    pub seed: u64,
    pub instruction: String,
    /// The interface of the policy whose episode is imagined: its cameras (the first is `rgb`,
    /// the others `views`, in order; a camera of size 0 is at `width`×`height`), its state
    /// parts (`state`) and its action space (what `step` is given). The original interface
    /// (`Interface::default()`) for clips of the task camera.
    pub interface: Interface,
    /// The first camera's frame size; every frame of it the model answers must have it.
    pub width: u32,
    pub height: u32,
    /// The first camera's real first frame: `height · width · 3` RGB bytes, row-major, top row
    /// first.
    pub rgb: Vec<u8>,
    /// The real first frames of the interface's cameras after the first, in its order.
    pub views: Vec<crate::interface::NamedImage>,
    /// The real first state: the interface's state vector (the original: tool x, y, z, holding).
    pub state: Vec<f32>,
    /// The scene objects' real first positions (x, y, z each, in the scene's order; the clip's
    /// objects' section), for a model that predicts them; empty when not known. Never shown to
    /// a policy.
    pub objects: Vec<f32>,
}

impl WorldStart {
    /// The `(width, height)` of camera `i` of the interface (0: the first camera's size).
    pub fn camera_size(&self, i: usize) -> (u32, u32) {
        match self.interface.cameras.get(i) {
            Some(c) if c.width != 0 => (c.width, c.height),
            _ => (self.width, self.height),
        }
    }
}

/// One imagined step: the frame of each camera after an action and, when the model predicts
/// it, the state.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldFrame {
    /// The first camera's frame.
    pub rgb: Vec<u8>,
    /// The frames of the cameras after the first, in the interface's order.
    pub views: Vec<Vec<u8>>,
    pub state: Option<Vec<f32>>,
    /// The scene objects' positions, when the model predicts them (as [`WorldStart::objects`]).
    pub objects: Option<Vec<f32>>,
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum WorldError {
    /// The server is down, closed the call or did not answer in time.
    #[error("world model unavailable: {0}")]
    Unavailable(String),
    /// An answer that breaks the protocol (wrong frame count or size, non-finite state).
    #[error("world model gave a bad answer: {0}")]
    BadAnswer(String),
    /// The model cannot do what was asked (an action width it does not take, a frame size).
    #[error("world model refused: {0}")]
    Refused(String),
}

/// One imagined episode.
pub trait ImaginedEpisode {
    /// Runs `actions` (a chunk, each as wide as the model takes) and returns one frame per
    /// action, in order.
    fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<WorldFrame>, WorldError>;
}

/// A world model that imagines episodes.
pub trait WorldModelService {
    /// What the report calls it.
    fn name(&self) -> String;
    /// Starts an imagined episode.
    fn reset(&self, start: &WorldStart) -> Result<Box<dyn ImaginedEpisode + '_>, WorldError>;
    /// The policy interfaces the model imagines in (cameras by source and size, state parts,
    /// action space); a policy at another cannot be ranked in it ([`check_policy_interface`]).
    /// Cameras of size 0 are at the frame size the proxy works at. The default: the original
    /// interface (one scene camera, tool position + holding, 4-float tool velocities).
    fn interfaces(&self) -> Vec<Interface> {
        vec![Interface::default()]
    }
    /// Open-loop runs, each a start and its actions: per run, the frames after its actions, as
    /// [`reset`](Self::reset) then [`ImaginedEpisode::step`] answer them. The default imagines
    /// the runs one after another; a model that imagines several at once answers the same, up to
    /// floating-point rounding, in less time.
    fn replay_many(
        &self,
        runs: &[(&WorldStart, &[Vec<f32>])],
    ) -> Result<Vec<Vec<WorldFrame>>, WorldError> {
        runs.iter()
            .map(|(start, actions)| self.reset(start)?.step(actions))
            .collect()
    }
}

/// Whether a policy at `policy_interface` can act inside a world model that imagines in
/// `accepted` (cameras of size 0 at `frame` pixels on either side): an `Err` names the model,
/// the policy and the field that differs from the closest accepted interface. Camera names are
/// the policy's own and are not compared; their sources and sizes are, and depth cannot be
/// imagined. The execution horizon is the policy's business.
pub fn check_policy_interface(
    model: &str,
    accepted: &[Interface],
    frame: u32,
    policy: &str,
    policy_interface: &Interface,
) -> Result<(), String> {
    let refuse = |field: String| {
        Err(format!(
            "world model '{model}' cannot imagine policy '{policy}': {field}"
        ))
    };
    if accepted.is_empty() {
        return refuse("interface: the model declares no interface a policy could act in".into());
    }
    let size = |c: &CameraRequest| {
        if c.width == 0 {
            (frame, frame)
        } else {
            (c.width, c.height)
        }
    };
    let camera = |c: &CameraRequest| {
        let (w, h) = size(c);
        format!("{} {w}x{h}", c.source.name())
    };
    let cameras = |i: &Interface| i.cameras.iter().map(camera).collect::<Vec<_>>().join(", ");
    let parts = |i: &Interface| {
        i.state
            .iter()
            .map(|p| p.name())
            .collect::<Vec<_>>()
            .join("+")
    };
    let p = policy_interface;
    // The first difference from each accepted interface; the closest is the one whose first
    // difference comes latest (action space, then state, then cameras).
    let mut best: Option<(usize, String)> = None;
    for a in accepted {
        let diff = if p.action != a.action {
            Some((
                0,
                format!(
                    "action_space: the policy answers in {}, the model takes {}",
                    p.action, a.action
                ),
            ))
        } else if p.state != a.state {
            Some((
                1,
                format!(
                    "state: the policy reads {}, the model predicts {}",
                    parts(p),
                    parts(a)
                ),
            ))
        } else if let Some((i, c)) = p.cameras.iter().enumerate().find(|(_, c)| c.depth) {
            Some((
                2,
                format!(
                    "cameras[{i}] '{}': the policy asks for depth, which no world model imagines",
                    c.name
                ),
            ))
        } else if p.cameras.len() != a.cameras.len()
            || p.cameras
                .iter()
                .zip(&a.cameras)
                .any(|(x, y)| x.source != y.source || size(x) != size(y))
        {
            Some((
                2,
                format!(
                    "cameras: the policy looks through {}, the model imagines {}",
                    cameras(p),
                    cameras(a)
                ),
            ))
        } else {
            None
        };
        match diff {
            None => return Ok(()),
            Some(d) if best.as_ref().is_none_or(|b| d.0 > b.0) => best = Some(d),
            Some(_) => {}
        }
    }
    refuse(best.expect("at least one accepted interface").1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn iface(args: &[(&str, &str)]) -> Interface {
        Interface::from_args(args).unwrap().unwrap_or_default()
    }

    #[test]
    fn a_policy_interface_is_checked_against_the_model_s_naming_the_field() {
        let legacy = [Interface::default()];
        // The original interface, at any name of its camera and at the proxy's frame size.
        let ok = check_policy_interface("m", &legacy, 64, "p", &iface(&[]));
        assert_eq!(ok, Ok(()));
        let renamed = iface(&[("cameras", "rgb:scene@64")]);
        assert_eq!(
            check_policy_interface("m", &legacy, 64, "p", &renamed),
            Ok(())
        );
        let big = iface(&[("cameras", "image:scene@224")]);
        let e = check_policy_interface("m", &legacy, 64, "p", &big).unwrap_err();
        assert!(
            e.contains("world model 'm' cannot imagine policy 'p': cameras:")
                && e.contains("scene 224x224")
                && e.contains("scene 64x64"),
            "{e}"
        );
        let seven = iface(&[
            ("space", "ee_delta"),
            ("cameras", "image:scene@224+wrist_image:wrist@224"),
            ("state", "ee_pos+ee_quat+gripper"),
        ]);
        let e = check_policy_interface("m", &legacy, 64, "p", &seven).unwrap_err();
        assert!(
            e.contains(
                "action_space: the policy answers in ee_delta, the model takes tool_velocity"
            ),
            "{e}"
        );
        // A model that declares the policy's interface takes it; the closest of several names
        // the field that differs.
        assert_eq!(
            check_policy_interface("m", &[Interface::default(), seven.clone()], 64, "p", &seven),
            Ok(())
        );
        let mut other_state = seven.clone();
        other_state.state.pop();
        let e = check_policy_interface(
            "m",
            &[Interface::default(), seven.clone()],
            64,
            "p",
            &other_state,
        )
        .unwrap_err();
        assert!(
            e.contains(
                "state: the policy reads ee_pos+ee_quat, the model predicts ee_pos+ee_quat+gripper"
            ),
            "{e}"
        );
        let depth = iface(&[("depth", "image")]);
        let e = check_policy_interface("m", &legacy, 64, "p", &depth).unwrap_err();
        assert!(
            e.contains("cameras[0] 'image': the policy asks for depth"),
            "{e}"
        );
        let e = check_policy_interface("m", &[], 64, "p", &iface(&[])).unwrap_err();
        assert!(e.contains("declares no interface"), "{e}");
    }
}
