"""The car-side runtime: frame preprocessing (grey weights, area / bilinear resize) in closed form,
ONNX policies against the torch networks they came from, and no torch import."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from laplab.agents.networks import ActionSpec, ActorCritic  # noqa: E402
from laplab.agents.onnx_export import policy_to_onnx, random_observations, torch_policy_output  # noqa: E402
from laplab.runtime import (CarAction, OnnxPolicy, RuntimeModelError, preprocess_frame,  # noqa: E402
                            resize_weights, to_grey)

REPO_ROOT = Path(__file__).resolve().parents[1]
ACTIONS = [{"steering_angle": a, "speed": s} for a, s in ((-30, 0.6), (-15, 1.0), (0, 1.5), (15, 1.0), (30, 0.6))]
DISCRETE_META = {"action_space": ACTIONS, "sensor": ["FRONT_FACING_CAMERA"], "action_space_type": "discrete",
                 "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "training_algorithm": "clipped_ppo",
                 "version": "5"}
CONTINUOUS_META = {**DISCRETE_META, "action_space_type": "continuous",
                   "action_space": {"steering_angle": {"low": -20, "high": 30}, "speed": {"low": 0.5, "high": 2.5}}}


def camera_export(folder: Path, space: gym.spaces.Box, metadata: dict, actions: ActionSpec, seed: int = 0):
    """A random-weight camera ActorCritic (head spread so outputs differ), exported to ``folder``."""
    torch.manual_seed(seed)
    network = ActorCritic(space, actions)
    with torch.no_grad():
        network.policy_head.weight.normal_(0.0, 0.3)
        network.policy_head.bias.normal_(0.0, 0.3)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.onnx").write_bytes(policy_to_onnx(network, space, metadata["sensor"]))
    (folder / "model_metadata.json").write_text(json.dumps(metadata))
    return network


@pytest.fixture(scope="module")
def discrete_camera(tmp_path_factory):
    folder = tmp_path_factory.mktemp("discrete")
    space = gym.spaces.Box(0, 255, (1, 120, 160), np.uint8)
    return folder, camera_export(folder, space, DISCRETE_META, ActionSpec(True, 5))


def frames(count: int, seed: int, shape=(480, 640, 3)) -> list[np.ndarray]:
    """Smooth random camera frames (a blurred noise field, like a road scene more than pure noise)."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (count, shape[0] // 40 + 1, shape[1] // 40 + 1, *shape[2:]))
    return [np.repeat(np.repeat(c, 40, 0), 40, 1)[: shape[0], : shape[1]].astype(np.uint8)
            + rng.integers(0, 3, shape, dtype=np.uint8) for c in coarse]


# -- preprocessing -------------------------------------------------------------------------------

def test_resize_weights_closed_forms():
    a, b, c = 10.0, 40.0, 100.0
    shrink = resize_weights(3, 2)  # output pixels cover input spans [0, 1.5) and [1.5, 3)
    assert np.allclose(shrink @ [a, b, c], [(a + 0.5 * b) / 1.5, (0.5 * b + c) / 1.5])
    grow = resize_weights(2, 4)  # output centres at input coordinates -0.25, 0.25, 0.75, 1.25
    assert np.allclose(grow @ [a, b], [a, 0.75 * a + 0.25 * b, 0.25 * a + 0.75 * b, b])
    assert np.array_equal(resize_weights(7, 7), np.eye(7))
    for n_in, n_out in ((640, 160), (480, 120), (500, 160), (90, 120), (1, 5), (5, 1)):
        assert np.allclose(resize_weights(n_in, n_out).sum(axis=1), 1.0)


def test_area_shrink_of_a_block_image_is_exact():
    blocks = np.random.default_rng(0).integers(0, 256, (120, 160)).astype(np.uint8)
    image = np.repeat(np.repeat(blocks, 4, axis=0), 4, axis=1)  # 480 x 640, constant 4 x 4 blocks
    out = preprocess_frame(image)
    assert out.shape == (120, 160) and out.dtype == np.float32
    assert np.array_equal(out, blocks.astype(np.float32))
    assert np.array_equal(preprocess_frame(blocks), blocks)  # already 160 x 120: untouched


