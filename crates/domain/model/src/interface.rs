//! What a policy sees and how it acts: the observation contract (named cameras, a state vector
//! built from named parts) and the action space it answers in. A policy declares its
//! [`Interface`] (a remote server in `Health`, any policy in its spec's arguments); Assay fills
//! the contract and runs the actions. The default is the original interface every policy had
//! before (one camera, 4 floats of proprio, 4-float tool-velocity actions), so nothing that
//! worked before changes. `docs/policies.md` gives every part with an example.

use std::fmt;

/// Joints of the built-in arms, root to flange.
pub fn arm_joint_count(model: &str) -> Option<usize> {
    match model {
        "ur5" => Some(6),
        "panda" => Some(7),
        _ => None,
    }
}

/// The action space a policy answers in. The last float of every action is the gripper:
/// ≥ 0.5 closes it (holding an object, grasping one under the tool if none is held), < 0.5
/// opens it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ActionSpace {
    /// The tool's velocity x, y, z (m/s, world frame) until the next control step, gripper: 4.
    #[default]
    ToolVelocity,
    /// The tool's move over one control step (SIMPLER / Bridge): dx, dy, dz (m, world frame),
    /// droll, dpitch, dyaw (rad; the rotation `Rz(dyaw)·Ry(dpitch)·Rx(droll)` in the world frame,
    /// applied to the tool's commanded turn), gripper: 7.
    EeDelta,
    /// The tool's target pose: x, y, z (m), quaternion x, y, z, w (world frame), gripper: 8.
    EePose,
    /// The arm's joint targets (rad, root to flange), gripper: the arm's joints + 1.
    JointPosition,
}

impl ActionSpace {
    pub const NAMES: &[&str] = &["tool_velocity", "ee_delta", "ee_pose", "joint_position"];

    pub fn parse(name: &str) -> Result<ActionSpace, String> {
        Ok(match name {
            "" | "tool_velocity" => ActionSpace::ToolVelocity,
            "ee_delta" => ActionSpace::EeDelta,
            "ee_pose" => ActionSpace::EePose,
            "joint_position" => ActionSpace::JointPosition,
            _ => {
                return Err(format!(
                    "unknown action space '{name}' (known: {})",
                    Self::NAMES.join(", ")
                ));
            }
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            ActionSpace::ToolVelocity => "tool_velocity",
            ActionSpace::EeDelta => "ee_delta",
            ActionSpace::EePose => "ee_pose",
            ActionSpace::JointPosition => "joint_position",
        }
    }

    /// Floats per action; `arm` is the task's arm model (joint_position needs one).
    pub fn dims(self, arm: Option<&str>) -> Result<usize, String> {
        Ok(match self {
            ActionSpace::ToolVelocity => 4,
            ActionSpace::EeDelta => 7,
            ActionSpace::EePose => 8,
            ActionSpace::JointPosition => {
                let arm = arm.ok_or("joint_position needs a task with an arm (arm.model)")?;
                arm_joint_count(arm).ok_or_else(|| format!("unknown arm '{arm}'"))? + 1
            }
        })
    }
}

impl ActionSpace {
    /// A name per float of an action, in order (a dataset's column names; `arm` as for
    /// [`ActionSpace::dims`]). The last one is the gripper (hold) command.
    pub fn value_names(self, arm: Option<&str>) -> Result<Vec<String>, String> {
        let names: &[&str] = match self {
            ActionSpace::ToolVelocity => &["ee_vx", "ee_vy", "ee_vz", "hold"],
            ActionSpace::EeDelta => &["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"],
            ActionSpace::EePose => &["x", "y", "z", "qx", "qy", "qz", "qw", "gripper"],
            ActionSpace::JointPosition => {
                let joints = self.dims(arm)? - 1;
                let mut v: Vec<String> = (1..=joints).map(|j| format!("joint_{j}")).collect();
                v.push("gripper".into());
                return Ok(v);
            }
        };
        Ok(names.iter().map(|n| (*n).to_owned()).collect())
    }
}

impl fmt::Display for ActionSpace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One part of the state vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatePart {
    /// Tool centre x, y, z (m, world frame): 3.
    EePos,
    /// Tool orientation, quaternion x, y, z, w (world frame): 4.
    EeQuat,
    /// The tool's turn about z (rad): 1.
    EeYaw,
    /// Gripper opening, 0 closed to 1 open (suction: 0 while holding): 1.
    Gripper,
    /// The arm's joint positions (rad): 6 (UR5) or 7 (Panda).
    Joints,
    /// 1 while the tool holds an object, else 0: 1.
    Holding,
}

impl StatePart {
    pub const NAMES: &[&str] = &[
        "ee_pos", "ee_quat", "ee_yaw", "gripper", "joints", "holding",
    ];

