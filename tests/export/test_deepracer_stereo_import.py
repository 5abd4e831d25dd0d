"""A DeepRacer STEREO_CAMERAS model with a deeper network imports weight for weight: the checkpoint is
built here with TensorFlow as rl_coach builds deepracer-simapp's clipped-PPO networks for it, with the
stereo embedder's layers written out from the simapp (``get_stereo_camera_embedders``: five 3x3
convolutions [32,3,1] [64,3,2] [64,3,1] [128,3,2] [128,3,1], no dense layer), not read from laplab;
laplab's policy probabilities and values then equal TensorFlow's (float64) on the same frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")
tf = pytest.importorskip("tensorflow", reason="the checkpoint is written with tensorflow-cpu")

import torch  # noqa: E402
from export_networks import float32_tolerance, varied_observations  # noqa: E402

from laplab.agents.networks import observation_to_tensor  # noqa: E402
from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.export.deepracer_import import import_deepracer_model  # noqa: E402
from laplab.export.policy_layers import policy_layers, reference_output  # noqa: E402
from laplab.train.policy import load_model_policy  # noqa: E402

ROOT = "main_level/agent/main/online"
SIMAPP_STEREO_CONVS = ((32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1))
MIDDLEWARE = (512,)  # DEEP_CONVOLUTIONAL_NETWORK's DEFAULT_MIDDLEWARE
ACTIONS = 5
METADATA = {**ModelMetadata().to_dict(), "version": "5", "sensor": ["STEREO_CAMERAS"],
            "neural_network": "DEEP_CONVOLUTIONAL_NETWORK",
            "action_space": [{"steering_angle": a, "speed": 1.0} for a in (-30, -15, 0, 15, 30)]}


def _variable(name: str, shape, stddev: float):
    value = tf.compat.v1.get_variable(name, shape, initializer=tf.compat.v1.random_normal_initializer(0, stddev))
    return tf.cast(value, tf.float64)


def _dense(x, units: int, name: str, gain: float = 1.0):
    with tf.compat.v1.variable_scope(name):
        kernel = _variable("kernel", [int(x.shape[-1]), units], gain / np.sqrt(int(x.shape[-1])))
        return tf.nn.bias_add(tf.matmul(x, kernel), _variable("bias", [units], 0.1))


def _network(frames, head: str):
    """One of rl_coach's networks (PPO: ``network_0`` value, ``network_1`` policy): the stereo embedder
    (Conv2d_0 .. Conv2d_8, images / 255, flattened (H, W, C)), the middleware, then ``head``'s layer."""
    x = frames / 255.0
    with tf.compat.v1.variable_scope("STEREO_CAMERAS"):
        channels = 2
        for index, (filters, kernel, stride) in enumerate(SIMAPP_STEREO_CONVS):
            with tf.compat.v1.variable_scope(f"Conv2d_{2 * index}"):
                weights = _variable("kernel", [kernel, kernel, channels, filters], np.sqrt(2.0 / (kernel * kernel * channels)))
                x = tf.nn.relu(tf.nn.bias_add(tf.nn.conv2d(x, weights, [1, stride, stride, 1], "VALID"),
                                              _variable("bias", [filters], 0.05)))
            channels = filters
    x = tf.reshape(x, [-1, int(np.prod(x.shape[1:]))])
    with tf.compat.v1.variable_scope("middleware_fc_embedder"):
        for index, width in enumerate(MIDDLEWARE):
            x = tf.nn.relu(_dense(x, width, f"Dense_{2 * index}", gain=np.sqrt(2.0)))
    tf.compat.v1.get_variable("gradients_from_head_0-0_rescalers", [], initializer=tf.ones_initializer())
    if head == "ppo_head_0":
        with tf.compat.v1.variable_scope(head):
            return tf.nn.softmax(_dense(x, ACTIONS, "policy_fc", gain=8.0))
    with tf.compat.v1.variable_scope(head):
        return _dense(x, 1, "output")[:, 0]


def simapp_stereo_checkpoint(folder: Path, prefix: str = "3_Step-900.ckpt", seed: int = 5):
    """rl_coach's graph saved to ``folder/prefix``; returns (the names saved, frames (B, H, W, 2) ->
    (policy probabilities (B, A), values (B,)))."""
    graph = tf.Graph()
    with graph.as_default():
        tf.compat.v1.set_random_seed(seed)
        frames = tf.compat.v1.placeholder(tf.float64, [None, 120, 160, 2], name="frames")
        with tf.compat.v1.variable_scope(f"{ROOT}/network_0"):
            values = _network(frames, "v_values_head_0")
        with tf.compat.v1.variable_scope(f"{ROOT}/network_1"):
            probabilities = _network(frames, "ppo_head_0")
        session = tf.compat.v1.Session(graph=graph)
        session.run(tf.compat.v1.global_variables_initializer())
        tf.compat.v1.train.Saver().save(session, str(folder / prefix), write_meta_graph=False, write_state=False)
    names = [name for name, _ in tf.train.list_variables(str(folder / prefix))]
    return names, lambda batch: session.run((probabilities, values), {frames: batch})


@pytest.fixture(scope="module")
def simapp(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stereo-simapp")
    (folder / "model").mkdir()
    (folder / "ip").mkdir()
    names, run = simapp_stereo_checkpoint(folder / "model")
    (folder / "model" / ".coach_checkpoint").write_text("3_Step-900.ckpt")
    (folder / "model_metadata.json").write_text(json.dumps(METADATA))
    (folder / "ip" / "hyperparameters.json").write_text(json.dumps({"batch_size": 32, "num_epochs": 3}))
    (folder / "reward_function.py").write_text("def reward_function(params):\n    return 1.0\n")
    return folder, names, run


def test_the_simapps_stereo_deep_checkpoint_imports_weight_for_weight(simapp, tmp_path, monkeypatch):
    folder, names, run = simapp
    assert f"{ROOT}/network_1/STEREO_CAMERAS/Conv2d_8/kernel" in names  # the fifth convolution
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    imported = import_deepracer_model(folder, "stereo-deep")
    assert imported.trainable and imported.checkpoint == "3_Step-900.ckpt"
    policy = load_model_policy("stereo-deep")
    assert policy.config.stereo_layout == "deepracer"
    frames = varied_observations(policy.observation_space, 16, seed=3)
    expected_probabilities, expected_values = run(np.moveaxis(frames, 1, -1).astype(np.float64))
    assert np.ptp(expected_probabilities, axis=0).max() > 1e-2  # differs between frames: the check means something
    probabilities = reference_output(policy.network, frames)
    layers = policy_layers(policy.network, policy.observation_space, list(policy.metadata.sensors))
    assert np.abs(probabilities - expected_probabilities).max() <= float32_tolerance(layers, expected_probabilities)
    with torch.no_grad():
        values = policy.network.value(observation_to_tensor(frames, "cpu")).numpy()
    assert np.abs(values - expected_values).max() <= float32_tolerance(layers, expected_values)
