"""Collecting whole episodes from a batch of cars: one episode per car, as DeepRacer's iteration does.

E cars start at E consecutive round-robin starts and each drives exactly one episode; a car whose
episode ended waits until the last one ends: it no longer acts (about half of an iteration's car-steps
were waits that ran the policy), and its rows are masked out of the rollout. The result holds the
time-major rollout for the learner, per-episode results for metrics, and simtrace rows.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from laplab.env.observations import ObservationBuilder, take_rows
from laplab.env.step import EpisodeStepper
from laplab.sim.state import IN_PROGRESS, LAP_COMPLETE, STATUS_NAMES


@dataclass
class EpisodeBatch:
    """E complete episodes.

    Time-major arrays (T, E): ``actions`` (T, E) or (T, E, 2), ``log_probs``, ``values``,
    ``rewards``, ``terminated``, ``truncated``, ``valid`` (the car was driving at that step);
    ``observations`` (T, E, ...) or a dict of them; ``bootstrap_values`` (T, E) V(final obs) where
    truncated. Per episode (E,): ``total_reward``, ``progress`` (%), ``status`` (codes),
    ``steps``, ``lap_time`` (s, NaN unless completed), ``duration`` (sim s). ``trace``: simtrace
    columns of every step (episode numbers are 0-based within the batch).
    """

    observations: Any
    actions: np.ndarray
    log_probs: np.ndarray
    values: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    valid: np.ndarray
    bootstrap_values: np.ndarray
    total_reward: np.ndarray
    progress: np.ndarray
    status: np.ndarray
    steps: np.ndarray
    lap_time: np.ndarray
    duration: np.ndarray
    trace: dict[str, np.ndarray]
    wall_seconds: float

    @property
    def env_steps(self) -> int:
        return int(self.valid.sum())

    @property
    def completed(self) -> np.ndarray:
        return self.status == LAP_COMPLETE

    def status_names(self) -> list[str]:
        return [STATUS_NAMES[s] for s in self.status]


class CollectionAborted(Exception):
    """``should_abort()`` returned True during collection; the partial episodes are discarded."""


PolicyFn = Callable[[Any], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
# Called after every step with the cars' poses (N, 3) (x m, y m, yaw rad) and the sim time (s) since
# the collection started: a live view's feed. It should be cheap; the arrays are the caller's to keep.
PosesHook = Callable[[np.ndarray, float], None]


def _stack(frames: list) -> Any:
    if isinstance(frames[0], dict):
        return {k: np.stack([f[k] for f in frames]) for k in frames[0]}
    return np.stack(frames)


def _scatter(outputs: tuple[np.ndarray, ...], rows: np.ndarray, num: int) -> tuple[np.ndarray, ...]:
    """A policy's outputs for ``rows`` of ``num`` cars -> arrays for all of them, zeros elsewhere (the
    waiting cars' rows are masked out of the rollout; a zero is a valid action of either kind)."""
    full = []
    for output in outputs:
        output = np.asarray(output)
        array = np.zeros((num, *output.shape[1:]), dtype=output.dtype)
        array[rows] = output
        full.append(array)
    return tuple(full)


def collect_episodes(stepper: EpisodeStepper, observations: ObservationBuilder, policy: PolicyFn,
                     value_fn: Callable[[Any], np.ndarray] | None = None, keep_observations: bool = True,
                     ndist: np.ndarray | None = None, should_abort: Callable[[], bool] | None = None,
                     on_poses: PosesHook | None = None) -> EpisodeBatch:
    """Run one episode on every car of ``stepper.sim`` with ``policy`` and return them.

    ``policy(obs) -> (action, env_action, log_prob, value)`` for a batch (B, ...) of observations: those
    of the B <= E cars still driving (a car whose episode ended does not act while it waits; its rows
    hold zeros and are not ``valid``); ``env_action`` is what the env receives (indices, or [-1, 1]^2
    points). The stepper's reward function may raise :class:`~laplab.reward.errors.RewardFunctionError`,
    which propagates. ``value_fn`` gives V(final obs) of episodes cut by the step cap. ``ndist``
    overrides the round-robin starts (evaluation uses fixed starts). ``should_abort`` is polled every
    step; when it returns True, :class:`CollectionAborted` is raised. ``on_poses(poses, sim_time)`` is
    called after every step.
    """
    started = time.perf_counter()
    sim = stepper.sim
    num = sim.num_cars
    sim.reset(ndist=ndist)
    st = sim.state
    frames, actions, log_probs, values, rewards, terminated, truncated, valid = [], [], [], [], [], [], [], []
    bootstrap = []
    trace_parts: list[dict[str, np.ndarray]] = []
    total = np.zeros(num)
    step_index = 0
    while (st.status == IN_PROGRESS).any():
        if should_abort is not None and should_abort():
            raise CollectionAborted
        obs = observations.observe()  # new arrays each step: safe to keep in the rollout
        driving = np.flatnonzero(st.status == IN_PROGRESS)
        if driving.size == num:
            action, env_action, log_prob, value = policy(obs)
        else:  # only the cars still driving act (about half of an iteration's car-steps are waits)
            action, env_action, log_prob, value = _scatter(policy(take_rows(obs, driving)), driving, num)
        result = stepper.step(env_action, trace=True)
        total += result.rewards
        cut = result.truncated
        boot = np.zeros(num, dtype=np.float32)
        if cut.any() and value_fn is not None:
            boot[cut] = value_fn(observations.observe(np.flatnonzero(cut)))
        if keep_observations:
            frames.append(obs)
        actions.append(action)
        log_probs.append(log_prob)
        values.append(value)
        rewards.append(result.rewards)
        terminated.append(result.terminated)
        truncated.append(cut)
        valid.append(result.stepped)
        bootstrap.append(boot)
        trace_parts.append(result.trace)
        step_index += 1
        if on_poses is not None:
            on_poses(sim.poses(), step_index * sim.dt)
    trace = {k: np.concatenate([p[k] for p in trace_parts]) for k in trace_parts[0]}
    lap_time = np.where(st.status == LAP_COMPLETE, st.lap_time, np.nan)
    return EpisodeBatch(
        observations=_stack(frames) if keep_observations else None, actions=np.stack(actions),
        log_probs=np.stack(log_probs), values=np.stack(values), rewards=np.stack(rewards),
        terminated=np.stack(terminated), truncated=np.stack(truncated), valid=np.stack(valid),
        bootstrap_values=np.stack(bootstrap), total_reward=total, progress=st.progress.copy(),
        status=st.status.copy(), steps=st.steps.copy(), lap_time=lap_time, duration=st.steps * sim.dt,
        trace=trace, wall_seconds=time.perf_counter() - started)
