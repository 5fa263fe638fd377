#!/usr/bin/env python3
"""Assay's action-conditioned video world model written again in PyTorch, served by the kit.

    python torch_video_model.py serve [--port 0] [--size 64] [--seed 0] [--checkpoint FILE]
        [--train-steps N] [--declare SPACE/STATE/CAMERAS]
    python torch_video_model.py bench [--steps 40] [--threads 1] [--size 64]

The network is the one of `workers/trainer/src/video_model.rs` with its default settings, layer
for layer (`VideoNet`): a convolutional encoder of the real start frames and state, actions
through Fourier features and an MLP, FiLM-conditioned residual blocks stepping a latent map once
per action, and a decoder with skips from the start frames' encoder that composites each
camera's RGB over its start through a mask. It is here for two reasons:

- `serve`: a PyTorch world model behind `assay.v1.WorldModel` (the kit's `serve_world_model`),
  as a lab would serve its own: one network shared by all episodes, one `Session` per imagined
  episode. It imagines at one policy interface, declared in Health: by default the original one
  (the scene camera at `--size`, tool position + holding, tool velocities); `--declare` another,
  e.g. `ee_delta/ee_pos+ee_quat+gripper/image:scene@224x224+wrist_image:wrist@224x224` — every
  camera is resized to `--size` inside the model and its prediction composited back at the
  camera's size. Its weights are a fresh initialisation from `--seed` unless `--checkpoint`
  names a `torch.save`d state dict; `--train-steps N` first trains it N steps on synthetic clips
  (the original interface only).
- `bench`: training throughput of the same architecture on PyTorch's CPU path, for
  `scripts/bench-video-model-torch`, which runs Assay's libtorch (tch) fit beside it: the same
  batch (8 windows of 8 steps of 64x64 frames), the same loss, Adam with the gradient clipped at a
  global norm of 100 and the same cosine learning rate, one intra-op thread. Prints one JSON line.

Needs torch, numpy, and (for `serve`) the kit (imported from ../src when not installed).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

STATE_DIMS = 4
ACTION_DIMS = 4


class Settings:
    """`VideoModelConfig`'s defaults (crates/domain/model/src/video.rs)."""

    depth = 16
    action_embed = 64
    fourier = 4
    blocks = 2
    horizon = 8
    batch = 8
    lr = 1e-3
    state_weight = 0.01
    motion_weight = 10.0


class Conv(nn.Module):
    """Kernel 4, stride 2 (transposed: up), then one-group GroupNorm and SiLU, or a bias."""

    def __init__(self, i, o, transposed=False, norm=True):
        super().__init__()
        cls = nn.ConvTranspose2d if transposed else nn.Conv2d
        self.conv = cls(i, o, 4, stride=2, padding=1, bias=not norm)
        self.norm = nn.GroupNorm(1, o, eps=1e-3) if norm else None

    def forward(self, x):
        y = self.conv(x)
        return F.silu(self.norm(y)) if self.norm is not None else y


class Block(nn.Module):
    """conv → GroupNorm → FiLM(action) → SiLU → conv, added to the input."""

    def __init__(self, c, embed):
        super().__init__()
        self.c = c
        self.groups = next(g for g in range(8, 0, -1) if c % g == 0)
        self.conv1 = nn.Conv2d(c, c, 3, padding=1)
        self.film = nn.Linear(embed, 2 * c)
        self.conv2 = nn.Conv2d(c, c, 3, padding=1)

    def forward(self, z, emb):
        h = F.group_norm(self.conv1(z), self.groups, eps=1e-5)
        film = self.film(emb).view(-1, 2, self.c, 1, 1)
        h = F.silu(h * (film[:, 0] + 1.0) + film[:, 1])
        return z + self.conv2(h)


def heat(uv, m):
    """A Gaussian bump [B, 1, m, m] at uv ([B, 2], x and y in [-1, 1]), one cell wide."""
    line = torch.linspace(-1.0, 1.0, m, device=uv.device).view(1, m)
    sigma = 2.0 / m
    x = torch.exp(-(line - uv[:, 0:1]).square() / (2 * sigma * sigma))
    y = torch.exp(-(line - uv[:, 1:2]).square() / (2 * sigma * sigma))
    return (y.unsqueeze(2) * x.unsqueeze(1)).unsqueeze(1)


