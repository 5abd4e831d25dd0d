"""What a :class:`~laplab.train.trainer.Trainer` is given when it is built, as protocols.

A job (:mod:`laplab.train.jobs`) hands the trainer its model folder, the folder's lock, its listeners
(the recorders that write the folder) and, when its episodes are collected elsewhere, a
:class:`Collector` and an :class:`Evaluator`; nothing is set on a trainer afterwards. A
:class:`WorkerLauncher` (:class:`laplab.cluster.launch.RayWorkers`: rollout workers on Ray) makes
that collector and evaluator for a job, after its folder is written and before its trainer is built.
The trainer owns what it is given: :meth:`Trainer.close` stops the collector and releases the lock.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Protocol

if TYPE_CHECKING:
    import numpy as np

    from laplab.reward.loader import RewardFunction
    from laplab.store.layout import ModelFolder
    from laplab.train.collect import EpisodeBatch
    from laplab.train.config import TrainConfig


class Collector(Protocol):
    """A trainer's collection step run elsewhere (Ray rollout workers:
    :class:`laplab.cluster.collector.RayCollector`)."""

    def collect(self, trainer, should_abort: Callable[[], bool],
                on_progress: Callable[[int, int], None] | None = None,
                on_poses: Callable[[np.ndarray, float], None] | None = None) -> EpisodeBatch:
        """The iteration's ``num_episodes_between_training`` episodes driven by ``trainer``'s current
        learner (its weights, ``trainer.iteration`` as the policy version, ``trainer.episodes`` for the
        round-robin starts); raises :class:`laplab.train.collect.CollectionAborted` once ``should_abort()``.
        ``on_progress(episodes done, env steps)`` and ``on_poses(poses (N, 3), sim_time s)`` as it goes."""

    def close(self) -> None:
        """Stop whatever the collector started (its workers); called once, when the job ends."""


class Evaluator(Protocol):
    """A trainer's evaluation laps run elsewhere (every track of a multi-track job:
    :class:`laplab.cluster.evaluate.MultiTrackEvaluator`)."""

    def evaluate(self, policy) -> EpisodeBatch:
        """Greedy laps of ``policy(obs) -> (action, env_action, log_prob, value)``."""


class JobLock(Protocol):
    """The model folder's job lock (:class:`laplab.store.lock.ModelLock`), held while the trainer lives."""

    def release(self) -> None:
        """Free the folder for the next job (idempotent)."""


class WorkerLauncher(Protocol):
    """Starts a training job's rollout workers (:class:`laplab.cluster.launch.RayWorkers`)."""

    def check(self, config: TrainConfig, reward_fn: RewardFunction) -> None:
        """Refuse (a :class:`laplab.errors.UserError`) a job these workers cannot run, before anything
        is written: too few or too many workers, a reward function that fails on one of its tracks."""

    def start(self, config: TrainConfig, reward_fn: RewardFunction, folder: ModelFolder,
              iteration: int) -> tuple[Collector | None, Evaluator | None]:
        """Start the workers of the job in ``folder`` (resumed at ``iteration``): its collector and
        evaluator, either None when the trainer does that part in its own process."""
