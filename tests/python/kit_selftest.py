#!/usr/bin/env python3
"""Self-test of the Assay policy kit (python/assay-policy-kit): exits 0 when every check passes.

    python tests/python/kit_selftest.py

Starts tests/python/serve_policy.py, tests/python/world_models/trivial.py (and the kit's CLI) in
subprocesses and talks to them with a Python gRPC client over the kit's generated stubs and with
openpi's real `WebsocketClientPolicy`; also regenerates the stubs into a temporary directory and
diffs them with the checked-in ones. Needs tests/python/requirements.txt and
`pip install --no-deps openpi-client==0.1.2`.
"""

import hashlib
import os
import re
import select
import subprocess
import sys
import tempfile
import time
import traceback

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
KIT = os.path.join(ROOT, "python", "assay-policy-kit")
sys.path.insert(0, os.path.join(KIT, "src"))
sys.path.insert(0, os.path.join(HERE, "policies"))

import grpc  # noqa: E402
import scripted  # noqa: E402
from assay_policy_kit import LeRobotAdapter  # noqa: E402
from assay_policy_kit._proto import policy_pb2 as pb  # noqa: E402
from assay_policy_kit._proto import policy_pb2_grpc as pb_grpc  # noqa: E402
from assay_policy_kit._proto import world_model_pb2 as wm  # noqa: E402
from assay_policy_kit._proto import world_model_pb2_grpc as wm_grpc  # noqa: E402

TOKEN = "selftest-token-0123456789abcdef"
STARTED = []


class Server:
    def __init__(self, argv, env=None, expect="listening on "):
        self.argv = argv
        self.stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=self.stderr, env=env, cwd=ROOT
        )
        STARTED.append(self.proc)
        line = b""
        deadline = time.monotonic() + 30
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                self.stop()
                raise AssertionError(
                    f"{' '.join(argv)}: no 'listening on' line (got {line!r}); stderr:\n"
                    + self.stderr_text()
                )
            r, _, _ = select.select([self.proc.stdout], [], [], left)
            if r:
                b = os.read(self.proc.stdout.fileno(), 1)
                if not b:
                    continue
                line += b
        m = re.fullmatch(r"listening on (http|ws)://([^\s]+):(\d+)\n", line.decode())
        assert m, f"unexpected first line {line!r}"
        self.url = f"{m.group(1)}://{m.group(2)}:{m.group(3)}"
        self.target = f"{m.group(2)}:{m.group(3)}"

    def stderr_text(self):
        self.stderr.seek(0)
        return self.stderr.read().decode(errors="replace")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def serve(protocol, policy, env=None, extra=()):
    return Server([sys.executable, os.path.join(HERE, "serve_policy.py"), "--protocol", protocol,
                   "--policy", policy, "--port", "0", *extra], env=env)


def clean_env(**kw):
    env = {k: v for k, v in os.environ.items() if not k.startswith("ASSAY_CLUSTER_TOKEN")}
    env.update(kw)
    return env


def frame(seed, w=32, h=32):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def scripted_obs(seed):
    rng = np.random.default_rng(1000 + seed)
    state = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.2, 0.2), rng.uniform(0.0, 0.2),
                      rng.uniform(-3, 3), float(seed % 2)], dtype=np.float32)
    return {"observation/image": frame(seed), "observation/state": state,
            "prompt": "pick up the red cube"}


def act_request(episode, obs, names=("image",), old=False):
    state = obs["observation/state"]
    first = obs["observation/" + names[0]]
    h, w = first.shape[:2]
    req = pb.PolicyActRequest(episode_id=episode, step=0, width=w, height=h,
                              rgb=first.tobytes(), proprio=state.tolist() if old else [])
    if not old:
        for n in names:
            img = obs["observation/" + n]
            req.images.add(name=n, width=img.shape[1], height=img.shape[0], rgb=img.tobytes())
        req.state.extend(state.tolist())
        req.instruction = obs["prompt"]
    return req


def expect_code(fn, code, text=None):
    try:
        fn()
    except grpc.RpcError as e:
        assert e.code() == code, f"expected {code}, got {e.code()}: {e.details()}"
        if text is not None:
            assert text in (e.details() or ""), f"{text!r} not in {e.details()!r}"
        return e
    raise AssertionError(f"expected {code}, the call succeeded")