class VideoNet(nn.Module):
    """Assay's video world model (see the module's doc), for `cams` cameras stacked on the
    channels, `state_dims` floats of state and `action_dims` floats of action (the original
    interface: 1, 4, 4)."""

    def __init__(self, s=Settings, cams=1, state_dims=STATE_DIMS, action_dims=ACTION_DIMS):
        super().__init__()
        d, e = s.depth, s.action_embed
        c = 4 * d
        self.c, self.fourier, self.cams, self.state_dims = c, s.fourier, cams, state_dims
        features = action_dims * (1 + 2 * s.fourier)
        self.enc = nn.ModuleList([Conv(3 * cams, d), Conv(d, 2 * d), Conv(2 * d, c)])
        self.state_in = nn.Linear(state_dims, c)
        self.act_in = nn.Linear(features, e)
        self.act_out = nn.Linear(e, e)
        self.blocks = nn.ModuleList([Block(c, e) for _ in range(s.blocks)])
        self.head_hidden = nn.Linear(c + e, 64)
        self.head_out = nn.Linear(64, state_dims)
        self.proj = nn.Linear(state_dims, 2)
        guides, hm = state_dims + 2, 2
        self.dec = nn.ModuleList([
            Conv(c + guides + hm, 2 * d, transposed=True),
            Conv(4 * d + hm, d, transposed=True),
            Conv(2 * d + hm, 4 * cams, transposed=True, norm=False),
        ])
        # Normalisation of actions and states (from training clips; identity until fitted).
        for name, n in (("act", action_dims), ("state", state_dims)):
            self.register_buffer(f"{name}_mean", torch.zeros(n))
            self.register_buffer(f"{name}_dev", torch.ones(n))

    def embed(self, actions):
        a = ((actions - self.act_mean) / self.act_dev).clamp(-10.0, 10.0)
        feats = [a]
        for k in range(self.fourier):
            x = a * (math.pi * 2**k)
            feats += [torch.sin(x), torch.cos(x)]
        return self.act_out(F.silu(self.act_in(torch.cat(feats, -1))))

    def start(self, first, state):
        """first: [B, 3, H, W] in [0, 1]; state: [B, S] raw. Returns the rollout's state."""
        s1 = self.enc[0](first - 0.5)
        s2 = self.enc[1](s1)
        sn = (state - self.state_mean) / self.state_dev
        z = self.enc[2](s2) + self.state_in(sn).view(-1, self.c, 1, 1)
        m = z.shape[2]
        line = torch.linspace(-1.0, 1.0, m, device=z.device)
        coords = torch.stack([line.view(1, m).expand(m, m), line.view(m, 1).expand(m, m)]).unsqueeze(0)
        return {"coords": coords, "uv0": self.proj(sn), "first": first, "skips": (s1, s2), "z": z, "state": sn}

    def step(self, r, emb):
        """One action's step: the next frame in [0, 1] and the next normalised state."""
        z = r["z"]
        for block in self.blocks:
            z = block(z, emb)
        pooled = z.mean(dim=(2, 3))
        r["state"] = r["state"] + self.head_out(F.silu(self.head_hidden(torch.cat([pooled, emb], -1))))
        b, m = z.shape[0], z.shape[2]
        guides = torch.cat([
            r["state"].view(b, -1, 1, 1).expand(b, self.state_dims, m, m),
            r["coords"].expand(b, 2, m, m),
        ], 1)
        uv = self.proj(r["state"])

        def with_heat(x, *parts):
            size = x.shape[2]
            return torch.cat([x, *parts, heat(uv, size), heat(r["uv0"], size)], 1)

        s1, s2 = r["skips"]
        u = self.dec[0](with_heat(z, guides))
        u = self.dec[1](with_heat(u, s2))
        out = self.dec[2](with_heat(u, s1))
        k = self.cams
        rgb, alpha = torch.sigmoid(out[:, :3 * k]), torch.sigmoid(out[:, 3 * k:4 * k])
        frame = alpha.repeat_interleave(3, 1) * rgb + (1 - alpha.repeat_interleave(3, 1)) * r["first"]
        r["z"], r["rgb"], r["alpha"] = z, rgb, alpha
        return frame, r["state"]

    def loss(self, batch, s=Settings):
        first, state, actions, targets, target_states, mask = batch
        r = self.start(first, state)
        emb = self.embed(actions)
        target_sn = (target_states - self.state_mean) / self.state_dev
        total = first.new_zeros(())
        for t in range(mask.shape[0]):
            frame, sn = self.step(r, emb[t])
            target = targets[t]
            moved = ((target - first).abs().amax(1, keepdim=True) > 0.1).float()
            image = ((frame - target).abs() * (moved * s.motion_weight + 1.0)).mean(dim=(1, 2, 3))
            st = (sn - target_sn[t]).square().mean(1)
            total = total + ((image + st * s.state_weight) * mask[t]).sum()
        return total / mask.sum().clamp_min(1.0)


