"""A scripted 7-D end-effector-delta policy that sees: it reads its task from the instruction and
finds everything through the cameras it asks for, never from the simulator's state.

Interface: cameras "scene" (Assay's standard top view, 128 x 128, with depth) and "wrist" (on the
tool, 64 x 64, with depth); state ee_pos + ee_yaw + holding; action space ee_delta (SIMPLER's
7 floats: dx, dy, dz, droll, dpitch, dyaw, gripper), one action per call.

What it does, as a lab's scripted baseline would:
  1. The instruction's first colour word is the object to move, the second the target ("put the
     red block in the green bowl", "stack the green cube on the red cube").
  2. The top view, back-projected through its depth, gives both as points on the table: their
     centres, top heights and yaw (the turn of the smallest enclosing rectangle, modulo 90°).
  3. Over the object it centres it in the wrist camera (the wrist view turns with the tool: its
     image's top is the tool's heading), goes down to its top, closes the gripper (suction), lifts.
  4. It carries the object over the target, turning the tool by the difference of their yaws
     (modulo 90°) so a square block enters a square fixture turned like it, lowers it to just
     above the target's top, opens, and goes up.

The cameras' placement is what the policy was "calibrated" for: Assay's top view looks straight
down from (0.5, 0, 0.95) m with a 50° field of view, its image's top towards +x; the wrist camera
is mounted beside the tool (4 cm behind its axis, 4 cm below its centre, in the tool's frame whose
x is its heading), looks down tilted 25° forward, with a 70° field of view. Distances in metres,
angles in radians.
"""

import math
import os
import sys

import numpy as np

DEBUG = bool(os.environ.get("ASSAY_VISION_DEBUG"))

SCENE_EYE = np.array([0.5, 0.0, 0.95])
SCENE_FOVY = math.radians(50.0)
WRIST_MOUNT = np.array([-0.04, 0.0, -0.04])
WRIST_TILT = math.radians(25.0)
WRIST_FOVY = math.radians(70.0)
TOOL_HALF_HEIGHT = 0.05
CRUISE_Z = 0.28
MAX_STEP = 0.03
MAX_TURN = 0.2
# Where the tool goes when the top view does not show the object or the target (the arm, which
# stands at the table's near edge, is then out of the way).
LOOK_FROM = np.array([0.25, 0.0, 0.4])

# Hue (degrees) of the colour words the instructions use, as Assay draws them.
HUES = {"red": 358.0, "green": 120.0, "blue": 220.0, "yellow": 55.0, "orange": 28.0,
        "purple": 285.0, "pink": 330.0, "cyan": 185.0}

STATE = ("ee_pos", "ee_yaw", "holding")


def hue_mask(rgb, hue, tolerance=14.0, min_saturation=0.45, min_value=0.2):
    """Pixels of `rgb` (uint8 [H, W, 3]) whose hue is within `tolerance` degrees of `hue`."""
    x = rgb.astype(np.float32) / 255.0
    mx, mn = x.max(axis=2), x.min(axis=2)
    chroma = mx - mn
    sat = np.where(mx > 0, chroma / np.maximum(mx, 1e-6), 0.0)
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    safe = np.maximum(chroma, 1e-6)
    h = np.where(mx == r, ((g - b) / safe) % 6.0,
                 np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0)) * 60.0
    d = np.abs((h - hue + 180.0) % 360.0 - 180.0)
    return (d <= tolerance) & (sat >= min_saturation) & (mx >= min_value) & (chroma > 0.05)