    pub fn parse(name: &str) -> Result<StatePart, String> {
        Ok(match name {
            "ee_pos" => StatePart::EePos,
            "ee_quat" => StatePart::EeQuat,
            "ee_yaw" => StatePart::EeYaw,
            "gripper" => StatePart::Gripper,
            "joints" => StatePart::Joints,
            "holding" => StatePart::Holding,
            _ => {
                return Err(format!(
                    "unknown state part '{name}' (known: {})",
                    Self::NAMES.join(", ")
                ));
            }
        })
    }

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// A name per float of this part, in order (a dataset's column names).
    pub fn value_names(self, arm: Option<&str>) -> Result<Vec<String>, String> {
        let names: &[&str] = match self {
            StatePart::EePos => &["ee_x", "ee_y", "ee_z"],
            StatePart::EeQuat => &["ee_qx", "ee_qy", "ee_qz", "ee_qw"],
            StatePart::EeYaw => &["ee_yaw"],
            StatePart::Gripper => &["gripper"],
            StatePart::Holding => &["holding"],
            StatePart::Joints => {
                let n = self.dims(arm)?;
                return Ok((1..=n).map(|j| format!("joint_{j}")).collect());
            }
        };
        Ok(names.iter().map(|n| (*n).to_owned()).collect())
    }

    pub fn dims(self, arm: Option<&str>) -> Result<usize, String> {
        Ok(match self {
            StatePart::EePos => 3,
            StatePart::EeQuat => 4,
            StatePart::Joints => {
                let arm = arm.ok_or("state part 'joints' needs a task with an arm")?;
                arm_joint_count(arm).ok_or_else(|| format!("unknown arm '{arm}'"))?
            }
            _ => 1,
        })
    }
}

/// Where a camera looks from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraSource {
    /// The task's first camera (else the top view): the original policy camera.
    Scene,
    /// On the tool, looking straight down, turning with it.
    Wrist,
    /// A camera of the task, by name.
    Named(String),
}

impl CameraSource {
    pub fn parse(s: &str) -> CameraSource {
        match s {
            "" | "scene" => CameraSource::Scene,
            "wrist" | "ee" => CameraSource::Wrist,
            other => CameraSource::Named(other.to_owned()),
        }
    }

    pub fn name(&self) -> &str {
        match self {
            CameraSource::Scene => "scene",
            CameraSource::Wrist => "wrist",
            CameraSource::Named(n) => n,
        }
    }
}

/// One camera a policy asks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraRequest {
    /// The name the policy knows it by ("image", "wrist_image").
    pub name: String,
    pub source: CameraSource,
    /// Pixels; 0: the batch's frame size.
    pub width: u32,
    pub height: u32,
    /// Also give depth (m along the camera's axis).
    pub depth: bool,
}

/// Most cameras one policy may ask for.
pub const MAX_CAMERAS: usize = 8;
/// Largest side of a policy camera (pixels).
pub const MAX_CAMERA_SIDE: u32 = 4096;

/// What a policy sees and how it acts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Interface {
    pub cameras: Vec<CameraRequest>,
    pub state: Vec<StatePart>,
    pub action: ActionSpace,
    /// Run at most this many actions of each chunk before asking again (None: all).
    pub execute: Option<u32>,
}

