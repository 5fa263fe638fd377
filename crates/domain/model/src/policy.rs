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
pub use crate::interface::{
    ActionSpace, CameraRequest, CameraSource, Interface, NamedImage, StatePart,
};

/// A policy the cluster knows how to run.
#[derive(Debug, Clone, PartialEq)]
pub enum PolicySpec {
    /// The task's scripted oracle plan, with uniform noise (± m) added to every target in x and y,
    /// locating objects either from the simulator's state or from what a camera sees. `grasp`:
    /// the chance (drawn once per episode) that its grasps close; in an episode drawn not to, the
    /// tool goes through the plan's motions open and nothing is held (a failure whose actions
    /// differ from a success's only in the hold command: data that teaches a world model what
    /// holding does).
    Oracle {
        noise: f64,
        sense: Sense,
        grasp: f64,
    },
    /// A TorchScript module (`torch.jit.save`) at `path` on the worker, run with libtorch; its
    /// calling convention is documented in `docs/policies.md`. `interface`: the one its spec's
    /// arguments declare (None: the original one).
    TorchScript {
        path: String,
        interface: Option<Interface>,
    },
    /// A policy served elsewhere over the `assay.v1.Policy` gRPC service (`proto/assay/v1/policy.proto`).
    Remote {
        url: String,
        /// Deadline of one `Act` call; a slower answer fails the episode.
        timeout_ms: u64,
        /// The interface the spec declares; None: the one the server's `Health` declares.
        interface: Option<Interface>,
    },
    /// A policy served over openpi's websocket + msgpack-numpy protocol (`ws://HOST:PORT`), as
    /// openpi's `serve_policy.py` and RoboArena servers speak it.
    OpenPi {
        url: String,
        timeout_ms: u64,
        /// The environment variable on the worker that holds the server's API key (sent as
        /// `Authorization: Api-Key …`); the key itself never appears in a policy name.
        api_key_env: Option<String>,
        interface: Interface,
    },
    /// A diffusion policy trained by the cluster's trainer role: its checkpoint's key in the
    /// artifact store (or a path on the worker).
    Diffusion { model: String },
    /// Exploration ("play") episodes to train world models on: the tool wanders at up to
    /// `speed` m/s per axis and the gripper flips with probability `hold` per chunk
    /// (`assay_policy::random`).
    Random { speed: f64, hold: f64 },
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
    /// Every camera of the policy's [`Interface`], in its order (the first is also `rgb`).
    pub images: Vec<NamedImage>,
    /// The state vector of the policy's interface (for the original one: `proprio`).
    pub state: Vec<f32>,
}

impl PolicyObservation {
    /// An observation of the original interface: one frame and the 4 floats of proprio.
    pub fn legacy(step: u32, width: u32, height: u32, rgb: Vec<u8>, proprio: [f32; 4]) -> Self {
        PolicyObservation {
            step,
            width,
            height,
            images: vec![NamedImage {
                name: "image".into(),
                width,
                height,
                rgb: rgb.clone(),
                depth: Vec::new(),
            }],
            rgb,
            state: proprio.to_vec(),
            proprio,
        }
    }
}

