"""Clipped PPO as DeepRacer trains it (rl_coach ``ClippedPPOAgent``, reference doc section 6).

One training iteration takes the experience of ``num_episodes_between_training`` episodes,
computes GAE advantages (lambda 0.95) and value targets, standardises the advantages, then makes
``num_epochs`` shuffled passes in minibatches of ``batch_size`` (the last one may be smaller),
minimising ``clipped surrogate (eps 0.2) + value loss (huber / MSE) - beta_entropy * entropy``
with Adam (eps 1e-5). Policy and value networks are separate, as in DeepRacer; no gradient
clipping.

Exploration while acting: ``categorical`` samples the policy; ``e-greedy`` takes a uniform
random action with probability epsilon (decaying linearly from 1 to ``e_greedy_value`` over
``epsilon_steps`` env steps) and otherwise the greedy action (discrete) or a policy sample
(continuous), as rl_coach's EGreedy does.
"""

from __future__ import annotations

import contextlib
from dataclasses import asdict
from typing import Any, Callable, ContextManager, Mapping, NamedTuple

import gymnasium as gym
import numpy as np
import torch

from laplab.agents.adam import FusedAdam
from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import (clipped_surrogate_loss, compute_gae, entropy_bonus,
                                  policy_change_stats, value_loss)
from laplab.agents.networks import (DEFAULT_NETWORK, ActionSpec, ActorCritic, PolicyStep,
                                    action_spec_from, has_convolutions, observation_to_tensor,
                                    set_compute_precision)
from laplab.agents.side_stream import RunOnSide, SideStream, run_now
from laplab.agents.torch_runtime import flush_denormals, limit_torch_threads
from laplab.env.observations import take_rows

CLIP_EPSILON = 0.2
GAE_LAMBDA = 0.95
ADAM_EPSILON = 1e-5
ADVANTAGE_EPSILON = 1e-8


class Rollout(NamedTuple):
    """The experience of one iteration, time-major: T steps of N environments (numpy arrays).

    - ``observations``: (T, N, *obs_shape), or a dict sensor -> (T, N, *sensor_shape).
    - ``actions``: (T, N) int64 indices, or (T, N, A) float32 as returned in ``PolicyStep.action``
      (unclipped samples).
    - ``log_probs``: (T, N) log pi(action | obs) of the acting policy.
    - ``values``: (T, N) V(obs) of the acting value network.
    - ``rewards``: (T, N) reward for the step.
    - ``terminated``: (T, N) bool, the episode ended with this step (off track, lap complete, ...);
      no bootstrapping, as DeepRacer treats every episode end.
    - ``truncated``: optional (T, N) bool, the episode was cut with this step (a step limit): its
      future is bootstrapped with ``bootstrap_values``.
    - ``bootstrap_values``: optional (T, N) V(final obs) where ``truncated`` (ignored elsewhere).
    - ``last_values``: optional (N,) V(obs after step T-1) for episodes still running at the end;
      None treats them as ended (train only on complete episodes, or mark the tail invalid).
    - ``valid``: optional (T, N) bool, the steps that take part in the update (None = all).
    """

    observations: Any
    actions: np.ndarray
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray | None = None
    bootstrap_values: np.ndarray | None = None
    last_values: np.ndarray | None = None
    valid: np.ndarray | None = None


