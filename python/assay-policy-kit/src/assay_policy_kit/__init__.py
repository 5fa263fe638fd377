"""Assay policy kit: serve any `obs -> actions` Python callable to Assay, over Assay's gRPC
service `assay.v1.Policy` or openpi's websocket protocol; and any action-conditioned world model
(`reset(frame, state, instruction)`, `step(actions) -> frames`) over `assay.v1.WorldModel`
(`serve_world_model`).

    from assay_policy_kit import Camera, Interface, serve_grpc_forever

    def policy(obs):            # obs["observation/image"]: uint8 [H, W, 3], ...
        return np.zeros((1, 7))  # [K, D] or [D]

    serve_grpc_forever(policy, Interface(cameras=[Camera("image", width=224, height=224)],
                                         state=["ee_pos", "ee_yaw", "gripper"],
                                         action_space="ee_delta"))
"""

from .interface import ACTION_SPACES, STATE_PARTS, Camera, Interface
from ._policy import Policies, PolicyError

__version__ = "0.1.0"

__all__ = [
    "ACTION_SPACES",
    "STATE_PARTS",
    "Camera",
    "Interface",
    "LeRobotAdapter",
    "Policies",
    "PolicyError",
    "serve_grpc",
    "serve_grpc_forever",
    "serve_openpi",
    "serve_world_model",
    "serve_world_model_forever",
    "WorldModelError",
    "__version__",
]


def __getattr__(name):
    # grpc and websockets are imported only by the protocol that is used.
    if name in ("serve_grpc", "serve_grpc_forever"):
        from . import grpc_server

        return getattr(grpc_server, name)
    if name in ("serve_world_model", "serve_world_model_forever", "WorldModelError"):
        from . import world_model_server

        return getattr(world_model_server, name)
    if name == "serve_openpi":
        from .openpi_server import serve_openpi

        return serve_openpi
    if name == "LeRobotAdapter":
        from .lerobot import LeRobotAdapter

        return LeRobotAdapter
    raise AttributeError(f"module 'assay_policy_kit' has no attribute {name!r}")
