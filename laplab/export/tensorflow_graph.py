"""A TensorFlow frozen graph (``model.pb``) of a laplab policy, frozen as DeepRacer freezes its own.

The car's software finds the graph's nodes by name (see docs/car.md for the sources):

- inputs ``main_level/agent/<head>/online/network_0/<SENSOR>/<SENSOR>``, ``<head>`` = ``main`` for
  clipped PPO and ``policy`` for SAC (aws-deepracer-model-optimizer-pkg ``constants.py``); float32,
  cameras ``[B, 120, 160, C]`` channels-last raw grey levels 0-255 (C = 1, stereo 2), lidars
  ``[B, n]``. The graph itself does the scaling laplab trains with (x / 255), as rl_coach's image
  embedder does;
- output ``main_level/agent/main/online/network_1/ppo_head_0/policy`` (PPO: softmax probabilities,
  or the Gaussian mean for a continuous action space) or
  ``main_level/agent/policy/online/network_0/sac_policy_head_0/policy`` (SAC: the Gaussian mean
  **before** tanh, as deepracer-simapp's ``SACPolicyHead`` names ``identity(mean)``), the names
  deepracer-simapp freezes (``markov/boto/s3/constants.py``). The car clips a continuous output to
  [-1, 1] (aws-deepracer-navigation-pkg), so it drives a laplab SAC model as it drives DeepRacer's.

The graph is rl_coach's network (:class:`laplab.export.tensorflow_checkpoint.CheckpointGraph`, the
variables named as in DeepRacer's checkpoints) frozen with ``convert_variables_to_constants``, as
deepracer-simapp freezes it: its ``Const`` nodes carry rl_coach's variable names, so laplab's import
(``frozen_graph_weights``) reads a laplab ``model.pb`` as it reads DeepRacer's. Needs ``tensorflow-cpu``.
"""

from __future__ import annotations

import contextlib
from typing import Any, Mapping

import numpy as np

from laplab.export.policy_layers import PolicyLayers

HEAD_SCOPE = {"clipped_ppo": "main", "sac": "policy"}
OUTPUT_NODE = {"clipped_ppo": "main_level/agent/main/online/network_1/ppo_head_0/policy",
               "sac": "main_level/agent/policy/online/network_0/sac_policy_head_0/policy"}
OLD_CAMERA_INPUT = "observation"  # the single camera of DeepRacer's first models (no 'sensor' key)


def input_node_name(sensor: str, algorithm: str) -> str:
    """DeepRacer's input node for ``sensor`` (e.g. main_level/agent/main/online/network_0/LIDAR/LIDAR)."""
    return f"main_level/agent/{HEAD_SCOPE[algorithm]}/online/network_0/{sensor}/{sensor}"


def output_node_name(algorithm: str) -> str:
    return OUTPUT_NODE[algorithm]


def _import_tensorflow():
    try:
        import tensorflow as tf
    except ImportError:
        raise ImportError("the car's model.pb needs TensorFlow: pip install 'laplab[deepracer]' "
                          "(tensorflow-cpu and openvino)") from None
    return tf


def _quiet_deprecations():
    """TensorFlow's context that keeps its TF1 deprecation notices off the export's output."""
    try:
        from tensorflow.python.util.deprecation import silence
    except ImportError:  # another TensorFlow layout: the notices show, nothing else changes
        return contextlib.nullcontext()
    return silence()


def build_graph_def(layers: PolicyLayers, input_names: Mapping[str, str] | None = None) -> Any:
    """The frozen ``tf.compat.v1.GraphDef`` of ``layers``: rl_coach's policy network with laplab's
    weights, its variables turned into constants of the same names. ``input_names`` maps a sensor to
    another input node name (e.g. ``observation/observation`` style names); by default DeepRacer's."""
    from laplab.export.tensorflow_checkpoint import CheckpointGraph, rl_coach_variables

    tf = _import_tensorflow()
    network = CheckpointGraph(layers, None, input_names)
    try:
        network.load(rl_coach_variables(layers))
        output = output_node_name(layers.algorithm)
        if network.output.op.name != output:
            raise ValueError(f"output node {output!r} came out as {network.output.op.name!r}")
        with network.graph.as_default(), _quiet_deprecations():
            return tf.compat.v1.graph_util.convert_variables_to_constants(
                network.session, network.graph.as_graph_def(), [output])
    finally:
        network.session.close()


def graph_bytes(layers: PolicyLayers, input_names: Mapping[str, str] | None = None) -> bytes:
    """``model.pb``: the serialised frozen graph."""
    return build_graph_def(layers, input_names).SerializeToString()


class FrozenGraph:
    """A ``model.pb`` loaded back into TensorFlow: ``run({input_node: array})`` -> the output node's value."""

    def __init__(self, data: bytes, output: str):
        tf = _import_tensorflow()
        graph_def = tf.compat.v1.GraphDef()
        graph_def.ParseFromString(data)
        self.graph = tf.Graph()
        with self.graph.as_default():
            tf.compat.v1.import_graph_def(graph_def, name="")
        self.session = tf.compat.v1.Session(graph=self.graph)
        self.output = self.graph.get_tensor_by_name(f"{output}:0")

    @property
    def placeholders(self) -> dict[str, tuple]:
        """Input node name -> shape (None for the batch axis)."""
        return {op.name: tuple(op.outputs[0].shape.as_list()) for op in self.graph.get_operations()
                if op.type == "Placeholder"}

    def run(self, feed: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.session.run(self.output, {self.graph.get_tensor_by_name(f"{k}:0"): v for k, v in feed.items()})


def graph_feed(layers: PolicyLayers, observations: Any, names: Mapping[str, str] | None = None) -> dict[str, np.ndarray]:
    """laplab observations (numpy, channels-first cameras; a dict by sensor for several sensors) ->
    the graph's feed, keyed by input node (DeepRacer's, or ``names[sensor]``): channels-last float32
    grey levels 0-255 for cameras (a float [0, 1] camera space is multiplied by 255), flattened
    float32 vectors for the others."""
    feed = {}
    for branch in layers.branches:
        name = (names or {}).get(branch.sensor) or input_node_name(branch.sensor, layers.algorithm)
        value = np.asarray(observations[branch.sensor] if isinstance(observations, Mapping) else observations)
        if branch.is_camera:
            # uint8 frames are grey levels already; a float camera space the network scales by 1/255
            # holds [0, 1] values, which the graph (and the car) take as 0-255
            to_levels = value.dtype != np.uint8 and branch.scale != 1.0
            value = np.transpose(value, (0, 2, 3, 1)).astype(np.float32) * (255.0 if to_levels else 1.0)
        feed[name] = np.ascontiguousarray(value.reshape(value.shape[0], *branch.shape), dtype=np.float32)
    return feed