def fold_truncation(rewards: np.ndarray, terminated: np.ndarray, truncated: np.ndarray | None,
                    bootstrap_values: np.ndarray | None, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Rewards and episode ends for GAE, all (T, N): a truncated (not terminated) step gets
    ``gamma * bootstrap_value`` added to its reward, and every terminated or truncated step ends
    its episode. -> (rewards float32, dones bool)."""
    rewards = np.asarray(rewards, dtype=np.float32)
    dones = np.asarray(terminated, dtype=bool)
    if truncated is None:
        return rewards, dones
    truncated = np.asarray(truncated, dtype=bool)
    if bootstrap_values is None:
        raise ValueError("A rollout with truncated steps needs bootstrap_values (V of their final obs).")
    bootstrap = np.where(truncated & ~dones, np.asarray(bootstrap_values, np.float32), 0.0)
    return (rewards + gamma * bootstrap).astype(np.float32), dones | truncated


def _flatten_time(observations: Any, rows: np.ndarray) -> Any:
    """(T, N, ...) -> (M, ...) for the selected flat ``rows`` (M,), dicts sensor-wise."""
    if isinstance(observations, Mapping):
        return {key: _flatten_time(value, rows) for key, value in observations.items()}
    array = np.asarray(observations)
    return array.reshape(-1, *array.shape[2:])[rows]


class PPOLearner:
    """DeepRacer's clipped PPO for a gymnasium observation space and a discrete or continuous
    action space (see ``action_spec_from``; continuous actions live in [-1, 1]^A).

    ``seed`` seeds torch's global RNG (network init, policy sampling) and this learner's numpy RNG
    (e-greedy draws, minibatch shuffling).
    """

    algorithm = "clipped_ppo"

    def __init__(self, observation_space: gym.spaces.Space, action_space_spec: Any,
                 hyperparameters: Hyperparameters = Hyperparameters(),
                 network_name: str = DEFAULT_NETWORK, device: str = "cpu",
                 seed: int | None = None, num_threads: int | None = None, precision: str = "float32"):
        limit_torch_threads(num_threads)
        flush_denormals()  # before any torch work: the threads torch starts inherit it
        if seed is not None:
            torch.manual_seed(seed)
        self.hyperparameters = hyperparameters
        self.network_name = network_name
        self.action_spec: ActionSpec = action_spec_from(action_space_spec)
        self.device = torch.device(device)
        self.model = ActorCritic(observation_space, self.action_spec, network_name).to(self.device)
        self.precision = set_compute_precision(self.model, precision)  # "auto": bfloat16 camera trunks where native
        # torch.optim.Adam(fused=True)'s update and state dicts, without its torch._dynamo import (laplab.agents.adam)
        self.optimizer = FusedAdam(self.model.parameters(), lr=hyperparameters.lr, eps=ADAM_EPSILON)
        self.rng = np.random.default_rng(seed)
        self.env_steps = 0  # environment steps acted with exploration (drives epsilon)
        self.iterations = 0
        self._split_step = self.model.value_trunk is not None and has_convolutions(self.model)
        self._value_stream = SideStream("laplab-ppo-value")

    @property
    def epsilon(self) -> float:
        """The current e-greedy epsilon (only used when ``exploration_type == "e-greedy"``)."""
        return self.hyperparameters.epsilon_at(self.env_steps)

    @torch.no_grad()
    def act(self, observations: Any, deterministic: bool = False, with_value: bool | None = None) -> PolicyStep:
        """Actions for a batch of B observations (numpy, leading axis B) -> ``PolicyStep`` of
        numpy arrays. Exploring calls advance the epsilon schedule by B steps. ``with_value=False``
        skips the value network (the step's values are then NaN); by default greedy calls skip it."""
        if with_value is None:
            with_value = not deterministic
        obs = observation_to_tensor(observations, self.device)
        if with_value:
            distribution, value = self.model(obs)
        else:
            distribution = self.model.distribution(obs)
            value = torch.full(distribution.batch_shape, float("nan"), device=self.device)
        greedy = distribution.probs.argmax(-1) if self.action_spec.discrete else distribution.mean
        if deterministic:
            action = greedy
        else:
            action = distribution.sample()
            if self.hyperparameters.exploration_type == "e-greedy":
                action = self._epsilon_greedy(action, greedy)
            self.env_steps += int(value.shape[0])
        env_action = action if self.action_spec.discrete else action.clamp(-1.0, 1.0)
        log_prob = distribution.log_prob(action)
        return PolicyStep(*(tensor.cpu().numpy() for tensor in (action, env_action, log_prob, value)))

    def _epsilon_greedy(self, sampled: torch.Tensor, greedy: torch.Tensor) -> torch.Tensor:
        """With probability epsilon a uniform random action, else greedy (discrete) or the
        policy sample (continuous)."""
        batch = sampled.shape[0]
        explore = torch.as_tensor(self.rng.random(batch) < self.epsilon, device=self.device)
        if self.action_spec.discrete:
            random = torch.as_tensor(self.rng.integers(0, self.action_spec.size, batch), device=self.device)
            return torch.where(explore, random, greedy)
        random = torch.as_tensor(self.rng.uniform(-1.0, 1.0, (batch, self.action_spec.size)),
                                 dtype=sampled.dtype, device=self.device)
        return torch.where(explore[:, None], random, sampled)

    @torch.no_grad()
    def values(self, observations: Any) -> np.ndarray:
        """V(obs) (B,) for a batch of observations, e.g. ``Rollout.last_values``."""
        return self.model.value(observation_to_tensor(observations, self.device)).cpu().numpy()

    @property
    def policy_network(self) -> ActorCritic:
        return self.model

    def learn(self, batch: Any, should_stop: Callable[[], bool] | None = None,
              on_progress: Callable[[int, int], None] | None = None) -> dict[str, float]:
        """One training iteration on complete episodes (a :class:`laplab.agents.learner.Experience`);
        ``should_stop`` and ``on_progress`` as in :meth:`update`."""
        return self.update(Rollout(batch.observations, batch.actions, batch.log_probs, batch.values, batch.rewards,
                                   batch.terminated, batch.truncated, batch.bootstrap_values, None, batch.valid),
                           should_stop, on_progress)

    def load_weights(self, state: Mapping[str, Any]) -> None:
        """Start from the network weights of ``state`` (a clone: fresh optimizer and schedules)."""
        if state.get("algorithm") != self.algorithm:
            raise ValueError(f"cannot start a {type(self).__name__} from a {state.get('algorithm')} checkpoint")
        self.model.load_state_dict(state["model"])

    def update(self, rollout: Rollout, should_stop: Callable[[], bool] | None = None,
               on_progress: Callable[[int, int], None] | None = None) -> dict[str, float]:
        """One DeepRacer training iteration on ``rollout``. Returns means over all minibatches:
        policy_loss, value_loss, entropy, approx_kl, clip_fraction; plus explained_variance,
        num_steps, num_minibatches, epsilon. ``should_stop()`` is polled before each minibatch (True
        ends the iteration early, after a whole minibatch step); ``on_progress(done, total)`` is
        called after each minibatch."""
        hp = self.hyperparameters
        rewards, dones = fold_truncation(rollout.rewards, rollout.terminated, rollout.truncated,
                                         rollout.bootstrap_values, hp.discount_factor)
        values = np.asarray(rollout.values, dtype=np.float32)
        steps, envs = values.shape
        for name in ("log_probs", "rewards", "terminated", "truncated", "valid"):
            field = getattr(rollout, name)
            if field is not None and np.shape(field) != (steps, envs):
                raise ValueError(f"Rollout.{name} has shape {np.shape(field)}; expected (T, N) = {(steps, envs)} "
                                 "like Rollout.values.")
        last = np.zeros(envs, np.float32) if rollout.last_values is None else rollout.last_values
        advantages, returns = compute_gae(torch.as_tensor(rewards), torch.as_tensor(values),
                                          torch.as_tensor(dones), torch.as_tensor(last, dtype=torch.float32),
                                          hp.discount_factor, GAE_LAMBDA)
        valid = np.ones((steps, envs), bool) if rollout.valid is None else np.asarray(rollout.valid, bool)
        rows = np.flatnonzero(valid.reshape(-1))
        if rows.size == 0:
            raise ValueError("PPO update got a rollout with no valid steps.")
        advantages = advantages.reshape(-1)[torch.as_tensor(rows)]
        advantages = (advantages - advantages.mean()) / (advantages.std(unbiased=False) + ADVANTAGE_EPSILON)
        returns = returns.reshape(-1)[torch.as_tensor(rows)]
        observations = _flatten_time(rollout.observations, rows)
        actions = np.asarray(rollout.actions)
        actions = actions.reshape(steps * envs, *actions.shape[2:])[rows]
        old_log_probs = torch.as_tensor(np.asarray(rollout.log_probs, np.float32).reshape(-1)[rows])
        old_values = values.reshape(-1)[rows]

        totals = np.zeros(5)
        minibatches = 0
        total = hp.num_epochs * -(-rows.size // hp.batch_size)
        stopped = False
        self.model.train()
        with self.value_stream() as value_side:
            for _ in range(hp.num_epochs):
                if stopped:
                    break
                order = self.rng.permutation(rows.size)
                for start in range(0, rows.size, hp.batch_size):
                    if should_stop is not None and should_stop():
                        stopped = True
                        break
                    index = order[start:start + hp.batch_size]
                    totals += self._minibatch_step(take_rows(observations, index), actions[index], old_log_probs[index],
                                                   advantages[index], returns[index], value_side)
                    minibatches += 1
                    if on_progress is not None:
                        on_progress(minibatches, total)
        self.iterations += 1
        means = totals / max(minibatches, 1) if minibatches else np.full(5, np.nan)
        return_variance = float(np.var(returns.numpy()))
        explained = 1.0 - float(np.var(returns.numpy() - old_values)) / return_variance if return_variance > 0 else 0.0
        return {"policy_loss": float(means[0]), "value_loss": float(means[1]), "entropy": float(means[2]),
                "approx_kl": float(means[3]), "clip_fraction": float(means[4]), "explained_variance": explained,
                "num_steps": int(rows.size), "num_minibatches": minibatches, "epsilon": self.epsilon}

    def value_stream(self) -> ContextManager[RunOnSide]:
        """Where a minibatch step's value half runs: a second thread with half of torch's threads when
        the value network has its own camera trunk on the CPU and there are two or more threads (the
        halves share no parameter; :mod:`laplab.agents.side_stream`), else at once on this thread."""
        if not self._split_step or self.device.type != "cpu":
            return contextlib.nullcontext(run_now)
        return self._value_stream.open()

    def _minibatch_step(self, observations: Any, actions: np.ndarray, old_log_probs: torch.Tensor,
                        advantages: torch.Tensor, returns: torch.Tensor,
                        value_side: RunOnSide = run_now) -> np.ndarray:
        """One Adam step on the minibatch's loss: clipped surrogate + value loss + entropy bonus. With
        a camera trunk of its own, ``value_side`` runs the value network's forward and backward pass
        (the gradient of the summed loss splits exactly between the two networks)."""
        device, hp = self.device, self.hyperparameters
        obs = observation_to_tensor(observations, device)
        action_tensor = torch.as_tensor(actions, device=device)
        action_tensor = action_tensor.long() if self.action_spec.discrete else action_tensor.float()
        old_log_probs, advantages, returns = (x.to(device) for x in (old_log_probs, advantages, returns))
        self.optimizer.zero_grad(set_to_none=True)
        if not self._split_step:  # one graph (vector networks: too small for two streams to pay)
            log_probs, entropy, predicted = self.model.evaluate(obs, action_tensor)
            policy_loss = clipped_surrogate_loss(log_probs, old_log_probs, advantages, CLIP_EPSILON)
            critic_loss = value_loss(predicted, returns, hp.loss_type)
            (policy_loss + critic_loss + entropy_bonus(entropy, hp.beta_entropy)).backward()
        else:
            def value_half() -> torch.Tensor:
                loss = value_loss(self.model.value(obs), returns, hp.loss_type)
                loss.backward()
                return loss.detach()

            value_done = value_side(value_half)
            log_probs, entropy = self.model.evaluate_policy(obs, action_tensor)
            policy_loss = clipped_surrogate_loss(log_probs, old_log_probs, advantages, CLIP_EPSILON)
            (policy_loss + entropy_bonus(entropy, hp.beta_entropy)).backward()
            critic_loss = value_done.result()
        with value_side.all_threads():  # both halves joined: the fused Adam step on every thread
            self.optimizer.step()
        approx_kl, clip_fraction = policy_change_stats(log_probs, old_log_probs, CLIP_EPSILON)
        return np.array([policy_loss.item(), critic_loss.item(), entropy.mean().item(), approx_kl, clip_fraction])

    def weights_state(self) -> dict[str, Any]:
        """Weights, schedules and config without the optimizer (checkpoints other than the last, exports)."""
        return {"algorithm": "clipped_ppo", "model": self.model.state_dict(), "env_steps": self.env_steps,
                "iterations": self.iterations, "hyperparameters": self.hyperparameters.to_dict(),
                "network_name": self.network_name, "action_spec": asdict(self.action_spec)}

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume: weights, optimizer, schedules and the full config."""
        return {**self.weights_state(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from ``state_dict()`` (or ``weights_state()``); the network and action space must match."""
        saved = (state.get("network_name"), state.get("action_spec"))
        if state.get("algorithm") != "clipped_ppo" or saved != (self.network_name, asdict(self.action_spec)):
            raise ValueError(
                f"Checkpoint is a {state.get('algorithm')} model for network {saved[0]!r} with actions "
                f"{saved[1]}, but this clipped_ppo learner "
                f"uses {self.network_name!r} with {asdict(self.action_spec)}; a model's action space "
                "and network cannot change."
            )
        self.model.load_state_dict(state["model"])
        if "optimizer" in state:  # a weights-only state (an export) resumes with a fresh optimizer
            self.optimizer.load_state_dict(state["optimizer"])
        self.env_steps = int(state["env_steps"])
        self.iterations = int(state["iterations"])
