"""Throughput of one loaded LeRobot checkpoint serving 1, 2 and 8 concurrent episodes through the
kit's LeRobotAdapter (`for_episode`: a queue per episode, inference serialized by one lock), on
the CPU with one torch thread, for the small ACT and Diffusion checkpoints of
tests/python/lerobot_adapter_check.py (untrained; shapes as there: two 64 px cameras, 8 floats of
state, 7-D actions).

    "$(scripts/setup-lerobot)" bench/lerobot_adapter_bench.py
"""

import contextlib
import io
import json
import os
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = tempfile.mkdtemp()
sys.argv = [sys.argv[0], os.path.join(ROOT, "python/assay-policy-kit/src"), OUT]
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, os.path.join(ROOT, "tests/python"))

import torch  # noqa: E402

import lerobot_adapter_check as check  # noqa: E402
from assay_policy_kit.lerobot import LeRobotAdapter  # noqa: E402

torch.set_num_threads(1)
STEPS = 48
result = {"actions_per_s": {}, "torch_threads": 1, "steps_per_episode": STEPS,
          "torch": torch.__version__}
for kind in ("act", "diffusion"):
    with contextlib.redirect_stdout(io.StringIO()):
        base = LeRobotAdapter.from_pretrained(check.save(kind), device="cpu")
    obs = [check.episode_obs(s)[1] for s in range(8)]
    for n in (1, 2, 8):
        episodes = [base.for_episode() for _ in range(n)]

        def run(ep):
            for s in range(STEPS):
                ep(obs[s % 8])

        threads = [threading.Thread(target=run, args=(e,)) for e in episodes]
        start = time.perf_counter()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        result["actions_per_s"].setdefault(kind, {})[n] = round(n * STEPS / (time.perf_counter() - start), 1)
print(json.dumps(result))
