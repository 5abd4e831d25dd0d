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
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from laplab.agents.learner import Learner, build_learner as build_model_learner
from laplab.env.observations import ObservationBuilder
from laplab.env.step import EpisodeStepper
from laplab.reward.errors import RewardFunctionError
from laplab.sim.race_type import HEAD_TO_BOT, HEAD_TO_MODEL
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.track.geometry import Track
from laplab.train.collect import CollectionAborted, EpisodeBatch, collect_episodes
from laplab.train.config import TrainConfig
from laplab.train.checkpoint_state import (checkpoint_writer, load_checkpoint, load_weights_only,  # noqa: F401
                                           merge_resume_state, resume_writer)
from laplab.sim.state import episodes_done_and_steps
from laplab.train.events import CheckpointReady, IterationEpisodes, IterationReport, PhaseProgress, PosesFrame
from laplab.vehicle.params import vehicle_preset

if TYPE_CHECKING:
    from laplab.store.layout import ModelFolder
    from laplab.train.collaborators import Collector, Evaluator, JobLock

__all__ = ["IterationReport", "TrainResult", "Trainer", "build_learner", "checkpoint_writer", "load_checkpoint",
           "load_weights_only", "merge_resume_state", "resume_writer"]


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
PROGRESS_INTERVAL_S = 1.0  # PhaseProgress events come at most this often


def _no_episodes(like: EpisodeBatch) -> EpisodeBatch:
    """An evaluation of zero episodes (a partial iteration runs no evaluation laps)."""
    empty = np.zeros((0, 0))
    per_episode = np.zeros(0)
    return EpisodeBatch(None, empty, empty, empty, empty, empty.astype(bool), empty.astype(bool), empty.astype(bool),
                        empty, per_episode, per_episode, per_episode.astype(like.status.dtype),
                        per_episode.astype(like.steps.dtype), per_episode, per_episode,
                        {key: value[:0] for key, value in like.trace.items()}, 0.0)


def build_learner(config: TrainConfig, seed: int, precision: str | None = None, device: str = "cpu") -> Learner:
    """The learner of a training job (its model spec, hyperparameters, threads, precision and torch device)."""
    return build_model_learner(config.spec, config.hyper(), seed=seed, num_threads=config.num_threads,
                               precision=precision or config.precision, device=device)


