"""The car's model.pb, proved with the car's own toolchain: for every sensor combination and algorithm
the car takes, the TensorFlow graph reproduces laplab's torch policy (within float32's rounding, 1e-5
or more, on 100 observations) as DeepRacer's graph holds it (SAC: the mean before tanh), and OpenVINO,
converting it with the input names and shapes the car's model optimizer passes, picks the same action
(outputs within 1e-4)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch", reason="the graph is built from laplab's torch networks")
pytest.importorskip("tensorflow", reason="model.pb needs tensorflow-cpu: pip install 'laplab[deepracer]'")
pytest.importorskip("openvino", reason="the car's conversion needs openvino: pip install 'laplab[deepracer]'")

from export_networks import CASES, SAMPLES, SHALLOW, case_id, float32_tolerance  # noqa: E402
from laplab.agents.onnx_export import random_observations  # noqa: E402
from laplab.export.openvino_model import OpenVinoPolicy, car_optimizer_inputs  # noqa: E402
from laplab.export.policy_layers import reference_output  # noqa: E402
from laplab.export.tensorflow_graph import (FrozenGraph, graph_bytes, graph_feed, input_node_name,  # noqa: E402
                                            output_node_name)


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_tensorflow_graph_matches_the_torch_policy(built_case, case):
    sensors, _, algorithm, kind = case
    built = built_case(case)
    model, observations, expected = built.model, built.observations, built.expected
    graph, got = built.frozen(output_node_name(algorithm))
    expected_inputs = {spec.name: (None, *spec.shape[1:]) for spec in car_optimizer_inputs(sensors, algorithm)}
    assert graph.placeholders == expected_inputs  # the names and layouts the car's optimizer passes
    assert got.shape == (SAMPLES, 5 if kind == "discrete" else 2)
    assert np.abs(got - expected).max() <= float32_tolerance(built.layers, expected)
    assert np.ptp(expected, axis=0).max() > 0.05  # not a comparison of near-constant outputs
    if kind == "discrete":
        assert np.allclose(got.sum(axis=1), 1.0, atol=1e-5)
        assert len(set(expected.argmax(axis=1))) > 1
    elif algorithm == "clipped_ppo":  # the car clips the mean to [-1, 1], as laplab drives
        assert np.abs(np.clip(got, -1, 1) - reference_output(model, observations, raw=False)).max() <= 1e-5
    else:  # SAC: the node is the mean before tanh, as deepracer-simapp's; laplab's action is its tanh
        policy = reference_output(model, observations)
        assert np.abs(np.tanh(got) - policy).max() <= 1e-5
        assert np.abs(got - policy).max() > 1e-3  # a graph ending in tanh (laplab before) fails here


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_openvino_runs_the_graph_as_the_car_does(built_case, case):
    sensors, _, algorithm, kind = case
    built = built_case(case)
    inputs = car_optimizer_inputs(sensors, algorithm)
    policy = OpenVinoPolicy(built.graph_path, inputs)
    assert any(name.split(":")[0] == output_node_name(algorithm) for name in policy.output_names)
    got = policy.run_batch(graph_feed(built.layers, built.observations))
    expected = built.expected
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


def test_old_single_camera_input_name(built_case):
    """DeepRacer's first models name their camera input observation/observation; the graph can too."""
    assert CASES[0] == (("FRONT_FACING_CAMERA",), SHALLOW, "clipped_ppo", "discrete")
    built = built_case(CASES[0])
    model, space, layers = built.model, built.space, built.layers
    name = "main_level/agent/main/online/network_0/observation/observation"
    graph = FrozenGraph(graph_bytes(layers, {"FRONT_FACING_CAMERA": name}), output_node_name("clipped_ppo"))
    assert list(graph.placeholders) == [name]
    observations = random_observations(space, 8, seed=3)
    got = graph.run(graph_feed(layers, observations, {"FRONT_FACING_CAMERA": name}))
    assert np.abs(got - reference_output(model, observations)).max() <= 1e-5
