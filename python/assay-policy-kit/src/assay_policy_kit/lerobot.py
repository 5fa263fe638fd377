"""Serving a LeRobot policy (ACT, Diffusion, pi0, SmolVLA, ...) with the kit, without importing
lerobot here: the adapter only relies on LeRobot's policy API, `reset()` and
`select_action(batch) -> [B, action_dim]`, with the batch keyed by the dataset's feature names.
"""

from __future__ import annotations

from typing import Any, Dict, Mapping, Optional

import numpy as np

try:  # tensors when torch is there (a real LeRobot policy needs it), else numpy arrays
    import torch as _torch
except Exception:  # noqa: BLE001 - torch missing or broken: fall back to numpy
    _torch = None

OBS_PREFIX = "observation/"


class LeRobotAdapter:
    """A kit policy around a LeRobot policy.

    image_keys: the kit's camera name -> LeRobot's image feature, e.g.
                {"image": "observation.images.top", "wrist": "observation.images.wrist"};
                default: every camera "X" of the observation as "observation.images.X".
    state_key:  LeRobot's state feature (None: no state).
    device:     where the tensors go (default: the policy's parameters' device, else CPU).

    The batch it builds: each image float32 [1, 3, H, W] in [0, 1] (channels first), the state
    float32 [1, S], "task": [prompt]; torch tensors when torch imports, else numpy arrays.
    LeRobot policies keep per-episode state (their action queue), so serve one adapter per
    episode: `serve_grpc(factory=lambda: LeRobotAdapter(policy))` resets it at every episode;
    with one loaded model shared by the factory, episodes must not run concurrently.
    """

    def __init__(
        self,
        policy: Any,
        image_keys: Optional[Mapping[str, str]] = None,
        state_key: Optional[str] = "observation.state",
        device: Any = None,
    ):
        self.policy = policy
        self.image_keys = dict(image_keys) if image_keys is not None else None
        self.state_key = state_key
        self.device = device if device is not None else _policy_device(policy)

    def reset(self, *args, **kwargs) -> None:
        """Starts an episode: `policy.reset()` (the kit's task_id, seed, instruction are unused)."""
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset()

    def batch(self, obs: Mapping[str, Any]) -> Dict[str, Any]:
        """LeRobot's batch of one observation of the kit."""
        if self.image_keys is not None:
            images = {}
            for name, key in self.image_keys.items():
                if OBS_PREFIX + name not in obs:
                    raise KeyError(f"the observation has no camera {name!r} (for {key})")
                images[key] = obs[OBS_PREFIX + name]
        else:
            images = {
                "observation.images." + k[len(OBS_PREFIX):]: v
                for k, v in obs.items()
                if k.startswith(OBS_PREFIX) and k != OBS_PREFIX + "state"
                and np.asarray(v).dtype == np.uint8 and np.ndim(v) == 3
            }
        batch: Dict[str, Any] = {}
        for key, img in images.items():
            a = np.asarray(img)
            if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
                raise ValueError(f"{key}: expected uint8 [H, W, 3], got {a.dtype} {list(a.shape)}")
            chw = np.ascontiguousarray(a.transpose(2, 0, 1)[None], dtype=np.float32)
            chw /= np.float32(255.0)
            batch[key] = self._tensor(chw)
        if self.state_key is not None:
            state = np.asarray(obs[OBS_PREFIX + "state"], dtype=np.float32).reshape(1, -1)
            batch[self.state_key] = self._tensor(np.array(state))
        batch["task"] = [str(obs.get("prompt", ""))]
        return batch

    def _tensor(self, a: np.ndarray) -> Any:
        if _torch is None:
            return a
        t = _torch.from_numpy(a)
        return t.to(self.device) if self.device is not None else t

    def __call__(self, obs: Mapping[str, Any]) -> np.ndarray:
        batch = self.batch(obs)
        if _torch is not None:
            with _torch.inference_mode():
                action = self.policy.select_action(batch)
        else:
            action = self.policy.select_action(batch)
        if hasattr(action, "detach"):
            action = action.detach().float().cpu().numpy()
        a = np.asarray(action, dtype=np.float32)
        if a.ndim >= 2 and a.shape[0] == 1:
            a = a[0]
        return a


def _policy_device(policy: Any) -> Any:
    params = getattr(policy, "parameters", None)
    if _torch is None or not callable(params):
        return None
    try:
        return next(iter(params())).device
    except (StopIteration, TypeError):
        return None
