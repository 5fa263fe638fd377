"""The observation dict a policy receives (the same over gRPC and over openpi's websocket):

    "observation/<camera>"        np.uint8   [H, W, 3]  one per camera of the interface
    "observation/<camera>_depth"  np.float32 [H, W]     cameras with depth only
    "observation/state"           np.float32 [S]
    "prompt"                      str                   the task's instruction
"""

from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from .interface import MAX_PIXELS, Interface


class BadRequest(ValueError):
    """An Act request outside the protocol's bounds (INVALID_ARGUMENT)."""


def _frame(name: str, width: int, height: int, rgb: bytes) -> np.ndarray:
    if not (1 <= width <= MAX_PIXELS and 1 <= height <= MAX_PIXELS):
        raise BadRequest(f"camera {name!r}: frame size {width}x{height} is not 1 to {MAX_PIXELS} each")
    if len(rgb) != width * height * 3:
        raise BadRequest(
            f"camera {name!r}: {len(rgb)} bytes of RGB for a {width}x{height} frame "
            f"(expected {width * height * 3})"
        )
    return np.frombuffer(rgb, dtype=np.uint8).reshape(height, width, 3)


def from_act_request(req, interface: Interface, instruction: str = "", state_dims: Optional[int] = None) -> Dict:
    """The observation dict of a `PolicyActRequest`, checked against the interface.

    `images` empty (a client that predates interfaces): `rgb`/`width`/`height` under the name of
    the interface's first camera, and `proprio` as the state.
    """
    obs: Dict = {}
    cams = {c.name: c for c in interface.cameras}
    if len(req.images) > 0:
        seen = set()
        for img in req.images:
            if img.name in seen:
                raise BadRequest(f"camera {img.name!r} appears twice in images")
            seen.add(img.name)
            cam = cams.get(img.name)
            if cam is None:
                raise BadRequest(
                    f"camera {img.name!r} is not in the interface (its cameras: "
                    f"{', '.join(interface.camera_names())})"
                )
            if cam.width and (img.width, img.height) != (cam.width, cam.height):
                raise BadRequest(
                    f"camera {img.name!r}: a {img.width}x{img.height} frame; the policy takes "
                    f"{cam.width}x{cam.height}"
                )
            obs["observation/" + img.name] = _frame(img.name, img.width, img.height, img.rgb)
            n_depth = len(img.depth)
            if n_depth:
                if n_depth != img.width * img.height:
                    raise BadRequest(
                        f"camera {img.name!r}: {n_depth} depth values for a {img.width}x{img.height} frame"
                    )
                obs["observation/" + img.name + "_depth"] = np.fromiter(
                    img.depth, dtype=np.float32, count=n_depth
                ).reshape(img.height, img.width)
            elif cam.depth:
                raise BadRequest(f"camera {img.name!r}: the policy asked for depth, none was sent")
        missing = [c.name for c in interface.cameras if c.name not in seen]
        if missing:
            raise BadRequest(f"no frame for camera(s) {', '.join(missing)} of the interface")
        state = req.state
    else:
        name = interface.camera_names()[0]
        cam = cams.get(name)
        if cam is not None and cam.width and (req.width, req.height) != (cam.width, cam.height):
            raise BadRequest(
                f"a {req.width}x{req.height} frame; the policy takes {cam.width}x{cam.height}"
            )
        if cam is not None and cam.depth:
            raise BadRequest(f"camera {name!r}: the policy asked for depth, none was sent (no images)")
        if len(interface.cameras) > 1:
            raise BadRequest(
                f"the policy takes {len(interface.cameras)} cameras; the request has no images"
            )
        obs["observation/" + name] = _frame(name, req.width, req.height, req.rgb)
        state = req.proprio if len(req.proprio) > 0 else req.state
    n = len(state)
    if state_dims is not None and n != state_dims:
        raise BadRequest(
            f"{n} floats of state; the policy's state ({' + '.join(interface.state)}) has {state_dims}"
        )
    obs["observation/state"] = np.fromiter(state, dtype=np.float32, count=n)
    obs["prompt"] = req.instruction or instruction
    return obs
