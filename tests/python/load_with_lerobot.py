"""Loads a dataset from `assay export lerobot` with the real LeRobot (`LeRobotDataset`, offline,
`root=` the folder) and compares what it returns with the files: states and actions with the
frames table, decoded frames with the run's dynamics clips (the same pictures before H.264): each
decoded frame nearer its own clip frame than the neighbours that differ from it, and the mean
error under 4 levels of 255 (a busy frame may lose more to H.264).

    python load_with_lerobot.py DATASET RUN

Run by tests/it/export.rs on the eval test's run, and by scripts/check-lerobot on any run, in
scripts/setup-lerobot's environment.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from lerobot.datasets.lerobot_dataset import LeRobotDataset

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

report = json.loads((run / "report.json").read_text())
clip_of = {"artifacts/" + e["artifact"]: (e.get("imagery") or {}).get("clip")
           for t in report["results"]["tasks"] for e in t["episodes"]}
eps = pd.read_parquet(root / "meta/episodes/chunk-000/file-000.parquet")
diffs, misplaced = [], []
for _, ep in eps.iterrows():
    clip = clip_of.get(ep["assay/episode_file"])
    if not clip:
        continue
    b = (run / "artifacts" / clip).read_bytes()
    T, H, W, _P, _A, _us = np.frombuffer(b, "<u4", 6, 8)
    rgb = np.frombuffer(b, np.uint8, T * H * W * 3, 32).reshape(T, H, W, 3).astype(np.float64)
    n = int(ep["length"])
    decoded = []
    for k in range(n):
        img = ds[int(ep["dataset_from_index"]) + k]["observation.images.scene"]
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
                misplaced.append((str(ep["assay/episode_file"]), k, j))
assert not misplaced, f"{len(misplaced)} frames nearer a neighbour than their own: {misplaced[:5]}"
assert not diffs or np.mean(diffs) < 4.0, np.mean(diffs)
print(json.dumps({
    "lerobot_episodes": ds.num_episodes, "lerobot_frames": len(ds), "video_backend": ds.video_backend,
    "frames_compared_with_clips": len(diffs),
    "mean_abs_diff_of_255": float(np.mean(diffs)) if diffs else None,
    "max_abs_diff_of_255": float(np.max(diffs)) if diffs else None,
    "frames_nearer_a_neighbour": len(misplaced),
}))
