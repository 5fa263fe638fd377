"""Deterministic test policies for the policy kit (numpy only; no kit import).

`policy` is the scripted policy a Rust test runs three ways (openpi websocket, the kit's gRPC
server, and a TorchScript twin written in Rust) and expects IDENTICAL episodes from. Its
interface: one camera "image" (scene, 32 x 32), state ee_pos + ee_yaw + holding (5 floats),
action space ee_delta (7 floats), a chunk of 2 actions.

The arithmetic, all in float32, elementwise, every constant exactly representable, so that torch
reproduces it bit for bit (each product below is by a power of two, hence exact: fusing a
multiply and an add into an FMA cannot change a result):

    s      = obs["observation/state"]                 # float32 [5]: x, y, z, yaw, holding
    img    = obs["observation/image"]                 # uint8 [32, 32, 3]
    p      = float32(img[8, 24]) / float32(255.0)     # one pixel (row 8, column 24), [3]
    target = [0.5    + 0.125 * p[0],                  # float32, one rounding per + and -
              -0.125 + 0.25  * p[1],
              0.125]
    d      = clip((target - s[0:3]) * 0.25, -0.03125, 0.03125)
    dyaw   = 0.0625
    grip   = 1.0 if s[2] < 0.0625 else 0.0
    action = [d[0], d[1], d[2], 0.0, 0.0, dyaw, grip]
    return [action, action]                           # float32 [2, 7]

A torch sketch (for the TorchScript twin), with state: float32 [5] and image: uint8 [32, 32, 3]:

    p = image[8, 24].to(torch.float32) / 255.0
    target = torch.stack([0.5 + 0.125 * p[0], -0.125 + 0.25 * p[1], torch.tensor(0.125)])
    d = torch.clamp((target - state[0:3]) * 0.25, -0.03125, 0.03125)
    grip = (state[2] < 0.0625).to(torch.float32)
    action = torch.stack([d[0], d[1], d[2], 0.0, 0.0, 0.0625, grip]); return action.repeat(2, 1)

The malformed policies below share the interface, for error tests: `wrong_shape` answers
[2, 5], `nan` puts a NaN in the first action, `raises` raises ValueError("policy exploded").
"""

import numpy as np

F = np.float32

CHUNK = 2
IMAGE_SIZE = 32
STATE = ("ee_pos", "ee_yaw", "holding")
ACTION_SPACE = "ee_delta"


def policy(obs):
    """The scripted policy (see the module's docstring): float32 [2, 7]."""
    s = np.asarray(obs["observation/state"], dtype=np.float32)
    img = np.asarray(obs["observation/image"])
    if s.shape != (5,):
        raise ValueError(f"scripted: state of shape {list(s.shape)}, expected [5]")
    if img.dtype != np.uint8 or img.shape != (IMAGE_SIZE, IMAGE_SIZE, 3):
        raise ValueError(f"scripted: image {img.dtype} {list(img.shape)}, expected uint8 [32, 32, 3]")
    p = img[8, 24].astype(np.float32) / F(255.0)
    target = np.array(
        [F(0.5) + F(0.125) * p[0], F(-0.125) + F(0.25) * p[1], F(0.125)], dtype=np.float32
    )
    d = np.clip((target - s[:3]) * F(0.25), F(-0.03125), F(0.03125)).astype(np.float32)
    dyaw = F(0.0625)
    grip = F(1.0) if s[2] < F(0.0625) else F(0.0)
    action = [d[0], d[1], d[2], F(0.0), F(0.0), dyaw, grip]
    return np.array([action] * CHUNK, dtype=np.float32)


def wrong_shape(obs):
    """Answers [2, 5] for an ee_delta (7-float) interface."""
    return policy(obs)[:, :5].copy()


def nan(obs):
    """The scripted answer with a NaN in the first action."""
    a = policy(obs)
    a[0, 0] = np.nan
    return a


def raises(obs):
    raise ValueError("policy exploded")


def zeros(obs):
    """A trivial echo-speed policy for benchmarks: zeros [1, 7]."""
    return np.zeros((1, 7), dtype=np.float32)


class LeRobotStandin:
    """A stand-in with LeRobot's policy API (`reset()`, `select_action(batch) -> [1, 7]`), for
    testing `LeRobotAdapter` without lerobot. Deterministic: it checks the batch is what LeRobot
    policies take and answers, in float32,

        top   = batch["observation.images.top"][0, :, 16, 16]   # channels of the centre pixel, [0, 1]
        wrist = batch["observation.images.wrist"][0, :, 16, 16]
        s     = batch["observation.state"][0]                   # [5]: x, y, z, yaw, holding
        action = [0.25 * top[0] - 0.125, 0.25 * wrist[1] - 0.125, -0.015625 * s[4],
                  0, 0, 0.03125 * steps, float(len(task) % 2)]

    where `steps` counts select_action calls since reset() (a per-episode state, like LeRobot's
    action queue) and `task` is batch["task"][0]. Accepts numpy arrays or torch tensors.
    """

    def __init__(self):
        self.steps = 0
        self.resets = 0

    def reset(self):
        self.steps = 0
        self.resets += 1

    def select_action(self, batch):
        def arr(x):
            if hasattr(x, "detach"):
                x = x.detach().cpu().numpy()
            return np.asarray(x)

        top = arr(batch["observation.images.top"])
        wrist = arr(batch["observation.images.wrist"])
        state = arr(batch["observation.state"])
        task = batch["task"]
        for key, a in (("top", top), ("wrist", wrist)):
            if a.dtype != np.float32 or a.ndim != 4 or a.shape[:2] != (1, 3):
                raise ValueError(f"standin: {key} is {a.dtype} {list(a.shape)}, expected float32 [1, 3, H, W]")
            if a.min() < 0.0 or a.max() > 1.0:
                raise ValueError(f"standin: {key} is not in [0, 1]")
        if state.dtype != np.float32 or state.shape != (1, 5):
            raise ValueError(f"standin: state is {state.dtype} {list(state.shape)}, expected float32 [1, 5]")
        if not (isinstance(task, list) and len(task) == 1 and isinstance(task[0], str)):
            raise ValueError(f"standin: task is {task!r}, expected [str]")
        self.steps += 1
        t, w, s = top[0, :, 16, 16], wrist[0, :, 16, 16], state[0]
        action = np.array(
            [F(0.25) * t[0] - F(0.125), F(0.25) * w[1] - F(0.125), F(-0.015625) * s[4],
             F(0.0), F(0.0), F(0.03125) * F(self.steps), F(len(task[0]) % 2)],
            dtype=np.float32,
        )
        return action[None]