class Trainer:
    """A training job: ``config`` on the loaded ``track`` with ``reward_fn`` (a
    :class:`~laplab.reward.loader.RewardFunction`); ``resume_from`` is a checkpoint
    (:func:`load_checkpoint`) to continue from; ``device``: the learner's torch device (``cuda`` for a
    GPU; collection stays on the CPU). Made by :mod:`laplab.train.jobs`, which gives it, keyword-only:

    - ``folder``: the :class:`~laplab.store.layout.ModelFolder` the job writes, for displays (None: no
      folder); the trainer itself writes no file,
    - ``lock``: that folder's job lock (a :class:`~laplab.train.collaborators.JobLock`), held until
      :meth:`close`,
    - ``listeners``: subscribed first, in order (the folder's recorders; more join with :meth:`subscribe`),
    - ``collector`` (None: in-process) and ``evaluator`` (None: the job's track): its collection and
      evaluation steps run elsewhere (:class:`~laplab.train.collaborators.Collector`,
      :class:`~laplab.train.collaborators.Evaluator`; Ray rollout workers: :mod:`laplab.cluster`).

    The trainer owns its lock and collector: :meth:`close` (or leaving ``with trainer:``) stops the
    collector and releases the lock when the job is over.
    """

    def __init__(self, config: TrainConfig, reward_fn, track: Track, resume_from: dict | None = None,
                 device: str = "cpu", *, folder: ModelFolder | None = None, lock: JobLock | None = None,
                 listeners: Sequence[object] = (), collector: Collector | None = None,
                 evaluator: Evaluator | None = None):
        self.config, self.reward_fn, self.track = config, reward_fn, track
        self.spec, self.hp = config.spec, config.hyper()
        self.metadata = self.spec.metadata
        self.folder, self.lock = folder, lock
        self.collector, self.evaluator = collector, evaluator
        self._listeners: list = list(listeners)
        self._closed = False
        vehicle = vehicle_preset(config.car)
        self.sim = Simulator(track, self.hp.num_episodes_between_training, vehicle, config.episode_params(),
                             race=config.race_type, seed=config.seed)
        self.eval_sim = Simulator(track, config.eval_episodes, vehicle,
                                  EpisodeParams(round_robin_advance=0.0, reverse=config.reverse),
                                  race=config.race_type, seed=config.seed + 1)
        randomization = None
        if config.domain_randomization:
            from laplab.sensors.randomize import DOMAIN_RANDOMIZATION
            randomization = DOMAIN_RANDOMIZATION
        self.observations = ObservationBuilder(self.sim, self.spec, seed=config.seed, randomization=randomization)
        self.eval_observations = ObservationBuilder(self.eval_sim, self.spec, seed=config.seed + 1)
        self.stepper = EpisodeStepper(self.sim, self.spec.action_space, reward_fn)
        self.eval_stepper = EpisodeStepper(self.eval_sim, self.spec.action_space, reward_fn)
        self.learner = build_learner(config, config.seed, device=device)
        self.iteration, self.env_steps, self.episodes, self.best_lap = 0, 0, 0, None
        self._last_progress = float("-inf")
        if resume_from is not None:
            self.learner.load_state_dict(resume_from["learner"])
            self.iteration = int(resume_from["iteration"])
            self.env_steps = int(resume_from["env_steps"])
            self.episodes = int(resume_from["episodes"])
            self.best_lap = resume_from.get("best_lap_time")
        # Continue the round-robin schedule where the job stopped.
        self.sim.restart_schedule(self.episodes)

    # -- lifetime ------------------------------------------------------------------------------

    def close(self) -> None:
        """End the job: stop the collector's workers and release the folder's lock (once; later calls
        do nothing). The trainer's state stays readable."""
        if self._closed:
            return
        self._closed = True
        try:
            for listener in self._listeners:  # the folder's writes end before its lock is released
                close = getattr(listener, "close", None) if getattr(listener, "wait", None) else None
                if close is not None:
                    close()
        finally:
            try:
                if self.collector is not None:
                    self.collector.close()
            finally:
                if self.lock is not None:
                    self.lock.release()  # the folder is free for the next job

    def __enter__(self) -> "Trainer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

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

    def _poses_emitter(self, evaluation: bool = False, sim=None):
        """``emit(poses, sim_time, obstacles=None)``: the running collection's (or evaluation's) cars as
        a :class:`PosesFrame` to the listeners, with their race obstacles (boxes, bots: ``obstacles``,
        else ``sim``'s when it has them); None when none listens (no frame is then made)."""
        if not any(getattr(listener, "on_poses", None) is not None for listener in self._listeners):
            return None
        iteration = self.iteration + (0 if evaluation else 1)  # evaluation runs after the iteration's count
        field = getattr(sim, "field", None)
        moving = self.config.race_type.kind in (HEAD_TO_BOT, HEAD_TO_MODEL)  # its bots drive

        def emit(poses, sim_time, obstacles=None) -> None:  # obstacles: rollout workers' (laplab.cluster)
            if obstacles is None and field is not None:
                obstacles = field.obstacles
            self._emit("on_poses", PosesFrame(iteration, poses, sim_time, evaluation, obstacles, moving))
        return emit

    def _poses_hook(self, started: float):
        """The collection's per-step hook: poses for those who listen (none copied otherwise) and,
        about once a second, the episodes done so far (:class:`PhaseProgress`)."""
        emit_poses = self._poses_emitter(sim=self.sim)
        total = self.sim.num_cars
        self._progress(started, "collect", 0, total, 0, force=True)

        def hook(poses, sim_time) -> None:
            if emit_poses is not None:
                emit_poses(poses, sim_time)
            if self._progress_due():  # counting the cars every step would be wasted work
                done, steps = episodes_done_and_steps(self.sim.state)
                self._progress(started, "collect", done, total, steps)
        return hook

    def _progress_due(self) -> bool:
        return time.perf_counter() - self._last_progress >= PROGRESS_INTERVAL_S

    def _progress(self, started: float, phase: str, done: int, total: int, env_steps: int = 0,
                  force: bool = False) -> None:
        """Emit :class:`PhaseProgress` at most once a second (always when ``force``)."""
        if force or self._progress_due():
            now = self._last_progress = time.perf_counter()
            iteration = self.iteration if phase == "evaluate" else self.iteration + 1  # evaluation follows the count
            self._emit("on_progress", PhaseProgress(iteration, phase, done, total, env_steps, now - started))

    # -- one iteration -------------------------------------------------------------------------

    def _policy(self, deterministic: bool):
        learner = self.learner

        def act(obs):  # greedy evaluation laps need no values: PPO's value network does not run
            step = learner.act(obs, deterministic)
            return step.action, step.env_action, step.log_prob, step.value
        return act

    def _collect(self, should_abort, started: float) -> EpisodeBatch:
        if self.collector is not None:  # rollout workers (laplab.cluster), counting their episodes as they go
            total = self.hp.num_episodes_between_training
            self._progress(started, "collect", 0, total, force=True)
            return self.collector.collect(self, should_abort, on_progress=lambda done, steps: self._progress(
                started, "collect", done, total, steps), on_poses=self._poses_emitter())
        return collect_episodes(self.stepper, self.observations, self._policy(False), self.learner.values,
                                should_abort=should_abort, on_poses=self._poses_hook(started))

    def _learn(self, batch: EpisodeBatch, should_abort, started: float) -> tuple[dict, bool]:
        """Train on ``batch`` until done or ``should_abort()`` -> (losses, whether it was cut short)."""
        cut = []

        def stop() -> bool:
            if should_abort():
                cut.append(True)
                return True
            return False
        self._progress(started, "learn", 0, 0, batch.env_steps, force=True)
        losses = self.learner.learn(batch, stop, lambda done, total: self._progress(
            started, "learn", done, total, batch.env_steps))
        return losses, bool(cut)

    def _evaluate(self, should_abort=None, started: float | None = None) -> EpisodeBatch:
        if self.evaluator is not None:  # every track of a multi-track job (laplab.cluster)
            return self.evaluator.evaluate(self._policy(True))
        starts = np.arange(self.config.eval_episodes) / self.config.eval_episodes
        hook = emit_poses = self._poses_emitter(evaluation=True, sim=self.eval_sim)  # the live view shows the laps too
        if started is not None:
            total = self.eval_sim.num_cars
            self._progress(started, "evaluate", 0, total, force=True)

            def hook(poses, sim_time) -> None:
                if emit_poses is not None:
                    emit_poses(poses, sim_time)
                if self._progress_due():
                    done, steps = episodes_done_and_steps(self.eval_sim.state)
                    self._progress(started, "evaluate", done, total, steps)
        return collect_episodes(self.eval_stepper, self.eval_observations, self._policy(True),
                                keep_observations=False, ndist=starts, should_abort=should_abort, on_poses=hook)

    def _checkpoint(self, evaluation: EpisodeBatch | None) -> CheckpointReady:
        """This iteration's checkpoint; its metric is the mean progress of the evaluation laps, and when
        they all lapped their mean lap time breaks ties (the faster of two lapping checkpoints is best)."""
        write = checkpoint_writer(self.learner, self.iteration, self.env_steps, self.episodes, self.best_lap)
        resume = resume_writer(self.learner)
        if evaluation is None or len(evaluation.status) == 0:
            return CheckpointReady(self.iteration, self.env_steps, self.episodes, None, None, write, resume)
        lap_time = float(evaluation.lap_time.mean()) if evaluation.completed.all() else None
        return CheckpointReady(self.iteration, self.env_steps, self.episodes, float(evaluation.progress.mean()),
                               lap_time, write, resume)

    def save_initial_checkpoint(self) -> None:
        """Checkpoint 0 (untrained weights), written when this returns: a brand-new folder is loadable
        from the start."""
        self._emit("on_checkpoint", self._checkpoint(None))
        self.wait_for_listeners()

    def wait_for_listeners(self, during: BaseException | None = None) -> None:
        """Wait until the listeners that write in the background (those with a ``wait`` method, e.g.
        :class:`laplab.train.background.BackgroundListeners`) have written everything handed to them;
        a failed write raises here, or, ``during`` an exception that already ends the job, is added to
        its notes."""
        for listener in self._listeners:
            wait = getattr(listener, "wait", None)
            if wait is None:
                continue
            if during is None:
                wait()
                continue
            try:
                wait()
            except Exception as exc:  # noqa: BLE001 - the job already fails with ``during``
                during.add_note(f"the model folder's writer failed too: {type(exc).__name__}: {exc}")

    # -- the loop ------------------------------------------------------------------------------

    def run(self, callbacks: tuple[Callback, ...] = (), should_stop: Callable[[], bool] = lambda: False) -> TrainResult:
        """Train until a stop condition holds or ``should_stop()``; returns once the model folder's
        files are all written (:meth:`wait_for_listeners`), however the job ends."""
        try:
            result = self._run(callbacks, should_stop)
        except BaseException as exc:
            self.wait_for_listeners(during=exc)
            raise
        self.wait_for_listeners()
        return result

    def _run(self, callbacks: tuple[Callback, ...], should_stop: Callable[[], bool]) -> TrainResult:
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
            out_of_time = lambda: should_stop() or time.perf_counter() >= deadline  # noqa: E731
            try:
                batch = self._collect(out_of_time, started)
                if should_stop():  # a signal during collection: keep the last complete model
                    reason = "stopped"
                    break
                t1 = time.perf_counter()
                # Learning stops at the limit too (SAC's gradient steps can take minutes): the partly
                # trained networks are whole and become the last checkpoint, without evaluation laps.
                losses, partial = self._learn(batch, out_of_time, started)
                self.iteration += 1
                self.env_steps += batch.env_steps
                t2 = time.perf_counter()
                evaluation = None
                if not partial:
                    try:
                        evaluation = self._evaluate(out_of_time, started)
                    except CollectionAborted:  # the limit fell during the evaluation laps: keep the training
                        partial = True
                if evaluation is None:
                    evaluation = _no_episodes(batch)
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
            # None, not 0 %: an iteration the time limit cut short ran no evaluation laps
            eval_progress = float(evaluation.progress.mean()) if len(evaluation.status) else None
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
                seconds=seconds, eval_progress_by_track=_progress_by_track(evaluation), partial=partial)
            self._emit("on_iteration", report)
            for callback in callbacks:
                callback(report)
            if partial:
                reason = "stopped" if should_stop() else "max_time"
                break
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
