//! A world model the proxy imagines in, whatever it is: Assay's RSSM in the trainer, or any
//! lab's model behind the `assay.v1.WorldModel` gRPC service (`proto/assay/v1/world_model.proto`;
//! the client is `assay_policy::world_model`). One imagined episode is a session: reset with
//! the first real frame, the state and the instruction, then stepped with chunks of actions,
//! each answered with the next frames (and, when the model predicts it, the next state).

use thiserror::Error;

/// The start of one imagined episode.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldStart {
    pub task_id: String,
    pub seed: u64,
    pub instruction: String,
    /// Frame size the proxy works at; every frame the model answers must have it.
    pub width: u32,
    pub height: u32,
    /// The real first frame: `height · width · 3` RGB bytes, row-major, top row first.
    pub rgb: Vec<u8>,
    /// The real first state (the clip's proprioception: tool x, y, z, holding).
    pub state: Vec<f32>,
}

/// One imagined step: the frame after an action and, when the model predicts it, the state.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldFrame {
    pub rgb: Vec<u8>,
    pub state: Option<Vec<f32>>,
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
}
