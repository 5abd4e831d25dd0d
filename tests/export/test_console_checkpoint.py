"""rl_coach's TensorFlow checkpoint written for the console's "Import model": the variables carry
rl_coach's names and layouts (deepracer-simapp's graph), the files are found the way TensorFlow
finds them (the ``checkpoint`` state file), and the restored networks give laplab's torch policy,
its value function and the frozen model.pb (within float32's rounding for the network: 1e-5 or more
for deep ones, on 100 observations)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch", reason="the checkpoint is built from laplab's torch networks")
tf = pytest.importorskip("tensorflow", reason="the checkpoint needs tensorflow-cpu: pip install 'laplab[deepracer]'")

import torch  # noqa: E402
from export_networks import CASES, DEEP, SHALLOW, case_id, float32_tolerance  # noqa: E402

from laplab.agents.networks import observation_to_tensor  # noqa: E402
from laplab.export.policy_layers import value_layers  # noqa: E402
from laplab.export.tensorflow_checkpoint import (channels_last_rows, checkpoint_files, restore_checkpoint,  # noqa: E402
                                                 rl_coach_variables)
from laplab.export.tensorflow_graph import graph_feed, output_node_name  # noqa: E402

PREFIX = "7_Step-2345.ckpt"
# camera + lidar, the three camera networks, PPO discrete / continuous and SAC
CHECKPOINT_CASES = [CASES[0], CASES[2], CASES[3], CASES[4], CASES[7], CASES[8]]
PPO_ROOT = "main_level/agent/main/online"


@pytest.fixture(scope="module")
def checkpoint(built_case, tmp_path_factory):
    """``checkpoint(case)`` -> (model, space, layers, value, written files, folder), built once per case
    (the policy itself: ``built_case``, shared with the graph tests)."""
    cache = {}

    def get(case):
        if case not in cache:
            built = built_case(case)
            model, space, layers = built.model, built.space, built.layers
            value = value_layers(model, space, list(case[0])) if case[2] == "clipped_ppo" else None
            written = checkpoint_files(PREFIX, layers, value)
            folder = tmp_path_factory.mktemp("checkpoint") / "model"
            folder.mkdir()
            for name, data in written.files.items():
                (folder / name).write_bytes(data)
            cache[case] = (model, space, layers, value, written, folder)
        return cache[case]
    return get


@pytest.mark.parametrize("case", CHECKPOINT_CASES, ids=case_id)
def test_checkpoint_restores_laplabs_policy_and_value(checkpoint, built_case, case):
    model, space, layers, value, written, folder = checkpoint(case)
    assert sorted(written.files) == sorted([f"{PREFIX}.index", f"{PREFIX}.data-00000-of-00001", f"{PREFIX}.meta",
                                            "checkpoint"])
    # TensorFlow finds the checkpoint through the state file, as tf.train.latest_checkpoint does
    state = tf.train.get_checkpoint_state(str(folder))
    assert state.model_checkpoint_path == str(folder / PREFIX)
    reader = tf.train.load_checkpoint(str(folder))
    expected = rl_coach_variables(layers, value)
    assert reader.get_variable_to_shape_map() == {name: list(array.shape) for name, array in expected.items()}
    for name, array in expected.items():
        assert np.array_equal(reader.get_tensor(name), array), name

    restored = restore_checkpoint(folder, layers, value)
    built = built_case(case)  # SAMPLES varied observations, the torch policy's and model.pb's outputs on them
    observations, torch_policy = built.observations, built.expected
    feed = graph_feed(layers, observations)
    got = restored.run(feed)
    frozen = built.frozen(output_node_name(layers.algorithm))[1]
    tolerance = float32_tolerance(layers, torch_policy)
    assert tolerance < 1e-4  # the bound stays a test: a wrong weight moves outputs by far more
    assert np.abs(got - torch_policy).max() <= tolerance
    assert np.abs(got - frozen).max() <= tolerance
    assert np.ptp(torch_policy, axis=0).max() > 0.05  # outputs that differ between observations
    if value is not None:
        with torch.no_grad():
            torch_value = model.value(observation_to_tensor(observations, "cpu")).numpy()
        assert np.abs(restored.run_value(feed) - torch_value).max() <= float32_tolerance(layers, torch_value)
        assert np.ptp(torch_value) > 0.0


def test_shallow_camera_ppo_has_rl_coachs_variable_names_and_shapes(checkpoint):
    """The names deepracer-simapp's rl_coach gives a FRONT_FACING_CAMERA shallow clipped-PPO model:
    network_0 value, network_1 policy; conv layers 0, 2, 4 (an activation layer after each);
    middleware Dense_0 over the channels-last flatten of the 11 x 16 x 64 conv output."""
    _, _, layers, _, _, folder = checkpoint(CASES[0])
    shapes = tf.train.load_checkpoint(str(folder)).get_variable_to_shape_map()
    expected = {}
    for network in ("network_0", "network_1"):
        camera = f"{PPO_ROOT}/{network}/FRONT_FACING_CAMERA"
        for index, shape in ((0, [8, 8, 1, 32]), (2, [4, 4, 32, 64]), (4, [3, 3, 64, 64])):
            expected[f"{camera}/Conv2d_{index}/kernel"] = shape
            expected[f"{camera}/Conv2d_{index}/bias"] = shape[-1:]
        expected[f"{PPO_ROOT}/{network}/middleware_fc_embedder/Dense_0/kernel"] = [11 * 16 * 64, 512]
        expected[f"{PPO_ROOT}/{network}/middleware_fc_embedder/Dense_0/bias"] = [512]
        expected[f"{PPO_ROOT}/{network}/gradients_from_head_0-0_rescalers"] = []
    expected[f"{PPO_ROOT}/network_0/v_values_head_0/output/kernel"] = [512, 1]
    expected[f"{PPO_ROOT}/network_0/v_values_head_0/output/bias"] = [1]
    expected[f"{PPO_ROOT}/network_1/ppo_head_0/policy_fc/kernel"] = [512, 5]
    expected[f"{PPO_ROOT}/network_1/ppo_head_0/policy_fc/bias"] = [5]
    assert shapes == expected
    # rl_coach flattens (H, W, C): row h * W * C + w * C + c of the kernel is laplab's row c * H * W + h * W + w
    kernel = tf.train.load_checkpoint(str(folder)).get_tensor(f"{PPO_ROOT}/network_1/middleware_fc_embedder/Dense_0/kernel")
    laplab_kernel = layers.middleware[0].kernel
    h, w, c = 3, 5, 7
    assert np.array_equal(kernel[h * 16 * 64 + w * 64 + c], laplab_kernel[c * 11 * 16 + h * 16 + w])
    assert sorted(channels_last_rows(11, 16, 64)) == list(range(11 * 16 * 64))


def test_continuous_ppo_and_sac_heads(checkpoint):
    names = set(checkpoint(CASES[3])[4].variables)
    assert {f"{PPO_ROOT}/network_1/ppo_head_0/policy_mean/kernel", f"{PPO_ROOT}/network_1/ppo_head_0/policy_log_std"} <= names
    assert not any("policy_fc" in name for name in names)
    _, _, _, value, written, folder = checkpoint(CASES[4])
    assert value is None  # laplab's twin critics do not map onto rl_coach's q / v networks
    assert all(name.startswith("main_level/agent/policy/online/network_0/") for name in written.variables)
    assert "main_level/agent/policy/online/network_0/sac_policy_head_0/policy_mean/kernel" in written.variables
    shapes = tf.train.load_checkpoint(str(folder)).get_variable_to_shape_map()
    assert shapes["main_level/agent/policy/online/network_0/sac_policy_head_0/policy_log_std/kernel"] == [512, 2]


def test_deep_network_layer_indices(checkpoint):
    """DEEP_CONVOLUTIONAL_NETWORK_DEEP: 4 convs, 2 dense in the camera embedder, middleware 256, 128."""
    assert CASES[2][1] == DEEP and CASES[0][1] == SHALLOW
    written = checkpoint(CASES[2])[4]
    camera = f"{PPO_ROOT}/network_1/FRONT_FACING_CAMERA"
    layer_names = {name.rsplit("/", 1)[0] for name in written.variables if name.startswith(camera)}
    assert layer_names == {f"{camera}/Conv2d_{i}" for i in (0, 2, 4, 6)} | {f"{camera}/Dense_{i}" for i in (8, 10)}
    middleware = {name.rsplit("/", 1)[0] for name in written.variables
                  if name.startswith(f"{PPO_ROOT}/network_1/middleware_fc_embedder/")}
    assert middleware == {f"{PPO_ROOT}/network_1/middleware_fc_embedder/Dense_{i}" for i in (0, 2)}


def test_what_the_simapp_cannot_restore_is_named():
    from laplab.export.console import simapp_limitations

    assert simapp_limitations({"sensor": ["FRONT_FACING_CAMERA"], "training_algorithm": "clipped_ppo",
                               "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_DEEP"}) == ()
    assert simapp_limitations({"sensor": ["STEREO_CAMERAS"], "training_algorithm": "clipped_ppo"}) == ()
    sac = simapp_limitations({"sensor": ["FRONT_FACING_CAMERA"], "training_algorithm": "sac"})
    assert len(sac) == 1 and sac[0].startswith("SAC:")
    stereo = {"sensor": ["STEREO_CAMERAS", "LIDAR"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK"}
    assert simapp_limitations(stereo) == ()  # laplab builds DeepRacer's stereo embedder now
    older = simapp_limitations(stereo, stereo_layout="laplab-1")  # trained before it did
    assert len(older) == 1 and "five-layer stereo" in older[0] and "laplab-1" in older[0]
