#!/usr/bin/env python3
"""Serves a test policy of tests/python/policies/scripted.py with the Assay policy kit.

    python tests/python/serve_policy.py --protocol grpc|openpi \
        --policy scripted|vision|vision_no_turn|wrong_shape|nan|raises|lerobot_standin|zeros [--port 0] [--api-key K]

Prints `listening on http://HOST:PORT` (grpc) or `listening on ws://HOST:PORT` (openpi) once
ready, then serves until killed. The kit is imported from python/assay-policy-kit/src (no pip
install needed); gRPC honours $ASSAY_CLUSTER_TOKEN / $ASSAY_CLUSTER_TOKEN_FILE.

Interfaces: vision (tests/python/policies/vision.py): cameras scene (the standard top view,
128x128, depth) and wrist (64x64, depth), state ee_pos+ee_yaw+holding, ee_delta, chunk 1, one
VisionPolicy per episode (vision_no_turn: one that never turns the tool). scripted, wrong_shape, nan, raises: camera image (scene, 32x32), state
ee_pos+ee_yaw+holding, ee_delta, chunk 2. lerobot_standin: cameras image (scene, 32x32) and
wrist (wrist, 32x32), same state, ee_delta, chunk 1, one LeRobotAdapter per episode. zeros:
cameras image and wrist_image (224x224), state ee_pos+ee_quat+holding (8 floats), ee_delta,
chunk 1 (for benchmarks).
"""

import argparse
import logging
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "python", "assay-policy-kit", "src"))
sys.path.insert(0, os.path.join(HERE, "policies"))

import scripted  # noqa: E402
import vision  # noqa: E402
from assay_policy_kit import Camera, Interface  # noqa: E402

SCRIPTED_INTERFACE = Interface(
    cameras=[Camera("image", "scene", 32, 32)],
    state=list(scripted.STATE),
    action_space="ee_delta",
)

VISION_INTERFACE = Interface(
    cameras=[Camera("scene", "top", 128, 128, depth=True), Camera("wrist", "wrist", 64, 64, depth=True)],
    state=list(vision.STATE),
    action_space="ee_delta",
)


def lerobot_standin():
    from assay_policy_kit import LeRobotAdapter

    return LeRobotAdapter(
        scripted.LeRobotStandin(),
        image_keys={"image": "observation.images.top", "wrist": "observation.images.wrist"},
        state_key="observation.state",
    )


# name -> (interface, chunk size, {"policy": fn} or {"factory": fn})
POLICIES = {
    "scripted": (SCRIPTED_INTERFACE, 2, {"policy": scripted.policy}),
    "wrong_shape": (SCRIPTED_INTERFACE, 2, {"policy": scripted.wrong_shape}),
    "nan": (SCRIPTED_INTERFACE, 2, {"policy": scripted.nan}),
    "raises": (SCRIPTED_INTERFACE, 2, {"policy": scripted.raises}),
    "lerobot_standin": (
        Interface(
            cameras=[Camera("image", "scene", 32, 32), Camera("wrist", "wrist", 32, 32)],
            state=list(scripted.STATE),
            action_space="ee_delta",
        ),
        1,
        {"factory": lerobot_standin},
    ),
    "vision": (VISION_INTERFACE, 1, {"factory": vision.VisionPolicy}),
    "vision_no_turn": (VISION_INTERFACE, 1, {"factory": lambda: vision.VisionPolicy(turn=False)}),
    "zeros": (
        Interface(
            cameras=[Camera("image", "scene", 224, 224), Camera("wrist_image", "wrist", 224, 224)],
            state=["ee_pos", "ee_quat", "holding"],
            action_space="ee_delta",
        ),
        1,
        {"policy": scripted.zeros},
    ),
}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--protocol", choices=("grpc", "openpi"), required=True)
    p.add_argument("--policy", choices=sorted(POLICIES), required=True)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--api-key", default=None, help="openpi: require Authorization: Api-Key KEY")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    interface, chunk, kw = POLICIES[args.policy]
    if args.protocol == "grpc":
        from assay_policy_kit import serve_grpc_forever

        serve_grpc_forever(
            interface=interface, host=args.host, port=args.port, name=args.policy,
            version="test", chunk_size=chunk, **kw,
        )
    else:
        from assay_policy_kit import serve_openpi

        serve_openpi(
            interface=interface, host=args.host, port=args.port, api_key=args.api_key,
            metadata={"policy": args.policy}, **kw,
        )


if __name__ == "__main__":
    main()