def test_bilinear_growth_keeps_a_ramp_linear():
    row = np.arange(80, dtype=np.float64) * 3.0  # 80 columns, 3 grey levels apart
    grown = resize_weights(80, 160) @ row
    centres = (np.arange(160) + 0.5) / 2.0 - 0.5  # source coordinate of each output pixel centre
    inside = (centres >= 0) & (centres <= 79)
    assert np.allclose(grown[inside], 3.0 * centres[inside])
    assert np.allclose(grown[~inside], [0.0, 237.0])  # clamped at the borders


def test_grey_uses_itu_601_weights():
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[0, 0] = (255, 0, 0)
    rgb[0, 1] = (0, 255, 0)
    rgb[0, 2] = (0, 0, 255)
    rgb[1] = (10, 200, 30)
    grey = to_grey(rgb)
    assert np.allclose(grey[0], [0.299 * 255, 0.587 * 255, 0.114 * 255])
    assert np.allclose(grey[1], 0.299 * 10 + 0.587 * 200 + 0.114 * 30)
    assert np.array_equal(to_grey(rgb[:, :, :1]), to_grey(rgb[:, :, 0]))
    for bad in (np.zeros((4, 4, 4)), np.zeros(5), np.zeros((0, 3))):
        with pytest.raises(RuntimeModelError, match="camera frame"):
            to_grey(bad)


# -- policies ------------------------------------------------------------------------------------

def test_camera_policy_matches_the_torch_network(discrete_camera):
    folder, network = discrete_camera
    policy = OnnxPolicy(folder)
    for frame in frames(4, seed=1) + frames(2, seed=2, shape=(300, 500)) + frames(1, seed=3, shape=(120, 160)):
        grey = preprocess_frame(frame).astype(np.uint8)[None, None]  # (1, 1, 120, 160), as laplab renders
        expected = torch_policy_output(network, torch.as_tensor(grey))[0]
        got = policy.probabilities(frame)
        assert np.abs(got - expected).max() < 1e-5
        action = policy.act(frame)
        best = ACTIONS[int(np.argmax(expected))]
        assert isinstance(action, CarAction) and action == (best["steering_angle"], best["speed"])
    grey_frame = frames(1, seed=4)[0][:, :, 1]
    assert np.allclose(policy.probabilities(grey_frame), policy.probabilities(grey_frame[:, :, None]))


def test_continuous_camera_policy_scales_the_mean(tmp_path):
    space = gym.spaces.Box(0, 255, (1, 120, 160), np.uint8)
    network = camera_export(tmp_path, space, CONTINUOUS_META, ActionSpec(False, 2), seed=4)
    policy = OnnxPolicy(tmp_path / "model.onnx")
    for frame in frames(3, seed=5):
        grey = preprocess_frame(frame).astype(np.uint8)[None, None]
        mean = torch_policy_output(network, torch.as_tensor(grey))[0]
        assert np.abs(policy.policy_output(frame) - mean).max() < 1e-5
        steer, speed = policy.act(frame)
        assert np.isclose(steer, -20 + (mean[0] + 1) / 2 * 50, atol=1e-4)
        assert np.isclose(speed, 0.5 + (mean[1] + 1) / 2 * 2.0, atol=1e-4)
    with pytest.raises(RuntimeModelError, match="no action probabilities"):
        policy.probabilities(frames(1, seed=6)[0])


