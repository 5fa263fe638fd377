"""Loads a dataset from `assay export lerobot` with the real LeRobot (`LeRobotDataset`, offline,
`root=` the folder) and compares what it returns with the files: states and actions with the
frames table, decoded frames with the run's dynamics clips (the same pictures before H.264): each
decoded frame nearer its own clip frame than the neighbours that differ from it, and the mean
error under 4 levels of 255 (a busy frame may lose more to H.264).

A dataset exported at a policy interface (`--interface`, named in meta/assay.json) is compared
with clips recorded at the same interface (a ranking's `config.interface`): every camera
(`observation.images.<name>`) with the clip's camera of that name, and the states and actions
with the clip's, value for value.

    python load_with_lerobot.py DATASET RUN

Run by tests/it/export.rs and tests/it/ranking.rs on their runs, and by scripts/check-lerobot on
any run, in scripts/setup-lerobot's environment.
"""

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from lerobot.datasets.lerobot_dataset import LeRobotDataset

PREFIX = "observation.images."


def read_clip(b):
    """A dynamics clip (docs/episode-format.md): interface, {camera name: frames [T, H, W, 3]},
    state [T, P], actions [T, A]. The first camera of a clip at an interface is the interface's
    first; the original interface's one camera is "scene"."""
    magic = b[:8]
    T, H, W, P, A, _us = struct.unpack_from("<6I", b, 8)
    at = 32
    interface, views = "", []
    if magic == b"ASYCLIP2":
        (n,) = struct.unpack_from("<I", b, at)
        interface = b[at + 4:at + 4 + n].decode()
        at += 4 + n
        (count,) = struct.unpack_from("<I", b, at)
        at += 4
        for _ in range(count):
            (n,) = struct.unpack_from("<I", b, at)
            name = b[at + 4:at + 4 + n].decode()
            at += 4 + n
            w, h = struct.unpack_from("<2I", b, at)
            at += 8
            views.append((name, h, w))
    else:
        assert magic == b"ASYCLIP1", magic
    first = "scene"
    if interface:
        cams = dict(a.split("=", 1) for a in interface.split(",")).get("cameras", "")
        first = cams.split("+")[0].split(":")[0].split("@")[0]
    frames = {}
    for name, h, w in [(first, H, W)] + views:
        n = T * h * w * 3
        frames[name] = np.frombuffer(b, np.uint8, n, at).reshape(T, h, w, 3).astype(np.float64)
        at += n
    state = np.frombuffer(b, "<f4", T * P, at).reshape(T, P)
    at += T * P * 4
    actions = np.frombuffer(b, "<f4", T * A, at).reshape(T, A)
    return interface, frames, state, actions


root, run = Path(sys.argv[1]), Path(sys.argv[2])
ds = LeRobotDataset("assay/export", root=root)
table = pq.read_table(root / "data/chunk-000/file-000.parquet").to_pandas()
assert len(ds) == len(table)
for i in range(len(ds)):
    item = ds[i]
    assert np.array_equal(item["observation.state"].numpy(),
                          np.asarray(table["observation.state"][i], dtype=np.float32)), i
    assert np.array_equal(item["action"].numpy(), np.asarray(table["action"][i], dtype=np.float32)), i
    assert isinstance(item["task"], str) and item["task"]

exported_at = json.loads((root / "meta/assay.json").read_text()).get("interface") or ""
cameras = [k[len(PREFIX):] for k in ds.meta.video_keys]
report = json.loads((run / "report.json").read_text())
clip_of = {"artifacts/" + e["artifact"]: (e.get("imagery") or {}).get("clip")
           for t in report["results"]["tasks"] for e in t["episodes"]}
eps = pd.read_parquet(root / "meta/episodes/chunk-000/file-000.parquet")
diffs, misplaced, values_compared = [], [], 0
for _, ep in eps.iterrows():
    clip = clip_of.get(ep["assay/episode_file"])
    if not clip:
        continue
    interface, clip_frames, clip_state, clip_actions = read_clip((run / "artifacts" / clip).read_bytes())
    n, start = int(ep["length"]), int(ep["dataset_from_index"])
    if exported_at and interface:
        # At the same interface, the clip recorded in the cluster and the export read from the
        # episode file agree value for value.
        assert clip_state.shape[0] == n, (clip_state.shape, n)
        for k in range(n):
            item = ds[start + k]
            assert np.array_equal(item["observation.state"].numpy(), clip_state[k]), (ep["assay/episode_file"], k)
            assert np.array_equal(item["action"].numpy(), clip_actions[k]), (ep["assay/episode_file"], k)
            values_compared += clip_state.shape[1] + clip_actions.shape[1]
    for camera in cameras:
        rgb = clip_frames.get(camera)
        if rgb is None:
            continue
        T, H, W, _ = rgb.shape
        decoded = []
        for k in range(n):
            img = ds[start + k][PREFIX + camera]
            if tuple(img.shape[1:]) != (H, W):
                break
            decoded.append(img.numpy().transpose(1, 2, 0) * 255)
        for k, img in enumerate(decoded):
            own = np.abs(img - rgb[k]).mean()
            diffs.append(own)
            # Each decoded frame is closer to its own clip frame than to its neighbours wherever
            # those differ from it: H.264 blurs busy frames by a few levels, a frame at the wrong
            # index is off by the motion between them.
            for j in (k - 1, k + 1):
                if 0 <= j < T and np.abs(rgb[j] - rgb[k]).mean() > 0.5 and np.abs(img - rgb[j]).mean() <= own:
                    misplaced.append((str(ep["assay/episode_file"]), camera, k, j))
assert not misplaced, f"{len(misplaced)} frames nearer a neighbour than their own: {misplaced[:5]}"
assert not diffs or np.mean(diffs) < 4.0, np.mean(diffs)
print(json.dumps({
    "lerobot_episodes": ds.num_episodes, "lerobot_frames": len(ds), "video_backend": ds.video_backend,
    "cameras": cameras,
    "frames_compared_with_clips": len(diffs),
    "values_compared_with_clips": values_compared,
    "mean_abs_diff_of_255": float(np.mean(diffs)) if diffs else None,
    "max_abs_diff_of_255": float(np.max(diffs)) if diffs else None,
    "frames_nearer_a_neighbour": len(misplaced),
}))
