"""Serving a world model as Assay's gRPC service `assay.v1.WorldModel`
(proto/assay/v1/world_model.proto), so that Assay's world-model proxy imagines policies'
episodes in it.

    class MyModel:                      # one instance per imagined episode
        def reset(self, frame, state, instruction):
            ...                         # frame: uint8 [H, W, 3], state: float32 [S]
        def step(self, actions):        # float32 [K, D]
            return frames               # uint8 [K, H, W, 3], or (frames, states [K, S])

    serve_world_model_forever(MyModel, name="my-video-model", action_dims=4)
"""

from __future__ import annotations

import inspect
import threading
from collections import OrderedDict
from typing import Any, Callable, Optional, Sequence, Tuple

import grpc
import numpy as np

from . import auth
from ._policy import describe
from ._proto import world_model_pb2 as pb
from ._proto import world_model_pb2_grpc as pb_grpc
from .grpc_server import GrpcPolicyServer, _serve_until_signal, _start
from .interface import MAX_PIXELS, Interface
from .observation import BadRequest, _frame

MAX_EPISODES = 1024
# Most actions in one Step.
MAX_ACTIONS = 1024


class WorldModelError(Exception):
    """The model answered something that is not frames (and states)."""


class _Episode:
    __slots__ = ("model", "name", "views", "lock")

    def __init__(self, model: Any, name: str, views: list):
        self.model = model
        self.name = name
        self.views = views  # the names of the cameras after the first
        self.lock = threading.Lock()


def _numpy(raw: Any) -> Any:
    if hasattr(raw, "detach") and hasattr(raw, "cpu"):  # a torch tensor, maybe on a GPU
        return raw.detach().cpu().numpy()
    return raw


def to_frames(raw: Any) -> np.ndarray:
    """A model's frames as a uint8 [K, H, W, 3] array ([H, W, 3] is one frame). Their count and
    size are not checked here: Assay's client refuses an answer that does not fit the request."""
    try:
        a = np.asarray(_numpy(raw))
    except (TypeError, ValueError) as e:
        raise WorldModelError(f"the model returned {type(raw).__name__} as frames, not an array: {e}") from e
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4 or a.shape[-1] != 3:
        raise WorldModelError(f"the model returned frames of shape {list(a.shape)}; expected [K, H, W, 3]")
    if a.dtype != np.uint8:
        raise WorldModelError(
            f"the model returned {a.dtype} frames; expected uint8 RGB (from floats in [0, 1]: "
            "(x.clip(0, 1) * 255).round().astype(np.uint8), or for a torch tensor "
            "(x.clamp(0, 1) * 255).round().byte())"
        )
    return np.ascontiguousarray(a)


def to_states(raw: Any) -> Optional[np.ndarray]:
    """A model's states as a float32 [K, S] array ([S] is one state); None when it gave none."""
    if raw is None:
        return None
    try:
        a = np.asarray(_numpy(raw), dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise WorldModelError(f"the model returned {type(raw).__name__} as states, not numbers: {e}") from e
    if a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] < 1:
        raise WorldModelError(f"the model returned states of shape {list(a.shape)}; expected [K, S]")
    return np.ascontiguousarray(a)


def split_answer(raw: Any) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """`step`'s answer: frames, a tuple (frames, states), or a dict {"frames", "states"} (see
    `split_views` for the other cameras' frames)."""
    if isinstance(raw, dict):
        if "frames" not in raw:
            raise WorldModelError(f"the model returned a dict without 'frames' (keys: {sorted(raw)})")
        return to_frames(raw["frames"]), to_states(raw.get("states"))
    if isinstance(raw, tuple):
        if len(raw) != 2:
            raise WorldModelError(
                f"the model returned a tuple of {len(raw)}; expected frames or (frames, states)"
            )
        return to_frames(raw[0]), to_states(raw[1])
    return to_frames(raw), None


def split_views(raw: Any, names: list) -> list:
    """The frames of the cameras after the first in `step`'s answer: its dict's "views", a dict
    {camera name: uint8 [K, H, W, 3]} (or a list in the interface's order); one array per name."""
    if not names:
        return []
    views = raw.get("views") if isinstance(raw, dict) else None
    if views is None:
        raise WorldModelError(
            f"the interface has cameras {names} after the first: answer "
            '{"frames": ..., "states": ..., "views": {name: frames}}'
        )
    if isinstance(views, dict):
        missing = [n for n in names if n not in views]
        if missing:
            raise WorldModelError(f"the model returned no frames of camera(s) {missing} (views: {sorted(views)})")
        return [to_frames(views[n]) for n in names]
    views = list(views)
    if len(views) != len(names):
        raise WorldModelError(f"the model returned {len(views)} views for cameras {names}")
    return [to_frames(v) for v in views]


