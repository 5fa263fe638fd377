"""How the kit calls a researcher's policy: plain callables, per-episode factories, actions."""

from __future__ import annotations

import inspect
from typing import Any, Callable, Optional

import numpy as np

MAX_CHUNK = 1024


class PolicyError(Exception):
    """The policy failed, or answered something that is not a chunk of actions."""


class Policies:
    """Makes the policy object of one episode.

    policy:  a stateless callable `fn(obs) -> actions` (or an object with `act(obs)`), shared by
             every episode and called concurrently from several threads.
    factory: a zero-argument callable returning a fresh per-episode object with `__call__(obs)` or
             `act(obs)`, and optionally `reset(task_id, seed, instruction)` (or `reset()`), which
             the kit calls once at the start of the episode.
    Exactly one of the two.
    """

    def __init__(self, policy: Optional[Callable] = None, factory: Optional[Callable] = None):
        if (policy is None) == (factory is None):
            raise ValueError("give exactly one of policy= (a callable) and factory=")
        if policy is not None and not (callable(policy) or hasattr(policy, "act")):
            raise TypeError(f"policy {policy!r} is neither callable nor has act()")
        if factory is not None and not callable(factory):
            raise TypeError(f"factory {factory!r} is not callable")
        self.policy = policy
        self.factory = factory

    def start_episode(self, task_id: str = "", seed: int = 0, instruction: str = "") -> Any:
        """The object that answers this episode (a fresh, reset one when there is a factory)."""
        if self.factory is None:
            return self.policy
        obj = self.factory()
        reset = getattr(obj, "reset", None)
        if callable(reset):
            call_reset(reset, task_id, seed, instruction)
        return obj


def call_reset(reset: Callable, task_id: str, seed: int, instruction: str) -> None:
    """`reset(task_id, seed, instruction)` when it takes them, else `reset()`."""
    try:
        inspect.signature(reset).bind(task_id, seed, instruction)
    except TypeError:
        reset()
    except ValueError:  # no signature (a builtin): try both
        try:
            reset(task_id, seed, instruction)
        except TypeError:
            reset()
    else:
        reset(task_id, seed, instruction)


def infer(obj: Any, obs: dict) -> Any:
    act = getattr(obj, "act", None)
    if callable(act):
        return act(obs)
    return obj(obs)


def to_actions(raw: Any, check_finite: bool = False, action_dims: Optional[int] = None) -> np.ndarray:
    """A policy's answer as a float32 [K, D] array (K >= 1).

    Accepts anything `np.asarray` takes (lists, numpy arrays, CPU or GPU torch tensors, jax
    arrays) of shape [K, D] or [D], or a dict holding it under "actions" (openpi's convention).
    """
    if isinstance(raw, dict):
        if "actions" not in raw:
            raise PolicyError(f"the policy returned a dict without 'actions' (keys: {sorted(raw)})")
        raw = raw["actions"]
    if hasattr(raw, "detach") and hasattr(raw, "cpu"):  # a torch tensor, maybe on a GPU
        raw = raw.detach().cpu().float().numpy()
    try:
        a = np.asarray(raw, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise PolicyError(f"the policy returned {type(raw).__name__}, not numbers: {e}") from e
    if a.ndim == 1:
        a = a.reshape(1, -1)
    if a.ndim != 2:
        raise PolicyError(f"the policy returned actions of shape {list(a.shape)}; expected [K, D] or [D]")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise PolicyError(f"the policy returned an empty chunk of shape {list(a.shape)}")
    if a.shape[0] > MAX_CHUNK:
        raise PolicyError(f"the policy returned {a.shape[0]} actions; at most {MAX_CHUNK}")
    if action_dims is not None and a.shape[1] != action_dims:
        raise PolicyError(
            f"the policy returned {a.shape[1]}-float actions; its interface needs {action_dims}"
        )
    if check_finite and not np.isfinite(a).all():
        raise PolicyError("the policy returned a non-finite action")
    return np.ascontiguousarray(a)


def describe(e: BaseException) -> str:
    text = str(e)
    return f"{type(e).__name__}: {text}" if text else type(e).__name__