def test_stereo_and_stacked_frames_reach_the_network_in_order(tmp_path):
    stereo_space = gym.spaces.Box(0, 255, (2, 120, 160), np.uint8)
    stereo_meta = {**DISCRETE_META, "sensor": ["STEREO_CAMERAS"]}
    network = camera_export(tmp_path / "stereo", stereo_space, stereo_meta, ActionSpec(True, 5), seed=7)
    policy = OnnxPolicy(tmp_path / "stereo")
    left, right = frames(2, seed=8)
    pair = np.stack([preprocess_frame(left), preprocess_frame(right)]).astype(np.uint8)[None]
    expected = torch_policy_output(network, torch.as_tensor(pair))[0]
    assert np.abs(policy.probabilities((left, right)) - expected).max() < 1e-5
    with pytest.raises(RuntimeModelError, match="needs 2 frames"):
        policy.act([left])
    # Two frames stacked on one camera: oldest first; a fresh stack repeats the first frame.
    network = camera_export(tmp_path / "stack", stereo_space, DISCRETE_META, ActionSpec(True, 5), seed=9)
    stacked = OnnxPolicy(tmp_path / "stack")
    first, second = (preprocess_frame(f).astype(np.uint8) for f in (left, right))
    for frame, channels in ((left, [first, first]), (right, [first, second])):
        expected = torch_policy_output(network, torch.as_tensor(np.stack(channels)[None]))[0]
        assert np.abs(stacked.probabilities(frame) - expected).max() < 1e-5
    stacked.reset()
    expected = torch_policy_output(network, torch.as_tensor(np.stack([second, second])[None]))[0]
    assert np.abs(stacked.probabilities(right) - expected).max() < 1e-5


def test_state_model_runtime_matches_the_trained_policy(tmp_path, monkeypatch):
    from laplab.commands.export import export_model_onnx
    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    from laplab.train.policy import load_model_policy

    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    base = TrainConfig()
    hyper = {**base.hyper().to_dict(), "num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}
    create_training("state", replace(base, hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(),
                                     max_episodes=8)).run()
    export_model_onnx("state", "best", tmp_path / "car")
    runtime, policy = OnnxPolicy(tmp_path / "car"), load_model_policy("state")
    observations = random_observations(policy.observation_space, 100, seed=11)
    steer, speed = policy.metadata.action_space.to_physical(policy.act(observations))
    got = np.array([runtime.act_vector(obs) for obs in observations])
    assert np.array_equal(got, np.stack([steer, speed], axis=1))
    probabilities = torch_policy_output(policy.network, torch.as_tensor(observations))
    assert np.abs(np.array([runtime.probabilities(vectors=o) for o in observations]) - probabilities).max() < 1e-5
    with pytest.raises(RuntimeModelError, match="must have shape"):
        runtime.act_vector(observations[0][:-1])
    with pytest.raises(RuntimeModelError, match="no camera"):
        runtime.act(np.zeros((120, 160)), observations[0])


def test_bad_inputs_are_refused(discrete_camera, tmp_path):
    folder, _ = discrete_camera
    policy = OnnxPolicy(folder)
    with pytest.raises(RuntimeModelError, match="NaN"):
        policy.act(np.full((120, 160), np.nan))
    with pytest.raises(RuntimeModelError, match="pass a frame"):
        policy.act_vector(np.zeros(3))
    with pytest.raises(RuntimeModelError, match="no such file"):
        OnnxPolicy(tmp_path / "absent")
    (tmp_path / "model.onnx").write_bytes((folder / "model.onnx").read_bytes())
    (tmp_path / "model_metadata.json").write_text(json.dumps({**DISCRETE_META, "action_space": ACTIONS[:3]}))
    with pytest.raises(RuntimeModelError, match="outputs 5 values"):
        OnnxPolicy(tmp_path)


def test_runtime_imports_no_torch(discrete_camera):
    folder, _ = discrete_camera
    script = (
        "import sys, numpy as np\n"
        "from laplab.runtime import OnnxPolicy\n"
        f"policy = OnnxPolicy({str(folder)!r})\n"
        "frame = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)\n"
        "steer, speed = policy.act(frame)\n"
        "assert policy.probabilities(frame).shape == (5,)\n"
        "assert 'torch' not in sys.modules, 'laplab.runtime imported torch'\n"
        "print(steer, speed)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    steer, speed = map(float, done.stdout.split())
    assert {"steering_angle": steer, "speed": speed} in [{k: float(v) for k, v in a.items()} for a in ACTIONS]