def grpc_actions(resp):
    a = np.array(resp.actions, dtype=np.float32)
    return a.reshape(-1, resp.action_dims)


def same(a, b):
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


# ---------------------------------------------------------------------------------- checks


def check_stubs():
    import importlib.util

    if importlib.util.find_spec("grpc_tools") is None:
        raise AssertionError("grpcio-tools is not installed (tests/python/requirements.txt)")
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHON=sys.executable)
        subprocess.run(["bash", os.path.join(KIT, "generate_stubs.sh"), tmp], check=True, env=env)
        for name in ("policy_pb2.py", "policy_pb2_grpc.py", "world_model_pb2.py", "world_model_pb2_grpc.py"):
            with open(os.path.join(tmp, name), "rb") as f:
                fresh = f.read()
            with open(os.path.join(KIT, "src", "assay_policy_kit", "_proto", name), "rb") as f:
                kept = f.read()
            assert fresh == kept, f"{name} differs from what generate_stubs.sh produces: rerun it"


def check_grpc_scripted():
    with serve("grpc", "scripted", env=clean_env()) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = pb_grpc.PolicyStub(ch)
        h = stub.Health(pb.PolicyHealthRequest(), timeout=10)
        assert (h.name, h.version) == ("scripted", "test"), h
        assert (h.action_dims, h.proprio_dims, h.chunk_size) == (7, 5, 2), h
        assert (h.image_width, h.image_height, h.live_episodes) == (32, 32, 0), h
        i = h.interface
        assert [(c.name, c.source, c.width, c.height, c.depth) for c in i.cameras] == [("image", "scene", 32, 32, False)], i
        assert list(i.state) == ["ee_pos", "ee_yaw", "holding"] and i.action_space == "ee_delta", i

        stub.Reset(pb.PolicyResetRequest(episode_id="e1", task_id="t", seed=7, instruction="pick"))
        for seed in range(20):
            obs = scripted_obs(seed)
            want = scripted.policy(obs)
            r = stub.Act(act_request("e1", obs))
            assert r.action_dims == 7 and len(r.actions) == 14, r
            assert same(grpc_actions(r), want), (grpc_actions(r), want)
            # an old client: rgb/width/height + proprio, no images
            r2 = stub.Act(act_request("e1", obs, old=True))
            assert same(grpc_actions(r2), want)
        # the grip switches with z
        obs = scripted_obs(0)
        obs["observation/state"][2] = 0.0
        assert grpc_actions(stub.Act(act_request("e1", obs)))[0, 6] == 1.0
        obs["observation/state"][2] = 0.1
        assert grpc_actions(stub.Act(act_request("e1", obs)))[0, 6] == 0.0

        obs = scripted_obs(1)
        NF, IA = grpc.StatusCode.NOT_FOUND, grpc.StatusCode.INVALID_ARGUMENT
        expect_code(lambda: stub.Act(act_request("nope", obs)), NF)
        bad = act_request("e1", obs)
        del bad.state[-1]
        expect_code(lambda: stub.Act(bad), IA, "state")
        bad = act_request("e1", obs)
        bad.images[0].rgb = bad.images[0].rgb[:-1]
        expect_code(lambda: stub.Act(bad), IA, "bytes")
        big = dict(obs, **{"observation/image": frame(1, 64, 64)})
        expect_code(lambda: stub.Act(act_request("e1", big)), IA, "32x32")
        bad = act_request("e1", obs)
        bad.images[0].name = "other"
        expect_code(lambda: stub.Act(bad), IA, "other")
        expect_code(lambda: stub.Reset(pb.PolicyResetRequest(episode_id="")), IA)
        expect_code(lambda: stub.Reset(pb.PolicyResetRequest(episode_id="x" * 129)), IA)

        assert stub.Health(pb.PolicyHealthRequest()).live_episodes == 1
        stub.End(pb.PolicyEndRequest(episode_id="e1"))
        stub.End(pb.PolicyEndRequest(episode_id="never-there"))  # not an error
        expect_code(lambda: stub.Act(act_request("e1", obs)), NF)
        assert stub.Health(pb.PolicyHealthRequest()).live_episodes == 0

        # LRU eviction beyond 1024 live episodes; an Act refreshes an episode
        for k in range(1024):
            stub.Reset(pb.PolicyResetRequest(episode_id=f"lru-{k}"))
        stub.Act(act_request("lru-0", obs))
        stub.Reset(pb.PolicyResetRequest(episode_id="lru-1024"))
        assert stub.Health(pb.PolicyHealthRequest()).live_episodes == 1024
        expect_code(lambda: stub.Act(act_request("lru-1", obs)), NF)
        stub.Act(act_request("lru-0", obs))
        stub.Act(act_request("lru-1024", obs))


