"""rl_coach's TensorFlow checkpoint of a laplab model: the ``<N>_Step-<steps>.ckpt.index /
.data-00000-of-00001 / .meta`` files the DeepRacer console's "Import model", deepracer-for-cloud's
``dr-upload-model`` and the simapp's evaluation / pretrained-model loading restore (docs/car.md).

The variables carry the names rl_coach gives them in DeepRacer's graph (deepracer-simapp's bundled
rl_coach: ``general_network.py``, ``embedders/embedder.py``, ``middlewares/fc_middleware.py``,
``heads/ppo_head.py``, ``heads/v_head.py``; ``markov/architecture/embedder_factory.py``):

- clipped PPO, ``main_level/agent/main/online/``: ``network_0`` the value network and ``network_1``
  the policy (``use_separate_networks_per_head``), each with its own input embedders;
- a layer's index counts the activation layer rl_coach inserts after every layer: a camera embedder
  is ``<SENSOR>/Conv2d_0, Conv2d_2, Conv2d_4[, Conv2d_6][, Dense_2n, Dense_2n+2]``, a lidar
  ``<SENSOR>/Dense_0, Dense_2``, the middleware ``middleware_fc_embedder/Dense_0[, Dense_2]``;
- heads: ``v_values_head_0/output``, ``ppo_head_0/policy_fc`` (discrete) or ``ppo_head_0/policy_mean``
  + the variable ``ppo_head_0/policy_log_std`` (1, A) (continuous); each network also holds
  ``gradients_from_head_0-0_rescalers`` (1.0);
- kernels in TensorFlow's layouts; a camera's features are flattened channels-last (H, W, C) as
  rl_coach does, so the first dense kernel after a camera has its rows reordered from laplab's
  channels-first flatten.

SAC (``main_level/agent/policy/online/network_0``): the embedders and middleware as above, then the
head ``sac_policy_head_0``. deepracer-simapp's ``SACPolicyHead`` (``policy_head_layers`` (256,))
holds a relu dense 256 named by TensorFlow's layer counter, ``dense``, then ``policy_mean`` and the
log-std layer ``dense_1`` (unnamed too), both reading the 256 features; laplab's own SAC head (no
hidden layer) has ``policy_mean`` and ``policy_log_std`` straight from the features. laplab's twin
critics do not map onto rl_coach's ``q`` network (its own embedders, no middleware, actions in the
model's units) nor its ``v`` network: they are not written. The simapp's saver keeps trainable
variables only, so no optimizer slots are written either.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from laplab.export.policy_layers import PolicyLayers, SensorBranch
from laplab.export.tensorflow_graph import _import_tensorflow, input_node_name

NETWORK_SCOPE = {"clipped_ppo": "main_level/agent/main/online", "sac": "main_level/agent/policy/online"}
RESCALER = "gradients_from_head_0-0_rescalers"
CHECKPOINT_STATE_FILE = "checkpoint"  # TensorFlow's CheckpointState, text format


def checkpoint_state_text(prefix: str) -> str:
    """``model/checkpoint`` naming ``prefix`` (relative to the folder), as tf.train.Saver writes it."""
    return f'model_checkpoint_path: "{prefix}"\nall_model_checkpoint_paths: "{prefix}"\n'


def conv_output_shape(branch: SensorBranch) -> tuple[int, int, int]:
    """(H, W, C) of a camera branch after its 'valid' convolutions."""
    height, width, channels = branch.shape
    for conv in branch.convs:
        size, _, _, channels = conv.kernel.shape
        height, width = (height - size) // conv.stride + 1, (width - size) // conv.stride + 1
    return height, width, channels


def channels_last_rows(height: int, width: int, channels: int) -> np.ndarray:
    """Row order taking a kernel over laplab's (C, H, W) flatten to rl_coach's (H, W, C) flatten."""
    return np.arange(channels * height * width).reshape(channels, height, width).transpose(1, 2, 0).ravel()


def _features(branch: SensorBranch) -> tuple[int, np.ndarray | None]:
    """(features out of the branch, rows reordering for the dense layer that first reads them)."""
    if branch.dense:
        return branch.dense[-1].kernel.shape[1], None
    if branch.is_camera:
        shape = conv_output_shape(branch)
        return int(np.prod(shape)), channels_last_rows(*shape)
    return branch.shape[0], None


def sac_head_names(hidden_layers: int) -> tuple[list[str], str, str]:
    """(hidden layers, mean layer, log-std layer) of rl_coach's SAC policy head, relative to its
    scope: deepracer-simapp's ``dense``, ``dense_1``... then ``policy_mean`` and the next ``dense_<k>``;
    without hidden layers laplab's ``policy_mean`` and ``policy_log_std``."""
    names = ["dense" if index == 0 else f"dense_{index}" for index in range(hidden_layers)]
    return names, "policy_mean", f"dense_{hidden_layers}" if hidden_layers else "policy_log_std"


