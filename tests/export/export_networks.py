"""Randomly initialised laplab policies for every sensor combination and algorithm the car takes,
shared by the export tests (tests/export/test_car_graph.py, test_console_checkpoint.py)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from laplab.agents.networks import ActorCritic, observation_to_tensor
from laplab.agents.sac_networks import SquashedGaussianActor
from laplab.agents.onnx_export import random_observations
from laplab.env.spec import network_layout

SHALLOW, STANDARD, DEEP = ("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "DEEP_CONVOLUTIONAL_NETWORK",
                           "DEEP_CONVOLUTIONAL_NETWORK_DEEP")
SPACES = {
    "FRONT_FACING_CAMERA": gym.spaces.Box(0, 255, (1, 120, 160), np.uint8),
    "LEFT_CAMERA": gym.spaces.Box(0, 255, (1, 120, 160), np.uint8),
    "STEREO_CAMERAS": gym.spaces.Box(0, 255, (2, 120, 160), np.uint8),
    "LIDAR": gym.spaces.Box(0.15, 1.0, (64,), np.float32),   # laplab's LIDAR: 64 ranges clipped to [0.15, 1] m
    "SECTOR_LIDAR": gym.spaces.Box(0.0, 1.0, (8,), np.float32),
}
SAMPLES = 100

# (sensors, network, algorithm, action space): what the car supports
CASES = [
    (("FRONT_FACING_CAMERA",), SHALLOW, "clipped_ppo", "discrete"),
    (("FRONT_FACING_CAMERA",), STANDARD, "clipped_ppo", "discrete"),
    (("FRONT_FACING_CAMERA",), DEEP, "clipped_ppo", "discrete"),
    (("FRONT_FACING_CAMERA",), SHALLOW, "clipped_ppo", "continuous"),
    (("FRONT_FACING_CAMERA",), SHALLOW, "sac", "continuous"),
    (("LEFT_CAMERA",), STANDARD, "clipped_ppo", "discrete"),
    (("STEREO_CAMERAS",), SHALLOW, "clipped_ppo", "discrete"),
    (("STEREO_CAMERAS", "LIDAR"), SHALLOW, "clipped_ppo", "discrete"),
    (("FRONT_FACING_CAMERA", "SECTOR_LIDAR"), SHALLOW, "clipped_ppo", "continuous"),
    (("STEREO_CAMERAS", "SECTOR_LIDAR"), STANDARD, "sac", "continuous"),
]


def varied_observations(space, count: int, seed: int):
    """Camera frames that differ from each other (a random brightness ramp per frame, plus noise:
    uniform noise alone gives near-identical features) and uniform vectors inside their bounds."""
    rng = np.random.default_rng(seed)
    observations = random_observations(space, count, seed)

    def frames(box):
        channels, height, width = box.shape
        rows, cols = np.mgrid[0:height, 0:width]
        ramps = rng.uniform(-2.0, 2.0, (count, channels, 1, 1, 3))
        image = 127.5 + 60.0 * (ramps[..., 0] + ramps[..., 1] * rows / height + ramps[..., 2] * cols / width)
        return np.clip(image + rng.normal(0.0, 20.0, image.shape), 0, 255).astype(np.uint8)

    if isinstance(space, gym.spaces.Dict):
        return {name: frames(box) if box.dtype == np.uint8 else observations[name]
                for name, box in space.spaces.items()}
    return frames(space) if space.dtype == np.uint8 else observations


def case_id(case) -> str:
    sensors, network, algorithm, kind = case
    return f"{'+'.join(sensors)}-{network.removeprefix('DEEP_CONVOLUTIONAL_NETWORK').strip('_') or 'STANDARD'}-{algorithm}-{kind}"


def make_network(sensors, network, algorithm, kind):
    """A randomly initialised laplab policy whose head is scaled to the spread of its features on
    varied observations, so outputs clearly differ between observations (the default head is ~0)."""
    space = SPACES[sensors[0]] if len(sensors) == 1 else gym.spaces.Dict({s: SPACES[s] for s in sensors})
    torch.manual_seed(len(sensors) * 7 + len(network))
    network = network_layout(network, sensors)  # stereo with a deeper network: DeepRacer's stereo embedder
    if algorithm == "sac":
        model = SquashedGaussianActor(space, 2, network)
        head, trunk = model.mean, model.trunk
    else:
        model = ActorCritic(space, 5 if kind == "discrete" else gym.spaces.Box(-1, 1, (2,)), network)
        head, trunk = model.policy_head, model.policy_trunk
    with torch.no_grad():
        features = trunk(observation_to_tensor(varied_observations(space, 32, seed=0), "cpu"))
        spread = float(features.std(dim=0).mean()) + 1e-6
        # logits spread ~0.4 between observations: clearly different probabilities, while the float32
        # rounding of the trunk (torch itself is ~1e-5 from a float64 forward of the DEEP network when
        # a random trunk's tiny feature spread is magnified to spread ~1) stays well below 1e-5
        head.weight.normal_(0.0, 0.4 / (spread * features.shape[1] ** 0.5))
        head.bias.normal_(0.0, 0.2)
        head.bias.sub_(head.weight @ features.mean(dim=0))  # centre the outputs (continuous: inside [-1, 1])
    return model.eval(), space


def float32_tolerance(layers, outputs: np.ndarray) -> float:
    """How far two float32 evaluations of one network may differ (TensorFlow's and torch's kernels sum in
    other orders, and hosts with AVX512-BF16 differ again): each layer's sums of fan-in terms round like a
    random walk, eps * sqrt(fan-in), and the layers' errors add up, on the outputs' scale (2.2e-5 for the
    camera networks; the DEEP one differed by 1.2e-5 on an AVX512-BF16 host). Never below 1e-5."""
    weights = [w for branch in layers.branches for w in (*branch.convs, *branch.dense)]
    weights += [*layers.middleware, *layers.head_hidden, layers.head]
    walk = sum(np.sqrt(np.prod(w.kernel.shape[:-1])) for w in weights)
    return max(1e-5, float(np.finfo(np.float32).eps) * float(walk) * max(float(np.abs(outputs).max()), 1.0))