impl Default for Interface {
    /// The original interface: one camera "image" (the scene camera at the batch's frame size),
    /// state = tool position + holding, tool-velocity actions.
    fn default() -> Self {
        Interface {
            cameras: vec![CameraRequest {
                name: "image".into(),
                source: CameraSource::Scene,
                width: 0,
                height: 0,
                depth: false,
            }],
            state: vec![StatePart::EePos, StatePart::Holding],
            action: ActionSpace::ToolVelocity,
            execute: None,
        }
    }
}

impl Interface {
    /// The original interface at a square frame size (0: the batch's).
    pub fn legacy(frame: u32) -> Self {
        Interface::default().sized(frame)
    }

    /// The interface with its cameras that have no size at `frame` × `frame` pixels.
    pub fn sized(mut self, frame: u32) -> Self {
        for c in self.cameras.iter_mut().filter(|c| c.width == 0) {
            (c.width, c.height) = (frame, frame);
        }
        self
    }

    /// Whether this is the original interface (any frame size).
    pub fn is_legacy(&self) -> bool {
        let d = Interface::default();
        self.action == d.action
            && self.state == d.state
            && self.execute.is_none()
            && self.cameras.len() == 1
            && self.cameras[0].source == CameraSource::Scene
            && !self.cameras[0].depth
    }

    /// Floats of the state vector for a task with arm `arm`.
    /// A name per float of the state vector, in order.
    pub fn state_names(&self, arm: Option<&str>) -> Result<Vec<String>, String> {
        let mut names = Vec::new();
        for p in &self.state {
            names.extend(p.value_names(arm)?);
        }
        Ok(names)
    }

    pub fn state_dims(&self, arm: Option<&str>) -> Result<usize, String> {
        self.state.iter().map(|p| p.dims(arm)).sum()
    }

    /// Checks the interface on its own (names, sizes); `who` names the policy in the error.
    pub fn validate(&self) -> Result<(), String> {
        if self.cameras.is_empty() {
            return Err("interface.cameras: a policy sees through at least one camera".into());
        }
        if self.cameras.len() > MAX_CAMERAS {
            return Err(format!(
                "interface.cameras: {} cameras, at most {MAX_CAMERAS}",
                self.cameras.len()
            ));
        }
        for (i, c) in self.cameras.iter().enumerate() {
            if c.name.is_empty()
                || c.name.len() > 64
                || !c
                    .name
                    .chars()
                    .all(|ch| ch.is_ascii_alphanumeric() || "_-.".contains(ch))
            {
                return Err(format!(
                    "interface.cameras[{i}].name: '{}' is not 1 to 64 letters, digits, '_', '-' or '.'",
                    c.name
                ));
            }
            if self.cameras[..i].iter().any(|o| o.name == c.name) {
                return Err(format!(
                    "interface.cameras[{i}].name: '{}' is named twice",
                    c.name
                ));
            }
            if c.width > MAX_CAMERA_SIDE
                || c.height > MAX_CAMERA_SIDE
                || (c.width == 0) != (c.height == 0)
            {
                return Err(format!(
                    "interface.cameras[{i}]: size {}×{} (each 1 to {MAX_CAMERA_SIDE}, or both 0 for the batch's)",
                    c.width, c.height
                ));
            }
        }
        if self.state.is_empty() {
            return Err("interface.state: empty (the default is ee_pos, holding)".into());
        }
        if self.execute == Some(0) {
            return Err("interface.execute_horizon: 0 (leave it out to run whole chunks)".into());
        }
        Ok(())
    }

    /// Checks the interface against a task: the arm its state and actions need. The error names
    /// the field.
    pub fn fits_task(&self, arm: Option<&str>) -> Result<(), String> {
        self.action
            .dims(arm)
            .map_err(|e| format!("action_space {}: {e}", self.action))?;
        self.state_dims(arm)
            .map_err(|e| format!("interface.state: {e}"))?;
        Ok(())
    }

