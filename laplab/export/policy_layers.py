"""A laplab policy network as a plain numpy description of its layers (what the TF graph is built from).

This is the thin adapter between laplab's torch networks (``laplab.agents.networks``: ``ActorCritic``
for PPO, ``SquashedGaussianActor`` for SAC) and the exporters: they only see ``PolicyLayers``, so a
change of the learner classes touches this module alone. Weights are copied out as float32 numpy
arrays in TensorFlow's layouts (conv kernels ``(kh, kw, in, out)``, dense kernels ``(in, out)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

CAR_CAMERAS = ("FRONT_FACING_CAMERA", "LEFT_CAMERA", "STEREO_CAMERAS")


@dataclass(frozen=True)
class Conv:
    """A 'valid' 2-D convolution followed by ``activation``: kernel (kh, kw, in, out), bias (out,)."""

    kernel: np.ndarray
    bias: np.ndarray
    stride: int
    activation: str = "relu"


@dataclass(frozen=True)
class Dense:
    """``activation(x @ kernel + bias)``: kernel (in, out), bias (out,); activation relu, tanh or none."""

    kernel: np.ndarray
    bias: np.ndarray
    activation: str


@dataclass(frozen=True)
class SensorBranch:
    """One sensor's input embedder. ``shape``: one sample as the graph takes it (camera ``(H, W, C)``
    channels-last grey levels 0-255; vector ``(n,)``). Cameras are multiplied by ``scale`` (1/255
    for laplab's uint8 frames), run through ``convs``, transposed back to laplab's channels-first
    order and flattened, then ``dense``."""

    sensor: str
    shape: tuple[int, ...]
    is_camera: bool
    scale: float
    convs: tuple[Conv, ...]
    dense: tuple[Dense, ...]


@dataclass(frozen=True)
class PolicyLayers:
    """The greedy policy: branches (concatenated in this order), middleware, head, output.

    ``output``: ``softmax`` (PPO discrete: action probabilities), ``identity`` (PPO continuous: the
    Gaussian mean, unclipped; a value network: V) or ``tanh`` (SAC: laplab's action is tanh of the
    mean; the car's graph outputs the mean itself, as DeepRacer's does). ``algorithm``:
    clipped_ppo or sac. The exploration noise, which the greedy policy does not use but a checkpoint
    keeps: ``log_std`` (PPO continuous: the state-independent log-std, (A,)) or ``log_std_head``
    (SAC: the layer giving the log-std from the features). ``head_hidden``: SAC's relu layers between
    the features and both head layers (deepracer-simapp's dense 256; empty for laplab's own SAC).
    """

    algorithm: str
    branches: tuple[SensorBranch, ...]
    middleware: tuple[Dense, ...]
    head: Dense
    output: str
    log_std: np.ndarray | None = None
    log_std_head: Dense | None = None
    head_hidden: tuple[Dense, ...] = ()

    @property
    def action_size(self) -> int:
        return int(self.head.kernel.shape[1])


def _array(tensor: Any) -> np.ndarray:
    return np.ascontiguousarray(tensor.detach().cpu().float().numpy(), dtype=np.float32)


def _dense_layers(sequential: Any) -> tuple[Dense, ...]:
    """``nn.Sequential`` of (Linear, activation) pairs -> Dense layers."""
    from torch import nn

    layers: list[Dense] = []
    for module in sequential:
        if isinstance(module, nn.Linear):
            layers.append(Dense(_array(module.weight).T.copy(), _array(module.bias), "none"))
        elif isinstance(module, (nn.ReLU, nn.Tanh)):
            last = layers[-1]
            layers[-1] = Dense(last.kernel, last.bias, "relu" if isinstance(module, nn.ReLU) else "tanh")
        else:
            raise TypeError(f"cannot export layer {type(module).__name__} of a dense stack")
    return tuple(layers)


def _branch(sensor: str, embedder: Any, space: Any) -> SensorBranch:
    from torch import nn

    from laplab.agents.networks import CameraEmbedder

    shape = tuple(int(s) for s in space.shape)
    if isinstance(embedder, CameraEmbedder):
        convs = []
        for module in embedder.convolutions:
            if isinstance(module, nn.Conv2d):
                convs.append(Conv(_array(module.weight).transpose(2, 3, 1, 0).copy(), _array(module.bias),
                                  int(module.stride[0])))
        # a float camera space in [0, 1]: the graph still takes 0-255 grey levels (as the car feeds)
        unit_range = space.dtype != np.uint8 and float(np.max(space.high)) <= 1.0
        scale = float(np.float32(embedder.scale) * (np.float32(1.0 / 255.0) if unit_range else np.float32(1.0)))
        return SensorBranch(sensor, (shape[1], shape[2], shape[0]), True, scale, tuple(convs),
                            _dense_layers(embedder.dense))
    return SensorBranch(sensor, (int(np.prod(shape)),), False, 1.0, (), _dense_layers(embedder.dense))


def policy_layers(network: Any, observation_space: Any, sensors: Sequence[str]) -> PolicyLayers:
    """The layers of a laplab PPO ``ActorCritic`` or SAC ``SquashedGaussianActor`` trained on
    ``observation_space`` (a Box for one sensor, a Dict keyed by sensor names); ``sensors`` is
    model_metadata.json's sensor list (it names the single sensor of a Box space)."""
    from laplab.agents.networks import ActorCritic
    from laplab.agents.sac_networks import SquashedGaussianActor

    log_std, log_std_head, head_hidden = None, None, ()
    if isinstance(network, ActorCritic):
        trunk, head_module, algorithm = network.policy_trunk, network.policy_head, "clipped_ppo"
        output = "softmax" if network.action_spec.discrete else "identity"
        log_std = None if network.log_std is None else _array(network.log_std)
    elif isinstance(network, SquashedGaussianActor):
        trunk, head_module, algorithm, output = network.trunk, network.mean, "sac", "tanh"
        log_std_head = Dense(_array(network.log_std.weight).T.copy(), _array(network.log_std.bias), "none")
        head_hidden = _dense_layers(network.head)
    else:
        raise TypeError(f"expected a PPO ActorCritic or a SAC SquashedGaussianActor, got {type(network).__name__}")
    branches, middleware = _trunk_layers(trunk, observation_space, sensors)
    head = Dense(_array(head_module.weight).T.copy(), _array(head_module.bias), "none")
    return PolicyLayers(algorithm, branches, middleware, head, output, log_std, log_std_head, head_hidden)


def value_layers(network: Any, observation_space: Any, sensors: Sequence[str]) -> PolicyLayers:
    """The state-value network V(s) of a PPO ``ActorCritic`` (its own trunk when the networks are
    separate, as DeepRacer's, else the policy's) as layers with a (features, 1) head, output identity."""
    from laplab.agents.networks import ActorCritic

    if not isinstance(network, ActorCritic):
        raise TypeError(f"only PPO's ActorCritic has a value network, got {type(network).__name__}")
    trunk = network.policy_trunk if network.value_trunk is None else network.value_trunk
    branches, middleware = _trunk_layers(trunk, observation_space, sensors)
    head = Dense(_array(network.value_head.weight).T.copy(), _array(network.value_head.bias), "none")
    return PolicyLayers("clipped_ppo", branches, middleware, head, "identity")


def _trunk_layers(trunk: Any, observation_space: Any, sensors: Sequence[str]) -> tuple[tuple[SensorBranch, ...],
                                                                                      tuple[Dense, ...]]:
    import gymnasium as gym

    from laplab.env.spec import sensor_spaces

    spaces = sensor_spaces(observation_space, sensors)
    if isinstance(observation_space, gym.spaces.Dict):
        keys = {name: name for name in spaces}
    else:  # a Box: the trunk's one embedder
        keys = {sensors[0]: trunk.sensor_names[0]}
    # laplab concatenates the embedders sorted by their key (sensor name; 'observation' for a Box)
    order = sorted(spaces, key=lambda name: keys[name])
    branches = tuple(_branch(name, trunk.sensors[keys[name]], spaces[name]) for name in order)
    return branches, _dense_layers(trunk.middleware)


def reference_output(network: Any, observations: Any, raw: bool = True) -> np.ndarray:
    """laplab's greedy policy through the network's own torch forward, for laplab observations
    (numpy, channels-first cameras): PPO discrete probabilities (B, A); PPO continuous the Gaussian
    mean (B, 2) (``raw``; else clipped to [-1, 1] as laplab drives); SAC tanh(mean)."""
    from laplab.agents.networks import observation_to_tensor
    from laplab.agents.onnx_export import torch_policy_output

    return torch_policy_output(network, observation_to_tensor(observations, "cpu"), raw=raw)


def graph_reference_output(network: Any, observations: Any) -> np.ndarray:
    """What the car's ``model.pb`` output node must hold, through torch: :func:`reference_output`
    (raw), except SAC's, which is the Gaussian mean before tanh (B, A), as deepracer-simapp freezes it."""
    from laplab.agents.sac_networks import SquashedGaussianActor

    if not isinstance(network, SquashedGaussianActor):
        return reference_output(network, observations)
    import torch

    from laplab.agents.networks import observation_to_tensor
    with torch.no_grad():
        features = network.trunk(observation_to_tensor(observations, "cpu"))
        return network.mean(network.head(features)).numpy()


def _set_dense(sequential: Any, layers: Sequence[Dense]) -> None:
    """Copy ``layers`` into the Linear modules of ``sequential`` (in order; the inverse of _dense_layers)."""
    import torch
    from torch import nn

    linears = [module for module in sequential if isinstance(module, nn.Linear)]
    if len(linears) != len(layers):
        raise ValueError(f"{len(layers)} dense layers for a stack of {len(linears)}")
    for linear, layer in zip(linears, layers):
        linear.weight.copy_(torch.from_numpy(np.ascontiguousarray(layer.kernel.T)))
        linear.bias.copy_(torch.from_numpy(layer.bias))


def _set_trunk(trunk: Any, layers: PolicyLayers, observation_space: Any) -> None:
    import gymnasium as gym
    import torch
    from torch import nn

    single = not isinstance(observation_space, gym.spaces.Dict)
    for branch in layers.branches:
        embedder = trunk.sensors[trunk.sensor_names[0] if single else branch.sensor]
        if branch.is_camera:
            convs = [module for module in embedder.convolutions if isinstance(module, nn.Conv2d)]
            for module, conv in zip(convs, branch.convs, strict=True):
                module.weight.copy_(torch.from_numpy(np.ascontiguousarray(conv.kernel.transpose(3, 2, 0, 1))))
                module.bias.copy_(torch.from_numpy(conv.bias))
        _set_dense(embedder.dense, branch.dense)
    _set_dense(trunk.middleware, layers.middleware)


def load_policy_layers(network: Any, observation_space: Any, policy: PolicyLayers,
                       value: PolicyLayers | None = None) -> None:
    """Write ``policy`` (and PPO's ``value``) into a laplab PPO ``ActorCritic`` or SAC
    ``SquashedGaussianActor`` built for ``observation_space``: the inverse of :func:`policy_layers`
    / :func:`value_layers` (layers must have the network's shapes: take them from those)."""
    import torch

    from laplab.agents.networks import ActorCritic

    with torch.no_grad():
        if isinstance(network, ActorCritic):
            _set_trunk(network.policy_trunk, policy, observation_space)
            _set_dense([network.policy_head], [policy.head])
            if network.log_std is not None and policy.log_std is not None:
                network.log_std.copy_(torch.from_numpy(policy.log_std.reshape(-1)))
            if value is not None:
                _set_trunk(network.policy_trunk if network.value_trunk is None else network.value_trunk, value,
                           observation_space)
                _set_dense([network.value_head], [value.head])
        else:
            _set_trunk(network.trunk, policy, observation_space)
            _set_dense(network.head, policy.head_hidden)
            _set_dense([network.mean], [policy.head])
            if policy.log_std_head is not None:
                _set_dense([network.log_std], [policy.log_std_head])