# ---------------------------------------------------------------------------------------------
# Data: synthetic clips (a square of a random colour moved by noisy velocity commands), as
# `workers/trainer/examples/world_model_bench.rs` draws them.


def synthetic_clip(length, size, rng):
    color = rng.uniform(60, 255, 3).astype(np.uint8)
    side = size // 6
    free = size - side
    x, y = rng.random(), rng.random()
    vx, vy = rng.uniform(-1, 1, 2)
    frames = np.empty((length, size, size, 3), np.uint8)
    states = np.zeros((length, STATE_DIMS), np.float32)
    actions = np.zeros((length, ACTION_DIMS), np.float32)
    for t in range(length):
        frames[t] = (30, 30, 40)
        px, py = int(x * free), int(y * free)
        frames[t, py:py + side, px:px + side] = color
        states[t, :2] = (x, y)
        if t + 1 < length:
            actions[t, :2] = (vx + rng.uniform(-0.5, 0.5), vy + rng.uniform(-0.5, 0.5))
        x = min(max(x + 0.1 * actions[t, 0], 0.0), 1.0)
        y = min(max(y + 0.1 * actions[t, 1], 0.0), 1.0)
    return frames, states, actions


def windows(clips, horizon):
    return [(i, s, min(horizon, len(c[0]) - 1 - s)) for i, c in enumerate(clips) for s in range(len(c[0]) - 1)]


def make_batch(clips, picked):
    """The windows `picked` as tensors: first frames, states, then time-major steps (as Rust)."""
    b, steps = len(picked), max(w[2] for w in picked)
    size = clips[0][0].shape[1]
    first = np.zeros((b, size, size, 3), np.uint8)
    state = np.zeros((b, STATE_DIMS), np.float32)
    actions = np.zeros((steps, b, ACTION_DIMS), np.float32)
    targets = np.zeros((steps, b, size, size, 3), np.uint8)
    target_states = np.zeros((steps, b, STATE_DIMS), np.float32)
    mask = np.zeros((steps, b), np.float32)
    for j, (ci, s, n) in enumerate(picked):
        frames, states, acts = clips[ci]
        first[j], state[j] = frames[s], states[s]
        actions[:n, j] = acts[s:s + n]
        targets[:n, j] = frames[s + 1:s + 1 + n]
        target_states[:n, j] = states[s + 1:s + 1 + n]
        mask[:n, j] = 1.0

    def pixels(a):
        return torch.from_numpy(a).permute(*range(a.ndim - 3), -1, -3, -2).float() / 255.0

    return (pixels(first), torch.from_numpy(state), torch.from_numpy(actions),
            pixels(targets), torch.from_numpy(target_states), torch.from_numpy(mask))


def fit_stats(net, clips):
    acts = np.concatenate([c[2][:-1] for c in clips])
    states = np.concatenate([c[1] for c in clips])
    for name, rows in (("act", acts), ("state", states)):
        dev = rows.std(0)
        dev[dev < 1e-6] = 1.0
        getattr(net, f"{name}_mean").copy_(torch.from_numpy(rows.mean(0)))
        getattr(net, f"{name}_dev").copy_(torch.from_numpy(dev))


def train(net, clips, steps, seed=0, s=Settings):
    """Trains `net` on `clips` for `steps` steps; returns (the mean loss of the last 100 steps,
    as Assay's `final_train_loss`; wall s; CPU s)."""
    fit_stats(net, clips)
    wins = windows(clips, s.horizon)
    opt = torch.optim.Adam(net.parameters(), lr=s.lr, eps=1e-8)
    rng = np.random.default_rng(seed)
    recent = []
    wall, cpu = time.perf_counter(), time.process_time()
    for step in range(steps):
        for g in opt.param_groups:
            g["lr"] = s.lr * (0.1 + 0.9 * 0.5 * (1.0 + math.cos(math.pi * step / max(steps, 1))))
        picked = [wins[k] for k in rng.integers(0, len(wins), s.batch)]
        value = net.loss(make_batch(clips, picked))
        opt.zero_grad(set_to_none=True)
        value.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 100.0)
        opt.step()
        if steps - step <= 100:
            recent.append(float(value.detach()))
    loss = sum(recent) / len(recent) if recent else float("nan")
    return loss, time.perf_counter() - wall, time.process_time() - cpu


