"""Serving a LeRobot policy (ACT, Diffusion, pi0, SmolVLA, ...) with the kit.

`LeRobotAdapter.from_pretrained(DIR)` loads a checkpoint folder as LeRobot's own evaluation
does (lerobot >= 0.4): the policy and its saved pre- and post-processor pipelines
(`policy_preprocessor.json`, `policy_postprocessor.json`: normalization with the dataset's
statistics lives there, not in the model), and answers an observation with
`postprocessor(policy.select_action(preprocessor(batch)))`. Its cameras and state are read from
the checkpoint's `input_features`. The plain constructor wraps a policy object (and, optionally,
its pipelines) without importing lerobot here: it relies on `reset()` and
`select_action(batch) -> [B, action_dim]`, the batch keyed by the dataset's feature names.
"""

from __future__ import annotations

import copy
import threading
from typing import Any, Dict, Mapping, Optional

import numpy as np

try:  # tensors when torch is there (a real LeRobot policy needs it), else numpy arrays
    import torch as _torch
except Exception:  # noqa: BLE001 - torch missing or broken: fall back to numpy
    _torch = None

OBS_PREFIX = "observation/"
IMAGE_FEATURE_PREFIX = "observation.images."
# Assay's camera sources a checkpoint's camera name may name directly.
CAMERA_SOURCES = ("scene", "top", "front", "oblique_left", "oblique_right", "wrist")


