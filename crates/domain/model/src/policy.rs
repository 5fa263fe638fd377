//! Policies: the names batches give them (`oracle`, `oracle:noise=0.01`,
//! `torchscript:path=/models/bc.pt`, `remote:url=http://10.0.0.7:50070`,
//! `diffusion:model=<artifact key>`) and the one interface every learned or served policy
//! implements ([`Policy`]: an observation in, a chunk of actions out).
//!
//! The scripted oracle runs inside the simulator (it reads the plan of the task spec). Every
//! other policy is closed-loop at the control rate of the dynamics clips
//! ([`CONTROL_STRIDE_STEPS`] physics steps, 10 Hz at the default 240 Hz): it sees the task
//! camera's RGB frame at the clip size and the robot's proprioception, and answers with actions
//! in the clips' action space, so a policy trained on clips acts in the same units it learned.

use crate::clip::{ACTION_DIMS, CLIP_STRIDE_STEPS, PROPRIO_DIMS};

/// A policy the cluster knows how to run.
#[derive(Debug, Clone, PartialEq)]
pub enum PolicySpec {
    /// The task's scripted oracle plan, with uniform noise (± m) added to every target in x and y,
    /// locating objects either from the simulator's state or from what a camera sees.
    Oracle { noise: f64, sense: Sense },
    /// A TorchScript module (`torch.jit.save`) at `path` on the worker, run with libtorch; its
    /// calling convention is documented in `docs/policies.md`.
    TorchScript { path: String },
    /// A policy served elsewhere over the `assay.v1.Policy` gRPC service (`proto/assay/v1/policy.proto`).
    Remote {
        url: String,
        /// Deadline of one `Act` call; a slower answer fails the episode.
        timeout_ms: u64,
    },
    /// A diffusion policy trained by the cluster's trainer role: its checkpoint's key in the
    /// artifact store (or a path on the worker).
    Diffusion { model: String },
}

/// Physics steps between two observations of a learned policy: the dynamics clips' stride, so
/// policies act at the rate of the data they learn from (10 Hz at the default 240 Hz).
pub const CONTROL_STRIDE_STEPS: u64 = CLIP_STRIDE_STEPS;

/// One action in the clips' action space: the tool's velocity x, y, z (m/s) until the next
/// control step and the hold command (≥ 0.5: hold an object, grasping one if none is held).
pub type Action = [f32; ACTION_DIMS];

/// What a learned policy sees at one control step.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyObservation {
    /// Control step from the first action of the episode (0, 1, …).
    pub step: u32,
    /// Frame size (the batch's clip size, 64 by default).
    pub width: u32,
    pub height: u32,
    /// `height · width · 3` bytes of RGB from the task's first camera (else the top view), top row
    /// first — the frames of the dynamics clips.
    pub rgb: Vec<u8>,
    /// Tool position x, y, z (m) and 1 while it holds an object, else 0.
    pub proprio: [f32; PROPRIO_DIMS],
}

/// The episode a policy is about to act in.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeContext {
    pub task_id: String,
    pub seed: u64,
    /// The task's instruction (its description).
    pub instruction: String,
}

/// Why a policy could not act. Every variant fails the episode with its message; whether running
/// it again could help decides whether the shard is retried.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PolicyError {
    /// The policy could not be reached or answered too late (a remote server down or slow).
    #[error("policy unavailable: {0}")]
    Unavailable(String),
    /// The policy answered with something that is not a chunk of actions.
    #[error("policy gave a bad answer: {0}")]
    BadAnswer(String),
    /// The policy cannot be built (missing file, wrong format, unknown model).
    #[error("policy cannot be loaded: {0}")]
    Load(String),
}

impl PolicyError {
    pub fn retryable(&self) -> bool {
        matches!(self, PolicyError::Unavailable(_))
    }
}

/// A closed-loop policy: observation in, a chunk of one or more actions out. The simulator runs
/// every action of a chunk (one per control step) before it asks again, so a policy with a
/// receding horizon returns only the part of its prediction it wants executed.
pub trait Policy: Send {
    /// Called before the first observation of every episode.
    fn reset(&mut self, episode: &EpisodeContext) -> Result<(), PolicyError>;
    /// The actions to take from `obs` on.
    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError>;
    /// The side of the square frames the policy wants (None: any; the simulator then draws the
    /// clips' 64).
    fn frame_size(&self) -> Option<u32> {
        None
    }
}

