"""Soft Actor-Critic for DeepRacer's continuous action space (``training_algorithm: sac``).

A squashed-Gaussian policy in (-1, 1)^A, twin Q networks and a fixed entropy temperature
``sac_alpha`` (DeepRacer does not tune it). Gamma is ``discount_factor``, both optimizers use
``lr``; an iteration makes ``num_epochs * ceil(new_steps / batch_size)`` gradient steps on uniform
replay samples, mirroring PPO's passes over the new experience. The target critic is a copy of the
critic taken as each iteration's learning starts and held through it, as DeepRacer's rl_coach
settings make it (``rate_for_copying_weights_to_target`` 1, copied once per training call).

Camera models share one trunk (laplab's choice, docs/deviations.md): the actor's heads read the
critic's trunk features, detached, as in SAC from pixels (SAC-AE, DrQ), so the convolutions learn from
the critic's loss alone and a gradient step runs one trunk backward pass instead of two. The policy
keeps DeepRacer's shape (trunk, then the mean and log-std heads): the car and the exports see the same
network. Vector models (STATE, lidar) keep separate actor and critic trunks, as rl_coach builds them.

With separate trunks and two or more torch threads, a gradient step runs the critic's half (its
trunk passes, backward, optimizer step) on a second thread while the calling thread runs the actor's
half (:mod:`laplab.agents.side_stream`).
"""

from __future__ import annotations

import contextlib
import copy
import math
from dataclasses import asdict
from typing import Any, Callable, Mapping

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

from laplab.agents.adam import FusedAdam
from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import sac_actor_loss, sac_critic_target
from laplab.agents.networks import (DEFAULT_NETWORK, ActionSpec, PolicyStep, action_spec_from, has_convolutions,
                                    observation_to_tensor, set_compute_precision)
from laplab.agents.replay import ReplayBatch, ReplayBuffer
from laplab.agents.sac_networks import SquashedGaussianActor, TwinQ, twin_q_from_separate
from laplab.agents.side_stream import RunOnSide, SideStream, run_now
from laplab.agents.torch_runtime import flush_denormals, limit_torch_threads