def check_grpc_malformed():
    obs = scripted_obs(3)
    for name, check in (
        ("wrong_shape", lambda r: r.action_dims == 5 and len(r.actions) == 10),
        ("nan", lambda r: r.action_dims == 7 and np.isnan(r.actions[0]) and not np.isnan(r.actions[1:]).any()),
    ):
        with serve("grpc", name, env=clean_env()) as srv, grpc.insecure_channel(srv.target) as ch:
            stub = pb_grpc.PolicyStub(ch)
            stub.Reset(pb.PolicyResetRequest(episode_id="e"))
            r = stub.Act(act_request("e", obs))
            assert check(r), (name, r)
    with serve("grpc", "raises", env=clean_env()) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = pb_grpc.PolicyStub(ch)
        stub.Reset(pb.PolicyResetRequest(episode_id="e"))
        e = expect_code(lambda: stub.Act(act_request("e", obs)), grpc.StatusCode.INTERNAL, "policy exploded")
        assert "ValueError" in e.details(), e.details()
        expect_code(lambda: stub.Act(act_request("e", obs)), grpc.StatusCode.INTERNAL, "policy exploded")


def check_grpc_auth():
    secret = hashlib.sha256(b"assay/policy\0" + TOKEN.encode()).hexdigest()
    with tempfile.NamedTemporaryFile("w", suffix=".token", delete=False) as f:
        f.write("  " + TOKEN + "\n")
    try:
        for env in (clean_env(ASSAY_CLUSTER_TOKEN=TOKEN), clean_env(ASSAY_CLUSTER_TOKEN_FILE=f.name)):
            with serve("grpc", "scripted", env=env) as srv, grpc.insecure_channel(srv.target) as ch:
                stub = pb_grpc.PolicyStub(ch)
                UA = grpc.StatusCode.UNAUTHENTICATED
                expect_code(lambda: stub.Health(pb.PolicyHealthRequest()), UA)
                expect_code(lambda: stub.Health(pb.PolicyHealthRequest(), metadata=[("authorization", "Bearer " + TOKEN)]), UA)
                expect_code(lambda: stub.Reset(pb.PolicyResetRequest(episode_id="e"), metadata=[("authorization", "Bearer x")]), UA)
                md = [("authorization", "Bearer " + secret)]
                assert stub.Health(pb.PolicyHealthRequest(), metadata=md).action_dims == 7
                stub.Reset(pb.PolicyResetRequest(episode_id="e"), metadata=md)
                obs = scripted_obs(4)
                r = stub.Act(act_request("e", obs), metadata=md)
                assert same(grpc_actions(r), scripted.policy(obs))
    finally:
        os.unlink(f.name)


def check_openpi_scripted():
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    with serve("openpi", "scripted") as srv:
        client = WebsocketClientPolicy(host=srv.url)
        meta = client.get_server_metadata()
        assert meta["policy"] == "scripted", meta
        assert meta["assay_interface"]["action_space"] == "ee_delta", meta
        for seed in range(20):
            obs = scripted_obs(seed)
            out = client.infer(obs)
            a = out["actions"]
            assert isinstance(a, np.ndarray) and a.dtype == np.float32 and a.shape == (2, 7), a
            assert same(a, scripted.policy(obs))
            assert "infer_ms" in out["server_timing"], out
        # a second connection is a second episode, served at the same time
        other = WebsocketClientPolicy(host=srv.url)
        assert same(other.infer(scripted_obs(5))["actions"], scripted.policy(scripted_obs(5)))
        assert same(client.infer(scripted_obs(6))["actions"], scripted.policy(scripted_obs(6)))