class LeRobotAdapter:
    """A kit policy around a LeRobot policy.

    image_keys: the kit's camera name -> LeRobot's image feature, e.g.
                {"image": "observation.images.top", "wrist": "observation.images.wrist"};
                default: every camera "X" of the observation as "observation.images.X".
    state_key:  LeRobot's state feature (None: no state).
    device:     where the tensors go (default: the policy's parameters' device, else CPU).
    preprocessor, postprocessor: LeRobot's pipelines around `select_action` (from
                `make_pre_post_processors`); without them the policy gets the raw batch and its
                raw output is returned, which is right only for a policy that normalizes itself
                (LeRobot before 0.4).

    The batch it builds: each image float32 [1, 3, H, W] in [0, 1] (channels first), the state
    float32 [1, S], "task": [prompt]; torch tensors when torch imports, else numpy arrays.
    LeRobot policies keep per-episode state (their action queue): serve one adapter per
    episode, `serve_grpc(factory=adapter.for_episode)`. Those share the loaded model and its
    weights, each keeps its own queue, and one lock serializes their inference, so episodes may
    run concurrently.
    """

    def __init__(
        self,
        policy: Any,
        image_keys: Optional[Mapping[str, str]] = None,
        state_key: Optional[str] = "observation.state",
        device: Any = None,
        preprocessor: Any = None,
        postprocessor: Any = None,
    ):
        self.policy = policy
        self.image_keys = dict(image_keys) if image_keys is not None else None
        self.state_key = state_key
        self.device = device if device is not None else _policy_device(policy)
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor
        self.lock = threading.Lock()
        # name -> shape of the checkpoint's input and output features (from_pretrained).
        self.input_features: Dict[str, tuple] = {}
        self.output_features: Dict[str, tuple] = {}

    @classmethod
    def from_pretrained(
        cls,
        path: Any,
        device: Any = None,
        image_keys: Optional[Mapping[str, str]] = None,
        state_key: Optional[str] = "auto",
    ) -> "LeRobotAdapter":
        """Loads a LeRobot checkpoint folder (or a hub id, where the hub is reachable) with its
        processors, as `lerobot-eval` does. `device`: "cpu", "cuda", ... (default: CUDA when
        torch sees it, else CPU; the saved pipeline's device step is set to it). Cameras: each
        image feature `observation.images.X` is the kit's camera X (`observation.image`:
        "image"), unless `image_keys` maps them; the state is `observation.state` when the
        checkpoint has it (`state_key` overrides; None: no state)."""
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        path = str(path)
        cfg = PreTrainedConfig.from_pretrained(path)
        if device is None:
            device = "cuda" if torch.cuda.is_available() else "cpu"
        cfg.device = str(device)
        policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        policy.eval()
        pre, post = make_pre_post_processors(
            cfg,
            pretrained_path=path,
            preprocessor_overrides={"device_processor": {"device": str(device)}},
        )
        inputs = {k: tuple(v.shape) for k, v in cfg.input_features.items()}
        if image_keys is None:
            image_keys = {
                camera_name(k): k for k, shape in inputs.items() if _is_image_feature(k, shape)
            }
        if state_key == "auto":
            state_key = "observation.state" if "observation.state" in inputs else None
        adapter = cls(
            policy, image_keys=image_keys, state_key=state_key, device=torch.device(device),
            preprocessor=pre, postprocessor=post,
        )
        adapter.input_features = inputs
        adapter.output_features = {k: tuple(v.shape) for k, v in cfg.output_features.items()}
        return adapter

    def interface(
        self,
        state: Optional[Any] = None,
        action_space: Optional[str] = None,
        sources: Optional[Mapping[str, str]] = None,
        **kwargs: Any,
    ):
        """The kit's Interface of a loaded checkpoint: its cameras at the sizes it was trained
        on, its state and its action space. A camera named as one of Assay's views ("top",
        "wrist", ...) is that view; any other is the scene camera (`sources` maps names to
        sources). State parts and action space follow from the widths where Assay's export
        writes them (state 4: ee_pos + holding; actions 4: tool_velocity, 7: ee_delta, 8:
        ee_pose); give them otherwise."""
        from .interface import Camera, Interface

        if not self.input_features:
            raise ValueError("interface(): only for an adapter made by from_pretrained")
        sources = dict(sources or {})
        cameras = []
        for name, key in (self.image_keys or {}).items():
            shape = self.input_features.get(key)
            if shape is None or len(shape) != 3:
                raise ValueError(f"camera {name!r}: the checkpoint has no image feature {key!r}")
            source = sources.get(name, name if name in CAMERA_SOURCES else "scene")
            cameras.append(Camera(name=name, source=source, width=int(shape[2]), height=int(shape[1])))
        if state is None:
            width = self.input_features.get(self.state_key, (0,))[0] if self.state_key else 0
            if width == 4:
                state = ["ee_pos", "holding"]
            elif width == 0:
                state = []
            else:
                raise ValueError(
                    f"the checkpoint's state has {width} floats: name its parts (state=...)"
                )
        elif isinstance(state, str):
            state = state.split("+")
        if action_space is None:
            width = self.output_features.get("action", (0,))[0]
            spaces = {4: "tool_velocity", 7: "ee_delta", 8: "ee_pose"}
            if width not in spaces:
                raise ValueError(
                    f"the checkpoint's actions have {width} floats: name the action space"
                )
            action_space = spaces[width]
        iface = Interface(cameras=cameras, state=list(state), action_space=action_space, **kwargs)
        iface.validate()
        want = self.input_features.get(self.state_key, (0,))[0] if self.state_key else 0
        if iface.state_dims() != want:
            raise ValueError(
                f"state {'+'.join(iface.state) or '(none)'} is {iface.state_dims()} floats; "
                f"the checkpoint's {self.state_key} has {want}"
            )
        actions = self.output_features.get("action", (0,))[0]
        if iface.action_dims() != actions:
            raise ValueError(
                f"action space {iface.action_space} is {iface.action_dims()} floats; "
                f"the checkpoint's actions have {actions}"
            )
        return iface

    def for_episode(self) -> "LeRobotAdapter":
        """A reset adapter for one more episode over the same loaded model. The policy is copied
        shallowly (its modules, parameters and buffers are the same objects) and reset, so the
        episode has its own action queue; per-episode helpers that the policy keeps outside its
        modules (ACT's temporal ensembler) are copied too. Inference is serialized by the lock
        all copies share."""
        policy = copy.copy(self.policy)
        for name, value in list(vars(policy).items()):
            if name.startswith("_") or _is_module(value) or not callable(getattr(value, "reset", None)):
                continue
            policy.__dict__[name] = copy.deepcopy(value)
        other = copy.copy(self)
        other.policy = policy
        other.lock = self.lock
        other.reset()
        return other

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
                action = self._act(batch)
        else:
            action = self._act(batch)
        if hasattr(action, "detach"):
            action = action.detach().float().cpu().numpy()
        a = np.asarray(action, dtype=np.float32)
        if a.ndim >= 2 and a.shape[0] == 1:
            a = a[0]
        return a


    def _act(self, batch: Dict[str, Any]) -> Any:
        with self.lock:
            return self._act_locked(batch)

    def _act_locked(self, batch: Dict[str, Any]) -> Any:
        if self.preprocessor is not None:
            batch = self.preprocessor(batch)
        action = self.policy.select_action(batch)
        if self.postprocessor is not None:
            action = self.postprocessor(action)
        return action


def camera_name(feature: str) -> str:
    """The kit's camera name of a LeRobot image feature: `observation.images.top` -> "top",
    `observation.image` -> "image"."""
    if feature.startswith(IMAGE_FEATURE_PREFIX):
        return feature[len(IMAGE_FEATURE_PREFIX):]
    return feature.rsplit(".", 1)[-1]


def _is_module(value: Any) -> bool:
    return _torch is not None and isinstance(value, _torch.nn.Module)


def _is_image_feature(key: str, shape: tuple) -> bool:
    return len(shape) == 3 and (key.startswith(IMAGE_FEATURE_PREFIX) or key == "observation.image")


def _policy_device(policy: Any) -> Any:
    params = getattr(policy, "parameters", None)
    if _torch is None or not callable(params):
        return None
    try:
        return next(iter(params())).device
    except (StopIteration, TypeError):
        return None