class SACLearner:
    """DeepRacer's SAC: ``act`` -> actions in [-1, 1]^A, ``observe`` transitions, ``update``.

    ``seed`` seeds torch's global RNG and this learner's numpy RNG (replay sampling).
    ``buffer_capacity`` counts replay slots (one frame each). ``num_threads``: torch threads (see
    :func:`limit_torch_threads`); with two or more and separate trunks, a gradient step's critic half
    takes half of them. ``shared_trunk``: the actor on the critic's trunk (default: camera models);
    a loaded checkpoint's own layout wins over it. ``action_scale`` (A,): half of each action's range
    in the model's units (steering degrees, m/s); with it the entropy term uses DeepRacer's
    log-probability (:func:`laplab.agents.sac_networks.deepracer_squashed_log_prob`), which a training
    job always gives. ``policy_head_layers``: the policy head's relu layers before its mean and log-std
    (the model spec's: () laplab's, (256,) deepracer-simapp's, see :class:`SquashedGaussianActor`).
    """

    algorithm = "sac"
    WEIGHTS = ("actor", "critic")  # what a weights-only checkpoint holds (the target is rebuilt from the critic)

    def __init__(self, observation_space: gym.spaces.Space, action_space_spec: Any,
                 hyperparameters: Hyperparameters = Hyperparameters(),
                 network_name: str = DEFAULT_NETWORK, device: str = "cpu",
                 buffer_capacity: int = 100_000, seed: int | None = None,
                 num_threads: int | None = None, precision: str = "float32", shared_trunk: bool | None = None,
                 action_scale: Any = None, policy_head_layers: tuple[int, ...] = ()):
        limit_torch_threads(num_threads)
        flush_denormals()  # before any torch work: the threads torch starts inherit it
        if seed is not None:
            torch.manual_seed(seed)
        self.action_spec: ActionSpec = action_spec_from(action_space_spec)
        if self.action_spec.discrete:
            raise ValueError("SAC needs a continuous action space (action_space_type 'continuous').")
        self.hyperparameters = hyperparameters
        self.network_name = network_name
        self.device = torch.device(device)
        dim = self.action_spec.size
        self.actor = SquashedGaussianActor(observation_space, dim, network_name, action_scale,
                                           policy_head_layers).to(self.device)
        self.critic = TwinQ(observation_space, dim, network_name).to(self.device)
        self.precision = set_compute_precision(self.actor, precision)
        set_compute_precision(self.critic, self.precision)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.shared_trunk = False
        self._share_trunk(has_convolutions(self.critic.trunk) if shared_trunk is None else shared_trunk)
        self.critic_optimizer = FusedAdam(self.critic.parameters(), lr=hyperparameters.lr)
        self.buffer = ReplayBuffer(buffer_capacity, observation_space, dim)
        self.rng = np.random.default_rng(seed)
        self.gradient_steps = 0
        self._critic_stream = SideStream("laplab-sac-critic")

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
        with torch.no_grad():  # the iteration's target: the critic as learning starts (in place)
            torch._foreach_copy_(list(self.target_critic.parameters()), list(self.critic.parameters()))
        totals = torch.zeros(4, dtype=torch.float64, device=self.device)  # on the GPU too: no sync per step
        done = 0
        two_streams = not self.shared_trunk and self.device.type == "cpu"
        with (self._critic_stream.open() if two_streams else contextlib.nullcontext(run_now)) as side:
            for _ in range(num_gradient_steps):
                if should_stop is not None and should_stop():
                    break
                batch = self.buffer.sample(hp.batch_size, self.rng)
                totals += (self._shared_gradient_step(batch) if self.shared_trunk
                           else self._gradient_step(batch, side))
                done += 1
                if on_progress is not None:
                    on_progress(done, num_gradient_steps)
        if done == 0:
            return nan
        means = (totals / done).tolist()
        return {"critic_loss": means[0], "actor_loss": means[1], "q_mean": means[2], "entropy": means[3],
                "num_gradient_steps": done}

    def _gradient_step(self, batch: ReplayBatch, critic_side: RunOnSide) -> torch.Tensor:
        """One step of both networks on one minibatch: the critic towards the soft Bellman target of
        the target critic, the actor against the critic as it was before this step (rl_coach's order).
        The critic's trunk runs once for both Q heads and both losses. ``critic_side`` runs the
        critic's trunk passes, backward pass and updates alongside the actor's (the two graphs share
        no parameter)."""
        hp = self.hyperparameters
        obs, next_obs, actions, rewards, terminated = self._tensors(batch)

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
        actor_loss = self._actor_loss(features.detach(), new_actions, log_probs)

        self.critic_optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        critic_backward = critic_side(critic_loss.backward)
        actor_loss.backward()
        # after the actor's backward, which needs the critic's heads as they were; in order after
        # the critic's backward, and not at all if that failed
        critic_update = critic_side(lambda: (critic_backward.result(), self.critic_optimizer.step()))
        self.actor_optimizer.step()
        critic_update.result()
        self.gradient_steps += 1
        return _step_stats(critic_loss, actor_loss, q1, log_probs)

    def _shared_gradient_step(self, batch: ReplayBatch) -> torch.Tensor:
        """One step on one minibatch with the actor on the critic's trunk: the critic (trunk and
        heads) towards the soft Bellman target, the actor's heads on the trunk's features detached,
        against the critic's heads as they were before this step. The trunk runs forward three times
        (the minibatch with gradients, the next observations for the next actions and, as the target,
        for their values) and backward once, on one stream with all of torch's threads (splitting
        the minibatch between two threads learned more slowly: BENCHMARKS.md, session 13)."""
        hp = self.hyperparameters
        obs, next_obs, actions, rewards, terminated = self._tensors(batch)
        with torch.no_grad():
            next_actions, next_log_probs = self.actor(next_obs)
            target = sac_critic_target(rewards, terminated, *self.target_critic(next_obs, next_actions),
                                       next_log_probs, hp.discount_factor, hp.sac_alpha)
        features = self.critic.trunk(obs)
        q1, q2 = self.critic.heads(features, actions)
        critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        detached = features.detach()
        new_actions, log_probs = self.actor.from_features(detached)
        actor_loss = self._actor_loss(detached, new_actions, log_probs)
        self.critic_optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        (critic_loss + actor_loss).backward()  # the two losses share no parameter
        self.actor_optimizer.step()
        self.critic_optimizer.step()
        self.gradient_steps += 1
        return _step_stats(critic_loss, actor_loss, q1, log_probs)

    def _tensors(self, batch: ReplayBatch) -> tuple[Any, Any, torch.Tensor, torch.Tensor, torch.Tensor]:
        """A minibatch on the learner's device: observations, next observations, actions, rewards,
        terminated."""
        device = self.device
        return (observation_to_tensor(batch.observations, device),
                observation_to_tensor(batch.next_observations, device),
                *(torch.as_tensor(x, device=device) for x in (batch.actions, batch.rewards, batch.terminated)))

    def _actor_loss(self, features: torch.Tensor, new_actions: torch.Tensor, log_probs: torch.Tensor) -> torch.Tensor:
        """SAC's policy loss on the critic's heads with their weights held fixed (the actor's loss must
        not train the critic; its gradient still flows through them to the actions)."""
        q1, q2 = self.critic.frozen_heads(features, new_actions)
        return sac_actor_loss(q1, q2, log_probs, self.hyperparameters.sac_alpha)

    def set_shared_trunk(self, shared: bool) -> None:
        """Put the actor on the critic's trunk or on its own (an imported DeepRacer policy keeps its own
        trunk, as rl_coach trains it); the checkpoints record the choice."""
        self._share_trunk(shared)

    def _share_trunk(self, shared: bool) -> None:
        """Put the actor on the critic's trunk (``shared``) or on its own, and give the actor a fresh
        optimizer over what it trains: its heads when shared, all of it otherwise."""
        if shared:
            self.actor.trunk = self.critic.trunk
        elif self.shared_trunk:  # leave the critic's trunk: the actor's own starts as a copy of it
            self.actor.trunk = copy.deepcopy(self.critic.trunk)
        self.shared_trunk = bool(shared)
        trained = ([*self.actor.head.parameters(), *self.actor.mean.parameters(), *self.actor.log_std.parameters()]
                   if shared
                   else list(self.actor.parameters()))
        self.actor_optimizer = FusedAdam(trained, lr=self.hyperparameters.lr)

    def _config(self) -> dict[str, Any]:
        return {"algorithm": "sac", "gradient_steps": self.gradient_steps, "shared_trunk": self.shared_trunk,
                "hyperparameters": self.hyperparameters.to_dict(), "network_name": self.network_name,
                "policy_head_layers": list(self.actor.head_layers),
                "action_spec": asdict(self.action_spec)}

    def weights_state(self) -> dict[str, Any]:
        """The networks' weights and config, no optimizer or target (a checkpoint other than the last,
        an export): what evaluation, export and clones need."""
        return {**self._config(), "actor": self.actor.state_dict(), "critic": self.critic.state_dict()}

    def state_dict(self) -> dict[str, Any]:
        """Everything to resume: weights, optimizers and config. Neither the replay buffer nor the
        target critic is saved: the next update copies the target from the critic as it starts."""
        return {**self.weights_state(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict()}

    def load_weights(self, state: Mapping[str, Any]) -> None:
        """Start from the network weights of ``state`` (a clone: fresh optimizers; the target critic
        starts as a copy of the critic), in its layout: a checkpoint from before shared trunks (no
        ``shared_trunk``) keeps its actor's own trunk."""
        if state.get("algorithm") != self.algorithm:
            raise ValueError(f"cannot start a {type(self).__name__} from a {state.get('algorithm')} checkpoint")
        self._share_trunk(bool(state.get("shared_trunk", False)))
        self.critic.load_state_dict(twin_q_from_separate(state["critic"]))
        self.actor.load_state_dict(state["actor"])
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
        saved_head = tuple(state.get("policy_head_layers", ()))
        if saved_head != self.actor.head_layers:
            raise ValueError(f"Checkpoint's SAC policy head has dense layers {list(saved_head)}, this learner's "
                             f"{list(self.actor.head_layers)}: the model spec's policy_head_layers must match.")
        self.load_weights(state)  # an older state's "target_critic" is not needed: see state_dict()
        if "actor_optimizer" in state and "critic_optimizer" in state and not _separate_layout(state):
            self.actor_optimizer.load_state_dict(state["actor_optimizer"])
            self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.gradient_steps = int(state.get("gradient_steps", 0))


def _step_stats(critic_loss: torch.Tensor, actor_loss: torch.Tensor, q1: torch.Tensor,
                log_probs: torch.Tensor) -> torch.Tensor:
    """A step's critic loss, actor loss, mean Q and entropy (= -mean log pi), float64 (4,)."""
    return torch.stack([critic_loss.detach(), actor_loss.detach(), q1.detach().mean(),
                        -log_probs.detach().mean()]).double()


def _separate_layout(state: Mapping[str, Any]) -> bool:
    """Whether ``state`` comes from laplab's older twin-Q layout (a trunk per Q head), whose critic
    optimizer state fits no longer."""
    return any(key.startswith("q1.trunk.") for key in state.get("critic", {}))
