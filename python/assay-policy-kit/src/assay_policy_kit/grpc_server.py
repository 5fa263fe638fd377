"""Serving a policy as Assay's gRPC service `assay.v1.Policy` (proto/assay/v1/policy.proto)."""

from __future__ import annotations

import signal
import sys
import threading
from collections import OrderedDict
from concurrent import futures
from typing import Any, Callable, Optional

import grpc

from . import auth
from ._policy import Policies, PolicyError, describe, infer, to_actions
from ._proto import policy_pb2, policy_pb2_grpc
from .interface import Interface
from .observation import BadRequest, from_act_request

MAX_EPISODES = 1024
MAX_MESSAGE = 256 * 1024 * 1024


class _Episode:
    __slots__ = ("policy", "instruction", "lock")

    def __init__(self, policy: Any, instruction: str):
        self.policy = policy
        self.instruction = instruction
        self.lock = threading.Lock()


class PolicyServicer(policy_pb2_grpc.PolicyServicer):
    """`assay.v1.Policy` over a kit policy: one policy object per live episode."""

    def __init__(
        self,
        policies: Policies,
        interface: Interface,
        name: str = "policy",
        version: str = "",
        chunk_size: int = 0,
        max_episodes: int = MAX_EPISODES,
        check_actions: bool = False,
    ):
        interface.validate()
        self._policies = policies
        self._interface = interface
        self._name = name
        self._version = version
        self._chunk_size = int(chunk_size)
        self._max_episodes = int(max_episodes)
        self._check_actions = check_actions
        self._state_dims = interface.state_dims()
        try:
            self._action_dims: Optional[int] = interface.action_dims()
        except ValueError:
            self._action_dims = None
        self._episodes: "OrderedDict[str, _Episode]" = OrderedDict()
        self._lock = threading.Lock()

    @property
    def live_episodes(self) -> int:
        with self._lock:
            return len(self._episodes)

    def Health(self, request, context):
        first = self._interface.cameras[0] if self._interface.cameras else None
        return policy_pb2.PolicyHealthResponse(
            name=self._name,
            version=self._version,
            image_width=first.width if first else 0,
            image_height=first.height if first else 0,
            action_dims=self._action_dims or 0,
            proprio_dims=self._state_dims,
            chunk_size=self._chunk_size,
            live_episodes=self.live_episodes,
            interface=self._interface.to_proto(),
        )

    def Reset(self, request, context):
        if not 1 <= len(request.episode_id.encode()) <= 128:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, "episode_id must be 1 to 128 bytes")
        error = None
        try:
            obj = self._policies.start_episode(request.task_id, request.seed, request.instruction)
        except Exception as e:  # noqa: BLE001 - any failure of the researcher's code
            error = describe(e)
        if error is not None:
            context.abort(
                grpc.StatusCode.FAILED_PRECONDITION,
                f"cannot start a policy for episode {request.episode_id!r}: {error}",
            )
        with self._lock:
            self._episodes[request.episode_id] = _Episode(obj, request.instruction)
            self._episodes.move_to_end(request.episode_id)
            while len(self._episodes) > self._max_episodes:
                self._episodes.popitem(last=False)
        return policy_pb2.PolicyResetResponse()

    def Act(self, request, context):
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
            obs = from_act_request(request, self._interface, ep.instruction, self._state_dims)
        except BadRequest as e:
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(e))
        error = None
        with ep.lock:
            try:
                actions = to_actions(
                    infer(ep.policy, obs),
                    check_finite=self._check_actions,
                    action_dims=self._action_dims if self._check_actions else None,
                )
            except PolicyError as e:
                error = str(e)
            except Exception as e:  # noqa: BLE001 - the policy failed on this observation
                error = "the policy raised " + describe(e)
        if error is not None:
            context.abort(grpc.StatusCode.INTERNAL, error)
        return policy_pb2.PolicyActResponse(
            actions=actions.ravel().tolist(), action_dims=actions.shape[1]
        )

    def End(self, request, context):
        with self._lock:
            self._episodes.pop(request.episode_id, None)
        return policy_pb2.PolicyEndResponse()


class _TokenInterceptor(grpc.ServerInterceptor):
    """Refuses every call without `authorization: Bearer <the service's secret>`
    (UNAUTHENTICATED); `service` is "policy" or "world-model" (see auth.py)."""

    def __init__(self, token: str, service: str = auth.POLICY):
        self._expected = auth.bearer(token, service)
        what = service.replace("-", " ")

        def deny(request, context):
            context.abort(
                grpc.StatusCode.UNAUTHENTICATED,
                f"this {what} server needs the cluster's token (authorization: Bearer ...)",
            )

        self._deny = grpc.unary_unary_rpc_method_handler(deny)

    def intercept_service(self, continuation, handler_call_details):
        presented = None
        for key, value in handler_call_details.invocation_metadata or ():
            if key == "authorization":
                presented = value
                break
        if auth.matches(self._expected, presented):
            return continuation(handler_call_details)
        return self._deny