/// The episode a policy is about to act in.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeContext {
    pub task_id: String,
    pub seed: u64,
    /// The task's instruction (its description).
    pub instruction: String,
    /// The task's arm model, if it has one (`ur5`, `panda`).
    pub arm: Option<String>,
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
    /// The actions to take from `obs` on, in the original 4-float space.
    fn act(&mut self, obs: &PolicyObservation) -> Result<Vec<Action>, PolicyError> {
        let _ = obs;
        Err(PolicyError::BadAnswer(
            "this policy answers only in its own action space (act_any)".into(),
        ))
    }
    /// The actions to take from `obs` on, each `self.interface().action`'s floats. The default
    /// is [`Policy::act`] for a policy of the original interface.
    fn act_any(&mut self, obs: &PolicyObservation) -> Result<Vec<Vec<f32>>, PolicyError> {
        Ok(self.act(obs)?.into_iter().map(|a| a.to_vec()).collect())
    }
    /// The side of the square frames the policy wants (None: any; the simulator then draws the
    /// clips' 64).
    fn frame_size(&self) -> Option<u32> {
        None
    }
    /// What the policy sees and how it acts; the default is the original interface at
    /// [`Policy::frame_size`].
    fn interface(&self) -> Interface {
        Interface::legacy(self.frame_size().unwrap_or(0))
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
pub const KNOWN_POLICIES: &[&str] = &[
    "oracle",
    "torchscript",
    "remote",
    "openpi",
    "diffusion",
    "random",
];

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
        // The interface arguments of a policy that declares its own.
        let interface = if matches!(kind, "torchscript" | "remote" | "openpi") {
            Interface::from_args(&args).map_err(|e| format!("policy '{name}': {e}"))?
        } else {
            None
        };
        let args: Vec<(&str, &str)> = if interface.is_some() || kind == "openpi" {
            args.into_iter()
                .filter(|(k, _)| !Interface::ARGS.contains(k))
                .collect()
        } else {
            args
        };
        let spec = match kind {
            "oracle" => {
                let mut noise = 0.0;
                let mut sense = Sense::State;
                let mut grasp = 1.0;
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
                        ("grasp", v) => match v.parse::<f64>() {
                            Ok(v) if (0.0..=1.0).contains(&v) => grasp = v,
                            _ => {
                                return Err(format!(
                                    "policy '{name}': bad grasp '{v}' (a chance, 0 to 1)"
                                ));
                            }
                        },
                        ("sense", "state") => sense = Sense::State,
                        ("sense", "camera") => sense = Sense::Camera,
                        _ => {
                            return Err(bad(
                                arg,
                                "noise=<metres>, grasp=<chance> or sense=state|camera",
                            ));
                        }
                    }
                }
                PolicySpec::Oracle {
                    noise,
                    sense,
                    grasp,
                }
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
                    interface,
                }
            }
            "openpi" => {
                let mut url = None;
                let mut timeout_ms = DEFAULT_REMOTE_TIMEOUT_MS;
                let mut api_key_env = None;
                for arg in &args {
                    match *arg {
                        ("url", v) if v.starts_with("ws://") || v.starts_with("wss://") => {
                            url = Some(v.to_owned())
                        }
                        ("timeout_ms", v) => match v.parse::<u64>() {
                            Ok(v) if v > 0 => timeout_ms = v,
                            _ => return Err(bad(arg, "timeout_ms=<milliseconds, > 0>")),
                        },
                        ("api_key_env", v)
                            if !v.is_empty()
                                && v.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') =>
                        {
                            api_key_env = Some(v.to_owned())
                        }
                        _ => {
                            return Err(bad(
                                arg,
                                "url=ws://host:port, timeout_ms=<ms>, api_key_env=<VARIABLE>, \
                                 space=, cameras=, state=, depth= or horizon=",
                            ));
                        }
                    }
                }
                PolicySpec::OpenPi {
                    url: required(url, "url")?,
                    timeout_ms,
                    api_key_env,
                    interface: interface.unwrap_or_default(),
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
                    interface,
                }
            }
            "random" => {
                let (mut speed, mut hold) = (0.2, 0.1);
                for arg in &args {
                    let value = arg.1.parse::<f64>().ok().filter(|v| v.is_finite());
                    match (arg.0, value) {
                        ("speed", Some(v)) if v > 0.0 && v <= 2.0 => speed = v,
                        ("hold", Some(v)) if (0.0..=1.0).contains(&v) => hold = v,
                        _ => {
                            return Err(bad(
                                arg,
                                "speed=<m/s, in (0, 2]> or hold=<probability per chunk>",
                            ));
                        }
                    }
                }
                PolicySpec::Random { speed, hold }
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

    /// The interface the spec itself declares (openpi always; TorchScript and remote policies
    /// when given interface arguments): checkable against tasks before anything runs.
    pub fn declared_interface(&self) -> Option<&Interface> {
        match self {
            PolicySpec::OpenPi { interface, .. } => Some(interface),
            PolicySpec::TorchScript { interface, .. } | PolicySpec::Remote { interface, .. } => {
                interface.as_ref()
            }
            _ => None,
        }
    }

    /// Whether the policy is the simulator's scripted oracle (every other kind acts through
    /// [`Policy`]).
    pub fn is_oracle(&self) -> bool {
        matches!(self, PolicySpec::Oracle { .. })
    }

    /// Whether an episode of this policy may need a renderer beside its simulator while it runs
    /// (camera frames in the loop): the oracle that senses with a camera, diffusion policies, and
    /// every served or TorchScript policy unless its spec declares an interface without cameras
    /// (a server that declares its interface only in `Health` may see, so it counts as seeing).
    /// The coordinator leases such an episode only to a worker with both roles.
    pub fn renders_in_loop(&self) -> bool {
        match self {
            PolicySpec::Oracle { .. } => self.sees(),
            PolicySpec::Random { .. } => false,
            PolicySpec::Diffusion { .. } => true,
            PolicySpec::OpenPi { interface, .. } => !interface.cameras.is_empty(),
            PolicySpec::TorchScript { interface, .. } | PolicySpec::Remote { interface, .. } => {
                interface.as_ref().is_none_or(|i| !i.cameras.is_empty())
            }
        }
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
                sense: Sense::State,
                grasp: 1.0
            })
        );
        assert_eq!(
            PolicySpec::parse("oracle:noise=0.02"),
            Ok(PolicySpec::Oracle {
                noise: 0.02,
                sense: Sense::State,
                grasp: 1.0
            })
        );
        assert_eq!(
            PolicySpec::parse("oracle:grasp=0.5"),
            Ok(PolicySpec::Oracle {
                noise: 0.0,
                sense: Sense::State,
                grasp: 0.5
            })
        );
        assert!(PolicySpec::parse("oracle:grasp=1.5").is_err());
        assert!(PolicySpec::parse("oracle:grasp=-0.1").is_err());
        assert!(PolicySpec::parse("oracle:grasp=nan").is_err());
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
            PolicySpec::parse("random:speed=0.3,hold=0.2,max_steps=1200"),
            Ok(PolicySpec::Random {
                speed: 0.3,
                hold: 0.2
            })
        );
        assert!(PolicySpec::parse("random:speed=-1").is_err());
        assert_eq!(
            PolicySpec::parse("diffusion:model=policies/abc.ckpt"),
            Ok(PolicySpec::Diffusion {
                model: "policies/abc.ckpt".into()
            })
        );
        assert_eq!(
            PolicySpec::parse("torchscript:path=/m/bc.pt"),
            Ok(PolicySpec::TorchScript {
                path: "/m/bc.pt".into(),
                interface: None
            })
        );
        assert_eq!(
            PolicySpec::parse("remote:url=http://127.0.0.1:50070,timeout_ms=250"),
            Ok(PolicySpec::Remote {
                url: "http://127.0.0.1:50070".into(),
                timeout_ms: 250,
                interface: None
            })
        );
        // openpi servers, with the interface they are fed in.
        let PolicySpec::OpenPi {
            url,
            api_key_env,
            interface,
            ..
        } = PolicySpec::parse(
            "openpi:url=ws://10.0.0.7:8000,api_key_env=PI_KEY,space=ee_delta,cameras=image@224+wrist_image:wrist@224,horizon=5",
        )
        .unwrap()
        else {
            panic!("not openpi")
        };
        assert_eq!(url, "ws://10.0.0.7:8000");
        assert_eq!(api_key_env.as_deref(), Some("PI_KEY"));
        assert_eq!(interface.action, ActionSpace::EeDelta);
        assert_eq!(interface.cameras.len(), 2);
        assert_eq!(interface.execute, Some(5));
        assert!(PolicySpec::parse("openpi:url=http://h:1").is_err());
        assert!(PolicySpec::parse("openpi:url=ws://h:1,api_key=secret").is_err());
        assert!(
            PolicySpec::parse("openpi:url=ws://h:1,space=joints")
                .unwrap_err()
                .contains("unknown action space")
        );
        // The original interface when none is declared.
        assert_eq!(
            PolicySpec::parse("openpi:url=ws://h:1"),
            Ok(PolicySpec::OpenPi {
                url: "ws://h:1".into(),
                timeout_ms: DEFAULT_REMOTE_TIMEOUT_MS,
                api_key_env: None,
                interface: Interface::default()
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
