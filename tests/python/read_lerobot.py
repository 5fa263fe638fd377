"""Checks a LeRobotDataset v3.0 written by `assay export lerobot` against the format's documented
schema (shared/FORMATS.md, read from huggingface/lerobot's datasets code) and against the run it
came from, reading it as LeRobot does: pandas for meta/, pyarrow for the frames table, PyAV for
the video at `from_timestamp + timestamp`.

    python read_lerobot.py DATASET RUN

Per episode it compares the dataset's states and actions with the run's episode file (the
recorded rows every 1/fps seconds from the policy's first step), and its decoded video frames
with the run's dynamics clip of that episode where the run has one of the same size. Prints one
JSON line of what it checked; exits non-zero (an AssertionError) on the first mismatch.
"""

import json
import sys
from pathlib import Path

import av
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.ipc
import pyarrow.parquet as pq

TOLERANCE_S = 1e-4  # LeRobotDataset's default tolerance between a query and a frame's timestamp

root, run = Path(sys.argv[1]), Path(sys.argv[2])
info = json.loads((root / "meta/info.json").read_text())
assert info["codebase_version"] == "v3.0", info["codebase_version"]
fps = info["fps"]
features = info["features"]
for key, dtype in [("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                   ("index", "int64"), ("task_index", "int64")]:
    assert features[key]["dtype"] == dtype and features[key]["shape"] == [1], (key, features[key])
video_keys = [k for k, f in features.items() if f["dtype"] == "video"]
assert video_keys == ["observation.images.scene"], video_keys
vkey = video_keys[0]
h, w, c = features[vkey]["shape"]
assert c == 3 and features[vkey]["info"]["video.fps"] == fps
state_dims = features["observation.state"]["shape"][0]
action_dims = features["action"]["shape"][0]
assert len(features["observation.state"]["names"]) == state_dims

# meta/tasks.parquet: a pandas frame indexed by the task text.
tasks = pd.read_parquet(root / "meta/tasks.parquet")
assert list(tasks["task_index"]) == list(range(len(tasks))), tasks
assert all(isinstance(t, str) and t for t in tasks.index), list(tasks.index)
assert len(tasks) == info["total_tasks"]

# meta/episodes: one row per episode, in episode order, frames back to back.
eps = pd.read_parquet(root / "meta/episodes/chunk-000/file-000.parquet")
assert list(eps["episode_index"]) == list(range(info["total_episodes"]))
assert (eps["dataset_to_index"] - eps["dataset_from_index"] == eps["length"]).all()
assert list(eps["dataset_from_index"][1:]) == list(eps["dataset_to_index"][:-1])
assert eps["length"].sum() == info["total_frames"]

# data/: the frames table with HF `Sequence(length=n)` columns (fixed-size lists).
data_path = root / info["data_path"].format(chunk_index=0, file_index=0)
table = pq.read_table(data_path)
assert table.schema.field("observation.state").type == pa.list_(pa.float32(), state_dims)
assert table.schema.field("action").type == pa.list_(pa.float32(), action_dims)
assert table.schema.field("timestamp").type == pa.float32()
frames = table.to_pandas()
assert len(frames) == info["total_frames"]
assert list(frames["index"]) == list(range(len(frames)))

# The video, decoded once: each frame with its presentation time.
video_path = root / info["video_path"].format(video_key=vkey, chunk_index=0, file_index=0)
decoded = []
with av.open(str(video_path)) as container:
    stream = container.streams.video[0]
    assert (stream.width, stream.height) == (w, h), (stream.width, stream.height)
    for frame in container.decode(stream):
        decoded.append((float(frame.pts * stream.time_base), frame.to_ndarray(format="rgb24")))
times = np.array([t for t, _ in decoded])
assert len(decoded) == info["total_frames"], (len(decoded), info["total_frames"])

report = json.loads((run / "report.json").read_text())
by_file = {}
for t in report["results"]["tasks"]:
    for e in t["episodes"]:
        by_file["artifacts/" + e["artifact"]] = (t, e)


def clip_of(artifact):
    b = (run / "artifacts" / artifact).read_bytes()
    assert b[:8] == b"ASYCLIP1"
    T, H, W, P, A, _us = np.frombuffer(b, "<u4", 6, 8)
    rgb = np.frombuffer(b, np.uint8, T * H * W * 3, 32).reshape(T, H, W, 3)
    o = 32 + T * H * W * 3
    proprio = np.frombuffer(b, "<f4", T * P, o).reshape(T, P)
    actions = np.frombuffer(b, "<f4", T * A, o + 4 * T * P).reshape(T, A)
    return rgb, proprio, actions


checked = {"episodes": 0, "frames": 0, "video_frames_compared": 0, "clips_compared": 0}
errors = []
for _, ep in eps.iterrows():
    i = ep["episode_index"]
    rows = frames.iloc[ep["dataset_from_index"]:ep["dataset_to_index"]]
    assert (rows["episode_index"] == i).all()
    n = len(rows)
    assert list(rows["frame_index"]) == list(range(n))
    assert np.allclose(rows["timestamp"], np.arange(n) / fps, atol=1e-6)
    assert tasks.iloc[rows["task_index"].iloc[0]].name == ep["tasks"][0]
    state = np.stack(rows["observation.state"].to_numpy()).astype(np.float32)
    action = np.stack(rows["action"].to_numpy()).astype(np.float32)

    # The run's episode file: the recorded rows every 1/fps s from the policy's first step (the
    # report's first keyframe).
    t, e = by_file[ep["assay/episode_file"]]
    assert (t["id"], e["seed"], e["policy"], e["success"]) == (
        ep["assay/task_id"], ep["assay/seed"], ep["assay/policy"], ep["assay/success"])
    rec = pa.ipc.open_file(run / ep["assay/episode_file"]).read_all()
    meta = {k.decode(): v.decode() for k, v in rec.schema.metadata.items()}
    dt = float(meta["assay.dt"])
    stride = round(1 / (fps * dt))
    start = e["imagery"]["keyframes"][0]["step"]
    step = rec.column("step").to_numpy()
    picked = [np.flatnonzero(step == s)[0] for s in range(start, int(step.max()) + 1, stride)
              if (step == s).any()]
    assert len(picked) == n, (i, len(picked), n)
    ee = np.stack([rec.column(f"ee_{a}").to_numpy() for a in "xyz"], 1)[picked]
    holding = (rec.column("grasped").to_numpy()[picked] >= 0).astype(np.float32)
    assert np.array_equal(state, np.column_stack([ee, holding]).astype(np.float32)), i
    cmd = np.stack([rec.column(f"ee_cmd_{a}").to_numpy() for a in "xyz"], 1)[picked].astype(np.float64)
    velocity = (cmd[1:] - cmd[:-1]) / (stride * dt)
    assert np.allclose(action[:-1, :3], velocity, rtol=1e-5, atol=1e-5), i
    assert np.array_equal(action[:-1, 3], holding[1:]) and not action[-1].any(), i

    # The video: every frame at from_timestamp + timestamp, within LeRobot's tolerance.
    from_ts = ep[f"videos/{vkey}/from_timestamp"]
    assert abs(ep[f"videos/{vkey}/to_timestamp"] - from_ts - n / fps) < 1e-6
    got = []
    for ts in from_ts + rows["timestamp"].to_numpy(np.float64):
        k = int(np.argmin(np.abs(times - ts)))
        assert abs(times[k] - ts) < TOLERANCE_S, (i, ts, times[k])
        got.append(decoded[k][1])
    got = np.stack(got).astype(np.int16)

    # Where the run kept a dynamics clip of this episode at this size and rate, the frames are
    # its frames (through H.264's loss) and the states and actions are its own.
    clip = (e.get("imagery") or {}).get("clip")
    if clip:
        rgb, proprio, actions = clip_of(clip)
        if rgb.shape[1:3] == (h, w) and len(rgb) == n:
            assert np.array_equal(proprio, state) and np.array_equal(actions, action), i
            diff = np.abs(got - rgb.astype(np.int16)).mean(axis=(1, 2, 3))
            assert diff.max() < 4.0, (i, diff.max())
            # Each decoded frame is nearest its own clip frame among those that differ from it.
            for k in range(n):
                for j in (k - 1, k + 1):
                    if 0 <= j < n and np.abs(rgb[j].astype(np.int16) - rgb[k]).mean() > 3 * diff[k]:
                        assert np.abs(got[k] - rgb[j].astype(np.int16)).mean() > diff[k], (i, k, j)
            checked["clips_compared"] += 1
            checked["video_frames_compared"] += n
    checked["episodes"] += 1
    checked["frames"] += n

stats = json.loads((root / "meta/stats.json").read_text())
all_states = np.stack(frames["observation.state"].to_numpy())
assert np.allclose(stats["observation.state"]["mean"], all_states.mean(0), atol=1e-5)
assert np.array(stats[vkey]["mean"]).shape == (3, 1, 1)
print(json.dumps(checked))