def network_variables(layers: PolicyLayers, scope: str, head: str) -> dict[str, np.ndarray]:
    """``{variable name: array}`` of one rl_coach network (embedders, middleware, ``head`` scope)."""
    variables: dict[str, np.ndarray] = {}
    merged_rows, offset = [], 0
    for branch in layers.branches:
        base = f"{scope}/{branch.sensor}"
        for index, conv in enumerate(branch.convs):
            variables[f"{base}/Conv2d_{2 * index}/kernel"] = conv.kernel
            variables[f"{base}/Conv2d_{2 * index}/bias"] = conv.bias
        for index, dense in enumerate(branch.dense):
            kernel = dense.kernel
            if index == 0 and branch.is_camera:
                kernel = kernel[channels_last_rows(*conv_output_shape(branch))]
            name = f"{base}/Dense_{2 * (len(branch.convs) + index)}"
            variables[f"{name}/kernel"], variables[f"{name}/bias"] = kernel, dense.bias
        count, rows = _features(branch)
        merged_rows.append(offset + (np.arange(count) if rows is None else rows))
        offset += count
    rows = np.concatenate(merged_rows)
    for index, dense in enumerate(layers.middleware):
        kernel = dense.kernel[rows] if index == 0 else dense.kernel
        name = f"{scope}/middleware_fc_embedder/Dense_{2 * index}"
        variables[f"{name}/kernel"], variables[f"{name}/bias"] = kernel, dense.bias
    first = layers.head_hidden[0] if layers.head_hidden else layers.head  # the layer reading the features
    head_rows = rows if not layers.middleware else np.arange(first.kernel.shape[0])
    variables[f"{scope}/{RESCALER}"] = np.array(1.0, np.float32)
    if layers.algorithm == "sac" and layers.output == "tanh":
        hidden_names, mean_name, log_std_name = sac_head_names(len(layers.head_hidden))
        for index, (name, dense) in enumerate(zip(hidden_names, layers.head_hidden)):
            variables[f"{scope}/{head}/{name}/kernel"] = dense.kernel[head_rows] if index == 0 else dense.kernel
            variables[f"{scope}/{head}/{name}/bias"] = dense.bias
        if layers.head_hidden:
            head_rows = np.arange(layers.head.kernel.shape[0])
        variables[f"{scope}/{head}/{mean_name}/kernel"] = layers.head.kernel[head_rows]
        variables[f"{scope}/{head}/{mean_name}/bias"] = layers.head.bias
        if layers.log_std_head is not None:
            variables[f"{scope}/{head}/{log_std_name}/kernel"] = layers.log_std_head.kernel[head_rows]
            variables[f"{scope}/{head}/{log_std_name}/bias"] = layers.log_std_head.bias
    elif head.startswith("v_values_head"):
        variables[f"{scope}/{head}/output/kernel"] = layers.head.kernel[head_rows]
        variables[f"{scope}/{head}/output/bias"] = layers.head.bias
    else:
        layer = "policy_fc" if layers.output == "softmax" else "policy_mean"
        variables[f"{scope}/{head}/{layer}/kernel"] = layers.head.kernel[head_rows]
        variables[f"{scope}/{head}/{layer}/bias"] = layers.head.bias
        if layers.log_std is not None:
            variables[f"{scope}/{head}/policy_log_std"] = layers.log_std.reshape(1, -1)
    return {name: np.array(value, dtype=np.float32, order="C") for name, value in variables.items()}


def rl_coach_variables(policy: PolicyLayers, value: PolicyLayers | None = None) -> dict[str, np.ndarray]:
    """Every variable the checkpoint holds: PPO ``network_1`` (policy) and ``network_0`` (``value``),
    or the SAC policy network."""
    root = NETWORK_SCOPE[policy.algorithm]
    if policy.algorithm == "sac":
        return network_variables(policy, f"{root}/network_0", "sac_policy_head_0")
    variables = network_variables(policy, f"{root}/network_1", "ppo_head_0")
    if value is not None:
        variables.update(network_variables(value, f"{root}/network_0", "v_values_head_0"))
    return variables


