"""The kit's LeRobotAdapter against the real LeRobot (lerobot 0.4.4): for an ACT and a Diffusion
policy saved with dataset statistics, the adapter's answer to each observation of an episode
equals LeRobot's own evaluation pipeline, `postprocessor(policy.select_action(preprocessor(
preprocess_observation(env_obs))))`, with the checkpoint loaded by LeRobot's own calls, to 1e-5.
The same policy without its processors (the kit before) answers on another scale. Two episodes
over one loaded model (`for_episode`), their steps taken in turn, each answer as if alone.

    python lerobot_adapter_check.py KIT_SRC OUT_DIR

Prints one JSON line of what it compared. Run by tests/it/real_policies.rs with the venv of
scripts/setup-lerobot; offline (nothing is downloaded: backbones start from random weights).
"""

import json
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")
sys.path.insert(0, sys.argv[1])
OUT = sys.argv[2]

import numpy as np  # noqa: E402
import torch  # noqa: E402
from lerobot.configs.policies import PreTrainedConfig  # noqa: E402
from lerobot.configs.types import FeatureType, PolicyFeature  # noqa: E402
from lerobot.envs.utils import preprocess_observation  # noqa: E402
from lerobot.policies.act.configuration_act import ACTConfig  # noqa: E402
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig  # noqa: E402
from lerobot.policies.factory import get_policy_class, make_pre_post_processors  # noqa: E402

from assay_policy_kit.lerobot import LeRobotAdapter  # noqa: E402

SIZE, STATE, ACTION, STEPS = 64, 8, 7, 6
PROMPT = "put the red block in the green bowl"


def features():
    inputs = {
        "observation.images.top": PolicyFeature(type=FeatureType.VISUAL, shape=(3, SIZE, SIZE)),
        "observation.images.wrist": PolicyFeature(type=FeatureType.VISUAL, shape=(3, SIZE, SIZE)),
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE,)),
    }
    outputs = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION,))}
    return inputs, outputs


def stats():
    """Dataset statistics far from 0/1, so that a pipeline skipped shows."""
    rng = np.random.default_rng(7)

    def vec(n, lo, hi):
        mean = rng.uniform(lo, hi, n).astype(np.float32)
        std = rng.uniform(0.05, 0.5, n).astype(np.float32)
        return {"mean": torch.tensor(mean), "std": torch.tensor(std),
                "min": torch.tensor(mean - 2 * std), "max": torch.tensor(mean + 2 * std)}

    image = {"mean": torch.tensor([[[0.485]], [[0.456]], [[0.406]]]),
             "std": torch.tensor([[[0.229]], [[0.224]], [[0.225]]]),
             "min": torch.zeros(3, 1, 1), "max": torch.ones(3, 1, 1)}
    return {"observation.images.top": image, "observation.images.wrist": image,
            "observation.state": vec(STATE, -1.0, 1.0), "action": vec(ACTION, -2.0, 2.0)}


def config(kind):
    inputs, outputs = features()
    if kind == "act":
        return ACTConfig(input_features=inputs, output_features=outputs, chunk_size=8,
                         n_action_steps=4, dim_model=64, n_heads=2, dim_feedforward=128,
                         n_encoder_layers=1, n_decoder_layers=1, latent_dim=8,
                         pretrained_backbone_weights=None, device="cpu")
    return DiffusionConfig(input_features=inputs, output_features=outputs, n_obs_steps=2,
                           horizon=8, n_action_steps=4, crop_shape=None, down_dims=(32, 64),
                           diffusion_step_embed_dim=32, num_inference_steps=4,
                           pretrained_backbone_weights=None, device="cpu")


def save(kind):
    torch.manual_seed(0)
    cfg = config(kind)
    policy = get_policy_class(cfg.type)(cfg)
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats())
    path = os.path.join(OUT, kind)
    policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path


def episode_obs(step):
    """An environment's observation (LeRobot's gym layout) and the same for the kit."""
    rng = np.random.default_rng(100 + step)
    top = rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    wrist = rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    state = rng.uniform(-1, 1, STATE).astype(np.float32)
    env = {"pixels": {"top": top[None], "wrist": wrist[None]}, "agent_pos": state[None]}
    kit = {"observation/top": top, "observation/wrist": wrist, "observation/state": state,
           "prompt": PROMPT}
    return env, kit