def check_openpi_errors_and_key():
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    with serve("openpi", "raises") as srv:
        client = WebsocketClientPolicy(host=srv.url)
        try:
            client.infer(scripted_obs(0))
        except RuntimeError as e:
            assert "policy exploded" in str(e) and "Traceback" in str(e), str(e)
        else:
            raise AssertionError("expected a RuntimeError from the raising policy")
    with serve("openpi", "scripted", extra=("--api-key", "k3y")) as srv:
        for key in (None, "wrong"):
            try:
                WebsocketClientPolicy(host=srv.url, api_key=key)
            except Exception as e:  # websockets' InvalidStatus (HTTP 401)
                assert "401" in str(e), str(e)
            else:
                raise AssertionError(f"api key {key!r} was accepted")
        client = WebsocketClientPolicy(host=srv.url, api_key="k3y")
        obs = scripted_obs(2)
        assert same(client.infer(obs)["actions"], scripted.policy(obs))


def check_lerobot():
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    def obs_of(seed):
        o = scripted_obs(seed)
        o["observation/wrist"] = frame(500 + seed)
        return o

    def local_episode(n):
        adapter = LeRobotAdapter(
            scripted.LeRobotStandin(),
            image_keys={"image": "observation.images.top", "wrist": "observation.images.wrist"},
        )
        adapter.reset()
        return [adapter(obs_of(s)) for s in range(n)]

    want = local_episode(5)
    assert want[0].shape == (7,) and want[4][5] == np.float32(0.03125 * 5), want
    # the batch LeRobot policies take
    b = LeRobotAdapter(scripted.LeRobotStandin(), image_keys={"image": "observation.images.top"}).batch(obs_of(0))
    top = np.asarray(b["observation.images.top"])
    assert top.shape == (1, 3, 32, 32) and top.dtype == np.float32
    assert np.allclose(top[0, :, 3, 4], obs_of(0)["observation/image"][3, 4] / 255.0)
    assert np.asarray(b["observation.state"]).shape == (1, 5) and b["task"] == ["pick up the red cube"]

    with serve("grpc", "lerobot_standin", env=clean_env()) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = pb_grpc.PolicyStub(ch)
        h = stub.Health(pb.PolicyHealthRequest())
        assert [c.name for c in h.interface.cameras] == ["image", "wrist"] and h.action_dims == 7, h
        for ep in ("a", "b"):  # a fresh, reset adapter per episode
            stub.Reset(pb.PolicyResetRequest(episode_id=ep, instruction="pick up the red cube"))
            for s in range(5):
                r = stub.Act(act_request(ep, obs_of(s), names=("image", "wrist")))
                assert same(grpc_actions(r), want[s][None]), (s, grpc_actions(r), want[s])
        # an old client has no wrist frame
        expect_code(lambda: stub.Act(act_request("a", obs_of(0), old=True)), grpc.StatusCode.INVALID_ARGUMENT)
    with serve("openpi", "lerobot_standin") as srv:
        for _ in range(2):  # one connection, one episode
            client = WebsocketClientPolicy(host=srv.url)
            for s in range(5):
                assert same(client.infer(obs_of(s))["actions"], want[s][None])


def check_cli():
    env = clean_env(PYTHONPATH=os.pathsep.join([os.path.join(KIT, "src"), os.path.join(HERE, "policies")]))
    argv = [sys.executable, "-m", "assay_policy_kit", "serve", "scripted:policy", "--protocol", "grpc",
            "--space", "ee_delta", "--camera", "image:scene@32x32", "--camera", "wrist:wrist@16x16:depth",
            "--state", "ee_pos+ee_yaw+holding", "--horizon", "1", "--chunk-size", "2"]
    with Server(argv, env=env) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = pb_grpc.PolicyStub(ch)
        h = stub.Health(pb.PolicyHealthRequest())
        assert h.name == "policy" and (h.action_dims, h.proprio_dims, h.chunk_size) == (7, 5, 2), h
        cams = [(c.name, c.source, c.width, c.height, c.depth) for c in h.interface.cameras]
        assert cams == [("image", "scene", 32, 32, False), ("wrist", "wrist", 16, 16, True)], cams
        assert h.interface.execute_horizon == 1
        stub.Reset(pb.PolicyResetRequest(episode_id="e"))
        obs = scripted_obs(8)
        req = act_request("e", obs)
        req.images.add(name="wrist", width=16, height=16, rgb=frame(9, 16, 16).tobytes())
        expect_code(lambda: stub.Act(req), grpc.StatusCode.INVALID_ARGUMENT, "depth")
        req.images[1].depth.extend([0.5] * 256)
        assert same(grpc_actions(stub.Act(req)), scripted.policy(obs))
    argv = [sys.executable, "-m", "assay_policy_kit", "serve", "scripted:zeros", "--protocol", "openpi",
            "--space", "ee_delta"]
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    with Server(argv, env=env) as srv:
        out = WebsocketClientPolicy(host=srv.url).infer({"observation/state": np.zeros(4, np.float32)})
        assert same(out["actions"], np.zeros((1, 7)))