    /// Checks the interface against `spec`: the arm its state and actions need, and the cameras
    /// it names (the task's own or Assay's standard views). The error names the field.
    pub fn check_task(&self, spec: &assay_spec::spec::TaskSpec) -> Result<(), String> {
        self.fits_task(spec.arm.as_ref().map(|a| a.model.as_str()))?;
        let task = assay_spec::scene::task_cameras(&spec.cameras);
        let standard = assay_spec::scene::scene_views();
        for (i, c) in self.cameras.iter().enumerate() {
            if let CameraSource::Named(n) = &c.source
                && !task.iter().chain(&standard).any(|t| &t.name == n)
            {
                let known: Vec<&str> = task
                    .iter()
                    .chain(&standard)
                    .map(|t| t.name.as_str())
                    .collect();
                return Err(format!(
                    "interface.cameras[{i}].source: the task has no camera '{n}' (its cameras and \
                     the standard views: {}; or scene, wrist)",
                    known.join(", ")
                ));
            }
        }
        Ok(())
    }

    /// Reads the interface arguments of a policy spec (`space=`, `cameras=`, `state=`,
    /// `depth=`, `horizon=`) over the default; returns None when none is given. `cameras` is
    /// `name:source@WxH` items joined by `+` (`image:scene@224+wrist_image:wrist@224`; `@W`
    /// for a square; without `@`, the batch's size), `state` parts joined by `+`, `depth` the
    /// camera names that also give depth, joined by `+`.
    pub fn from_args(args: &[(&str, &str)]) -> Result<Option<Interface>, String> {
        let mut iface = Interface::default();
        let mut any = false;
        let mut depth: Vec<&str> = Vec::new();
        for &(k, v) in args {
            match k {
                "space" => iface.action = ActionSpace::parse(v)?,
                "cameras" => {
                    iface.cameras = v.split('+').map(parse_camera).collect::<Result<_, _>>()?;
                }
                "state" => {
                    iface.state = v
                        .split('+')
                        .map(StatePart::parse)
                        .collect::<Result<_, _>>()?;
                }
                "depth" => depth = v.split('+').collect(),
                "horizon" => match v.parse::<u32>() {
                    Ok(n) if n > 0 => iface.execute = Some(n),
                    _ => return Err(format!("bad horizon '{v}' (actions per chunk, > 0)")),
                },
                _ => continue,
            }
            any = true;
        }
        for name in depth {
            let c = iface
                .cameras
                .iter_mut()
                .find(|c| c.name == name)
                .ok_or_else(|| format!("depth={name}: no camera of that name"))?;
            c.depth = true;
        }
        if any {
            iface.validate()?;
        }
        Ok(any.then_some(iface))
    }

    /// The keys [`Interface::from_args`] reads.
    pub const ARGS: &[&str] = &["space", "cameras", "state", "depth", "horizon"];

    /// The interface as policy-spec arguments (`space=ee_delta,cameras=image:scene@224x224+…,
    /// state=ee_pos+holding`), what [`Interface::parse_args`] reads back; empty for the
    /// original interface at any size.
    pub fn to_args(&self) -> String {
        if *self == Interface::default() {
            return String::new();
        }
        let camera = |c: &CameraRequest| {
            let size = if c.width == 0 {
                String::new()
            } else {
                format!("@{}x{}", c.width, c.height)
            };
            format!("{}:{}{size}", c.name, c.source.name())
        };
        let mut out = vec![
            format!("space={}", self.action),
            format!(
                "cameras={}",
                self.cameras
                    .iter()
                    .map(camera)
                    .collect::<Vec<_>>()
                    .join("+")
            ),
            format!(
                "state={}",
                self.state
                    .iter()
                    .map(|p| p.name())
                    .collect::<Vec<_>>()
                    .join("+")
            ),
        ];
        let depth: Vec<&str> = self
            .cameras
            .iter()
            .filter(|c| c.depth)
            .map(|c| c.name.as_str())
            .collect();
        if !depth.is_empty() {
            out.push(format!("depth={}", depth.join("+")));
        }
        if let Some(h) = self.execute {
            out.push(format!("horizon={h}"));
        }
        out.join(",")
    }

