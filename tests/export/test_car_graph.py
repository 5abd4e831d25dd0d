"""The car's model.pb, proved with the car's own toolchain: for every sensor combination and algorithm
the car takes, the TensorFlow graph reproduces laplab's torch policy (<= 1e-5 on 100 observations),
and OpenVINO, converting it with the input names and shapes the car's model optimizer passes,
picks the same action (probabilities within 1e-4)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch", reason="the graph is built from laplab's torch networks")
pytest.importorskip("tensorflow", reason="model.pb needs tensorflow-cpu: pip install 'laplab[deepracer]'")
pytest.importorskip("openvino", reason="the car's conversion needs openvino: pip install 'laplab[deepracer]'")

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402

from laplab.agents.networks import ActorCritic, SquashedGaussianActor, observation_to_tensor  # noqa: E402
from laplab.agents.onnx_export import random_observations  # noqa: E402
from laplab.export.openvino_model import OpenVinoPolicy, car_optimizer_inputs  # noqa: E402
from laplab.export.policy_layers import policy_layers, reference_output  # noqa: E402
from laplab.export.tensorflow_graph import (FrozenGraph, graph_bytes, graph_feed, input_node_name,  # noqa: E402
                                            output_node_name)

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


@pytest.fixture(scope="module")
def built(request, tmp_path_factory):
    cache = {}

    def get(case):
        if case not in cache:
            model, space = make_network(*case)
            layers = policy_layers(model, space, list(case[0]))
            path = tmp_path_factory.mktemp("graphs") / "model.pb"
            path.write_bytes(graph_bytes(layers))
            cache[case] = (model, space, layers, path)
        return cache[case]
    return get


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_tensorflow_graph_matches_the_torch_policy(built, case):
    sensors, _, algorithm, kind = case
    model, space, layers, path = built(case)
    graph = FrozenGraph(path.read_bytes(), output_node_name(algorithm))
    expected_inputs = {spec.name: (None, *spec.shape[1:]) for spec in car_optimizer_inputs(sensors, algorithm)}
    assert graph.placeholders == expected_inputs  # the names and layouts the car's optimizer passes
    observations = varied_observations(space, SAMPLES, seed=11)
    got = graph.run(graph_feed(layers, observations))
    expected = reference_output(model, observations)
    assert got.shape == (SAMPLES, 5 if kind == "discrete" else 2)
    assert np.abs(got - expected).max() <= 1e-5
    assert np.ptp(expected, axis=0).max() > 0.05  # not a comparison of near-constant outputs
    if kind == "discrete":
        assert np.allclose(got.sum(axis=1), 1.0, atol=1e-5)
        assert len(set(expected.argmax(axis=1))) > 1
    elif algorithm == "clipped_ppo":  # the car clips the mean to [-1, 1], as laplab drives
        assert np.abs(np.clip(got, -1, 1) - reference_output(model, observations, raw=False)).max() <= 1e-5


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_openvino_runs_the_graph_as_the_car_does(built, case):
    sensors, _, algorithm, kind = case
    model, space, layers, path = built(case)
    inputs = car_optimizer_inputs(sensors, algorithm)
    policy = OpenVinoPolicy(path, inputs)
    assert any(name.split(":")[0] == output_node_name(algorithm) for name in policy.output_names)
    observations = varied_observations(space, SAMPLES, seed=12)
    got = policy.run_batch(graph_feed(layers, observations))
    expected = reference_output(model, observations)
    assert np.abs(got - expected).max() <= 1e-4
    if kind == "discrete":
        assert np.array_equal(got.argmax(axis=1), expected.argmax(axis=1))


def test_input_names_follow_the_model_optimizer():
    assert input_node_name("FRONT_FACING_CAMERA", "clipped_ppo") == \
        "main_level/agent/main/online/network_0/FRONT_FACING_CAMERA/FRONT_FACING_CAMERA"
    assert input_node_name("LIDAR", "sac") == "main_level/agent/policy/online/network_0/LIDAR/LIDAR"
    assert output_node_name("clipped_ppo") == "main_level/agent/main/online/network_1/ppo_head_0/policy"
    assert output_node_name("sac") == "main_level/agent/policy/online/network_0/sac_policy_head_0/policy"
    shapes = [spec.shape for spec in car_optimizer_inputs(["STEREO_CAMERAS", "SECTOR_LIDAR"], "clipped_ppo")]
    assert shapes == [(1, 120, 160, 2), (1, 8)]


def test_old_single_camera_input_name(tmp_path):
    """DeepRacer's first models name their camera input observation/observation; the graph can too."""
    model, space = make_network(("FRONT_FACING_CAMERA",), SHALLOW, "clipped_ppo", "discrete")
    layers = policy_layers(model, space, ["FRONT_FACING_CAMERA"])
    name = "main_level/agent/main/online/network_0/observation/observation"
    graph = FrozenGraph(graph_bytes(layers, {"FRONT_FACING_CAMERA": name}), output_node_name("clipped_ppo"))
    assert list(graph.placeholders) == [name]
    observations = random_observations(space, 8, seed=3)
    got = graph.run(graph_feed(layers, observations, {"FRONT_FACING_CAMERA": name}))
    assert np.abs(got - reference_output(model, observations)).max() <= 1e-5
