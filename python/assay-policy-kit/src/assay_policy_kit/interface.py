"""What a policy sees and how it acts: the kit's mirror of `assay.v1.PolicyInterface`."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

# Floats per action, by action space ("joint_position" is the arm's joints + 1).
ACTION_SPACES = ("tool_velocity", "ee_delta", "ee_pose", "joint_position")
_ACTION_DIMS = {"tool_velocity": 4, "ee_delta": 7, "ee_pose": 8}
# Floats per state part ("joints" is the arm's joint count).
STATE_PARTS = ("ee_pos", "ee_quat", "ee_yaw", "gripper", "joints", "holding")
_STATE_DIMS = {"ee_pos": 3, "ee_quat": 4, "ee_yaw": 1, "gripper": 1, "holding": 1}

MAX_PIXELS = 4096


@dataclass
class Camera:
    """One camera a policy asks for (`assay.v1.CameraRequest`).

    name:   the name the policy knows it by; the observation holds `observation/<name>`.
    source: a camera of the task by name, one of Assay's standard views ("top", "front",
            "oblique_left", "oblique_right"), "scene" (the task's first camera) or "wrist".
    width, height: pixels, 1 to 4096 each; 0 means the batch's frame size.
    depth:  also send depth (`observation/<name>_depth`, float32 metres [H, W]).
    """

    name: str
    source: str = "scene"
    width: int = 0
    height: int = 0
    depth: bool = False

    def validate(self) -> None:
        if not 1 <= len(self.name) <= 64:
            raise ValueError(f"camera name {self.name!r}: 1 to 64 characters")
        if not self.source:
            raise ValueError(f"camera {self.name!r}: empty source")
        for what, v in (("width", self.width), ("height", self.height)):
            if not 0 <= int(v) <= MAX_PIXELS:
                raise ValueError(f"camera {self.name!r}: {what} {v} is not 0 to {MAX_PIXELS}")
        if (self.width == 0) != (self.height == 0):
            raise ValueError(f"camera {self.name!r}: give both width and height, or neither")

    @classmethod
    def parse(cls, spec: str) -> "Camera":
        """A camera from `name[:source][@WxH][:depth]`, e.g. `wrist_image:wrist@224x224:depth`."""
        m = re.fullmatch(
            r"(?P<name>[^:@]+)(?::(?P<source>[^:@]+))?(?:@(?P<w>\d+)x(?P<h>\d+))?(?P<depth>:depth)?",
            spec.strip(),
        )
        if not m:
            raise ValueError(f"camera {spec!r}: expected name[:source][@WxH][:depth]")
        cam = cls(
            name=m.group("name"),
            source=m.group("source") or "scene",
            width=int(m.group("w") or 0),
            height=int(m.group("h") or 0),
            depth=bool(m.group("depth")),
        )
        cam.validate()
        return cam


def _default_cameras() -> List[Camera]:
    return [Camera("image")]


def _default_state() -> List[str]:
    return ["ee_pos", "holding"]


@dataclass
class Interface:
    """The observation a policy wants and the action space it answers in.

    The default is Assay's original interface: one camera "image" (the scene camera at the
    batch's frame size), state = ee_pos + holding (4 floats), tool_velocity actions (4 floats).
    `arm_joints` is only needed when the state has "joints" or the action space is
    "joint_position" (UR5: 6, Panda: 7).
    """

    cameras: List[Camera] = field(default_factory=_default_cameras)
    state: List[str] = field(default_factory=_default_state)
    action_space: str = "tool_velocity"
    execute_horizon: int = 0
    arm_joints: Optional[int] = None

    def validate(self) -> None:
        names = set()
        for cam in self.cameras:
            if not isinstance(cam, Camera):
                raise ValueError(f"cameras: {cam!r} is not a Camera")
            cam.validate()
            if cam.name in names:
                raise ValueError(f"camera {cam.name!r} appears twice")
            names.add(cam.name)
        for part in self.state:
            if part not in STATE_PARTS:
                raise ValueError(f"state part {part!r}: expected one of {', '.join(STATE_PARTS)}")
        if (self.action_space or "tool_velocity") not in ACTION_SPACES:
            raise ValueError(
                f"action space {self.action_space!r}: expected one of {', '.join(ACTION_SPACES)}"
            )
        if self.execute_horizon < 0:
            raise ValueError("execute_horizon must be >= 0")

    def action_dims(self, arm_joints: Optional[int] = None) -> int:
        """Floats per action: tool_velocity 4, ee_delta 7, ee_pose 8, joint_position n + 1."""
        space = self.action_space or "tool_velocity"
        if space in _ACTION_DIMS:
            return _ACTION_DIMS[space]
        if space == "joint_position":
            n = arm_joints if arm_joints is not None else self.arm_joints
            if n is None:
                raise ValueError("joint_position actions need the arm's joint count (arm_joints)")
            return int(n) + 1
        raise ValueError(f"unknown action space {space!r}")

    def state_dims(self, arm_joints: Optional[int] = None) -> int:
        """Floats of the state vector (`observation/state`)."""
        total = 0
        for part in self.state:
            if part == "joints":
                n = arm_joints if arm_joints is not None else self.arm_joints
                if n is None:
                    raise ValueError('state part "joints" needs the arm\'s joint count (arm_joints)')
                total += int(n)
            else:
                total += _STATE_DIMS[part]
        return total

    def camera_names(self) -> List[str]:
        return [c.name for c in self.cameras] if self.cameras else ["image"]

    def to_dict(self) -> Dict[str, Any]:
        return dataclasses.asdict(self)

    def to_proto(self):
        from ._proto import policy_pb2

        return policy_pb2.PolicyInterface(
            cameras=[
                policy_pb2.CameraRequest(
                    name=c.name, source=c.source, width=c.width, height=c.height, depth=c.depth
                )
                for c in self.cameras
            ],
            state=list(self.state),
            action_space=self.action_space,
            execute_horizon=self.execute_horizon,
        )
