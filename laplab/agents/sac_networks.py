"""SAC's networks as DeepRacer builds them (rl_coach's ``SACPolicyHead`` and ``SACQHead`` on the
observation trunks of :mod:`laplab.agents.networks`): a tanh-squashed Gaussian policy and a twin Q
critic whose one trunk feeds both heads."""

from __future__ import annotations

import math
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from laplab.agents.networks import DEFAULT_NETWORK, build_embedder, dense_stack


def _frozen_dense(layers: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``layers`` (nested Sequentials of Linear and ReLU) applied to ``x`` with detached weights."""
    for layer in layers.modules():
        if isinstance(layer, nn.Linear):
            x = F.linear(x, layer.weight.detach(), None if layer.bias is None else layer.bias.detach())
        elif isinstance(layer, nn.ReLU):
            x = F.relu(x)
        elif not isinstance(layer, nn.Sequential):
            raise TypeError(f"_frozen_dense cannot run a {type(layer).__name__}")
    return x


def squashed_gaussian_log_prob(pre_tanh: torch.Tensor, normal: torch.distributions.Normal) -> torch.Tensor:
    """log-density (B,) of ``tanh(pre_tanh)`` where ``pre_tanh ~ normal`` (both (B, A)):
    ``log N(u) - sum log(1 - tanh(u)^2)``, the correction written in a stable form."""
    correction = 2.0 * (math.log(2.0) - pre_tanh - nn.functional.softplus(-2.0 * pre_tanh))
    return (normal.log_prob(pre_tanh) - correction).sum(-1)


FLOAT32_EPS = float(np.finfo(np.float32).eps)


def deepracer_squashed_log_prob(pre_tanh: torch.Tensor, normal: torch.distributions.Normal,
                                action_scale: torch.Tensor) -> torch.Tensor:
    """DeepRacer's SAC log-probability (B,) of the squashed action (deepracer-simapp's ``SACPolicyHead``
    with ``rescale_action_values``): ``log N(u) - sum log(clip(scale * (1 - tanh(u)^2) + eps, 1e-10, 1))``.
    ``action_scale`` (A,) is half of each action's range in the model's units (30 for steering of
    -30..30 degrees, 1.5 for 1..4 m/s). The clip at 1 drops the correction, and with it its pull
    towards the middle of the range, wherever ``scale * (1 - tanh(u)^2) >= 1``: for a 30-degree
    steering range everywhere but the last 2 % of it."""
    squashed = torch.tanh(pre_tanh)
    jacobian = (action_scale * (1.0 - squashed * squashed) + FLOAT32_EPS).clamp(1e-10, 1.0)
    return (normal.log_prob(pre_tanh) - torch.log(jacobian)).sum(-1)


class SquashedGaussianActor(nn.Module):
    """SAC's policy: a state-dependent Gaussian squashed by tanh into (-1, 1)^A.

    ``head_layers``: relu dense layers between the trunk and the mean / log-std layers: () laplab's
    (both read the trunk's features), (256,) deepracer-simapp's ``SACPolicyHead`` (a dense 256 first).
    ``action_scale`` (A,) switches the log-probability to DeepRacer's (:func:`deepracer_squashed_log_prob`);
    without it the exact change of variables into (-1, 1)^A. Either way the actions are the same."""

    def __init__(self, observation_space: gym.spaces.Space, action_dim: int, network_name: str = DEFAULT_NETWORK,
                 action_scale: Any = None, head_layers: tuple[int, ...] = ()):
        super().__init__()
        self.trunk = build_embedder(observation_space, network_name)
        self.head_layers = tuple(int(size) for size in head_layers)
        self.head = dense_stack(self.trunk.output_dim, self.head_layers, nn.ReLU)  # empty: no parameters
        width = self.head_layers[-1] if self.head_layers else self.trunk.output_dim
        self.mean = nn.Linear(width, action_dim)
        self.log_std = nn.Linear(width, action_dim)
        scale = None if action_scale is None else torch.as_tensor(action_scale, dtype=torch.float32).reshape(action_dim)
        self.register_buffer("action_scale", scale, persistent=False)  # not in checkpoints: it comes from the metadata

    def forward(self, observations: Any, deterministic: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """-> actions (B, A) in (-1, 1) (reparameterised, differentiable), log_prob (B,)."""
        return self.from_features(self.trunk(observations), deterministic)

    def from_features(self, features: torch.Tensor, deterministic: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's heads on trunk ``features`` (B, F) -> actions (B, A), log_prob (B,)."""
        features = self.head(features)
        mean = self.mean(features)
        normal = torch.distributions.Normal(mean, self.log_std(features).clamp(-20.0, 2.0).exp())
        pre_tanh = mean if deterministic else normal.rsample()
        if self.action_scale is None:
            return torch.tanh(pre_tanh), squashed_gaussian_log_prob(pre_tanh, normal)
        return torch.tanh(pre_tanh), deepracer_squashed_log_prob(pre_tanh, normal, self.action_scale)


    def greedy(self, features: torch.Tensor) -> torch.Tensor:
        """The greedy action tanh(mean) (B, A) on trunk ``features`` (B, F)."""
        return torch.tanh(self.mean(self.head(features)))


class TwinQ(nn.Module):
    """SAC's twin Q(s, a) (clipped double-Q) as rl_coach's ``SACQHead`` builds it: one observation
    trunk (embedders + middleware) whose features, concatenated with the action, feed two
    independent dense 256, 256, 1 heads. The trunk runs once for both heads."""

    def __init__(self, observation_space: gym.spaces.Space, action_dim: int, network_name: str = DEFAULT_NETWORK):
        super().__init__()
        self.trunk = build_embedder(observation_space, network_name)
        width = self.trunk.output_dim + action_dim
        self.q1 = nn.Sequential(dense_stack(width, (256, 256), nn.ReLU), nn.Linear(256, 1))
        self.q2 = nn.Sequential(dense_stack(width, (256, 256), nn.ReLU), nn.Linear(256, 1))

    def heads(self, features: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Both heads on trunk ``features`` (B, F) and ``actions`` (B, A) -> (q1 (B,), q2 (B,))."""
        joined = torch.cat([features, actions], dim=-1)
        return self.q1(joined).squeeze(-1), self.q2(joined).squeeze(-1)

    def frozen_heads(self, features: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``heads`` with their weights held fixed: gradients reach ``actions`` (and ``features``), never
        the weights. Safe on several threads at once: the modules are not touched (no ``requires_grad``
        switching, no parameter swapping as ``torch.func.functional_call`` does)."""
        joined = torch.cat([features, actions], dim=-1)
        return _frozen_dense(self.q1, joined).squeeze(-1), _frozen_dense(self.q2, joined).squeeze(-1)

    def forward(self, observations: Any, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """-> (q1 (B,), q2 (B,))."""
        return self.heads(self.trunk(observations), actions)


def twin_q_from_separate(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A :class:`TwinQ` state dict from one of laplab's older layout (``q1.trunk``, ``q1.head``,
    ``q2.trunk``, ``q2.head``: a trunk per head): the shared trunk takes q1's trunk, each head
    keeps its dense layers (q2's own trunk is dropped). States of the current layout pass through."""
    if not any(key.startswith("q1.trunk.") for key in state):
        return dict(state)
    out = {}
    for key, value in state.items():
        if key.startswith("q1.trunk."):
            out["trunk." + key[len("q1.trunk."):]] = value
        elif key.startswith(("q1.head.", "q2.head.")):
            out[key[:2] + key[len("q1.head"):]] = value
    return out
