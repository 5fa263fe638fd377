"""Serving a policy over openpi's websocket protocol (what openpi's `WebsocketPolicyServer`
speaks and `openpi_client.websocket_client_policy.WebsocketClientPolicy` expects).

On connect the server sends one binary message, the msgpack-numpy packed metadata dict; then it
answers each binary message (a packed observation dict) with one binary message, the packed dict
`{"actions": float32 [K, D], "server_timing": {"infer_ms": ...}}`. When the policy fails it sends
the traceback as a text frame and closes the connection (code 1011). One connection is one
episode. `GET /healthz` answers 200 OK, as openpi's server does.

Needs `msgpack`, `websockets` (>= 13) and `openpi-client` (for `openpi_client.msgpack_numpy`;
install that one with `pip install --no-deps openpi-client==0.1.2`: it pins numpy 1.26).
"""

from __future__ import annotations

import asyncio
import functools
import http
import logging
import time
import traceback
from typing import Any, Callable, Dict, Optional

from . import auth
from ._policy import Policies, infer, to_actions
from .interface import Interface

logger = logging.getLogger("assay_policy_kit.openpi")


def _imports():
    try:
        import websockets
        import websockets.asyncio.server
        import websockets.frames
        from openpi_client import msgpack_numpy
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"serving over openpi's protocol needs msgpack, websockets>=13 and openpi-client ({e}); "
            "pip install msgpack websockets && pip install --no-deps openpi-client==0.1.2"
        ) from e
    return websockets, msgpack_numpy


def _host_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class OpenpiPolicyServer:
    """The server's state; `serve_openpi` runs one, `run()` is its coroutine."""

    def __init__(
        self,
        policies: Policies,
        interface: Optional[Interface] = None,
        host: str = "127.0.0.1",
        port: int = 0,
        metadata: Optional[Dict] = None,
        api_key: Optional[str] = None,
        check_actions: bool = False,
        announce: bool = True,
    ):
        self._websockets, self._msgpack_numpy = _imports()
        self._policies = policies
        self._interface = interface
        self._host = host
        self._port = port
        self._metadata = dict(metadata or {})
        if interface is not None:
            interface.validate()
            self._metadata.setdefault("assay_interface", interface.to_dict())
        self._expected_auth = f"Api-Key {api_key}" if api_key else None
        self._check_actions = check_actions
        self._announce = announce
        self._action_dims = None
        if interface is not None and check_actions:
            try:
                self._action_dims = interface.action_dims()
            except ValueError:
                pass
        self.port: Optional[int] = None
        self.url: Optional[str] = None

    def _process_request(self, connection, request):
        if request.path == "/healthz":
            return connection.respond(http.HTTPStatus.OK, "OK\n")
        if self._expected_auth is not None and not auth.matches(
            self._expected_auth, request.headers.get("Authorization")
        ):
            return connection.respond(
                http.HTTPStatus.UNAUTHORIZED, "this policy server needs Authorization: Api-Key <key>\n"
            )
        return None

    async def _handler(self, websocket) -> None:
        websockets = self._websockets
        packer = self._msgpack_numpy.Packer()
        loop = asyncio.get_running_loop()
        try:
            policy = await loop.run_in_executor(None, self._policies.start_episode)
        except Exception:  # noqa: BLE001 - the researcher's factory or reset failed
            await self._fail(websocket, traceback.format_exc())
            return
        await websocket.send(packer.pack(self._metadata))
        prev_total = None
        while True:
            try:
                message = await websocket.recv()
            except websockets.ConnectionClosed:
                return
            start = time.monotonic()
            try:
                if isinstance(message, str):
                    raise TypeError("expected a binary (msgpack) observation, got a text frame")
                obs = self._msgpack_numpy.unpackb(message)
                if not isinstance(obs, dict):
                    raise TypeError(f"the observation is a {type(obs).__name__}, not a dict")
                t0 = time.monotonic()
                raw = await loop.run_in_executor(None, functools.partial(infer, policy, obs))
                infer_s = time.monotonic() - t0
                actions = to_actions(raw, check_finite=self._check_actions, action_dims=self._action_dims)
                timing = {"infer_ms": infer_s * 1000.0}
                if prev_total is not None:
                    timing["prev_total_ms"] = prev_total * 1000.0
                reply = packer.pack({"actions": actions, "server_timing": timing})
            except Exception:  # noqa: BLE001 - reported to the client, as openpi does
                await self._fail(websocket, traceback.format_exc())
                return
            try:
                await websocket.send(reply)
            except websockets.ConnectionClosed:
                return
            prev_total = time.monotonic() - start

    async def _fail(self, websocket, text: str) -> None:
        logger.error("policy failed:\n%s", text)
        try:
            await websocket.send(text)
            await websocket.close(
                code=self._websockets.frames.CloseCode.INTERNAL_ERROR,
                reason="Internal server error. Traceback included in previous frame.",
            )
        except self._websockets.ConnectionClosed:
            pass

    async def run(self, started: Optional[Callable[["OpenpiPolicyServer"], Any]] = None) -> None:
        serve = self._websockets.asyncio.server.serve
        async with serve(
            self._handler,
            self._host,
            self._port,
            compression=None,
            max_size=None,
            process_request=self._process_request,
        ) as server:
            self.port = next(iter(server.sockets)).getsockname()[1]
            self.url = "ws://" + _host_port(self._host, self.port)
            if self._announce:
                print(f"listening on {self.url}", flush=True)
            if started is not None:
                started(self)
            await server.serve_forever()


def serve_openpi(
    policy: Optional[Callable] = None,
    interface: Optional[Interface] = None,
    *,
    factory: Optional[Callable] = None,
    host: str = "127.0.0.1",
    port: int = 0,
    metadata: Optional[Dict] = None,
    api_key: Optional[str] = None,
    check_actions: bool = False,
    announce: bool = True,
) -> None:
    """Serves the policy over openpi's websocket protocol until interrupted (blocking).

    policy / factory: as for `serve_grpc`; with a factory each connection (one episode) gets a
    fresh object, reset with `reset("", 0, "")` (or `reset()`) when it has one (the protocol
    carries no task or seed; the instruction comes with every observation as "prompt").
    metadata: the dict sent on connect (default {}; the interface is added as "assay_interface").
    api_key: when given, a connection must send `Authorization: Api-Key <key>` (as openpi's
    client does with api_key=...), else it is refused with HTTP 401.
    Prints `listening on ws://HOST:PORT` to stdout once listening (unless announce=False).
    """
    server = OpenpiPolicyServer(
        Policies(policy, factory), interface, host=host, port=port, metadata=metadata,
        api_key=api_key, check_actions=check_actions, announce=announce,
    )
    try:
        asyncio.run(server.run())
    except KeyboardInterrupt:
        pass