# ---------------------------------------------------------------------------------------------
# Serving.


def _resized(x, size):
    """[N, C, h, w] at size x size: area-averaged down, bilinear up (as Assay's model)."""
    h, w = x.shape[-2:]
    if (h, w) == (size, size):
        return x
    if h >= size and w >= size:
        return F.adaptive_avg_pool2d(x, size)
    return F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)


class Session:
    """One imagined episode in a shared `VideoNet` (the kit makes one per Reset): every camera
    resized to the model's size on the way in, its prediction composited back at the camera's
    own size over the camera's real start frame."""

    def __init__(self, net, size, cameras, holding_last=True):
        self.net, self.size, self.cameras, self.holding_last = net, size, cameras, holding_last
        self.rollout = None

    def reset(self, frame, state, instruction, views=None):
        given = [frame] + [views[name] for name, _, _ in self.cameras[1:] if name in (views or {})]
        if [f.shape[:2] for f in given] != [(h, w) for _, w, h in self.cameras]:
            want = ", ".join(f"{n} {w}x{h}" for n, w, h in self.cameras)
            got = ", ".join(f"{f.shape[1]}x{f.shape[0]}" for f in given)
            raise ValueError(f"frames of {got}: this model imagines {want}")
        if state.shape != (self.net.state_dims,):
            raise ValueError(f"a state of {state.shape[0]} floats: this model takes {self.net.state_dims}")
        with torch.no_grad():
            self.full = [torch.from_numpy(f.copy()).permute(2, 0, 1)[None].float() / 255.0 for f in given]
            first = torch.cat([_resized(f, self.size) for f in self.full], 1)
            self.rollout = self.net.start(first, torch.from_numpy(state.copy())[None])

    def step(self, actions):
        frames, states = [[] for _ in self.cameras], []
        with torch.no_grad():
            emb = self.net.embed(torch.from_numpy(actions))
            for k in range(len(actions)):
                small, sn = self.net.step(self.rollout, emb[k:k + 1])
                for c, start in enumerate(self.full):
                    h, w = start.shape[-2:]
                    if (h, w) == (self.size, self.size):
                        picture = small[:, 3 * c:3 * c + 3]
                    else:
                        size = dict(size=(h, w), mode="bilinear", align_corners=False)
                        rgb = F.interpolate(self.rollout["rgb"][:, 3 * c:3 * c + 3], **size)
                        alpha = F.interpolate(self.rollout["alpha"][:, c:c + 1], **size)
                        picture = alpha * rgb + (1 - alpha) * start
                    frames[c].append((picture[0].permute(1, 2, 0).clamp(0, 1) * 255).round().byte())
                raw = sn[0] * self.net.state_dev + self.net.state_mean
                if self.holding_last:
                    raw[-1] = float(raw[-1] >= 0.5)  # holding, 0 or 1
                states.append(raw)
        return {
            "frames": torch.stack(frames[0]),
            "states": torch.stack(states),
            "views": {name: torch.stack(f) for (name, _, _), f in zip(self.cameras[1:], frames[1:])},
        }


STATE_PART_DIMS = {"ee_pos": 3, "ee_quat": 4, "ee_yaw": 1, "gripper": 1, "holding": 1}
ACTION_SPACE_DIMS = {"tool_velocity": 4, "ee_delta": 7, "ee_pose": 8}


def _kit():
    try:
        import assay_policy_kit  # noqa: F401
    except ImportError:
        sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))