# ------------------------------------------------------------------------- world models

WORLD_MODELS = os.path.join(HERE, "world_models")


def serve_world_model(*args, env=None):
    return Server([sys.executable, os.path.join(WORLD_MODELS, "trivial.py"), "--port", "0", *args],
                  env=env if env is not None else clean_env())


def wm_reset(stub, episode, frame, state=(0.5, 0.0, 0.1, 0.0), **kw):
    h, w = frame.shape[:2]
    req = wm.WorldModelResetRequest(episode_id=episode, task_id="t", seed=3, instruction="pick",
                                    state=list(state))
    req.frames.add(name="image", width=w, height=h, rgb=frame.tobytes())
    return stub.Reset(req, **kw)


def wm_step(stub, episode, actions, **kw):
    a = np.asarray(actions, np.float32)
    return stub.Step(wm.WorldModelStepRequest(episode_id=episode, actions=a.ravel().tolist(),
                                              action_dims=a.shape[1]), **kw)


def wm_frames(resp):
    return [np.frombuffer(f.rgb, np.uint8).reshape(f.height, f.width, 3) for f in resp.frames]


def wm_states(resp):
    return np.array(resp.states, np.float32).reshape(-1, resp.state_dims)


RIGHT = [[1, 0, 0, 1], [0, 1, 0, 1], [0.5, 0.5, 0.2, 0]]
LEFT = [[-1, 0, 0, 0]] * 3


def check_world_model():
    sys.path.insert(0, WORLD_MODELS)
    import trivial

    start = frame(1, 16, 12)
    # the model itself, as the server will run it
    local = trivial.Trivial()
    local.reset(start, np.array([0.5, 0.0, 0.1, 0.0], np.float32), "pick")
    want_frames, want_states = local.step(np.array(RIGHT, np.float32))
    assert want_frames.shape == (3, 12, 16, 3) and want_frames.dtype == np.uint8
    assert np.allclose(want_states[2], [0.65, 0.15, 0.12, 0.0]), want_states

    with serve_world_model() as srv, grpc.insecure_channel(srv.target) as ch:
        stub = wm_grpc.WorldModelStub(ch)
        h = stub.Health(wm.WorldModelHealthRequest(), timeout=10)
        assert (h.name, h.width, h.height, h.action_dims, h.live_episodes) == ("trivial-ok", 0, 0, 0, 0), h
        wm_reset(stub, "a", start)
        wm_reset(stub, "b", start)  # a second episode: a model of its own
        r = wm_step(stub, "a", RIGHT)
        assert len(r.frames) == 3 and all((f.width, f.height) == (16, 12) for f in r.frames), r.frames
        assert same(np.stack(wm_frames(r)), want_frames)
        assert r.state_dims == 4 and same(wm_states(r), want_states)
        other = wm_step(stub, "b", LEFT)
        assert not same(np.stack(wm_frames(other)), want_frames)
        assert stub.Health(wm.WorldModelHealthRequest()).live_episodes == 2

        NF, IA = grpc.StatusCode.NOT_FOUND, grpc.StatusCode.INVALID_ARGUMENT
        expect_code(lambda: wm_step(stub, "nope", RIGHT), NF)
        expect_code(lambda: stub.Step(wm.WorldModelStepRequest(episode_id="a", actions=[0.0] * 5, action_dims=4)), IA, "5 floats")
        expect_code(lambda: stub.Step(wm.WorldModelStepRequest(episode_id="a", actions=[], action_dims=4)), IA)
        expect_code(lambda: wm_step(stub, "a", [[np.nan, 0, 0, 0]]), IA, "non-finite")
        expect_code(lambda: stub.Reset(wm.WorldModelResetRequest(episode_id="c")), IA, "no frame")
        bad = wm.WorldModelResetRequest(episode_id="c")
        bad.frames.add(width=16, height=12, rgb=start.tobytes()[:-1])
        expect_code(lambda: stub.Reset(bad), IA, "bytes")
        expect_code(lambda: wm_reset(stub, "", start), IA)

        stub.End(wm.WorldModelEndRequest(episode_id="a"))
        stub.End(wm.WorldModelEndRequest(episode_id="never-there"))  # not an error
        expect_code(lambda: wm_step(stub, "a", RIGHT), NF)
        assert stub.Health(wm.WorldModelHealthRequest()).live_episodes == 1

    with serve_world_model("--variant", "raises") as srv, grpc.insecure_channel(srv.target) as ch:
        stub = wm_grpc.WorldModelStub(ch)
        wm_reset(stub, "e", start)
        e = expect_code(lambda: wm_step(stub, "e", RIGHT), grpc.StatusCode.INTERNAL, "world model exploded")
        assert "ValueError" in e.details(), e.details()
    # malformed answers are passed on for the client to refuse
    for variant, check in (
        ("wrong_size", lambda r: [(f.width, f.height) for f in r.frames] == [(17, 12)] * 3),
        ("too_few", lambda r: len(r.frames) == 2),
        ("frames_only", lambda r: len(r.frames) == 3 and len(r.states) == 0 and r.state_dims == 0),
    ):
        with serve_world_model("--variant", variant) as srv, grpc.insecure_channel(srv.target) as ch:
            stub = wm_grpc.WorldModelStub(ch)
            wm_reset(stub, "e", start)
            r = wm_step(stub, "e", RIGHT)
            assert check(r), (variant, r.frames[0].width, len(r.frames), r.state_dims)


