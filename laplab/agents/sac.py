"""Soft Actor-Critic for DeepRacer's continuous action space (``training_algorithm: sac``).

A squashed-Gaussian policy in (-1, 1)^A, twin Q networks with Polyak-averaged targets and a
fixed entropy temperature ``sac_alpha`` (DeepRacer does not tune it). Gamma is
``discount_factor``, both optimizers use ``lr``; an iteration makes
``num_epochs * ceil(new_steps / batch_size)`` gradient steps on uniform replay samples,
mirroring PPO's passes over the new experience.

A gradient step runs the critic's half (its trunk passes, backward, optimizer step and target
update) on a second thread while the calling thread runs the actor's half, each with half of
torch's intra-op threads: two independent streams of work keep two cores busy better than two
threads meeting at the end of every operation, most of all on a shared machine.
"""

from __future__ import annotations

import contextlib
import copy
import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict
from typing import Any, Callable, Iterator, Mapping, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import sac_actor_loss, sac_critic_target
from laplab.agents.networks import (DEFAULT_NETWORK, ActionSpec, PolicyStep, SquashedGaussianActor,
                                    TwinQ, action_spec_from, observation_to_tensor, set_compute_precision,
                                    twin_q_from_separate)
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


class SACLearner:
    """DeepRacer's SAC: ``act`` -> actions in [-1, 1]^A, ``observe`` transitions, ``update``.

    ``seed`` seeds torch's global RNG and this learner's numpy RNG (replay sampling).
    ``buffer_capacity`` counts replay slots (one frame each). ``num_threads``: torch threads (see
    :func:`limit_torch_threads`); with two or more, a gradient step's critic half takes half of them.
    """

    algorithm = "sac"
    WEIGHTS = ("actor", "critic")  # what a weights-only checkpoint holds (the target is rebuilt from the critic)

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
        self._head_parameters = [*self.critic.q1.parameters(), *self.critic.q2.parameters()]
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=hyperparameters.lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=hyperparameters.lr, fused=True)
        self.buffer = ReplayBuffer(buffer_capacity, observation_space, dim)
        self.rng = np.random.default_rng(seed)
        self.gradient_steps = 0
        self._side_thread: tuple[int, ThreadPoolExecutor] | None = None  # (process id, pool of one thread)

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

    def learn(self, batch: Any, should_stop: Callable[[], bool] | None = None,
              on_progress: Callable[[int, int], None] | None = None) -> dict[str, float]:
        """Add complete episodes (a :class:`laplab.agents.learner.Experience`) to the replay buffer and
        make the iteration's gradient steps (see :meth:`update` for ``should_stop`` and ``on_progress``).

        Each episode's frames go in once: the observation after step t is step t + 1's. The observation
        after a car's last step is never recorded (the car stops); its target is not bootstrapped, so
        none is needed. A truncated episode's final observation is not recorded either: SAC treats the
        cut as an end (time_up only fires at the 100,000-step cap, so the bias is negligible)."""
        obs, valid = batch.observations, batch.valid
        ended = batch.terminated | batch.truncated
        for car in range(valid.shape[1]):
            steps = np.flatnonzero(valid[:, car])
            if steps.size == 0:
                continue
            frames = {k: v[steps, car] for k, v in obs.items()} if isinstance(obs, Mapping) else obs[steps, car]
            self.buffer.add_episode(frames, batch.actions[steps, car], batch.rewards[steps, car], ended[steps, car])
        return self.update(self.gradient_steps_for(int(valid.sum())), should_stop, on_progress)

    def observe(self, observations: Any, actions: np.ndarray, rewards: np.ndarray,
                next_observations: Any, terminated: np.ndarray) -> None:
        """Add B independent transitions to the replay buffer (``next_observations`` of ended episodes
        must be their final observation, not the reset one)."""
        self.buffer.add(observations, actions, rewards, next_observations, terminated)

    def gradient_steps_for(self, num_new_steps: int) -> int:
        """Gradient steps of one iteration that collected ``num_new_steps`` env steps."""
        return self.hyperparameters.num_epochs * math.ceil(num_new_steps / self.hyperparameters.batch_size)

    def update(self, num_gradient_steps: int, should_stop: Callable[[], bool] | None = None,
               on_progress: Callable[[int, int], None] | None = None) -> dict[str, float]:
        """Make up to ``num_gradient_steps`` critic + actor steps (none while the buffer holds fewer
        than ``batch_size`` transitions). ``should_stop()`` is polled before each step (True ends the
        update early: the networks stay consistent, as after any whole step); ``on_progress(done, total)``
        is called after each. Returns means: critic_loss, actor_loss, q_mean, entropy (= -mean log pi),
        and num_gradient_steps made."""
        hp = self.hyperparameters
        nan = {"critic_loss": float("nan"), "actor_loss": float("nan"), "q_mean": float("nan"),
               "entropy": float("nan"), "num_gradient_steps": 0}
        if len(self.buffer) < hp.batch_size or num_gradient_steps <= 0:
            return nan
        totals = torch.zeros(4, dtype=torch.float64)
        done = 0
        with self._critic_stream() as critic_side:
            for _ in range(num_gradient_steps):
                if should_stop is not None and should_stop():
                    break
                totals += self._gradient_step(self.buffer.sample(hp.batch_size, self.rng), critic_side)
                done += 1
                if on_progress is not None:
                    on_progress(done, num_gradient_steps)
        if done == 0:
            return nan
        means = (totals / done).tolist()
        return {"critic_loss": means[0], "actor_loss": means[1], "q_mean": means[2], "entropy": means[3],
                "num_gradient_steps": done}

    @contextlib.contextmanager
    def _critic_stream(self) -> Iterator[Callable[[Callable[[], Any]], Future]]:
        """A ``run(fn) -> Future`` for the critic's half of the steps made inside: with two or more
        torch threads, ``fn`` runs on this learner's second thread with half of them (the caller
        keeps the rest, and gets its thread count back on leaving); with one, it runs at once."""
        threads = torch.get_num_threads()
        if threads < 2:
            yield _run_now
            return
        side_threads = threads // 2
        if self._side_thread is None or self._side_thread[0] != os.getpid():  # a forked child has no thread
            self._side_thread = (os.getpid(), ThreadPoolExecutor(1, thread_name_prefix="laplab-sac-critic"))
        pool = self._side_thread[1]

        def on_side(fn: Callable[[], Any]) -> Any:
            if torch.get_num_threads() != side_threads:  # a thread's own count (OpenMP), set once
                torch.set_num_threads(side_threads)
            return fn()

        torch.set_num_threads(threads - side_threads)
        try:
            yield lambda fn: pool.submit(on_side, fn)
        finally:
            pool.submit(lambda: None).result()  # after a failure, nothing of this update still runs
            torch.set_num_threads(threads)

    def _gradient_step(self, batch: ReplayBatch, critic_side: Callable[[Callable[[], Any]], Future]) -> torch.Tensor:
        """One step of both networks on one minibatch: the critic towards the soft Bellman target of
        the target critic, the actor against the critic as it was before this step (rl_coach's order);
        then the target critic moves ``TARGET_SMOOTHING`` of the way (in place). The critic's trunk
        runs once for both Q heads and both losses. ``critic_side`` runs the critic's trunk passes,
        backward pass and updates alongside the actor's (the two graphs share no parameter)."""
        hp, device = self.hyperparameters, self.device
        obs = observation_to_tensor(batch.observations, device)
        next_obs = observation_to_tensor(batch.next_observations, device)
        actions, rewards, terminated = (torch.as_tensor(x, device=device)
                                        for x in (batch.actions, batch.rewards, batch.terminated))

        def critic_trunks() -> tuple[torch.Tensor, torch.Tensor]:
            with torch.no_grad():  # grad mode is per thread
                next_features = self.target_critic.trunk(next_obs)
            return next_features, self.critic.trunk(obs)

        trunks = critic_side(critic_trunks)
        with torch.no_grad():
            next_actions, next_log_probs = self.actor(next_obs)
        new_actions, log_probs = self.actor(obs)
        next_features, features = trunks.result()
        with torch.no_grad():
            target = sac_critic_target(rewards, terminated, *self.target_critic.heads(next_features, next_actions),
                                       next_log_probs, hp.discount_factor, hp.sac_alpha)
        q1, q2 = self.critic.heads(features, actions)
        critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        for parameter in self._head_parameters:  # the actor's loss must not train the critic
            parameter.requires_grad_(False)
        actor_loss = sac_actor_loss(*self.critic.heads(features.detach(), new_actions), log_probs, hp.sac_alpha)
        for parameter in self._head_parameters:
            parameter.requires_grad_(True)

        self.critic_optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        critic_backward = critic_side(critic_loss.backward)
        actor_loss.backward()
        # after the actor's backward, which needs the critic's heads as they were; in order after
        # the critic's backward, and not at all if that failed
        critic_update = critic_side(lambda: (critic_backward.result(), self._critic_update()))
        self.actor_optimizer.step()
        critic_update.result()
        self.gradient_steps += 1
        return torch.stack([critic_loss.detach(), actor_loss.detach(), q1.detach().mean(),
                            -log_probs.detach().mean()]).double()

    def _critic_update(self) -> None:
        self.critic_optimizer.step()
        with torch.no_grad():
            torch._foreach_lerp_(list(self.target_critic.parameters()), list(self.critic.parameters()),
                                 TARGET_SMOOTHING)

    def _config(self) -> dict[str, Any]:
        return {"algorithm": "sac", "gradient_steps": self.gradient_steps,
                "hyperparameters": self.hyperparameters.to_dict(), "network_name": self.network_name,
                "action_spec": asdict(self.action_spec)}

    def weights_state(self) -> dict[str, Any]:
        """The networks' weights and config, no optimizer or target (a checkpoint other than the last,
        an export): what evaluation, export and clones need."""
        return {**self._config(), "actor": self.actor.state_dict(), "critic": self.critic.state_dict()}

    def state_dict(self) -> dict[str, Any]:
        """Everything to resume: weights, target critic, optimizers and config (the replay buffer is
        not saved)."""
        return {**self.weights_state(), "target_critic": self.target_critic.state_dict(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict()}

    def load_weights(self, state: Mapping[str, Any]) -> None:
        """Start from the network weights of ``state`` (a clone: fresh optimizers; the target critic
        starts as a copy of the critic)."""
        if state.get("algorithm") != self.algorithm:
            raise ValueError(f"cannot start a {type(self).__name__} from a {state.get('algorithm')} checkpoint")
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(twin_q_from_separate(state["critic"]))
        self.target_critic.load_state_dict(self.critic.state_dict())

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from ``state_dict()`` (or ``weights_state()``: fresh optimizers, the target critic
        a copy of the critic); the network and action space must match."""
        saved = (state.get("network_name"), state.get("action_spec"))
        if state.get("algorithm") != "sac" or saved != (self.network_name, asdict(self.action_spec)):
            raise ValueError(
                f"Checkpoint ({state.get('algorithm')}, network {saved[0]!r}, actions {saved[1]}) does "
                f"not match this SAC learner ({self.network_name!r}, {asdict(self.action_spec)})."
            )
        self.load_weights(state)
        if "target_critic" in state:
            self.target_critic.load_state_dict(twin_q_from_separate(state["target_critic"]))
        if "actor_optimizer" in state and "critic_optimizer" in state and not _separate_layout(state):
            self.actor_optimizer.load_state_dict(state["actor_optimizer"])
            self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.gradient_steps = int(state.get("gradient_steps", 0))


def _run_now(fn: Callable[[], Any]) -> Future:
    """``fn()`` run at once, as a finished ``Future``."""
    future: Future = Future()
    try:
        future.set_result(fn())
    except BaseException as error:  # noqa: BLE001 - handed to whoever reads the result
        future.set_exception(error)
    return future


def _separate_layout(state: Mapping[str, Any]) -> bool:
    """Whether ``state`` comes from laplab's older twin-Q layout (a trunk per Q head), whose critic
    optimizer state fits no longer."""
    return any(key.startswith("q1.trunk.") for key in state.get("critic", {}))