def lerobot_episode(path):
    """LeRobot's own: load as lerobot-eval does, and act as its rollout does."""
    cfg = PreTrainedConfig.from_pretrained(path)
    cfg.device = "cpu"
    policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    policy.eval()
    pre, post = make_pre_post_processors(cfg, pretrained_path=path)
    policy.reset()
    out = []
    for step in range(STEPS):
        env, _ = episode_obs(step)
        batch = preprocess_observation(env)
        batch["task"] = [PROMPT]
        torch.manual_seed(step)
        with torch.inference_mode():
            out.append(post(policy.select_action(pre(batch))).numpy()[0])
    return out, policy


def kit_episode(adapter, offset=0):
    adapter.reset()
    out = []
    for step in range(STEPS):
        _, kit = episode_obs(offset + step)
        torch.manual_seed(offset + step)
        out.append(adapter(kit))
    return out


def interleaved(adapter):
    """Two episodes over one loaded model, their steps taken in turn."""
    a, b = adapter.for_episode(), adapter.for_episode()
    out_a, out_b = [], []
    for step in range(STEPS):
        for ep, out, offset in ((a, out_a, 0), (b, out_b, 50)):
            _, kit = episode_obs(offset + step)
            torch.manual_seed(offset + step)
            out.append(ep(kit))
    return out_a, out_b


def main():
    result = {"lerobot": __import__("lerobot").__version__, "torch": torch.__version__}
    for kind in ("act", "diffusion"):
        path = save(kind)
        want, policy = lerobot_episode(path)
        adapter = LeRobotAdapter.from_pretrained(path, device="cpu")
        assert adapter.image_keys == {"top": "observation.images.top",
                                      "wrist": "observation.images.wrist"}, adapter.image_keys
        got = kit_episode(adapter)
        diff = max(float(np.abs(g - w).max()) for g, w in zip(got, want))
        assert all(g.shape == (ACTION,) for g in got), [g.shape for g in got]
        assert diff <= 1e-5, f"{kind}: the adapter differs from LeRobot's pipeline by {diff}"
        # Without its processors (the kit's adapter before lerobot 0.4's pipelines).
        raw = kit_episode(LeRobotAdapter(policy, image_keys=adapter.image_keys))
        raw_diff = max(float(np.abs(r - w).max()) for r, w in zip(raw, want))
        assert raw_diff > 1e-2, f"{kind}: raw policy output equals the pipeline's ({raw_diff})"
        # One loaded model, two concurrent episodes: each as if it ran alone.
        alone_b = kit_episode(adapter.for_episode(), offset=50)
        got_a, got_b = interleaved(adapter)
        inter = max(max(float(np.abs(g - w).max()) for g, w in zip(got_a, want)),
                    max(float(np.abs(g - w).max()) for g, w in zip(got_b, alone_b)))
        assert inter <= 1e-5, f"{kind}: interleaved episodes differ from episodes alone by {inter}"
        iface = adapter.interface(state="ee_pos+ee_quat+gripper")
        assert iface.action_space == "ee_delta" and iface.state_dims() == STATE, iface
        assert [(c.name, c.source, c.width, c.height) for c in iface.cameras] == [
            ("top", "top", SIZE, SIZE), ("wrist", "wrist", SIZE, SIZE)], iface.cameras
        for bad, field in (("ee_pos+holding", "state"), (None, "state")):
            try:
                adapter.interface(state=bad)
            except ValueError as e:
                assert field in str(e), str(e)
            else:
                raise AssertionError(f"state {bad!r} was accepted for 8 floats")
        result[kind] = {"steps": STEPS, "max_abs_diff": diff, "interleaved_max_abs_diff": inter, "without_processors_max_abs_diff": raw_diff,
                        "first_action": [round(float(v), 4) for v in want[0]],
                        "first_action_without_processors": [round(float(v), 4) for v in raw[0]]}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
