"""Soft Actor-Critic for DeepRacer's continuous action space (``training_algorithm: sac``).

A squashed-Gaussian policy in (-1, 1)^A, twin Q networks with Polyak-averaged targets and a
fixed entropy temperature ``sac_alpha`` (DeepRacer does not tune it). Gamma is
``discount_factor``, all three optimizers use ``lr``; an iteration makes
``num_epochs * ceil(new_steps / batch_size)`` gradient steps on uniform replay samples,
mirroring PPO's passes over the new experience.
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict
from typing import Any, Mapping, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import sac_actor_loss, sac_critic_target
from laplab.agents.networks import (DEFAULT_NETWORK, ActionSpec, PolicyStep, SquashedGaussianActor,
                                    TwinQ, action_spec_from, observation_to_tensor, set_compute_precision)
from laplab.agents.ppo import limit_torch_threads

TARGET_SMOOTHING = 0.005  # tau of the Polyak target update


class ReplayBatch(NamedTuple):
    """B transitions: observations / next_observations (B, *obs_shape) or dicts of such,
    actions (B, A) float32 in [-1, 1], rewards (B,) float32, terminated (B,) float32 (1 = no
    bootstrap)."""

    observations: Any
    actions: np.ndarray
    rewards: np.ndarray
    next_observations: Any
    terminated: np.ndarray


class ReplayBuffer:
    """A fixed-capacity ring buffer of transitions in preallocated numpy arrays (observation
    dtypes kept, so camera frames stay uint8)."""

    def __init__(self, capacity: int, observation_space: gym.spaces.Space, action_dim: int):
        if capacity < 1:
            raise ValueError(f"Replay buffer capacity must be >= 1, got {capacity}.")
        self.capacity = int(capacity)
        self.is_dict = isinstance(observation_space, gym.spaces.Dict)
        spaces = dict(observation_space.spaces) if self.is_dict else {"": observation_space}
        self.observations = {k: np.zeros((capacity, *s.shape), s.dtype) for k, s in spaces.items()}
        self.next_observations = {k: np.zeros((capacity, *s.shape), s.dtype) for k, s in spaces.items()}
        self.actions = np.zeros((capacity, action_dim), np.float32)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.float32)
        self.position = 0
        self.size = 0

    def __len__(self) -> int:
        return self.size

    def add(self, observations: Any, actions: np.ndarray, rewards: np.ndarray,
            next_observations: Any, terminated: np.ndarray) -> None:
        """Store B transitions (arrays with leading axis B; dict observations sensor-wise)."""
        rewards = np.asarray(rewards, np.float32).reshape(-1)
        batch = rewards.shape[0]
        slots = (self.position + np.arange(batch)) % self.capacity
        obs = observations if self.is_dict else {"": observations}
        next_obs = next_observations if self.is_dict else {"": next_observations}
        for key in self.observations:
            self.observations[key][slots] = obs[key]
            self.next_observations[key][slots] = next_obs[key]
        self.actions[slots] = np.asarray(actions, np.float32).reshape(batch, -1)
        self.rewards[slots] = rewards
        self.terminated[slots] = np.asarray(terminated, np.float32).reshape(-1)
        self.position = int((self.position + batch) % self.capacity)
        self.size = min(self.size + batch, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> ReplayBatch:
        """B transitions drawn uniformly with replacement."""
        index = rng.integers(0, self.size, batch_size)
        obs = {key: value[index] for key, value in self.observations.items()}
        next_obs = {key: value[index] for key, value in self.next_observations.items()}
        if not self.is_dict:
            obs, next_obs = obs[""], next_obs[""]
        return ReplayBatch(obs, self.actions[index], self.rewards[index], next_obs, self.terminated[index])


class SACLearner:
    """DeepRacer's SAC: ``act`` -> actions in [-1, 1]^A, ``observe`` transitions, ``update``.

    ``seed`` seeds torch's global RNG and this learner's numpy RNG (replay sampling).
    """

    algorithm = "sac"

    def __init__(self, observation_space: gym.spaces.Space, action_space_spec: Any,
                 hyperparameters: Hyperparameters = Hyperparameters(),
                 network_name: str = DEFAULT_NETWORK, device: str = "cpu",
                 buffer_capacity: int = 100_000, seed: int | None = None,
                 num_threads: int | None = None, precision: str = "float32"):
        limit_torch_threads(num_threads)
        if seed is not None:
            torch.manual_seed(seed)
        self.action_spec: ActionSpec = action_spec_from(action_space_spec)
        if self.action_spec.discrete:
            raise ValueError("SAC needs a continuous action space (action_space_type 'continuous').")
        self.hyperparameters = hyperparameters
        self.network_name = network_name
        self.device = torch.device(device)
        dim = self.action_spec.size
        self.actor = SquashedGaussianActor(observation_space, dim, network_name).to(self.device)
        self.critic = TwinQ(observation_space, dim, network_name).to(self.device)
        self.precision = set_compute_precision(self.actor, precision)
        set_compute_precision(self.critic, self.precision)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=hyperparameters.lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=hyperparameters.lr, fused=True)
        self.buffer = ReplayBuffer(buffer_capacity, observation_space, dim)
        self.rng = np.random.default_rng(seed)
        self.gradient_steps = 0

    @torch.no_grad()
    def act(self, observations: Any, deterministic: bool = False) -> PolicyStep:
        """Actions for B observations: ``action`` = ``env_action`` (B, A) in [-1, 1] (tanh of the mean
        when deterministic); ``log_prob`` and ``value`` are zeros (SAC learns off-policy, from a buffer)."""
        actions, _ = self.actor(observation_to_tensor(observations, self.device), deterministic)
        actions = actions.cpu().numpy()
        zeros = np.zeros(actions.shape[0], np.float32)
        return PolicyStep(actions, actions, zeros, zeros)

    def values(self, observations: Any) -> np.ndarray:
        """Zeros (B,): SAC has no state-value network; an episode cut by the step cap ends its target."""
        first = next(iter(observations.values())) if isinstance(observations, Mapping) else observations
        return np.zeros(len(first), np.float32)

    @property
    def policy_network(self) -> SquashedGaussianActor:
        return self.actor

    def learn(self, batch: Any) -> dict[str, float]:
        """Add complete episodes (a :class:`laplab.agents.learner.Experience`) to the replay buffer and
        make the iteration's gradient steps."""
        obs, valid = batch.observations, batch.valid
        t_idx, e_idx = np.nonzero(valid)
        following = np.minimum(t_idx + 1, valid.shape[0] - 1)
        done = batch.terminated[t_idx, e_idx] | batch.truncated[t_idx, e_idx]
        # The observation after a car's last step is never recorded (the car stops); its target is not
        # bootstrapped (terminated), so any placeholder works: use the same observation. A truncated
        # episode's final observation is not recorded either: SAC treats the cut as an end (time_up
        # only fires at the 100,000-step cap, so the bias this causes is negligible).
        next_t = np.where(done, t_idx, following)

        def pick(t: np.ndarray) -> Any:
            return {k: v[t, e_idx] for k, v in obs.items()} if isinstance(obs, Mapping) else obs[t, e_idx]
        self.observe(pick(t_idx), batch.actions[t_idx, e_idx], batch.rewards[t_idx, e_idx], pick(next_t), done)
        return self.update(self.gradient_steps_for(int(valid.sum())))

    def load_weights(self, state: Mapping[str, Any]) -> None:
        """Start from the network weights of ``state`` (a clone: fresh optimizers)."""
        if state.get("algorithm") != self.algorithm:
            raise ValueError(f"cannot start a {type(self).__name__} from a {state.get('algorithm')} checkpoint")
        for name in ("actor", "critic", "target_critic"):
            getattr(self, name).load_state_dict(state[name])

    def observe(self, observations: Any, actions: np.ndarray, rewards: np.ndarray,
                next_observations: Any, terminated: np.ndarray) -> None:
        """Add B transitions to the replay buffer (``next_observations`` of ended episodes must be
        their final observation, not the reset one)."""
        self.buffer.add(observations, actions, rewards, next_observations, terminated)

    def gradient_steps_for(self, num_new_steps: int) -> int:
        """Gradient steps of one iteration that collected ``num_new_steps`` env steps."""
        return self.hyperparameters.num_epochs * math.ceil(num_new_steps / self.hyperparameters.batch_size)

    def update(self, num_gradient_steps: int) -> dict[str, float]:
        """Make ``num_gradient_steps`` critic + actor steps (none while the buffer holds fewer
        than ``batch_size`` transitions). Returns means: critic_loss, actor_loss, q_mean,
        entropy (= -mean log pi), num_gradient_steps."""
        hp = self.hyperparameters
        if len(self.buffer) < hp.batch_size or num_gradient_steps <= 0:
            return {"critic_loss": float("nan"), "actor_loss": float("nan"), "q_mean": float("nan"),
                    "entropy": float("nan"), "num_gradient_steps": 0}
        totals = np.zeros(4)
        for _ in range(num_gradient_steps):
            totals += self._gradient_step(self.buffer.sample(hp.batch_size, self.rng))
        means = totals / num_gradient_steps
        return {"critic_loss": float(means[0]), "actor_loss": float(means[1]), "q_mean": float(means[2]),
                "entropy": float(means[3]), "num_gradient_steps": num_gradient_steps}

    def _gradient_step(self, batch: ReplayBatch) -> np.ndarray:
        hp, device = self.hyperparameters, self.device
        obs = observation_to_tensor(batch.observations, device)
        next_obs = observation_to_tensor(batch.next_observations, device)
        actions, rewards, terminated = (torch.as_tensor(x, device=device)
                                        for x in (batch.actions, batch.rewards, batch.terminated))
        with torch.no_grad():
            next_actions, next_log_probs = self.actor(next_obs)
            next_q1, next_q2 = self.target_critic(next_obs, next_actions)
            target = sac_critic_target(rewards, terminated, next_q1, next_q2, next_log_probs,
                                       hp.discount_factor, hp.sac_alpha)
        q1, q2 = self.critic(obs, actions)
        critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optimizer.step()

        new_actions, log_probs = self.actor(obs)
        self.critic.requires_grad_(False)  # the actor's loss must not train the critics
        actor_loss = sac_actor_loss(*self.critic(obs, new_actions), log_probs, hp.sac_alpha)
        self.critic.requires_grad_(True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_optimizer.step()

        with torch.no_grad():
            for target_param, param in zip(self.target_critic.parameters(), self.critic.parameters()):
                target_param.lerp_(param, TARGET_SMOOTHING)
        self.gradient_steps += 1
        return np.array([critic_loss.item(), actor_loss.item(), q1.mean().item(), -log_probs.mean().item()])

    def state_dict(self) -> dict[str, Any]:
        """Weights, optimizers and config (the replay buffer is not saved)."""
        return {"algorithm": "sac", "actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "target_critic": self.target_critic.state_dict(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict(),
                "gradient_steps": self.gradient_steps, "hyperparameters": self.hyperparameters.to_dict(),
                "network_name": self.network_name, "action_spec": asdict(self.action_spec)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from ``state_dict()``; the network and action space must match."""
        saved = (state.get("network_name"), state.get("action_spec"))
        if state.get("algorithm") != "sac" or saved != (self.network_name, asdict(self.action_spec)):
            raise ValueError(
                f"Checkpoint ({state.get('algorithm')}, network {saved[0]!r}, actions {saved[1]}) does "
                f"not match this SAC learner ({self.network_name!r}, {asdict(self.action_spec)})."
            )
        for name in ("actor", "critic", "target_critic", "actor_optimizer", "critic_optimizer"):
            getattr(self, name).load_state_dict(state[name])
        self.gradient_steps = int(state["gradient_steps"])
