"""SAC's replay buffer: a ring of observations in preallocated numpy arrays, each frame stored once."""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np


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
    """A fixed-capacity ring of observations in preallocated numpy arrays (observation dtypes kept,
    so camera frames stay uint8), each frame stored once.

    Slot ``i`` holds an observation; when it starts a transition (``starts[i]``) it also holds that
    transition's action, reward and end flag, and its next observation is in slot ``i + 1`` (mod
    capacity) unless the transition ended its episode (then the next observation is never used:
    the target is not bootstrapped). Episodes are written in order, so a slot is always overwritten
    before the slot after it and a transition never points at a newer frame. Capacity counts slots.
    """

    def __init__(self, capacity: int, observation_space: gym.spaces.Space, action_dim: int):
        if capacity < 2:
            raise ValueError(f"Replay buffer capacity must be >= 2, got {capacity}.")
        self.capacity = int(capacity)
        self.is_dict = isinstance(observation_space, gym.spaces.Dict)
        spaces = dict(observation_space.spaces) if self.is_dict else {"": observation_space}
        self.observations = {k: np.zeros((capacity, *s.shape), s.dtype) for k, s in spaces.items()}
        self.actions = np.zeros((capacity, action_dim), np.float32)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.float32)
        self.starts = np.zeros(capacity, bool)  # the slot starts a transition
        self.has_next = np.zeros(capacity, bool)  # its next observation is in the following slot
        self.position = 0
        self.filled = 0  # slots written
        self._start_slots: np.ndarray | None = None

    def __len__(self) -> int:
        """Transitions held."""
        return int(self.starts.sum()) if self._start_slots is None else len(self._start_slots)

    def _write(self, observations: Any, count: int) -> np.ndarray:
        slots = (self.position + np.arange(count)) % self.capacity
        obs = observations if self.is_dict else {"": observations}
        for key, array in self.observations.items():
            array[slots] = obs[key]
        self.starts[slots] = False
        self.has_next[slots] = False
        self.position = int((self.position + count) % self.capacity)
        self.filled = min(self.filled + count, self.capacity)
        self._start_slots = None
        return slots

    def add_episode(self, observations: Any, actions: np.ndarray, rewards: np.ndarray, ended: np.ndarray) -> None:
        """One episode's L steps in order: observations (L, ...) (a dict sensor-wise), actions (L, A),
        rewards (L,), ended (L,) (1 where the step ended the episode; the observation after step t is
        observation t + 1 otherwise)."""
        ended = np.asarray(ended, np.float32).reshape(-1)
        count = ended.shape[0]
        if count == 0:
            return
        if count > self.capacity - 1:
            raise ValueError(f"an episode of {count} steps does not fit a replay buffer of {self.capacity} slots")
        slots = self._write(observations, count)
        self.actions[slots] = np.asarray(actions, np.float32).reshape(count, -1)
        self.rewards[slots] = np.asarray(rewards, np.float32).reshape(-1)
        self.terminated[slots] = ended
        self.starts[slots] = True
        self.has_next[slots] = ended == 0
        if ended[-1] == 0:  # a cut-off tail: its next frame is missing, so it is no transition
            self.starts[slots[-1]] = False

    def add(self, observations: Any, actions: np.ndarray, rewards: np.ndarray,
            next_observations: Any, terminated: np.ndarray) -> None:
        """Store B independent transitions (arrays with leading axis B; dict observations sensor-wise):
        each takes two slots, its observation and its next observation."""
        rewards = np.asarray(rewards, np.float32).reshape(-1)
        batch = rewards.shape[0]
        if 2 * batch > self.capacity:
            raise ValueError(f"{batch} transitions do not fit a replay buffer of {self.capacity} slots")
        pick = lambda o, k: {key: np.asarray(v)[k] for key, v in o.items()} if self.is_dict else np.asarray(o)[k]
        actions = np.asarray(actions, np.float32).reshape(batch, -1)
        terminated = np.asarray(terminated, np.float32).reshape(-1)
        for k in range(batch):
            first = self._write(_expand(pick(observations, k), self.is_dict), 1)
            self._write(_expand(pick(next_observations, k), self.is_dict), 1)
            self.actions[first] = actions[k]
            self.rewards[first] = rewards[k]
            self.terminated[first] = terminated[k]
            self.starts[first] = True
            self.has_next[first] = True

    def sample(self, batch_size: int, rng: np.random.Generator) -> ReplayBatch:
        """B transitions drawn uniformly with replacement."""
        if self._start_slots is None:
            self._start_slots = np.flatnonzero(self.starts)
        index = self._start_slots[rng.integers(0, len(self._start_slots), batch_size)]
        following = np.where(self.has_next[index], (index + 1) % self.capacity, index)
        obs = {key: value[index] for key, value in self.observations.items()}
        next_obs = {key: value[following] for key, value in self.observations.items()}
        if not self.is_dict:
            obs, next_obs = obs[""], next_obs[""]
        return ReplayBatch(obs, self.actions[index], self.rewards[index], next_obs, self.terminated[index])


def _expand(observation: Any, is_dict: bool) -> Any:
    """One observation -> a batch of one."""
    if is_dict:
        return {key: np.asarray(value)[None] for key, value in observation.items()}
    return np.asarray(observation)[None]
