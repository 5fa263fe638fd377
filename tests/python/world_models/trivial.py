#!/usr/bin/env python3
"""A trivial, deterministic, action-dependent world model for tests, and its server.

    python tests/python/world_models/trivial.py [--variant ok] [--port 0] [--size WxH]
        [--action-dims D] [--sleep-s S] [--name NAME]

Prints `listening on http://HOST:PORT` once ready, then serves `assay.v1.WorldModel` with the
Assay policy kit until killed (imported from python/assay-policy-kit/src, no pip install needed;
honours $ASSAY_CLUSTER_TOKEN / $ASSAY_CLUSTER_TOKEN_FILE). The kit's CLI serves it too:
`PYTHONPATH=tests/python/world_models python -m assay_policy_kit world-model trivial:Trivial`.

The model starts from the real first frame and draws a white square of SQUARE pixels whose
centre starts at the frame's centre and moves by SCALE pixels per unit of the action's first two
components at every step (x right, y down; clamped to the frame). The state is the previous
state plus 0.1 · action[:3], and state[3] ("holding") is 1.0 when action[3] >= 0.5, else 0.0.

Variants (malformed ones break the protocol for the client to refuse):
  ok           frames and states
  frames_only  frames, no states
  wrong_size   every frame one column wider than the reset's
  too_few      one frame fewer than actions
  nan_state    the first state's first float is NaN
  sleep        sleeps --sleep-s seconds (default 10) before every Step answer
  raises       step raises ValueError("world model exploded")
"""

import argparse
import logging
import os
import sys
import time

import numpy as np

SQUARE = 4
SCALE = 8.0
VARIANTS = ("ok", "frames_only", "wrong_size", "too_few", "nan_state", "sleep", "raises")


class Trivial:
    """One imagined episode of the trivial model (see the module's doc)."""

    def __init__(self, variant="ok", sleep_s=10.0):
        if variant not in VARIANTS:
            raise ValueError(f"unknown variant {variant!r} (one of {', '.join(VARIANTS)})")
        self.variant = variant
        self.sleep_s = sleep_s
        self.base = None

    def reset(self, frame, state, instruction):
        self.base = np.array(frame, dtype=np.uint8)
        h, w = self.base.shape[:2]
        self.pos = np.array([w / 2.0, h / 2.0])
        self.state = np.array(state, dtype=np.float32)
        self.instruction = instruction

    def _frame(self):
        h, w = self.base.shape[:2]
        f = self.base.copy()
        x, y = (int(round(v)) for v in self.pos)
        half = SQUARE // 2
        f[max(0, y - half):max(0, y + half), max(0, x - half):max(0, x + half)] = 255
        return f

    def step(self, actions):
        if self.base is None:
            raise RuntimeError("step before reset")
        if self.variant == "raises":
            raise ValueError("world model exploded")
        if self.variant == "sleep":
            time.sleep(self.sleep_s)
        h, w = self.base.shape[:2]
        frames, states = [], []
        for a in np.asarray(actions, dtype=np.float32):
            move = np.zeros(2)
            move[: min(2, len(a))] = a[:2]
            self.pos = np.clip(self.pos + SCALE * move, [0.0, 0.0], [w - 1.0, h - 1.0])
            s = self.state.copy()
            n = min(3, len(s), len(a))
            s[:n] += np.float32(0.1) * a[:n]
            if len(s) >= 4 and len(a) >= 4:
                s[3] = 1.0 if a[3] >= 0.5 else 0.0
            self.state = s
            frames.append(self._frame())
            states.append(s)
        frames, states = np.stack(frames), np.stack(states)
        if self.variant == "wrong_size":
            frames = np.concatenate([frames, frames[:, :, :1]], axis=2)
        elif self.variant == "too_few":
            frames = frames[:-1]
        elif self.variant == "nan_state":
            states[0, 0] = np.nan
        elif self.variant == "frames_only":
            return frames
        return frames, states


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path.insert(0, os.path.join(here, "..", "..", "..", "python", "assay-policy-kit", "src"))
    from assay_policy_kit import serve_world_model_forever

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", choices=VARIANTS, default="ok")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--size", default=None, metavar="WxH", help="the frame size declared in Health (default: any)")
    p.add_argument("--action-dims", type=int, default=0, help="declared in Health (0: any)")
    p.add_argument("--sleep-s", type=float, default=10.0, help="variant sleep: seconds per Step")
    p.add_argument("--name", default=None, help="the name in Health (default: trivial-VARIANT)")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    width, height = (int(v) for v in args.size.split("x")) if args.size else (0, 0)
    serve_world_model_forever(
        lambda: Trivial(args.variant, args.sleep_s), host=args.host, port=args.port,
        name=args.name or f"trivial-{args.variant}", description="tests/python/world_models/trivial.py",
        width=width, height=height, action_dims=args.action_dims,
    )


if __name__ == "__main__":
    main()