/// Where a policy learns where things are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sense {
    /// The simulator's true object poses (privileged state).
    State,
    /// Depth and segmentation from the top-down camera, rendered every
    /// [`OBSERVE_EVERY_STEPS`] physics steps while the policy acts: a closed-loop policy that
    /// needs the render role on its worker.
    Camera,
}

/// A seeing policy's observation rate: every 8 physics steps, 30 Hz at the default 240 Hz.
pub const OBSERVE_EVERY_STEPS: u64 = 8;
/// Size of a seeing policy's camera images.
pub const OBSERVATION_SIZE: (u32, u32) = (320, 240);

/// The camera a seeing policy looks through: the top-down scene view at [`OBSERVATION_SIZE`].
pub fn observation_camera() -> assay_spec::spec::Camera {
    let (width, height) = OBSERVATION_SIZE;
    assay_spec::spec::Camera {
        width,
        height,
        ..assay_spec::scene::scene_views().remove(0)
    }
}

/// Kinds of policy this release runs.
pub const KNOWN_POLICIES: &[&str] = &["oracle", "torchscript", "remote", "diffusion"];

/// Default deadline of a remote policy's `Act` call.
pub const DEFAULT_REMOTE_TIMEOUT_MS: u64 = 5000;

impl PolicySpec {
    pub fn parse(name: &str) -> Result<PolicySpec, String> {
        Self::parse_with_horizon(name).map(|(spec, _)| spec)
    }

    /// [`PolicySpec::parse`], with the episode horizon a policy object may be given
    /// (`max_steps=N` physics steps, any kind but the oracle, whose plan ends by itself): its
    /// episodes end there, or at the task's `physics.max_steps` if that comes first.
    pub fn parse_with_horizon(name: &str) -> Result<(PolicySpec, Option<u32>), String> {
        let (kind, args) = name.split_once(':').unwrap_or((name, ""));
        if !KNOWN_POLICIES.contains(&kind) {
            return Err(format!(
                "unknown policy '{kind}' (known: {})",
                KNOWN_POLICIES.join(", ")
            ));
        }
        let args: Vec<(&str, &str)> = args
            .split(',')
            .filter(|a| !a.is_empty())
            .map(|arg| {
                arg.split_once('=')
                    .ok_or_else(|| format!("policy '{name}': argument '{arg}' is not key=value"))
            })
            .collect::<Result<_, _>>()?;
        let mut horizon = None;
        let args: Vec<(&str, &str)> = if kind == "oracle" {
            args
        } else {
            let mut rest = Vec::with_capacity(args.len());
            for (k, v) in args {
                if k == "max_steps" {
                    match v.parse::<u32>() {
                        Ok(n) if n > 0 => horizon = Some(n),
                        _ => {
                            return Err(format!(
                                "policy '{name}': bad max_steps '{v}' (physics steps, > 0)"
                            ));
                        }
                    }
                } else {
                    rest.push((k, v));
                }
            }
            rest
        };
        let bad = |arg: &(&str, &str), expected: &str| {
            format!(
                "policy '{name}': bad argument '{}={}' (expected {expected})",
                arg.0, arg.1
            )
        };
        let required = |value: Option<String>, key: &str| {
            value.ok_or_else(|| format!("policy '{name}': missing {key}=..."))
        };
        let spec = match kind {
            "oracle" => {
                let mut noise = 0.0;
                let mut sense = Sense::State;
                for arg in &args {
                    match *arg {
                        ("noise", v) => match v.parse::<f64>() {
                            Ok(v) if v.is_finite() && v >= 0.0 => noise = v,
                            _ => {
                                return Err(format!(
                                    "policy '{name}': bad noise '{v}' (metres, ≥ 0)"
                                ));
                            }
                        },
                        ("sense", "state") => sense = Sense::State,
                        ("sense", "camera") => sense = Sense::Camera,
                        _ => {
                            return Err(bad(arg, "noise=<metres> or sense=state|camera"));
                        }
                    }
                }
                PolicySpec::Oracle { noise, sense }
            }
            "torchscript" => {
                let mut path = None;
                for arg in &args {
                    match *arg {
                        ("path", v) if !v.is_empty() => path = Some(v.to_owned()),
                        _ => return Err(bad(arg, "path=<file.pt>")),
                    }
                }
                PolicySpec::TorchScript {
                    path: required(path, "path")?,
                }
            }
            "remote" => {
                let mut url = None;
                let mut timeout_ms = DEFAULT_REMOTE_TIMEOUT_MS;
                for arg in &args {
                    match *arg {
                        ("url", v) if v.starts_with("http://") || v.starts_with("https://") => {
                            url = Some(v.to_owned())
                        }
                        ("timeout_ms", v) => match v.parse::<u64>() {
                            Ok(v) if v > 0 => timeout_ms = v,
                            _ => return Err(bad(arg, "timeout_ms=<milliseconds, > 0>")),
                        },
                        _ => return Err(bad(arg, "url=http(s)://host:port or timeout_ms=<ms>")),
                    }
                }
                PolicySpec::Remote {
                    url: required(url, "url")?,
                    timeout_ms,
                }
            }
            _ => {
                let mut model = None;
                for arg in &args {
                    match *arg {
                        ("model", v) if !v.is_empty() => model = Some(v.to_owned()),
                        _ => return Err(bad(arg, "model=<artifact key or path>")),
                    }
                }
                PolicySpec::Diffusion {
                    model: required(model, "model")?,
                }
            }
        };
        Ok((spec, horizon))
    }

