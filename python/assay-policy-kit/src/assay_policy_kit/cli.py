"""`python -m assay_policy_kit serve MODULE:ATTR ...`: serve a policy from the command line;
`python -m assay_policy_kit lerobot --checkpoint DIR ...`: serve a LeRobot checkpoint with its
processors; `python -m assay_policy_kit world-model MODULE:ATTR ...`: serve a world model."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import List, Optional

from .interface import ACTION_SPACES, Camera, Interface


def load(target: str):
    """`MODULE:ATTR` (ATTR may be dotted) -> the object. The current directory is importable."""
    module_name, sep, attr = target.partition(":")
    if not sep or not module_name or not attr:
        raise SystemExit(f"{target!r}: expected MODULE:ATTR, e.g. my_policies:policy")
    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    obj = importlib.import_module(module_name)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m assay_policy_kit", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("serve", help="serve a policy to Assay")
    s.add_argument("target", help="MODULE:ATTR, a callable obs -> actions (a factory with --factory)")
    s.add_argument("--protocol", choices=("grpc", "openpi"), default="grpc")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=0, help="0: any free port (printed)")
    s.add_argument("--factory", action="store_true",
                   help="ATTR makes one policy object per episode (with reset() and __call__/act)")
    s.add_argument("--space", default="tool_velocity", choices=ACTION_SPACES, help="action space")
    s.add_argument("--camera", action="append", default=[], metavar="NAME[:SOURCE][@WxH][:depth]",
                   help="a camera of the interface, in order (repeatable; default: image:scene)")
    s.add_argument("--state", default="ee_pos+holding", help="state parts joined by '+'")
    s.add_argument("--horizon", type=int, default=0, help="execute_horizon (0: the whole chunk)")
    s.add_argument("--arm-joints", type=int, default=None,
                   help="the arm's joint count (for state 'joints' or joint_position actions)")
    s.add_argument("--name", default=None, help="the policy's name in Health (default: ATTR)")
    s.add_argument("--version", default="", help="the policy's version in Health")
    s.add_argument("--chunk-size", type=int, default=0, help="actions per answer, 0: varies")
    s.add_argument("--api-key", default=None, help="openpi: require Authorization: Api-Key KEY")
    s.add_argument("--check-actions", action="store_true",
                   help="refuse actions of the wrong width or not finite (else the client does)")
    r = sub.add_parser("lerobot", help="serve a LeRobot checkpoint (with its processors) to Assay")
    r.add_argument("--checkpoint", required=True,
                   help="the checkpoint folder (.../pretrained_model) or a hub id where the hub is reachable")
    r.add_argument("--serve", choices=("grpc", "openpi"), default="grpc", help="the protocol")
    r.add_argument("--host", default="127.0.0.1")
    r.add_argument("--port", type=int, default=0, help="0: any free port (printed)")
    r.add_argument("--device", default=None, help="cpu, cuda, ... (default: CUDA when torch sees it)")
    r.add_argument("--camera", action="append", default=[], metavar="NAME=FEATURE",
                   help="the kit camera NAME is the image feature FEATURE (repeatable; default: "
                        "each observation.images.X is camera X)")
    r.add_argument("--source", action="append", default=[], metavar="NAME=SOURCE",
                   help="camera NAME is Assay's SOURCE view (default: a view's own name, else scene)")
    r.add_argument("--state", default=None,
                   help="state parts joined by '+' (default: ee_pos+holding for 4 floats)")
    r.add_argument("--space", default=None, choices=ACTION_SPACES,
                   help="action space (default: from the action width, 4/7/8)")
    r.add_argument("--horizon", type=int, default=0, help="execute_horizon (0: the whole chunk)")
    r.add_argument("--arm-joints", type=int, default=None)
    r.add_argument("--name", default=None, help="the policy's name in Health (default: lerobot-TYPE)")
    r.add_argument("--api-key", default=None, help="openpi: require Authorization: Api-Key KEY")
    w = sub.add_parser("world-model", help="serve a world model to Assay (assay.v1.WorldModel)")
    w.add_argument("target", help="MODULE:ATTR, a factory (e.g. the model's class) making one model "
                                  "per episode, with reset(frame, state, instruction) and step(actions)")
    w.add_argument("--host", default="127.0.0.1")
    w.add_argument("--port", type=int, default=0, help="0: any free port (printed)")
    w.add_argument("--name", default=None, help="the model's name in Health (default: ATTR)")
    w.add_argument("--description", default="", help="free text in Health")
    w.add_argument("--size", default=None, metavar="WxH",
                   help="the frame size the model takes (default: any)")
    w.add_argument("--action-dims", type=int, default=0, help="floats per action it takes (0: any)")
    return p


def _size(text: Optional[str]):
    if text is None:
        return 0, 0
    w, sep, h = text.partition("x")
    if not sep or not w.isdigit() or not h.isdigit():
        raise SystemExit(f"--size {text!r}: expected WxH, e.g. 64x64")
    return int(w), int(h)


def main(argv: Optional[List[str]] = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")
    if args.command == "world-model":
        from .world_model_server import serve_world_model_forever

        width, height = _size(args.size)
        serve_world_model_forever(
            load(args.target), host=args.host, port=args.port,
            name=args.name or args.target.partition(":")[2], description=args.description,
            width=width, height=height, action_dims=args.action_dims,
        )
        return 0
    if args.command == "lerobot":
        return _serve_lerobot(args)
    interface = Interface(
        cameras=[Camera.parse(c) for c in args.camera] or [Camera("image")],
        state=[s for s in args.state.split("+") if s],
        action_space=args.space,
        execute_horizon=args.horizon,
        arm_joints=args.arm_joints,
    )
    interface.validate()
    obj = load(args.target)
    kw = {"factory": obj} if args.factory else {"policy": obj}
    if args.protocol == "grpc":
        from .grpc_server import serve_grpc_forever

        serve_grpc_forever(
            interface=interface, host=args.host, port=args.port,
            name=args.name or args.target.partition(":")[2], version=args.version,
            chunk_size=args.chunk_size, check_actions=args.check_actions, **kw,
        )
    else:
        from .openpi_server import serve_openpi

        serve_openpi(
            interface=interface, host=args.host, port=args.port, api_key=args.api_key,
            check_actions=args.check_actions, **kw,
        )
    return 0


def _pairs(items: List[str], flag: str):
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise SystemExit(f"{flag} {item!r}: expected NAME=VALUE")
        out[name] = value
    return out


def _serve_lerobot(args) -> int:
    import contextlib

    from .lerobot import LeRobotAdapter

    # LeRobot prints as it loads; stdout's first line is the server's address.
    with contextlib.redirect_stdout(sys.stderr):
        adapter = LeRobotAdapter.from_pretrained(
            args.checkpoint, device=args.device,
            image_keys=_pairs(args.camera, "--camera") or None,
        )
    try:
        interface = adapter.interface(
            state=args.state, action_space=args.space, sources=_pairs(args.source, "--source"),
            execute_horizon=args.horizon, arm_joints=args.arm_joints,
        )
        interface.validate()
    except ValueError as e:
        raise SystemExit(f"{args.checkpoint}: {e}")
    name = args.name or "lerobot-" + str(getattr(adapter.policy.config, "type", "policy"))
    if args.serve == "grpc":
        from .grpc_server import serve_grpc_forever

        serve_grpc_forever(factory=adapter.for_episode, interface=interface, host=args.host,
                           port=args.port, name=name)
    else:
        from .openpi_server import serve_openpi

        serve_openpi(factory=adapter.for_episode, interface=interface, host=args.host,
                     port=args.port, api_key=args.api_key)
    return 0
