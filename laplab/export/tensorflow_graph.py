"""A TensorFlow frozen graph (``model.pb``) of a laplab policy, with the node names DeepRacer's car uses.

The car's software finds the graph's nodes by name (see docs/car.md for the sources):

- inputs ``main_level/agent/<head>/online/network_0/<SENSOR>/<SENSOR>``, ``<head>`` = ``main`` for
  clipped PPO and ``policy`` for SAC (aws-deepracer-model-optimizer-pkg ``constants.py``); float32,
  cameras ``[B, 120, 160, C]`` channels-last raw grey levels 0-255 (C = 1, stereo 2), lidars
  ``[B, n]``. The graph itself does the scaling laplab trains with (x / 255), as rl_coach's image
  embedder does;
- output ``main_level/agent/main/online/network_1/ppo_head_0/policy`` (PPO: softmax probabilities,
  or the Gaussian mean for a continuous action space) or
  ``main_level/agent/policy/online/network_0/sac_policy_head_0/policy`` (SAC: tanh of the mean),
  the names deepracer-simapp freezes (``markov/boto/s3/constants.py``).

Built with ``tf.compat.v1`` ops on constants only (nothing to freeze); needs ``tensorflow-cpu``.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from laplab.export.policy_layers import Dense, PolicyLayers, SensorBranch

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


def _dense(tf, x, layer: Dense, name: str):
    x = tf.nn.bias_add(tf.matmul(x, tf.constant(layer.kernel, name=f"{name}/kernel")),
                       tf.constant(layer.bias, name=f"{name}/bias"), name=f"{name}/BiasAdd")
    if layer.activation == "relu":
        return tf.nn.relu(x, name=f"{name}/Relu")
    if layer.activation == "tanh":
        return tf.nn.tanh(x, name=f"{name}/Tanh")
    return x


def _branch(tf, placeholder, branch: SensorBranch, scope: str):
    x = placeholder
    if branch.is_camera:
        x = tf.multiply(x, tf.constant(np.float32(branch.scale)), name=f"{scope}/rescale")
        for index, conv in enumerate(branch.convs):
            x = tf.nn.conv2d(x, tf.constant(conv.kernel, name=f"{scope}/Conv2d_{index}/kernel"),
                             strides=[1, conv.stride, conv.stride, 1], padding="VALID", name=f"{scope}/Conv2d_{index}")
            x = tf.nn.relu(tf.nn.bias_add(x, tf.constant(conv.bias, name=f"{scope}/Conv2d_{index}/bias")),
                           name=f"{scope}/Conv2d_{index}/Relu")
        # laplab flattens channels-first (C, H, W): transpose back before flattening
        x = tf.transpose(x, [0, 3, 1, 2], name=f"{scope}/to_channels_first")
        features = int(np.prod(x.shape[1:]))
        x = tf.reshape(x, [-1, features], name=f"{scope}/Flatten")
    for index, layer in enumerate(branch.dense):
        x = _dense(tf, x, layer, f"{scope}/Dense_{index}")
    return x


def build_graph_def(layers: PolicyLayers, input_names: Mapping[str, str] | None = None) -> Any:
    """The frozen ``tf.compat.v1.GraphDef`` of ``layers``. ``input_names`` maps a sensor to another
    input node name (e.g. ``observation/observation`` style names); by default DeepRacer's."""
    tf = _import_tensorflow()
    algorithm = layers.algorithm
    head_scope = HEAD_SCOPE[algorithm]
    network = "network_1" if algorithm == "clipped_ppo" else "network_0"
    body = f"main_level/agent/{head_scope}/online/{network}"
    graph = tf.Graph()
    with graph.as_default():
        features = []
        for branch in layers.branches:
            name = (input_names or {}).get(branch.sensor) or input_node_name(branch.sensor, algorithm)
            scope, leaf = name.rsplit("/", 1) if "/" in name else ("", name)
            with tf.name_scope(f"{scope}/" if scope else None):
                placeholder = tf.compat.v1.placeholder(tf.float32, [None, *branch.shape], name=leaf)
            if placeholder.op.name != name:
                raise ValueError(f"input node {name!r} came out as {placeholder.op.name!r}")
            features.append(_branch(tf, placeholder, branch, f"{body}/{branch.sensor}"))
        x = features[0] if len(features) == 1 else tf.concat(features, axis=1, name=f"{body}/concat")
        for index, layer in enumerate(layers.middleware):
            x = _dense(tf, x, layer, f"{body}/middleware_fc_embedder/Dense_{index}")
        head_name = "ppo_head_0" if algorithm == "clipped_ppo" else "sac_policy_head_0"
        for index, layer in enumerate(layers.head_hidden):  # SAC: deepracer-simapp's dense 256
            x = _dense(tf, x, layer, f"{body}/{head_name}/dense" + (f"_{index}" if index else ""))
        x = _dense(tf, x, layers.head, f"{body}/{head_name}/policy_fc")
        output = output_node_name(algorithm)
        if layers.output == "softmax":
            result = tf.nn.softmax(x, name=output)
        elif layers.output == "tanh":
            result = tf.nn.tanh(x, name=output)
        else:
            result = tf.identity(x, name=output)
        if result.op.name != output:
            raise ValueError(f"output node {output!r} came out as {result.op.name!r}")
    return graph.as_graph_def()


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