    /// [`Interface::to_args`]'s text back (empty: the original interface).
    pub fn parse_args(text: &str) -> Result<Interface, String> {
        let args = text
            .split(',')
            .filter(|a| !a.is_empty())
            .map(|a| {
                a.split_once('=')
                    .ok_or_else(|| format!("interface argument '{a}' is not key=value"))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Interface::from_args(&args)?.unwrap_or_default())
    }
}

/// `name:source@WxH`, `name:source@W`, `name:source` or `name` (the scene camera).
fn parse_camera(item: &str) -> Result<CameraRequest, String> {
    let (head, size) = match item.split_once('@') {
        Some((h, s)) => (h, Some(s)),
        None => (item, None),
    };
    let (name, source) = head.split_once(':').unwrap_or((head, "scene"));
    let (width, height) = match size {
        None => (0, 0),
        Some(s) => {
            let (w, h) = s.split_once('x').unwrap_or((s, s));
            match (w.parse::<u32>(), h.parse::<u32>()) {
                (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
                _ => return Err(format!("camera '{item}': bad size '{s}' (W or WxH pixels)")),
            }
        }
    };
    Ok(CameraRequest {
        name: name.to_owned(),
        source: CameraSource::parse(source),
        width,
        height,
        depth: false,
    })
}

/// One camera's frame, as a policy gets it.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedImage {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// `height · width · 3` bytes, RGB8, top row first.
    pub rgb: Vec<u8>,
    /// `height · width` metres when asked for, else empty.
    pub depth: Vec<f32>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interface_arguments_parse_and_bad_ones_name_the_field() {
        assert_eq!(Interface::from_args(&[("url", "x")]), Ok(None));
        let i = Interface::from_args(&[
            ("space", "ee_delta"),
            ("cameras", "image:scene@224+wrist_image:wrist@128x96"),
            ("state", "ee_pos+ee_quat+gripper"),
            ("depth", "wrist_image"),
            ("horizon", "4"),
        ])
        .unwrap()
        .unwrap();
        assert_eq!(i.action, ActionSpace::EeDelta);
        assert_eq!(i.cameras[1].source, CameraSource::Wrist);
        assert_eq!((i.cameras[1].width, i.cameras[1].height), (128, 96));
        assert!(i.cameras[1].depth && !i.cameras[0].depth);
        assert_eq!(i.state_dims(None), Ok(8));
        assert_eq!(i.execute, Some(4));
        assert!(!i.is_legacy() && Interface::legacy(64).is_legacy());
        assert_eq!(Interface::parse_args(&i.to_args()), Ok(i.clone()));
        assert_eq!(Interface::default().to_args(), "");
        assert_eq!(Interface::parse_args(""), Ok(Interface::default()));
        let sized = Interface::legacy(64);
        assert_eq!(Interface::parse_args(&sized.to_args()), Ok(sized));
        assert!(
            Interface::from_args(&[("space", "joint_velocity")])
                .unwrap_err()
                .contains("unknown action space")
        );
        assert!(
            Interface::from_args(&[("cameras", "a+a")])
                .unwrap_err()
                .contains("named twice")
        );
        assert!(Interface::from_args(&[("depth", "nope")]).is_err());
        assert!(Interface::from_args(&[("cameras", "a:scene@0")]).is_err());
        // joint_position and joints need an arm; the error names the field.
        let j = Interface::from_args(&[("space", "joint_position"), ("state", "joints")])
            .unwrap()
            .unwrap();
        assert!(
            j.fits_task(None)
                .unwrap_err()
                .starts_with("action_space joint_position")
        );
        assert_eq!(j.fits_task(Some("panda")), Ok(()));
        assert_eq!(j.action.dims(Some("panda")), Ok(8));
        assert_eq!(j.action.dims(Some("ur5")), Ok(7));
    }
}
