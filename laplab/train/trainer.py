"""The training loop as a library call: iterations of DeepRacer's PPO (or SAC), reported to listeners.

One iteration collects ``num_episodes_between_training`` episodes (one per car of a batched
simulator, at consecutive round-robin starts), trains the learner, runs greedy evaluation laps, and
reports: the episodes, a checkpoint, the iteration's figures (:mod:`laplab.train.events`). The
trainer writes no file and knows no terminal: the model folder is one listener
(:class:`laplab.train.recorder.ModelFolderRecorder`), the progress display another. It stops when a
stop condition holds or ``should_stop()`` says so.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from laplab.agents.learner import Learner, build_learner as build_model_learner
from laplab.env.observations import ObservationBuilder
from laplab.env.step import EpisodeStepper
from laplab.reward.errors import RewardFunctionError
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.track.geometry import Track
from laplab.train.collect import CollectionAborted, EpisodeBatch, collect_episodes
from laplab.train.config import TrainConfig
from laplab.train.events import CheckpointReady, IterationEpisodes, IterationReport, PosesFrame
from laplab.vehicle.params import vehicle_preset

__all__ = ["IterationReport", "TrainResult", "Trainer", "build_learner", "checkpoint_writer", "load_checkpoint",
           "load_weights_only"]


@dataclass
class TrainResult:
    iterations: int
    episodes: int
    env_steps: int
    elapsed_s: float
    stop_reason: str
    best_lap_time: float | None
    error: str | None = None


Callback = Callable[[IterationReport], None]


def build_learner(config: TrainConfig, seed: int, precision: str | None = None, device: str = "cpu") -> Learner:
    """The learner of a training job (its model spec, hyperparameters, threads, precision and torch device)."""
    return build_model_learner(config.spec, config.hyper(), seed=seed, num_threads=config.num_threads,
                               precision=precision or config.precision, device=device)


def checkpoint_writer(learner: Learner, iteration: int, env_steps: int, episodes: int, best_lap_time: float | None):
    """A checkpoint (the learner's state plus where the job stood: what ``--resume`` continues from),
    as a function that writes it to a path (straight to the file: a camera checkpoint is ~140 MB)."""
    state = {"learner": learner.state_dict(), "iteration": iteration, "env_steps": env_steps,
             "episodes": episodes, "best_lap_time": best_lap_time}
    return lambda path: torch.save(state, path)


def load_weights_only(learner: Learner, state: dict) -> None:
    """Start ``learner`` from the network weights in ``state`` (a clone: fresh optimizer, new
    hyperparameters, schedules from zero)."""
    learner.load_weights(state)


def load_checkpoint(path) -> dict:
    """Read a checkpoint written by :func:`checkpoint_writer`."""
    return torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain data only: no code runs


class Trainer:
    """A training job: ``config`` on the loaded ``track`` with ``reward_fn``; ``resume_from`` is a
    checkpoint (:func:`load_checkpoint`) to continue from. Made by :mod:`laplab.train.jobs`, which
    subscribes the model folder's recorder; ``folder`` names that folder for displays (None: no folder).
    ``device``: the learner's torch device (``cuda`` for a GPU; collection stays on the CPU).

    Collection and evaluation are pluggable: ``collector`` (None: in-process) is an object whose
    ``collect(trainer, should_abort) -> EpisodeBatch`` drives the iteration's episodes elsewhere (Ray
    rollout workers: :mod:`laplab.cluster`); ``evaluator`` (None: the job's track) has
    ``evaluate(policy) -> EpisodeBatch``.
    """

    def __init__(self, config: TrainConfig, reward_fn, track: Track, resume_from: dict | None = None,
                 device: str = "cpu"):
        self.config, self.reward_fn, self.track = config, reward_fn, track
        self.spec, self.hp = config.spec, config.hyper()
        self.metadata = self.spec.metadata
        self.folder = None
        self._listeners: list = []
        vehicle = vehicle_preset(config.vehicle)
        self.sim = Simulator(track, self.hp.num_episodes_between_training, vehicle, config.episode_params())
        self.eval_sim = Simulator(track, config.eval_episodes, vehicle,
                                  EpisodeParams(round_robin_advance=0.0, reverse=config.reverse))
        randomization = None
        if config.domain_randomization:
            from laplab.sensors.randomize import RandomizationParams
            randomization = RandomizationParams(enabled=True)
        self.observations = ObservationBuilder(self.sim, self.spec, seed=config.seed, randomization=randomization)
        self.eval_observations = ObservationBuilder(self.eval_sim, self.spec, seed=config.seed + 1)
        self.stepper = EpisodeStepper(self.sim, self.spec.action_space, reward_fn)
        self.eval_stepper = EpisodeStepper(self.eval_sim, self.spec.action_space, reward_fn)
        self.learner = build_learner(config, config.seed, device=device)
        self.collector = None
        self.evaluator = None
        self.iteration, self.env_steps, self.episodes, self.best_lap = 0, 0, 0, None
        if resume_from is not None:
            self.learner.load_state_dict(resume_from["learner"])
            self.iteration = int(resume_from["iteration"])
            self.env_steps = int(resume_from["env_steps"])
            self.episodes = int(resume_from["episodes"])
            self.best_lap = resume_from.get("best_lap_time")
        # Continue the round-robin schedule where the job stopped.
        self.sim.restart_schedule(self.episodes)

    # -- listeners -----------------------------------------------------------------------------

    def subscribe(self, listener) -> None:
        """Add a listener (any object with some of the ``on_*`` methods of
        :class:`laplab.train.events.TrainerListener`)."""
        self._listeners.append(listener)

    def _emit(self, event: str, payload) -> None:
        for listener in self._listeners:
            handler = getattr(listener, event, None)
            if handler is not None:
                handler(payload)

    def _poses_hook(self):
        """The collection's per-step hook, or None when nobody listens (then no poses are copied)."""
        if all(getattr(listener, "on_poses", None) is None for listener in self._listeners):
            return None
        iteration = self.iteration + 1
        return lambda poses, sim_time: self._emit("on_poses", PosesFrame(iteration, poses, sim_time))

    # -- one iteration -------------------------------------------------------------------------

    def _policy(self, deterministic: bool):
        learner = self.learner

        def act(obs):  # greedy evaluation laps need no values: PPO's value network does not run
            step = learner.act(obs, deterministic)
            return step.action, step.env_action, step.log_prob, step.value
        return act

    def _collect(self, should_abort) -> EpisodeBatch:
        if self.collector is not None:
            return self.collector.collect(self, should_abort)
        return collect_episodes(self.stepper, self.observations, self._policy(False), self.learner.values,
                                should_abort=should_abort, on_poses=self._poses_hook())

    def _evaluate(self) -> EpisodeBatch:
        if self.evaluator is not None:
            return self.evaluator.evaluate(self._policy(True))
        starts = np.arange(self.config.eval_episodes) / self.config.eval_episodes
        return collect_episodes(self.eval_stepper, self.eval_observations, self._policy(True),
                                keep_observations=False, ndist=starts)

    def _checkpoint(self, evaluation: EpisodeBatch | None) -> CheckpointReady:
        """This iteration's checkpoint; its metric is the mean progress of the evaluation laps, and when
        they all lapped their mean lap time breaks ties (the faster of two lapping checkpoints is best)."""
        write = checkpoint_writer(self.learner, self.iteration, self.env_steps, self.episodes, self.best_lap)
        if evaluation is None:
            return CheckpointReady(self.iteration, self.env_steps, self.episodes, None, None, write)
        lap_time = float(evaluation.lap_time.mean()) if evaluation.completed.all() else None
        return CheckpointReady(self.iteration, self.env_steps, self.episodes, float(evaluation.progress.mean()),
                               lap_time, write)

    def save_initial_checkpoint(self) -> None:
        """Checkpoint 0 (untrained weights): a brand-new folder is loadable from the start."""
        self._emit("on_checkpoint", self._checkpoint(None))

    # -- the loop ------------------------------------------------------------------------------

    def run(self, callbacks: tuple[Callback, ...] = (), should_stop: Callable[[], bool] = lambda: False) -> TrainResult:
        cfg, hp = self.config, self.hp
        started = time.perf_counter()
        reason, error = "max_time", None
        episode_limit = cfg.episode_limit
        while True:
            elapsed = time.perf_counter() - started
            if should_stop():
                reason = "stopped"
                break
            if elapsed >= cfg.max_time_s:
                reason = "max_time"
                break
            if self.episodes >= episode_limit:
                reason = "max_episodes"
                break
            t0 = time.perf_counter()
            deadline = started + cfg.max_time_s
            try:
                batch = self._collect(lambda: should_stop() or time.perf_counter() >= deadline)
                if should_stop():  # a signal during collection: keep the last complete model
                    reason = "stopped"
                    break
                t1 = time.perf_counter()
                losses = self.learner.learn(batch)
                self.iteration += 1
                self.env_steps += batch.env_steps
                t2 = time.perf_counter()
                evaluation = self._evaluate()
                t3 = time.perf_counter()
            except CollectionAborted:  # the partial iteration is dropped; the last checkpoint stands
                reason = "stopped" if should_stop() else "max_time"
                break
            except RewardFunctionError as exc:  # in training or evaluation episodes alike
                error, reason = str(exc), "reward_error"
                self._emit("on_error", error)
                break
            self._emit("on_episodes", IterationEpisodes(self.iteration, self.episodes, batch, evaluation))
            self.episodes += len(batch.status)
            eval_progress = float(evaluation.progress.mean())
            laps = np.concatenate([batch.lap_time, evaluation.lap_time])
            if np.isfinite(laps).any():
                best = float(np.nanmin(laps))
                self.best_lap = best if self.best_lap is None else min(self.best_lap, best)
            self._emit("on_checkpoint", self._checkpoint(evaluation))
            eval_laps = evaluation.lap_time[np.isfinite(evaluation.lap_time)]
            wall = time.perf_counter() - t0
            seconds = {"collect": t1 - t0, "learn": t2 - t1, "evaluate": t3 - t2, "save": t0 + wall - t3}
            elapsed = time.perf_counter() - started
            report = IterationReport(
                iteration=self.iteration, episodes=self.episodes, env_steps=self.env_steps,
                mean_reward=float(batch.total_reward.mean()), mean_progress=float(batch.progress.mean()),
                completion_rate=float(batch.completed.mean()), eval_progress=eval_progress,
                eval_completed=int(evaluation.completed.sum()), eval_episodes=len(evaluation.status),
                best_lap_time=self.best_lap, eval_lap_time=float(eval_laps.mean()) if eval_laps.size else None,
                steps_per_second=(batch.env_steps + evaluation.env_steps) / max(wall, 1e-9),
                elapsed_s=elapsed, time_left_s=max(cfg.max_time_s - elapsed, 0.0), losses=losses,
                seconds=seconds, eval_progress_by_track=_progress_by_track(evaluation))
            self._emit("on_iteration", report)
            for callback in callbacks:
                callback(report)
            if batch.total_reward.mean() >= hp.term_cond_avg_score:
                reason = "avg_score"
                break
        return TrainResult(self.iteration, self.episodes, self.env_steps, time.perf_counter() - started,
                           reason, self.best_lap, error)


def _progress_by_track(evaluation: EpisodeBatch) -> dict[str, float]:
    """Mean evaluation progress per track of a multi-track job (its batch tags episodes by track)."""
    labels = getattr(evaluation, "track", None)
    if labels is None:
        return {}
    labels = np.asarray(labels)
    return {str(t): float(evaluation.progress[labels == t].mean()) for t in dict.fromkeys(labels.tolist())}