def _call_reset(reset: Callable, frame: np.ndarray, state: np.ndarray, instruction: str, **extra) -> None:
    """`reset(frame, state, instruction)`, with those of `extra` (task_id, seed, frames) that its
    signature names (all of them when it takes **kwargs)."""
    try:
        params = list(inspect.signature(reset).parameters.values())
    except (TypeError, ValueError):  # no signature (a builtin)
        reset(frame, state, instruction)
        return
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        reset(frame, state, instruction, **extra)
        return
    names = {
        p.name
        for p in params
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }
    reset(frame, state, instruction, **{k: v for k, v in extra.items() if k in names})


class WorldModelServicer(pb_grpc.WorldModelServicer):
    """`assay.v1.WorldModel` over a factory of models: one model object per live episode."""

    def __init__(
        self,
        factory: Callable[[], Any],
        name: str = "world-model",
        description: str = "",
        width: int = 0,
        height: int = 0,
        action_dims: int = 0,
        max_episodes: int = MAX_EPISODES,
        interfaces: Optional[Sequence[Interface]] = None,
    ):
        if not callable(factory):
            raise TypeError(
                f"factory {factory!r} is not callable: give the model's class, or a function that "
                "returns a fresh model (e.g. lambda: MyModel(shared_network))"
            )
        if (width == 0) != (height == 0) or not (0 <= width <= MAX_PIXELS and 0 <= height <= MAX_PIXELS):
            raise ValueError(f"frame size {width}x{height}: both 0 (any) or both 1 to {MAX_PIXELS}")
        if action_dims < 0:
            raise ValueError(f"action_dims {action_dims} is negative (0: any width)")
        self._factory = factory
        self._name = name
        self._description = description
        self._width = int(width)
        self._height = int(height)
        self._action_dims = int(action_dims)
        self._max_episodes = int(max_episodes)
        self._interfaces = list(interfaces or [])
        for i, interface in enumerate(self._interfaces):
            if not isinstance(interface, Interface):
                raise TypeError(f"interfaces[{i}] is {type(interface).__name__}, not an assay_policy_kit.Interface")
            interface.validate()
        self._episodes: "OrderedDict[str, _Episode]" = OrderedDict()
        self._lock = threading.Lock()

    @property
    def live_episodes(self) -> int:
        with self._lock:
            return len(self._episodes)

    def Health(self, request, context):
        return pb.WorldModelHealthResponse(
            name=self._name,
            description=self._description,
            width=self._width,
            height=self._height,
            action_dims=self._action_dims,
            live_episodes=self.live_episodes,
            interfaces=[i.to_proto() for i in self._interfaces],
        )

    def _frames(self, request) -> np.ndarray:
        if len(request.frames) == 0:
            raise BadRequest("no frame to start from (frames is empty)")
        first = request.frames[0]
        size = (first.width, first.height)
        if self._width and size != (self._width, self._height):
            raise BadRequest(
                f"a {first.width}x{first.height} frame; the model takes {self._width}x{self._height}"
            )
        frames = []
        for i, img in enumerate(request.frames):
            if (img.width, img.height) != size:
                raise BadRequest(
                    f"frame {i} is {img.width}x{img.height}, frame 0 {first.width}x{first.height}"
                )
            frames.append(_frame(img.name or f"frame {i}", img.width, img.height, img.rgb))
        return np.stack(frames)

    def Reset(self, request, context):
        if not 1 <= len(request.episode_id.encode()) <= 128:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, "episode_id must be 1 to 128 bytes")
        try:
            frames = self._frames(request)
        except BadRequest as e:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(e))
        state = np.array(request.state, dtype=np.float32)
        try:
            views = {
                img.name or f"view {i}": _frame(img.name or f"view {i}", img.width, img.height, img.rgb)
                for i, img in enumerate(request.views)
            }
        except BadRequest as e:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(e))
        interface = request.interface if request.HasField("interface") else None
        error = None
        try:
            model = self._factory()
            reset = getattr(model, "reset", None)
            if callable(reset):
                _call_reset(
                    reset, frames[-1].copy(), state, request.instruction,
                    task_id=request.task_id, seed=request.seed, frames=frames.copy(),
                    views=views, interface=interface,
                )
            if not callable(getattr(model, "step", None)):
                raise TypeError(f"{type(model).__name__} has no step(actions) method")
        except Exception as e:  # noqa: BLE001 - any failure of the researcher's code
            error = describe(e)
        if error is not None:
            context.abort(
                grpc.StatusCode.FAILED_PRECONDITION,
                f"cannot start a world model for episode {request.episode_id!r}: {error}",
            )
        with self._lock:
            self._episodes[request.episode_id] = _Episode(model, request.frames[-1].name, list(views))
            self._episodes.move_to_end(request.episode_id)
            while len(self._episodes) > self._max_episodes:
                self._episodes.popitem(last=False)
        return pb.WorldModelResetResponse()

    def _actions(self, request) -> np.ndarray:
        d = request.action_dims
        n = len(request.actions)
        if d < 1:
            raise BadRequest("action_dims must be at least 1")
        if self._action_dims and d != self._action_dims:
            raise BadRequest(f"{d}-float actions; the model takes {self._action_dims}")
        if n == 0 or n % d:
            raise BadRequest(f"{n} floats are not a chunk of one or more {d}-float actions")
        if n // d > MAX_ACTIONS:
            raise BadRequest(f"{n // d} actions in one Step; at most {MAX_ACTIONS}")
        a = np.array(request.actions, dtype=np.float32).reshape(n // d, d)
        if not np.isfinite(a).all():
            raise BadRequest("a non-finite action")
        return a

    def Step(self, request, context):
        with self._lock:
            ep = self._episodes.get(request.episode_id)
            if ep is not None:
                self._episodes.move_to_end(request.episode_id)
        if ep is None:
            context.abort(
                grpc.StatusCode.NOT_FOUND,
                f"no live episode {request.episode_id!r} (never reset, ended, evicted, or the "
                "server restarted)",
            )
        try:
            actions = self._actions(request)
        except BadRequest as e:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(e))
        error = None
        with ep.lock:
            try:
                raw = ep.model.step(actions)
                frames, states = split_answer(raw)
                views = split_views(raw, ep.views)
            except WorldModelError as e:
                error = str(e)
            except Exception as e:  # noqa: BLE001 - the model failed on these actions
                error = "the world model raised " + describe(e)
        if error is not None:
            context.abort(grpc.StatusCode.INTERNAL, error)
        _, h, w, _ = frames.shape
        answer = pb.WorldModelStepResponse()
        for f in frames:
            answer.frames.add(name=ep.name, width=w, height=h, rgb=f.tobytes())
        if states is not None:
            answer.states.extend(states.ravel().tolist())
            answer.state_dims = states.shape[1]
        for k in range(len(frames)):
            for name, v in zip(ep.views, views):
                if k < len(v):
                    answer.views.add(name=name, width=v.shape[2], height=v.shape[1], rgb=v[k].tobytes())
        return answer

    def End(self, request, context):
        with self._lock:
            self._episodes.pop(request.episode_id, None)
        return pb.WorldModelEndResponse()


