"""A trained policy as an ONNX graph for the physical car (reference doc section 9).

The graph holds the policy only (no value head, no critic) and takes DeepRacer's tensors: one input
per sensor, named by its DeepRacer sensor name, with a dynamic batch axis ``B``:

- camera (``FRONT_FACING_CAMERA``, ``LEFT_CAMERA``, ``STEREO_CAMERAS``): float32 ``(B, H, W, C)``
  channels-last grey levels 0-255 (DeepRacer's ``[1, 120, 160, 1]``); the graph transposes to
  laplab's ``(B, C, H, W)`` and scales as the network was trained (``uint8`` spaces: x / 255);
- vector sensors (``STATE``, lidars): float32 ``(B, *shape)`` exactly as the env observes them.

Output ``probabilities`` (B, A) for a discrete action space (softmax of the PPO head), or ``action``
(B, 2) in [-1, 1]^2 for a continuous one (PPO: the Gaussian mean clipped to [-1, 1]; SAC:
tanh of the mean), i.e. what the greedy policy sends to the env.

Uses torch's TorchScript exporter (``dynamo=False``: no ``onnxscript`` needed), opset 17.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from laplab.agents.networks import CAMERA_SENSORS, ActorCritic
from laplab.agents.sac_networks import SquashedGaussianActor
from laplab.env.spec import ModelSpec, sensor_spaces

ONNX_OPSET = 17
PROBABILITIES = "probabilities"
ACTION = "action"


@dataclass(frozen=True)
class GraphInput:
    """One input of the graph: ``name`` (a DeepRacer sensor name), per-sample ``shape`` as fed to the
    graph (camera: ``(H, W, C)``), ``is_camera``, and ``scale`` applied after the camera transpose."""

    name: str
    shape: tuple[int, ...]
    is_camera: bool
    scale: float = 1.0


def graph_inputs(observation_space: gym.Space, sensors: Sequence[str]) -> tuple[GraphInput, ...]:
    """The graph inputs of a network trained on ``observation_space`` (a ``Box`` for one sensor,
    a ``Dict`` keyed by sensor names), in the order of ``sensors`` (model_metadata.json's list)."""
    inputs = []
    for name, space in sensor_spaces(observation_space, sensors).items():
        shape = tuple(int(s) for s in space.shape)
        if name in CAMERA_SENSORS:
            if len(shape) != 3:
                raise ValueError(f"camera observation {name!r} must be (C, H, W), got {shape}")
            # uint8 spaces are scaled by the network itself; a float space in [0, 1] needs x / 255 here.
            unit_range = space.dtype != np.uint8 and float(np.max(space.high)) <= 1.0
            inputs.append(GraphInput(name, (shape[1], shape[2], shape[0]), True, 1.0 / 255.0 if unit_range else 1.0))
        else:
            inputs.append(GraphInput(name, shape, False))
    return tuple(inputs)


class PolicyGraph(nn.Module):
    """DeepRacer tensors in (see the module docstring), greedy policy output out."""

    def __init__(self, network: nn.Module, observation_space: gym.Space, sensors: Sequence[str]):
        super().__init__()
        if not isinstance(network, (ActorCritic, SquashedGaussianActor)):
            raise TypeError(f"expected a PPO ActorCritic or a SAC SquashedGaussianActor, got {type(network).__name__}")
        self.network = network
        self.inputs = graph_inputs(observation_space, sensors)
        self.single_box = isinstance(observation_space, gym.spaces.Box)
        self.discrete = isinstance(network, ActorCritic) and network.action_spec.discrete

    @property
    def output_name(self) -> str:
        return PROBABILITIES if self.discrete else ACTION

    def forward(self, *tensors: torch.Tensor) -> torch.Tensor:
        observation: dict[str, torch.Tensor] = {}
        for spec, tensor in zip(self.inputs, tensors):
            if spec.is_camera:
                tensor = tensor.permute(0, 3, 1, 2)
                if spec.scale != 1.0:
                    tensor = tensor * spec.scale
            observation[spec.name] = tensor
        obs: Any = observation[self.inputs[0].name] if self.single_box else observation
        if isinstance(self.network, SquashedGaussianActor):
            return self.network.greedy(self.network.trunk(obs))
        out = self.network.policy_head(self.network.policy_trunk(obs))
        return torch.softmax(out, dim=-1) if self.discrete else out.clamp(-1.0, 1.0)


def model_to_onnx(network: nn.Module, spec: ModelSpec, metadata_json: str | None = None) -> bytes:
    """The greedy policy of a model's ``network`` as ONNX bytes: inputs from the model's spec (its
    observation space, sensor order and ``stack_size``, recorded as the property ``stack_size``)."""
    return policy_to_onnx(network, spec.observation_space, spec.sensors, metadata_json,
                          extra_properties={"stack_size": str(spec.stack_size)})


def model_parity_error(onnx_bytes: bytes, network: nn.Module, spec: ModelSpec, samples: int = 16,
                       seed: int = 0) -> float:
    """Max |ONNX - torch| of a model's graph over random observations of its spec (needs onnxruntime)."""
    return onnx_parity_error(onnx_bytes, network, spec.observation_space, spec.sensors, samples, seed)


def policy_to_onnx(network: nn.Module, observation_space: gym.Space, sensors: Sequence[str],
                   metadata_json: str | None = None, extra_properties: dict[str, str] | None = None) -> bytes:
    """Serialise the greedy policy of ``network`` as an ONNX model (bytes).

    ``metadata_json`` (the model's model_metadata.json text) is embedded as the ONNX metadata
    property ``model_metadata`` so the graph alone still says which action each output means;
    ``extra_properties`` are added as further metadata properties.
    """
    import onnx  # optional dependency: pip install onnx onnxruntime

    graph = PolicyGraph(network, observation_space, sensors).eval()
    examples = tuple(torch.zeros((2, *spec.shape), dtype=torch.float32) for spec in graph.inputs)
    names = [spec.name for spec in graph.inputs]
    dynamic = {name: {0: "batch"} for name in [*names, graph.output_name]}
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter is deprecated
        warnings.simplefilter("ignore", UserWarning)
        torch.onnx.export(graph, examples, buffer, dynamo=False, opset_version=ONNX_OPSET, input_names=names,
                          output_names=[graph.output_name], dynamic_axes=dynamic, do_constant_folding=True)
    model = onnx.load_from_string(buffer.getvalue())
    model.producer_name = "laplab"
    model.doc_string = ("DeepRacer policy exported by laplab: camera inputs NHWC grey 0-255 float32, vector "
                        f"inputs as observed; output '{graph.output_name}'.")
    properties = {"input_layout": ",".join(f"{s.name}:{'NHWC' if s.is_camera else 'vector'}" for s in graph.inputs),
                  "output": graph.output_name}
    if metadata_json is not None:
        properties["model_metadata"] = metadata_json
    properties.update(extra_properties or {})
    onnx.helper.set_model_props(model, properties)
    onnx.checker.check_model(model)
    return model.SerializeToString()


def torch_policy_output(network: nn.Module, observations: Any, raw: bool = False) -> np.ndarray:
    """The reference the graph must reproduce, through the network's own forward: discrete action
    probabilities (B, A) or the greedy continuous action (B, 2) for laplab observations
    (channels-first cameras, a tensor or a dict of tensors). A continuous PPO action is the Gaussian
    mean clipped to [-1, 1] as laplab drives (``raw``: unclipped); SAC's is tanh(mean)."""
    with torch.no_grad():
        if isinstance(network, SquashedGaussianActor):
            return network(observations, deterministic=True)[0].numpy()
        distribution, _ = network(observations)
        if network.action_spec.discrete:
            return distribution.probs.numpy()
        mean = distribution.mean
        return (mean if raw else mean.clamp(-1.0, 1.0)).numpy()


def random_observations(observation_space: gym.Space, batch: int, seed: int = 0) -> Any:
    """``batch`` random laplab observations of ``observation_space`` (numpy; uint8 images 0-255,
    bounded boxes uniform inside their bounds, unbounded ones standard normal)."""
    rng = np.random.default_rng(seed)

    def sample(space: gym.spaces.Box) -> np.ndarray:
        shape = (batch, *space.shape)
        if space.dtype == np.uint8:
            return rng.integers(0, 256, shape, dtype=np.uint8)
        low, high = np.broadcast_to(space.low, space.shape), np.broadcast_to(space.high, space.shape)
        bounded = np.isfinite(low) & np.isfinite(high)
        values = np.where(bounded, rng.uniform(np.where(bounded, low, 0.0), np.where(bounded, high, 1.0), shape),
                          rng.standard_normal(shape))
        return values.astype(np.float32)

    if isinstance(observation_space, gym.spaces.Dict):
        return {name: sample(space) for name, space in observation_space.spaces.items()}
    return sample(observation_space)


def graph_feed(inputs: Sequence[GraphInput], observations: Any) -> dict[str, np.ndarray]:
    """laplab observations (channels-first cameras) -> the graph's input dict (channels-last float32)."""
    feed = {}
    for spec in inputs:
        value = observations[spec.name] if isinstance(observations, dict) else observations
        value = np.asarray(value)
        if spec.is_camera:
            value = np.transpose(value, (0, 2, 3, 1))
            if spec.scale != 1.0:  # a [0, 1] float space: the graph takes 0-255 grey levels
                value = value * 255.0
        feed[spec.name] = np.ascontiguousarray(value, dtype=np.float32)
    return feed


def onnx_parity_error(onnx_bytes: bytes, network: nn.Module, observation_space: gym.Space,
                      sensors: Sequence[str], samples: int = 16, seed: int = 0) -> float:
    """Max |ONNX - torch| over ``samples`` random observations (needs onnxruntime)."""
    import onnxruntime

    from laplab.agents.networks import observation_to_tensor

    session = onnxruntime.InferenceSession(onnx_bytes, providers=["CPUExecutionProvider"])
    observations = random_observations(observation_space, samples, seed)
    expected = torch_policy_output(network, observation_to_tensor(observations, "cpu"))
    got = session.run(None, graph_feed(graph_inputs(observation_space, sensors), observations))[0]
    return float(np.max(np.abs(got - expected)))
