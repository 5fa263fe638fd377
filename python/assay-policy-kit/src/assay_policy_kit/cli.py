"""`python -m assay_policy_kit serve MODULE:ATTR ...`: serve a policy from the command line;
`python -m assay_policy_kit world-model MODULE:ATTR ...`: serve a world model."""

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