def serve(args):
    _kit()
    from assay_policy_kit import Camera, Interface, serve_world_model_forever

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    interface = _declared(args.declare, args.size, Camera, Interface)
    cameras = [(c.name, c.width, c.height) for c in interface.cameras]
    unknown = [p for p in interface.state if p not in STATE_PART_DIMS]
    if unknown or interface.action_space not in ACTION_SPACE_DIMS or any(w == 0 for _, w, _ in cameras):
        raise SystemExit(f"--declare: sized cameras, state parts of {sorted(STATE_PART_DIMS)} and an "
                         f"action space of {sorted(ACTION_SPACE_DIMS)}")
    dims = sum(STATE_PART_DIMS[p] for p in interface.state), ACTION_SPACE_DIMS[interface.action_space]
    if args.train_steps and (len(cameras), *dims) != (1, STATE_DIMS, ACTION_DIMS):
        raise SystemExit("--train-steps: the synthetic clips are of the original interface only")
    net = VideoNet(cams=len(cameras), state_dims=dims[0], action_dims=dims[1]).eval()
    how = f"fresh weights from seed {args.seed}"
    if args.checkpoint:
        net.load_state_dict(torch.load(args.checkpoint, map_location="cpu"))
        how = f"weights of {args.checkpoint}"
    if args.train_steps:
        rng = np.random.default_rng(args.seed)
        loss, wall, _ = train(net.train(), [synthetic_clip(40, args.size, rng) for _ in range(16)], args.train_steps)
        net.eval()
        how += f", then {args.train_steps} steps on synthetic clips (loss {loss:.4f}, {wall:.0f} s)"
    params = sum(p.numel() for p in net.parameters())
    holding_last = interface.state[-1:] == ["holding"]
    serve_world_model_forever(
        lambda: Session(net, args.size, cameras, holding_last), host=args.host, port=args.port,
        name=f"torch-video-model ({params} parameters, torch {torch.__version__})",
        description=f"Assay's video world model in PyTorch; {how}",
        width=cameras[0][1], height=cameras[0][2], action_dims=dims[1],
        # The interface it imagines in: by default the scene camera at its frame size, tool
        # position + holding, tool velocities; `--declare` another, as
        # `space/state/camera[+camera...]`.
        interfaces=[interface],
    )


def _declared(text, size, Camera, Interface):
    if not text:
        return Interface(cameras=[Camera("image", "scene", size, size)])
    space, state, cameras = text.split("/")
    return Interface(
        cameras=[Camera.parse(c) for c in cameras.split("+")],
        state=state.split("+"),
        action_space=space,
    )


def bench(args):
    torch.set_num_threads(args.threads)
    torch.set_num_interop_threads(1)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    # As the Rust bench: 16 clips of 40 frames.
    clips = [synthetic_clip(40, args.size, rng) for _ in range(16)]
    net = VideoNet()
    train(net, clips, 3)  # warm-up
    net = VideoNet()
    loss, wall, cpu = train(net, clips, args.steps)
    print(json.dumps({
        "bench": "video-model-train",
        "implementation": "pytorch",
        "torch": torch.__version__,
        "threads": args.threads,
        "image_size": args.size,
        "batch": Settings.batch,
        "horizon": Settings.horizon,
        "parameters": sum(p.numel() for p in net.parameters()),
        "steps": args.steps,
        "seconds": wall,
        "cpu_seconds": cpu,
        "steps_per_s": args.steps / wall,
        "steps_per_cpu_s": args.steps / cpu,
        "final_loss": loss,
    }))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    sv = sub.add_parser("serve", help="serve the model as assay.v1.WorldModel")
    sv.add_argument("--host", default="127.0.0.1")
    sv.add_argument("--port", type=int, default=0)
    sv.add_argument("--size", type=int, default=64, help="frame side (a multiple of 8)")
    sv.add_argument("--seed", type=int, default=0)
    sv.add_argument("--checkpoint", help="a torch.save'd state dict of VideoNet")
    sv.add_argument("--train-steps", type=int, default=0, help="train this many steps on synthetic clips first")
    sv.add_argument("--threads", type=int, default=1)
    sv.add_argument("--declare", help="declare this interface instead of the model's own: SPACE/STATE+STATE/CAMERA+CAMERA, "
                    "e.g. ee_delta/ee_pos+ee_quat+gripper/image:scene@224x224+wrist_image:wrist@224x224")
    bn = sub.add_parser("bench", help="training throughput on synthetic clips, one JSON line")
    bn.add_argument("--steps", type=int, default=40)
    bn.add_argument("--threads", type=int, default=1)
    bn.add_argument("--size", type=int, default=64)
    args = p.parse_args(argv)
    if args.size % 8:
        p.error(f"--size {args.size}: a multiple of 8")
    (serve if args.command == "serve" else bench)(args)


if __name__ == "__main__":
    main()
