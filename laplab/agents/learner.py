"""The interface every learning algorithm offers, and the one place that picks the algorithm.

The trainer and the stored-model loader talk to a :class:`Learner` only; neither knows whether it
is PPO or SAC. This module imports without torch (the implementations load on first use).
"""

from __future__ import annotations

import importlib
from typing import Any, Callable, Mapping, NamedTuple, Protocol, runtime_checkable

import numpy as np

from laplab.agents.hyperparameters import Hyperparameters
from laplab.env.spec import ModelSpec

# model_metadata.json's training_algorithm -> "module:class" of its learner
LEARNERS = {"clipped_ppo": "laplab.agents.ppo:PPOLearner", "sac": "laplab.agents.sac:SACLearner"}


class Action(NamedTuple):
    """A learner's actions for B observations (numpy): ``action`` to learn from ((B,) int64 or (B, A)
    float32), ``env_action`` to send to the env (continuous: within [-1, 1]), ``log_prob`` (B,) and
    ``value`` (B,) (NaN or 0 where the algorithm has none)."""

    action: Any
    env_action: Any
    log_prob: Any
    value: Any


class Experience(Protocol):
    """Complete episodes, time-major (T, E): what :meth:`Learner.learn` takes
    (:class:`laplab.train.collect.EpisodeBatch` is one)."""

    observations: Any  # (T, E, ...) or a dict of them
    actions: np.ndarray  # (T, E) or (T, E, A)
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray  # bool
    truncated: np.ndarray  # bool
    valid: np.ndarray  # bool: the car was driving at that step
    bootstrap_values: np.ndarray  # V(final obs) where truncated


@runtime_checkable
class Learner(Protocol):
    """A learning algorithm with its networks.

    - ``act(obs, deterministic)``: actions for a batch; exploring calls advance exploration schedules.
    - ``values(obs)``: V(obs) (B,) for bootstrapping cut episodes (zeros where there is no V).
    - ``learn(batch, should_stop=None, on_progress=None)``: one training iteration on an
      :class:`Experience`; returns loss figures. ``should_stop()`` is polled between gradient steps
      (True ends the iteration early, the networks whole); ``on_progress(done, total)`` follows each step.
    - ``state_dict()`` / ``load_state_dict(state)``: everything to resume (weights, optimizers, schedules);
      ``load_state_dict`` also takes a ``weights_state()`` (fresh optimizers, targets rebuilt from weights).
    - ``weights_state()``: the weights, schedules and config without optimizers (compact checkpoints).
    - ``load_weights(state)``: the network weights of a ``state_dict()`` only (a clone: fresh optimizer).
    - ``policy_network``: the torch module that maps observations to the greedy policy (for export).
    - ``rng``: the numpy generator of its exploration (seeded evaluations replace it).
    """

    algorithm: str
    rng: np.random.Generator

    def act(self, observations: Any, deterministic: bool = False) -> Action: ...

    def values(self, observations: Any) -> np.ndarray: ...

    def learn(self, batch: Experience, should_stop: Callable[[], bool] | None = None,
              on_progress: Callable[[int, int], None] | None = None) -> dict[str, float]: ...

    def state_dict(self) -> dict[str, Any]: ...

    def weights_state(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...

    def load_weights(self, state: Mapping[str, Any]) -> None: ...

    @property
    def policy_network(self) -> Any: ...


def learner_class(algorithm: str) -> type:
    """The learner class of a ``training_algorithm`` (imports torch)."""
    try:
        module, name = LEARNERS[algorithm].split(":")
    except KeyError:
        raise ValueError(f"unknown training_algorithm {algorithm!r}; known: {', '.join(LEARNERS)}") from None
    return getattr(importlib.import_module(module), name)


def build_learner(spec: ModelSpec, hyperparameters: Hyperparameters, seed: int | None = None,
                  num_threads: int | None = None, precision: str = "float32", device: str = "cpu") -> Learner:
    """The learner of a model: its algorithm, networks for its observation space and action space.

    Small vector networks run fastest on one thread (more threads only add synchronisation, and
    collapse when the cores are shared), so ``num_threads`` None means 1 for them; camera networks
    use every core and keep freed memory for reuse (see :func:`laplab.agents.torch_runtime.keep_freed_memory`).
    """
    cls = learner_class(spec.algorithm)
    if spec.camera is not None:
        from laplab.agents.torch_runtime import keep_freed_memory
        keep_freed_memory()
    threads = num_threads or (1 if spec.camera is None else None)
    extra = {}
    if spec.algorithm == "sac" and not spec.action_space.is_discrete:
        extra["action_scale"] = spec.action_space.half_ranges()  # DeepRacer's log-probability in the model's units
        extra["policy_head_layers"] = spec.policy_head_layers
    return cls(spec.observation_space, spec.gym_action_space, hyperparameters, spec.network_layout, seed=seed,
               num_threads=threads, precision=precision, device=device, **extra)