def check_world_model_auth():
    secret = hashlib.sha256(b"assay/world-model\0" + TOKEN.encode()).hexdigest()
    policy_secret = hashlib.sha256(b"assay/policy\0" + TOKEN.encode()).hexdigest()
    with serve_world_model(env=clean_env(ASSAY_CLUSTER_TOKEN=TOKEN)) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = wm_grpc.WorldModelStub(ch)
        UA = grpc.StatusCode.UNAUTHENTICATED
        expect_code(lambda: stub.Health(wm.WorldModelHealthRequest()), UA, "world model server")
        for wrong in (TOKEN, policy_secret, "x"):
            expect_code(lambda: stub.Health(wm.WorldModelHealthRequest(), metadata=[("authorization", "Bearer " + wrong)]), UA)
        md = [("authorization", "Bearer " + secret)]
        assert stub.Health(wm.WorldModelHealthRequest(), metadata=md).name == "trivial-ok"
        wm_reset(stub, "e", frame(2, 16, 12), metadata=md)
        assert len(wm_step(stub, "e", RIGHT, metadata=md).frames) == 3


def check_world_model_cli():
    env = clean_env(PYTHONPATH=os.pathsep.join([os.path.join(KIT, "src"), WORLD_MODELS]))
    argv = [sys.executable, "-m", "assay_policy_kit", "world-model", "trivial:Trivial", "--size", "16x12",
            "--action-dims", "4", "--description", "from the CLI"]
    with Server(argv, env=env) as srv, grpc.insecure_channel(srv.target) as ch:
        stub = wm_grpc.WorldModelStub(ch)
        h = stub.Health(wm.WorldModelHealthRequest())
        assert (h.name, h.description, h.width, h.height, h.action_dims) == ("Trivial", "from the CLI", 16, 12, 4), h
        IA = grpc.StatusCode.INVALID_ARGUMENT
        expect_code(lambda: wm_reset(stub, "e", frame(3, 32, 32)), IA, "16x12")
        wm_reset(stub, "e", frame(3, 16, 12))
        expect_code(lambda: wm_step(stub, "e", [[0, 0, 0]]), IA, "takes 4")
        assert len(wm_step(stub, "e", RIGHT).frames) == 3


CHECKS = [check_stubs, check_grpc_scripted, check_grpc_malformed, check_grpc_auth,
          check_openpi_scripted, check_openpi_errors_and_key, check_lerobot, check_cli,
          check_world_model, check_world_model_auth, check_world_model_cli]


def main():
    failed = 0
    for check in CHECKS:
        t0 = time.monotonic()
        try:
            check()
        except Exception:  # noqa: BLE001
            failed += 1
            print(f"FAIL {check.__name__}\n{traceback.format_exc()}", flush=True)
        else:
            print(f"ok   {check.__name__} ({time.monotonic() - t0:.1f} s)", flush=True)
    for p in STARTED:
        if p.poll() is None:
            p.kill()
            p.wait()
    print(f"{len(CHECKS) - failed}/{len(CHECKS)} checks passed", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