    /// Whether the policy is the simulator's scripted oracle (every other kind acts through
    /// [`Policy`]).
    pub fn is_oracle(&self) -> bool {
        matches!(self, PolicySpec::Oracle { .. })
    }

    /// Whether episodes of this policy need camera frames while they run.
    pub fn sees(&self) -> bool {
        matches!(
            self,
            PolicySpec::Oracle {
                sense: Sense::Camera,
                ..
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_known_policies_and_rejects_the_rest() {
        assert_eq!(
            PolicySpec::parse("oracle"),
            Ok(PolicySpec::Oracle {
                noise: 0.0,
                sense: Sense::State
            })
        );
        assert_eq!(
            PolicySpec::parse("oracle:noise=0.02"),
            Ok(PolicySpec::Oracle {
                noise: 0.02,
                sense: Sense::State
            })
        );
        let seeing = PolicySpec::parse("oracle:sense=camera,noise=0.01").unwrap();
        assert!(seeing.sees());
        assert!(PolicySpec::parse("oracle:sense=lidar").is_err());
        assert!(
            PolicySpec::parse("bc:path=x")
                .unwrap_err()
                .contains("unknown policy")
        );
        assert!(
            PolicySpec::parse("diffusion")
                .unwrap_err()
                .contains("missing model")
        );
        assert_eq!(
            PolicySpec::parse("diffusion:model=policies/abc.ckpt"),
            Ok(PolicySpec::Diffusion {
                model: "policies/abc.ckpt".into()
            })
        );
        assert_eq!(
            PolicySpec::parse("torchscript:path=/m/bc.pt"),
            Ok(PolicySpec::TorchScript {
                path: "/m/bc.pt".into()
            })
        );
        assert_eq!(
            PolicySpec::parse("remote:url=http://127.0.0.1:50070,timeout_ms=250"),
            Ok(PolicySpec::Remote {
                url: "http://127.0.0.1:50070".into(),
                timeout_ms: 250
            })
        );
        assert!(PolicySpec::parse("remote:url=127.0.0.1:1").is_err());
        assert!(PolicySpec::parse("remote:url=http://h:1,timeout_ms=0").is_err());
        assert!(PolicySpec::parse("oracle:noise").is_err());
        // A policy object's horizon; the oracle's plan has its own end.
        assert_eq!(
            PolicySpec::parse_with_horizon("diffusion:model=m,max_steps=6000"),
            Ok((PolicySpec::Diffusion { model: "m".into() }, Some(6000)))
        );
        assert_eq!(
            PolicySpec::parse_with_horizon("remote:url=http://h:1").map(|p| p.1),
            Ok(None)
        );
        assert!(PolicySpec::parse("torchscript:path=p,max_steps=0").is_err());
        assert!(PolicySpec::parse("oracle:max_steps=100").is_err());
        assert!(PolicySpec::parse("oracle:noise=-1").is_err());
        assert!(PolicySpec::parse("oracle:speed=2").is_err());
    }
}