def back_project(depth, eye, right, up, forward, fovy):
    """World points of every pixel of a pinhole camera (depth along its axis): [H, W, 3]."""
    h, w = depth.shape
    t = math.tan(fovy / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * (w / h)
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t
    d = np.where(np.isfinite(depth), depth, np.nan)[..., None]
    rays = forward + xs[None, :, None] * right + ys[:, None, None] * up
    return eye + d * rays


def scene_points(depth):
    # Straight down: forward -z, image right -y, image up +x.
    return back_project(depth, SCENE_EYE, np.array([0.0, -1.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                        np.array([0.0, 0.0, -1.0]), SCENE_FOVY)


def wrist_points(depth, tool, heading):
    c, s = math.cos(heading), math.sin(heading)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    eye = np.asarray(tool, dtype=np.float64) + turn @ WRIST_MOUNT
    ts, tc = math.sin(WRIST_TILT), math.cos(WRIST_TILT)
    forward = turn @ np.array([ts, 0.0, -tc])
    up = turn @ np.array([tc, 0.0, ts])
    return back_project(depth, eye, np.cross(forward, up), up, forward, WRIST_FOVY)


def rectangle(xy):
    """The smallest rectangle (over 1° turns) around points `xy` [N, 2]: its centre and its turn
    (mod 90°)."""
    c = xy.mean(axis=0)
    best = None
    for deg in np.arange(0.0, 90.0, 1.0):
        a = math.radians(deg)
        axes = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        rot = (xy - c) @ axes
        lo, hi = rot.min(axis=0), rot.max(axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            best = (area, a, c + axes @ ((lo + hi) / 2))
    return best[2], best[1]


def blob(points, mask, min_pixels=4):
    """Centre (x, y), top height and yaw of the masked points, or None."""
    pts = points[mask]
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < min_pixels:
        return None
    centre, yaw = rectangle(pts[:, :2])
    return {"xy": centre, "top": float(np.percentile(pts[:, 2], 90)), "yaw": yaw, "n": len(pts)}


def wrap(a, period=2 * math.pi):
    return (a + period / 2) % period - period / 2


class VisionPolicy:
    """One episode's state (a fresh instance per episode: the kit's factory). `turn=False` never
    turns the tool (to show that a task needs the turn)."""

    def __init__(self, turn=True):
        self.turns = turn
        self.reset()

    def reset(self, task_id="", seed=0, instruction=""):
        self.words = [w for w in instruction.lower().replace(",", " ").replace(".", " ").split()
                      if w in HUES]
        self.phase = "look"
        self.obj = self.target = None
        self.turn = 0.0
        self.start_yaw = None
        self.wait = 0

    def __call__(self, obs):
        a = self.step(obs)
        if DEBUG:
            s = obs["observation/state"]
            print(f"vision: {self.words} {self.phase} tool {np.round(s, 3)} obj "
                  f"{None if self.obj is None else (np.round(self.obj['xy'], 3), round(self.obj['top'], 3))} "
                  f"target {None if self.target is None else (np.round(self.target['xy'], 3), round(self.target['top'], 3))} "
                  f"turn {self.turn:.3f} -> {np.round(a[0], 3)}", file=sys.stderr, flush=True)
        return a

    def step(self, obs):
        s = np.asarray(obs["observation/state"], dtype=np.float64)
        tool, yaw, holding = s[:3], s[3], s[4] > 0.5
        if not self.words and "prompt" in obs:
            self.reset(instruction=obs["prompt"])
        if len(self.words) < 2:
            return self._action(np.zeros(3), 0.0, 0.0)
        scene = scene_points(np.asarray(obs["observation/scene_depth"], dtype=np.float64))
        rgb = np.asarray(obs["observation/scene"])
        if self.phase == "look":
            self.obj = blob(scene, hue_mask(rgb, HUES[self.words[0]]))
            self.target = blob(scene, hue_mask(rgb, HUES[self.words[1]]))
            if self.obj is None or self.target is None:
                # Hidden under the arm: take the tool back towards the base and look again.
                return self.toward(tool, LOOK_FROM, yaw, yaw, 0.0)
            self.turn = wrap(self.target["yaw"] - self.obj["yaw"], math.pi / 2) if self.turns else 0.0
            self.start_yaw = yaw
            self.phase = "over"
        if self.phase == "over":
            goal = np.array([*self.obj["xy"], CRUISE_Z])
            if self.reach(tool, goal, 0.004):
                self.phase, self.wait = "centre", 0
            return self.toward(tool, goal, self.start_yaw, yaw, 0.0)
        if self.phase == "centre":
            # The wrist camera sees the object under the tool: centre it there.
            wrist = wrist_points(np.asarray(obs["observation/wrist_depth"], dtype=np.float64),
                                 tool, yaw)
            seen = blob(wrist, hue_mask(np.asarray(obs["observation/wrist"]),
                                        HUES[self.words[0]]))
            if seen is not None:
                self.obj["xy"], self.obj["top"] = seen["xy"], seen["top"]
            goal = np.array([*self.obj["xy"], CRUISE_Z])
            # Pixels are ~4 mm apart at this height: within 3 mm, or after 10 tries, is centred.
            self.wait += 1
            if self.reach(tool, goal, 0.003) or self.wait > 10:
                self.phase = "down"
            return self.toward(tool, goal, self.start_yaw, yaw, 0.0)
        if self.phase == "down":
            goal = np.array([*self.obj["xy"], self.obj["top"] + TOOL_HALF_HEIGHT + 0.002])
            if self.reach(tool, goal, 0.002):
                self.phase, self.wait = "grasp", 0
            return self.toward(tool, goal, self.start_yaw, yaw, 0.0)
        if self.phase == "grasp":
            self.wait += 1
            if holding or self.wait > 3:
                self.phase = "lift"
            return self._action(np.zeros(3), 0.0, 1.0)
        if self.phase == "lift":
            goal = np.array([*self.obj["xy"], CRUISE_Z])
            if self.reach(tool, goal, 0.004):
                self.phase = "carry"
            return self.toward(tool, goal, self.start_yaw, yaw, 1.0)
        carried_height = self.obj["top"]  # the object's height: it stood on the table
        if self.phase == "carry":
            goal = np.array([*self.target["xy"], CRUISE_Z])
            want_yaw = self.start_yaw + self.turn
            if self.reach(tool, goal, 0.002) and abs(wrap(want_yaw - yaw)) < 0.01:
                self.phase = "lower"
            return self.toward(tool, goal, want_yaw, yaw, 1.0)
        if self.phase == "lower":
            goal = np.array([*self.target["xy"],
                             self.target["top"] + carried_height + TOOL_HALF_HEIGHT + 0.006])
            want_yaw = self.start_yaw + self.turn
            if self.reach(tool, goal, 0.002):
                self.phase, self.wait = "release", 0
            return self.toward(tool, goal, want_yaw, yaw, 1.0)
        if self.phase == "release":
            self.wait += 1
            if self.wait > 3:
                self.phase = "away"
            return self._action(np.zeros(3), 0.0, 0.0)
        goal = np.array([*self.target["xy"], CRUISE_Z])
        return self.toward(tool, goal, yaw, yaw, 0.0)

    @staticmethod
    def reach(tool, goal, tolerance):
        return float(np.linalg.norm(goal - tool)) < tolerance

    def toward(self, tool, goal, want_yaw, yaw, grip):
        d = goal - tool
        n = float(np.linalg.norm(d))
        if n > MAX_STEP:
            d = d * (MAX_STEP / n)
        turn = max(-MAX_TURN, min(MAX_TURN, wrap(want_yaw - yaw))) if want_yaw is not None else 0.0
        return self._action(d, turn, grip)

    @staticmethod
    def _action(d, turn, grip):
        return np.array([[d[0], d[1], d[2], 0.0, 0.0, turn, grip]], dtype=np.float32)