class CheckpointGraph:
    """rl_coach's networks as a TF1 graph of variables (shapes from ``policy`` / ``value``), with
    DeepRacer's input placeholders (``input_names`` maps a sensor to another node name, e.g. the old
    ``observation/observation``); ``output`` = the node DeepRacer freezes (``model.pb``'s output:
    PPO's softmax or Gaussian mean, SAC's mean before tanh, as rl_coach's heads name ``policy``) and,
    for PPO with a value network, V (B,). ``restore(prefix)`` reads a checkpoint by name."""

    def __init__(self, policy: PolicyLayers, value: PolicyLayers | None = None,
                 input_names: Mapping[str, str] | None = None):
        tf = _import_tensorflow()
        self.policy, self.value = policy, value
        self.input_nodes = {branch.sensor: (input_names or {}).get(branch.sensor)
                            or input_node_name(branch.sensor, policy.algorithm) for branch in policy.branches}
        shapes = rl_coach_variables(policy, value)
        self.graph = tf.Graph()
        with self.graph.as_default():
            self.variables = {name: tf.compat.v1.get_variable(name, array.shape, tf.float32, use_resource=False,
                                                              initializer=tf.compat.v1.zeros_initializer())
                              for name, array in shapes.items()}
            self.inputs = {}
            for branch in policy.branches:
                name = self.input_nodes[branch.sensor]
                self.inputs[branch.sensor] = tf.compat.v1.placeholder(tf.float32, [None, *branch.shape], name=name)
                if self.inputs[branch.sensor].op.name != name:
                    raise ValueError(f"input node {name!r} came out as {self.inputs[branch.sensor].op.name!r}")
            root = NETWORK_SCOPE[policy.algorithm]
            if policy.algorithm == "sac":
                features = self._trunk(tf, policy, f"{root}/network_0")
                for name in sac_head_names(len(policy.head_hidden))[0]:
                    features = self._dense(tf, features, f"{root}/network_0/sac_policy_head_0/{name}", "relu")
                mean = self._dense(tf, features, f"{root}/network_0/sac_policy_head_0/policy_mean", "none")
                # deepracer-simapp's SACPolicyHead: policy = identity(mean), the tanh comes after it
                self.output = tf.identity(mean, name=f"{root}/network_0/sac_policy_head_0/policy")
            else:
                features = self._trunk(tf, policy, f"{root}/network_1")
                layer = "policy_fc" if policy.output == "softmax" else "policy_mean"
                logits = self._dense(tf, features, f"{root}/network_1/ppo_head_0/{layer}", "none")
                name = f"{root}/network_1/ppo_head_0/policy"
                self.output = tf.nn.softmax(logits, name=name) if policy.output == "softmax" else \
                    tf.identity(logits, name=name)
            self.value_output = None
            if value is not None:
                features = self._trunk(tf, value, f"{root}/network_0")
                self.value_output = tf.squeeze(self._dense(tf, features, f"{root}/network_0/v_values_head_0/output",
                                                           "none"), axis=1)
            self.placeholders = {name: tf.compat.v1.placeholder(tf.float32, array.shape)
                                 for name, array in shapes.items()}
            self.assign = tf.group(*[tf.compat.v1.assign(self.variables[name], self.placeholders[name])
                                     for name in shapes])
            self.saver = tf.compat.v1.train.Saver(self.variables, max_to_keep=None, save_relative_paths=True)
            self.initialize = tf.compat.v1.global_variables_initializer()
        self.session = tf.compat.v1.Session(graph=self.graph)
        self.session.run(self.initialize)

    def _dense(self, tf, x, name: str, activation: str):
        x = tf.nn.bias_add(tf.matmul(x, self.variables[f"{name}/kernel"]), self.variables[f"{name}/bias"])
        return tf.nn.relu(x) if activation == "relu" else tf.nn.tanh(x) if activation == "tanh" else x

    def _trunk(self, tf, layers: PolicyLayers, scope: str):
        features = []
        for branch in layers.branches:
            base = f"{scope}/{branch.sensor}"
            x = self.inputs[branch.sensor]
            if branch.is_camera:
                x = x * np.float32(branch.scale)
                for index, conv in enumerate(branch.convs):
                    name = f"{base}/Conv2d_{2 * index}"
                    x = tf.nn.conv2d(x, self.variables[f"{name}/kernel"], [1, conv.stride, conv.stride, 1], "VALID")
                    x = tf.nn.relu(tf.nn.bias_add(x, self.variables[f"{name}/bias"]))
                x = tf.reshape(x, [-1, int(np.prod(conv_output_shape(branch)))])  # flattened (H, W, C)
            for index, dense in enumerate(branch.dense):
                x = self._dense(tf, x, f"{base}/Dense_{2 * (len(branch.convs) + index)}", dense.activation)
            features.append(x)
        x = features[0] if len(features) == 1 else tf.concat(features, axis=-1, name=f"{scope}/merger")
        for index, dense in enumerate(layers.middleware):
            x = self._dense(tf, x, f"{scope}/middleware_fc_embedder/Dense_{2 * index}", dense.activation)
        return x * self.variables[f"{scope}/{RESCALER}"]  # rl_coach's head input at rescaler 1

    def load(self, variables: Mapping[str, np.ndarray]) -> None:
        self.session.run(self.assign, {self.placeholders[name]: value for name, value in variables.items()})

    def save(self, folder: str | Path, prefix: str) -> list[str]:
        """Write ``folder/prefix.index``, ``.data-00000-of-00001`` and ``.meta`` (no state file);
        returns the file names."""
        with self.graph.as_default():  # outside it, TensorFlow 2 takes the save for an eager one
            self.saver.save(self.session, str(Path(folder) / prefix), write_meta_graph=True, write_state=False)
        return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith(prefix))

    def restore(self, path: str) -> None:
        with self.graph.as_default():
            self.saver.restore(self.session, path)

    def run(self, feed: Mapping[str, np.ndarray]) -> np.ndarray:
        """The policy's output for ``feed`` keyed by sensor (as ``graph_feed`` gives it, by input node)."""
        return self.session.run(self.output, self._feed(feed))

    def run_value(self, feed: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.session.run(self.value_output, self._feed(feed))

    def _feed(self, feed: Mapping[str, np.ndarray]) -> dict:
        by_node = {self.input_nodes[sensor]: tensor for sensor, tensor in self.inputs.items()}
        return {by_node[name]: value for name, value in feed.items()}


@dataclass(frozen=True)
class CheckpointFiles:
    """A written checkpoint: ``files`` {file name: bytes} (the three ``prefix.*`` files and the
    ``checkpoint`` state file naming them) and the names of the variables it holds."""

    prefix: str
    files: dict[str, bytes]
    variables: tuple[str, ...]


def checkpoint_files(prefix: str, policy: PolicyLayers, value: PolicyLayers | None = None) -> CheckpointFiles:
    """The checkpoint ``prefix`` (e.g. ``3_Step-1200.ckpt``) of ``policy`` (+ PPO's ``value``) in
    rl_coach's names, written by ``tf.compat.v1.train.Saver`` and read back as bytes."""
    graph = CheckpointGraph(policy, value)
    variables = rl_coach_variables(policy, value)
    graph.load(variables)
    with tempfile.TemporaryDirectory(prefix="laplab-ckpt-") as folder:
        names = graph.save(folder, prefix)
        files = {name: (Path(folder) / name).read_bytes() for name in names}
    graph.session.close()
    files[CHECKPOINT_STATE_FILE] = checkpoint_state_text(prefix).encode()
    return CheckpointFiles(prefix, files, tuple(sorted(variables)))


def random_feed(layers: PolicyLayers, count: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``count`` random inputs keyed by input node, as the car feeds them: cameras grey levels
    0..255 (a brightness ramp plus noise, so frames differ), vectors uniform in [0, 1]."""
    rng = np.random.default_rng(seed)
    feed = {}
    for branch in layers.branches:
        if branch.is_camera:
            height, width, channels = branch.shape
            ramp = rng.uniform(0.0, 255.0, (count, 1, 1, channels)) * np.linspace(0.0, 1.0, width)[None, None, :, None]
            value = np.clip(ramp + rng.normal(0.0, 30.0, (count, height, width, channels)), 0, 255).round()
        else:
            value = rng.uniform(0.0, 1.0, (count, *branch.shape))
        feed[input_node_name(branch.sensor, layers.algorithm)] = value.astype(np.float32)
    return feed


def restore_checkpoint(folder: str | Path, policy: PolicyLayers, value: PolicyLayers | None = None) -> Any:
    """A ``CheckpointGraph`` restored from the checkpoint ``folder/checkpoint`` names (as
    ``tf.train.latest_checkpoint`` finds it)."""
    tf = _import_tensorflow()
    path = tf.train.latest_checkpoint(str(folder))
    if path is None:
        raise FileNotFoundError(f"{folder}: no TensorFlow checkpoint state file ('checkpoint') naming a checkpoint")
    graph = CheckpointGraph(policy, value)
    graph.restore(path)
    return graph
