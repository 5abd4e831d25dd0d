"""DeepRacer's neural networks in torch, built from a gymnasium observation space.

A network is rl_coach's layout, as DeepRacer uses it: one input embedder per sensor, their
outputs concatenated, a "middleware" of dense layers, then heads. Camera embedders are the conv
schemes named in ``model_metadata.json`` (reference doc section 4); all layers use ReLU except
the ``STATE`` vector embedder (tanh). Convolutions use no padding ("valid"), as rl_coach does.
STEREO_CAMERAS with the standard and deep networks gets deepracer-simapp's own stereo embedder
(:data:`STEREO_CONV_LAYERS`, under the key ``laplab.env.spec.network_layout`` names).

Observations are a tensor (a gymnasium ``Box``) or a dict ``{sensor_name: tensor}`` (a ``Dict``
space keyed by DeepRacer sensor names). Camera images are channels-first ``(B, C, H, W)`` with
``C = stack_size * cameras`` (STEREO_CAMERAS: 2 per frame); ``uint8`` images are scaled by 1/255.
PPO's actor-critic is here; SAC's actor and twin critic are in :mod:`laplab.agents.sac_networks`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from laplab.agents.hyperparameters import PRECISIONS
from laplab.agents.learner import Action
from laplab.env.metadata import ALL_SENSORS as SENSOR_NAMES
from laplab.env.metadata import CAMERA_SENSORS, LIDAR_SENSORS, STATE_SENSOR
from laplab.env.spec import DEEPER_STEREO_NETWORKS, STEREO_SCHEME_SUFFIX

LIDAR_LAYERS = (256, 256)
STATE_LAYERS = (256, 256)
DEFAULT_NETWORK = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
_SINGLE = "observation"  # the embedder key of a plain Box observation


@dataclass(frozen=True)
class NetworkScheme:
    """Layer sizes of a named network: conv ``(filters, kernel, stride)`` layers and dense layers
    of the camera embedder, then the dense middleware shared by all sensors."""

    conv_layers: tuple[tuple[int, int, int], ...]
    camera_dense: tuple[int, ...]
    middleware: tuple[int, ...]


NETWORK_SCHEMES: dict[str, NetworkScheme] = {
    "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW": NetworkScheme(((32, 8, 4), (64, 4, 2), (64, 3, 1)), (), (512,)),
    "DEEP_CONVOLUTIONAL_NETWORK": NetworkScheme(
        ((32, 5, 2), (32, 3, 1), (64, 3, 2), (64, 3, 1)), (64,), (512,)),
    "DEEP_CONVOLUTIONAL_NETWORK_DEEP": NetworkScheme(
        ((32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)), (512, 512), (256, 128)),
    "MLP": NetworkScheme((), (), ()),  # vector observations only (STATE, lidar)
}

#: deepracer-simapp's STEREO_CAMERAS embedder with the deeper networks (``get_stereo_camera_embedders``):
#: five 3x3 convolutions, no dense layer; the middleware stays the network's. The shallow network
#: keeps its camera scheme for stereo too.
STEREO_CONV_LAYERS = ((32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1))
for _deeper in DEEPER_STEREO_NETWORKS:  # keys "<network>+STEREO_CAMERAS" (laplab.env.spec.network_layout)
    NETWORK_SCHEMES[_deeper + STEREO_SCHEME_SUFFIX] = NetworkScheme(
        STEREO_CONV_LAYERS, (), NETWORK_SCHEMES[_deeper].middleware)


@dataclass(frozen=True)
class ActionSpec:
    """What the policy outputs: ``size`` discrete actions (indices into the model's action list)
    or a ``size``-dimensional continuous action in [-1, 1] (the env scales it to the metadata's
    steering/speed bounds)."""

    discrete: bool
    size: int


def action_spec_from(spec: Any) -> ActionSpec:
    """An ``ActionSpec`` from an ``ActionSpec``, an int (discrete count), a gymnasium ``Discrete``
    or 1-D ``Box``, or a ``model_metadata.json`` dict (``action_space_type`` + ``action_space``)."""
    if isinstance(spec, ActionSpec):
        return spec
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool) and spec >= 1:
        return ActionSpec(True, int(spec))
    if isinstance(spec, gym.spaces.Discrete):
        return ActionSpec(True, int(spec.n))
    if isinstance(spec, gym.spaces.Box) and len(spec.shape) == 1:
        return ActionSpec(False, int(spec.shape[0]))
    if isinstance(spec, Mapping) and "action_space" in spec:
        kind = str(spec.get("action_space_type", "discrete")).lower()
        if kind == "discrete" and isinstance(spec["action_space"], list) and spec["action_space"]:
            return ActionSpec(True, len(spec["action_space"]))
        if kind == "continuous":
            return ActionSpec(False, 2)  # steering_angle, speed
    raise ValueError(
        f"Cannot read an action space from {spec!r} ({type(spec).__name__}); give a number of "
        "discrete actions, a gymnasium Discrete or 1-D Box, or a model_metadata.json dict."
    )


def dense_stack(in_dim: int, sizes: tuple[int, ...], activation: type[nn.Module]) -> nn.Sequential:
    """Dense layers of ``sizes`` from ``in_dim`` inputs, each followed by ``activation``."""
    layers: list[nn.Module] = []
    for size in sizes:
        layers += [nn.Linear(in_dim, size), activation()]
        in_dim = size
    return nn.Sequential(*layers)


def _channels_last(gradient: torch.Tensor) -> torch.Tensor:
    return gradient.contiguous(memory_format=torch.channels_last)


class ConvFeaturesFlatten(nn.Flatten):
    """``nn.Flatten`` of channels-last conv features (the logical NCHW order, as rl_coach flattens)
    whose gradient goes back channels-last too: ReLU's backward pass on a channels-last output with
    a channels-first gradient is ~13x slower than with matching layouts."""

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        if features.requires_grad and not torch.jit.is_tracing():
            features.register_hook(_channels_last)
        return super().forward(features)


class CameraEmbedder(nn.Module):
    """``(B, C, H, W)`` images -> ``(B, output_dim)`` features: conv scheme, flatten, dense."""

    def __init__(self, shape: tuple[int, int, int], scheme: NetworkScheme, scale: float, name: str):
        super().__init__()
        channels, height, width = shape
        if channels > 16 and width <= 16:
            raise ValueError(
                f"Observation '{name}' has shape {shape}: camera images must be channels-first "
                "(C, H, W), e.g. (1, 120, 160); this looks channels-last."
            )
        layers: list[nn.Module] = []
        for filters, kernel, stride in scheme.conv_layers:
            height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1
            if height < 1 or width < 1:
                raise ValueError(
                    f"Camera observation '{name}' of shape {shape} is too small for the conv "
                    f"layers {scheme.conv_layers}."
                )
            layers += [nn.Conv2d(channels, filters, kernel, stride), nn.ReLU()]
            channels = filters
        layers.append(ConvFeaturesFlatten())
        # Channels-last convolutions run ~1.4x faster on CPU (oneDNN); Flatten keeps the logical NCHW
        # order, so the dense layer, checkpoints and ONNX graphs are the same as with contiguous weights.
        self.convolutions = nn.Sequential(*layers).to(memory_format=torch.channels_last)
        self.dense = dense_stack(channels * height * width, scheme.camera_dense, nn.ReLU)
        self.output_dim = scheme.camera_dense[-1] if scheme.camera_dense else channels * height * width
        self.scale = scale

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        pixels = (images.float() * self.scale).contiguous(memory_format=torch.channels_last)
        return self.dense(self.convolutions(pixels))


class VectorEmbedder(nn.Module):
    """``(B, *shape)`` vectors (lidar ranges, state) -> flattened -> dense layers."""

    def __init__(self, in_dim: int, sizes: tuple[int, ...], activation: type[nn.Module]):
        super().__init__()
        self.dense = dense_stack(in_dim, sizes, activation)
        self.output_dim = sizes[-1]

    def forward(self, vectors: torch.Tensor) -> torch.Tensor:
        return self.dense(vectors.float().flatten(1))


class Embedder(nn.Module):
    """Observation -> ``(B, output_dim)``: per-sensor embedders, concatenated (sorted by sensor
    name), then the middleware."""

    def __init__(self, embedders: dict[str, nn.Module], middleware: tuple[int, ...], single_box: bool):
        super().__init__()
        self.sensors = nn.ModuleDict(embedders)
        self.sensor_names = sorted(embedders)
        concatenated = sum(module.output_dim for module in embedders.values())
        self.middleware = dense_stack(concatenated, middleware, nn.ReLU)
        self.output_dim = middleware[-1] if middleware else concatenated
        self.single_box = single_box
        self.compute_dtype: torch.dtype | None = None  # see set_compute_precision

    def forward(self, observations: torch.Tensor | Mapping[str, torch.Tensor]) -> torch.Tensor:
        if self.compute_dtype is None:
            return self._features(observations)
        device_type = next(self.parameters()).device.type
        with torch.autocast(device_type, dtype=self.compute_dtype):
            return self._features(observations).float()

    def _features(self, observations: torch.Tensor | Mapping[str, torch.Tensor]) -> torch.Tensor:
        if self.single_box:
            observations = {_SINGLE: observations}
        parts = [self.sensors[name](observations[name]) for name in self.sensor_names]
        return self.middleware(parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1))


def has_convolutions(module: nn.Module) -> bool:
    return any(isinstance(m, CameraEmbedder) for m in module.modules())


def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AVX512-BF16 or AMX), where oneDNN runs
    bfloat16 convolutions about twice as fast as float32."""
    cpu = getattr(torch, "cpu", None)
    checks = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(bool(getattr(cpu, name, lambda: False)()) for name in checks)


def bfloat16_is_native(device_type: str) -> bool:
    """Whether a network on ``device_type`` ("cpu", "cuda") computes bfloat16 in hardware: the
    CPU's own instructions, or the GPU's (Ampere and later)."""
    if device_type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    return device_type == "cpu" and native_bfloat16()


def resolve_precision(precision: str, module: nn.Module) -> str:
    """``"auto"`` -> ``"bfloat16"`` for camera networks on a device with native bfloat16 (where the
    module's parameters live, not the machine's CPU: a GPU learner on a CPU without it still
    gets it), else ``"float32"``; the others pass through."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        device_type = next((p.device.type for p in module.parameters()), "cpu")
        return "bfloat16" if has_convolutions(module) and bfloat16_is_native(device_type) else "float32"
    return precision


def set_compute_precision(module: nn.Module, precision: str) -> str:
    """Run every observation trunk inside ``module`` in ``precision`` (mixed precision: the weights,
    gradients, optimizer and heads stay float32; trunk features come back as float32). Returns
    the resolved precision."""
    resolved = resolve_precision(precision, module)
    dtype = torch.bfloat16 if resolved == "bfloat16" else None
    for child in module.modules():
        if isinstance(child, Embedder):
            child.compute_dtype = dtype
    return resolved


def _sensor_embedder(name: str, space: gym.spaces.Space, scheme: NetworkScheme, network_name: str) -> nn.Module:
    if not isinstance(space, gym.spaces.Box):
        raise ValueError(f"Observation '{name}' must be a gymnasium Box, got {type(space).__name__}.")
    shape = tuple(int(s) for s in space.shape)
    is_camera = name in CAMERA_SENSORS or (name == _SINGLE and len(shape) == 3)
    if is_camera:
        if len(shape) != 3:
            raise ValueError(f"Camera observation '{name}' must be (C, H, W), got shape {shape}.")
        if not scheme.conv_layers:
            raise ValueError(
                f"Network '{network_name}' has no convolutions and cannot take camera observation "
                f"'{name}'; use one of {[n for n, s in NETWORK_SCHEMES.items() if s.conv_layers]}."
            )
        scale = 1.0 / 255.0 if space.dtype == np.uint8 else 1.0
        return CameraEmbedder(shape, scheme, scale, name)
    in_dim = int(math.prod(shape))
    if name in LIDAR_SENSORS:
        return VectorEmbedder(in_dim, LIDAR_LAYERS, nn.ReLU)
    if name == STATE_SENSOR or (name == _SINGLE and len(shape) == 1):
        return VectorEmbedder(in_dim, STATE_LAYERS, nn.Tanh)
    raise ValueError(
        f"Observation '{name}' with shape {shape} is not a known sensor; a Box must be an image "
        f"(C, H, W) or a vector, and Dict keys must be among {', '.join(SENSOR_NAMES)}."
    )


def build_embedder(observation_space: gym.spaces.Space, network_name: str = DEFAULT_NETWORK) -> Embedder:
    """The trunk of a DeepRacer network for ``observation_space``: a ``Box`` (image ``(C, H, W)``
    -> camera embedder, vector -> STATE embedder) or a ``Dict`` keyed by sensor names."""
    if network_name not in NETWORK_SCHEMES:
        raise ValueError(
            f"Unknown neural_network {network_name!r}; known: {', '.join(NETWORK_SCHEMES)}."
        )
    scheme = NETWORK_SCHEMES[network_name]
    if isinstance(observation_space, gym.spaces.Dict):
        spaces = dict(observation_space.spaces)
        cameras = [name for name in spaces if name in CAMERA_SENSORS]
        lidars = [name for name in spaces if name in LIDAR_SENSORS]
        if len(cameras) > 1 or len(lidars) > 1:
            raise ValueError(
                f"A DeepRacer model has at most one camera and one lidar sensor; got {sorted(spaces)}."
            )
        unknown = [name for name in spaces if name not in SENSOR_NAMES]
        if unknown:
            raise ValueError(
                f"Unknown sensor(s) {unknown} in the observation space; known: {', '.join(SENSOR_NAMES)}."
            )
        embedders = {name: _sensor_embedder(name, space, scheme, network_name) for name, space in spaces.items()}
        return Embedder(embedders, scheme.middleware, single_box=False)
    embedder = _sensor_embedder(_SINGLE, observation_space, scheme, network_name)
    return Embedder({_SINGLE: embedder}, scheme.middleware, single_box=True)


def observation_to_tensor(observations: Any, device: torch.device | str) -> Any:
    """numpy observation(s) (an array or a dict of arrays) -> torch tensors on ``device``;
    ``uint8`` stays ``uint8`` (4x less to copy), everything else becomes float32."""
    if isinstance(observations, Mapping):
        return {key: observation_to_tensor(value, device) for key, value in observations.items()}
    array = np.asarray(observations)
    if array.dtype != np.uint8:
        array = array.astype(np.float32, copy=False)
    return torch.as_tensor(array, device=device)


# Output of ``act`` for B observations: ``action`` to store for training ((B,) int64 or (B, A) float32,
# unclipped), ``env_action`` to send to the env (continuous: clipped to [-1, 1]), ``log_prob`` (B,) of
# ``action``, ``value`` (B,) state value. One type for every learner (laplab.agents.learner.Action).
PolicyStep = Action


class ActorCritic(nn.Module):
    """PPO's policy and value function (rl_coach ``ClippedPPO``: a V head and a PPO head).

    Discrete: Categorical over ``size`` logits. Continuous: Gaussian with a state-independent
    log-std (starting at std 1), sampled without tanh; actions are clipped to [-1, 1] only when
    sent to the env. ``separate_networks=True`` gives policy and value their own trunks, as
    rl_coach's ``use_separate_networks_per_head`` does for DeepRacer.
    """

    def __init__(self, observation_space: gym.spaces.Space, action_spec: Any,
                 network_name: str = DEFAULT_NETWORK, separate_networks: bool = True):
        super().__init__()
        self.action_spec = action_spec_from(action_spec)
        self.policy_trunk = build_embedder(observation_space, network_name)
        self.value_trunk = build_embedder(observation_space, network_name) if separate_networks else None
        features = self.policy_trunk.output_dim
        self.policy_head = nn.Linear(features, self.action_spec.size)
        with torch.no_grad():  # a near-uniform / zero-mean starting policy, as rl_coach's PPO head
            self.policy_head.weight.mul_(0.01)
            self.policy_head.bias.zero_()
        self.log_std = None if self.action_spec.discrete else nn.Parameter(torch.zeros(self.action_spec.size))
        self.value_head = nn.Linear(features, 1)

    def forward(self, observations: Any) -> tuple[torch.distributions.Distribution, torch.Tensor]:
        """-> (action distribution over B rows, values (B,))."""
        policy_features = self.policy_trunk(observations)
        value_features = policy_features if self.value_trunk is None else self.value_trunk(observations)
        return self._distribution(policy_features), self.value_head(value_features).squeeze(-1)

    def distribution(self, observations: Any) -> torch.distributions.Distribution:
        """The action distribution alone (the value trunk does not run)."""
        return self._distribution(self.policy_trunk(observations))

    def _distribution(self, policy_features: torch.Tensor) -> torch.distributions.Distribution:
        out = self.policy_head(policy_features)
        if self.action_spec.discrete:
            return torch.distributions.Categorical(logits=out)
        std = self.log_std.clamp(-20.0, 2.0).exp().expand_as(out)
        return torch.distributions.Independent(torch.distributions.Normal(out, std), 1)

    def value(self, observations: Any) -> torch.Tensor:
        """State values (B,)."""
        trunk = self.policy_trunk if self.value_trunk is None else self.value_trunk
        return self.value_head(trunk(observations)).squeeze(-1)

    def evaluate(self, observations: Any, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> log_prob (B,), entropy (B,), value (B,) of stored ``actions``."""
        distribution, values = self(observations)
        return distribution.log_prob(actions), distribution.entropy(), values

    def evaluate_policy(self, observations: Any, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """-> log_prob (B,), entropy (B,) of stored ``actions`` (the value trunk does not run)."""
        distribution = self.distribution(observations)
        return distribution.log_prob(actions), distribution.entropy()

    @torch.no_grad()
    def act(self, observations: Any, deterministic: bool = False) -> PolicyStep:
        """Sample (or, deterministic, take the mode of) the policy for B observations."""
        distribution, values = self(observations)
        if deterministic:
            action = distribution.probs.argmax(-1) if self.action_spec.discrete else distribution.mean
        else:
            action = distribution.sample()
        env_action = action if self.action_spec.discrete else action.clamp(-1.0, 1.0)
        return PolicyStep(action, env_action, distribution.log_prob(action), values)