def serve_world_model(
    factory: Callable[[], Any],
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    name: str = "world-model",
    description: str = "",
    width: int = 0,
    height: int = 0,
    action_dims: int = 0,
    token: Optional[str] = None,
    max_workers: int = 32,
    max_episodes: int = MAX_EPISODES,
    announce: bool = True,
    interfaces: Optional[Sequence[Interface]] = None,
) -> GrpcPolicyServer:
    """Starts serving `assay.v1.WorldModel` and returns at once (see `serve_world_model_forever`).

    factory:     a zero-argument callable making one fresh model per imagined episode, at `Reset`
                 (the model's class, or e.g. `lambda: MyModel(shared_network)` to share weights).
                 The model has `reset(frame, state, instruction)` — frame uint8 [H, W, 3], the
                 real first frame; state float32 [S]; also given `task_id=`, `seed=`,
                 `frames=` (uint8 [T, H, W, 3], every frame the client sent), `views=` ({camera
                 name: uint8 [H, W, 3]}, the first frames of the interface's cameras after the
                 first) and `interface=` (the `PolicyInterface` message, None for the original)
                 when its signature names them — and `step(actions)` — float32 [K, D] —
                 returning uint8 frames [K, H, W, 3] at the reset's size, or `(frames, states)`
                 with states [K, S], or `{"frames": ..., "states": ..., "views": {camera name:
                 uint8 [K, h, w, 3]}}` ("views" required when the interface has more than one
                 camera; numpy arrays or torch tensors). Episodes run concurrently on several
                 threads; one episode's calls are sequential.
    name, description: what `Health` declares (reports show the name with the server's address).
    width, height: the frame size the model takes (0: any); action_dims: floats per action it
                 takes (0: any). Requests that differ are refused with INVALID_ARGUMENT.
    interfaces:  the policy interfaces (`assay_policy_kit.Interface`) the model imagines in:
                 Assay ranks only policies at one of them (same action space, state parts,
                 cameras by source and size) and refuses the others before a ranking starts,
                 naming the field. None: the original interface (one scene camera at
                 width x height, ee_pos + holding, tool_velocity) when action_dims is 0 or 4.
    token:       the cluster token; default `$ASSAY_CLUSTER_TOKEN` / `$ASSAY_CLUSTER_TOKEN_FILE`
                 (none set: every call is accepted). Calls must carry the world-model secret
                 derived from it (auth.py).
    Prints `listening on http://HOST:PORT` to stdout once started (unless announce=False).
    Returns the started server: `url`, `port`, `servicer`, `stop()`, `wait()`.
    """
    servicer = WorldModelServicer(
        factory, name=name, description=description, width=width, height=height,
        action_dims=action_dims, max_episodes=max_episodes, interfaces=interfaces,
    )
    return _start(
        servicer, pb_grpc.add_WorldModelServicer_to_server, auth.WORLD_MODEL, token=token,
        host=host, port=port, max_workers=max_workers, announce=announce,
    )


def serve_world_model_forever(*args, **kwargs) -> None:
    """`serve_world_model`, then blocks until SIGINT or SIGTERM (then stops, giving calls 2 s)."""
    _serve_until_signal(serve_world_model(*args, **kwargs))