def _host_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class GrpcPolicyServer:
    """A started gRPC server (of a policy, or of a world model): `url`, `port`, `stop()`,
    `wait()`; a context manager."""

    def __init__(self, server: grpc.Server, servicer: PolicyServicer, host: str, port: int):
        self.server = server
        self.servicer = servicer
        self.host = host
        self.port = port
        self.url = "http://" + _host_port(host, port)

    def stop(self, grace: Optional[float] = None) -> None:
        self.server.stop(grace).wait()

    def wait(self, timeout: Optional[float] = None) -> bool:
        return self.server.wait_for_termination(timeout)

    def __enter__(self) -> "GrpcPolicyServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop(None)


def serve_grpc(
    policy: Optional[Callable] = None,
    interface: Optional[Interface] = None,
    *,
    factory: Optional[Callable] = None,
    host: str = "127.0.0.1",
    port: int = 0,
    name: str = "policy",
    version: str = "",
    chunk_size: int = 0,
    token: Optional[str] = None,
    max_workers: int = 32,
    max_episodes: int = MAX_EPISODES,
    check_actions: bool = False,
    announce: bool = True,
) -> GrpcPolicyServer:
    """Starts serving `assay.v1.Policy` and returns at once (see `serve_grpc_forever`).

    policy:    a stateless `fn(obs) -> actions`, shared by all episodes (called from many threads).
    factory:   instead of policy: `factory()` makes one object per episode, at `Reset`; it is
               called as `obj(obs)` or `obj.act(obs)`, and `obj.reset(task_id, seed,
               instruction)` (or `obj.reset()`) is called first when it has one.
    interface: what the policy sees and answers (default: Assay's original interface).
    token:     the cluster token; default `$ASSAY_CLUSTER_TOKEN` / `$ASSAY_CLUSTER_TOKEN_FILE`
               (none set: every call is accepted).
    check_actions: refuse (INTERNAL) actions of the wrong width or not finite, instead of
               passing them on for the client to refuse.
    Prints `listening on http://HOST:PORT` to stdout once started (unless announce=False).
    """
    interface = interface if interface is not None else Interface()
    servicer = PolicyServicer(
        Policies(policy, factory), interface, name=name, version=version, chunk_size=chunk_size,
        max_episodes=max_episodes, check_actions=check_actions,
    )
    return _start(
        servicer, policy_pb2_grpc.add_PolicyServicer_to_server, auth.POLICY, token=token,
        host=host, port=port, max_workers=max_workers, announce=announce,
    )


def _start(servicer, add_servicer, service: str, *, token, host, port, max_workers, announce):
    """Starts a gRPC server of `servicer` (registered by `add_servicer`) on host:port: a thread
    pool of `max_workers`, the kit's message limits, and, with a cluster token (`token`, else
    the environment's), every call checked for `service`'s bearer. Prints `listening on URL`
    when `announce`."""
    token = auth.token_from_env() if token is None else auth.check_token(token)
    server = grpc.server(
        futures.ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix=f"assay-{service}"),
        interceptors=[_TokenInterceptor(token, service)] if token else None,
        options=[
            ("grpc.max_receive_message_length", MAX_MESSAGE),
            ("grpc.max_send_message_length", MAX_MESSAGE),
        ],
    )
    add_servicer(servicer, server)
    bound = server.add_insecure_port(_host_port(host, port))
    if bound == 0:
        raise OSError(f"cannot listen on {_host_port(host, port)}")
    server.start()
    running = GrpcPolicyServer(server, servicer, host, bound)
    if announce:
        print(f"listening on {running.url}", flush=True)
    return running


def serve_grpc_forever(*args, **kwargs) -> None:
    """`serve_grpc`, then blocks until SIGINT or SIGTERM (then stops, giving calls 2 s)."""
    _serve_until_signal(serve_grpc(*args, **kwargs))


def _serve_until_signal(running: "GrpcPolicyServer") -> None:
    """Blocks until SIGINT or SIGTERM, then stops `running`, giving calls 2 s."""
    done = threading.Event()

    def stop(signum, frame):
        done.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)
    try:
        while not done.wait(0.5):
            pass
    finally:
        running.stop(2.0)
        sys.stdout.flush()
