#!/usr/bin/env python3
"""Round-trip latency of openpi's own Python client against an openpi-protocol server.

    python tests/python/openpi_roundtrip.py --url ws://HOST:PORT [--n 200] [--size 224] [--api-key K]

Uses the real `openpi_client.websocket_client_policy.WebsocketClientPolicy` (openpi-client 0.1.2,
installed with `pip install --no-deps openpi-client==0.1.2`; that module needs only msgpack,
websockets and typing_extensions). The observation: "observation/image" and
"observation/wrist_image", uint8 [size, size, 3]; "observation/state", float32 [8]; "prompt".
Warms up with 20 calls, times N `infer` calls and prints one JSON line:
{"client": "openpi-client (python)", "n": N, "median_us": ..., "p90_us": ..., "p99_us": ...}.
Serve the kit's zeros policy for it: tests/python/serve_policy.py --protocol openpi --policy zeros.
"""

import argparse
import json
import time

import numpy as np
from openpi_client.websocket_client_policy import WebsocketClientPolicy

WARMUP = 20


def percentile(sorted_us, q):
    # nearest rank
    i = min(len(sorted_us) - 1, max(0, int(np.ceil(q * len(sorted_us))) - 1))
    return sorted_us[i]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", required=True, help="ws://HOST:PORT")
    p.add_argument("--n", type=int, default=200)
    p.add_argument("--size", type=int, default=224)
    p.add_argument("--api-key", default=None)
    args = p.parse_args()
    if args.n < 1:
        p.error("--n must be >= 1")

    rng = np.random.default_rng(0)
    obs = {
        "observation/image": rng.integers(0, 256, (args.size, args.size, 3), dtype=np.uint8),
        "observation/wrist_image": rng.integers(0, 256, (args.size, args.size, 3), dtype=np.uint8),
        "observation/state": rng.standard_normal(8).astype(np.float32),
        "prompt": "pick up the red cube and put it in the bowl",
    }
    client = WebsocketClientPolicy(host=args.url, api_key=args.api_key)
    for _ in range(WARMUP):
        out = client.infer(obs)
    actions = np.asarray(out["actions"])
    if actions.ndim != 2 or actions.dtype != np.float32:
        raise SystemExit(f"unexpected answer: actions {actions.dtype} {list(actions.shape)}")
    times = []
    for _ in range(args.n):
        t0 = time.perf_counter_ns()
        client.infer(obs)
        times.append((time.perf_counter_ns() - t0) / 1e3)
    times.sort()
    print(json.dumps({
        "client": "openpi-client (python)",
        "n": args.n,
        "median_us": round(float(np.median(times)), 1),
        "p90_us": round(percentile(times, 0.90), 1),
        "p99_us": round(percentile(times, 0.99), 1),
    }), flush=True)


if __name__ == "__main__":
    main()
