"""The training loop as a library call: iterations of DeepRacer's PPO (or SAC), reported through callbacks.

One iteration collects ``num_episodes_between_training`` episodes (one per car of a batched
simulator, at consecutive round-robin starts), writes their simtrace and metrics, trains the
learner, runs greedy evaluation laps, and saves a checkpoint. The trainer knows nothing of the CLI;
it reports through callbacks and stops when a stop condition holds or ``should_stop()`` says so.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from laplab.agents.ppo import PPOLearner, Rollout, keep_freed_memory
from laplab.agents.sac import SACLearner
from laplab.env.observations import ObservationBuilder
from laplab.reward.errors import RewardFunctionError
from laplab.reward.params import ParamsBuilder
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import ModelFolder
from laplab.store.metrics import TrainingMetricsWriter
from laplab.store.robomaker_log import RobomakerLogWriter, robomaker_log_path
from laplab.store.simtrace import SimtraceWriter
from laplab.train.collect import CollectionAborted, EpisodeBatch, collect_episodes
from laplab.train.config import TrainConfig
from laplab.track.registry import load_track
from laplab.vehicle.params import vehicle_preset


@dataclass
class IterationReport:
    """What one iteration did; handed to every callback."""

    iteration: int
    episodes: int  # training episodes so far
    env_steps: int  # training steps so far
    mean_reward: float
    mean_progress: float
    completion_rate: float  # fraction of this iteration's training episodes that lapped
    eval_progress: float  # mean progress of the greedy evaluation laps
    eval_completed: int
    eval_episodes: int
    best_lap_time: float | None  # best lap (training or evaluation) so far, s
    eval_lap_time: float | None  # mean lap time of this iteration's completed evaluation laps
    steps_per_second: float  # env steps per wall second this iteration (collection + training)
    elapsed_s: float
    time_left_s: float
    losses: dict[str, float] = field(default_factory=dict)
    # wall seconds of this iteration spent collecting episodes, learning, on evaluation laps and on
    # writing logs and the checkpoint
    seconds: dict[str, float] = field(default_factory=dict)


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


def build_learner(config: TrainConfig, observation_space, seed: int):
    metadata, hp = config.metadata(), config.hyper()
    action_space = metadata.action_space.gym_space()
    # Small vector networks run fastest on one thread (more threads only add synchronisation, and
    # collapse when the cores are shared); camera networks use every core.
    threads = config.num_threads or (1 if metadata.camera is None else None)
    if metadata.camera is not None:
        keep_freed_memory()
    learner_class = SACLearner if metadata.training_algorithm == "sac" else PPOLearner
    return learner_class(observation_space, action_space, hp, metadata.neural_network, seed=seed,
                         num_threads=threads, precision=config.precision)


def checkpoint_writer(learner, iteration: int, env_steps: int, episodes: int, best_lap_time: float | None):
    """A checkpoint (the learner's state plus where the job stood: what ``--resume`` continues from),
    as a function that writes it to a path (straight to the file: a camera checkpoint is ~140 MB)."""
    state = {"learner": learner.state_dict(), "iteration": iteration, "env_steps": env_steps,
             "episodes": episodes, "best_lap_time": best_lap_time}
    return lambda path: torch.save(state, path)


def load_weights_only(learner, state: dict) -> None:
    """Start ``learner`` from the network weights in ``state`` (a clone: fresh optimizer, new
    hyperparameters, schedules from zero)."""
    if state.get("algorithm") != ("sac" if isinstance(learner, SACLearner) else "clipped_ppo"):
        raise ValueError(f"cannot start a {type(learner).__name__} from a {state.get('algorithm')} checkpoint")
    if isinstance(learner, SACLearner):
        for name in ("actor", "critic", "target_critic"):
            getattr(learner, name).load_state_dict(state[name])
    else:
        learner.model.load_state_dict(state["model"])


def load_checkpoint(path) -> dict:
    """Read a checkpoint written by :func:`checkpoint_writer`."""
    return torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain data only: no code runs


class Trainer:
    """A training job over one model folder (made by :func:`laplab.train.jobs.create_training`)."""

    def __init__(self, folder: ModelFolder, config: TrainConfig, reward_fn, resume_from: dict | None = None):
        self.folder, self.config, self.reward_fn = folder, config, reward_fn
        self.metadata, self.hp = config.metadata(), config.hyper()
        vehicle = vehicle_preset(config.vehicle)
        track = load_track(config.track)
        episodes = self.hp.num_episodes_between_training
        self.sim = Simulator(track, episodes, vehicle, config.episode_params())
        self.eval_sim = Simulator(track, config.eval_episodes, vehicle,
                                  EpisodeParams(round_robin_advance=0.0, reverse=config.reverse))
        stack = self.hp.stack_size
        randomization = None
        if config.domain_randomization:
            from laplab.sensors.randomize import RandomizationParams
            randomization = RandomizationParams(enabled=True)
        self.observations = ObservationBuilder(self.sim, self.metadata, seed=config.seed, stack_size=stack,
                                               randomization=randomization)
        self.eval_observations = ObservationBuilder(self.eval_sim, self.metadata, seed=config.seed + 1, stack_size=stack)
        self.params = ParamsBuilder(self.sim)
        self.eval_params = ParamsBuilder(self.eval_sim)
        self.learner = build_learner(config, self.observations.single_space, config.seed)
        self.checkpoints = CheckpointStore(folder)
        self.iteration, self.env_steps, self.episodes, self.best_lap = 0, 0, 0, None
        if resume_from is not None:
            self.learner.load_state_dict(resume_from["learner"])
            self.iteration = int(resume_from["iteration"])
            self.env_steps = int(resume_from["env_steps"])
            self.episodes = int(resume_from["episodes"])
            self.best_lap = resume_from.get("best_lap_time")
            self._drop_records_after_checkpoint()
        self.metrics = TrainingMetricsWriter(folder.training_metrics)
        # robomaker-format log for deepracer-utils / deepracer-log-guru (laplab/store/robomaker_log.py)
        self.robomaker_log = RobomakerLogWriter(robomaker_log_path(folder.root), self.hp.to_dict(),
                                                self.metadata.to_dict(), str(config.track))
        self._iteration_rows = self._read_iteration_log()
        # Continue the round-robin schedule where the job stopped.
        self.sim._episodes_done[:] = self.episodes

    def _drop_records_after_checkpoint(self) -> None:
        """A job killed between writing an iteration's logs and its checkpoint left logs of an
        iteration the checkpoint does not have: remove them so the resumed job rewrites them."""
        from laplab.store.atomic import atomic_write_json, read_json
        for iteration in self.folder.list_training_iterations():
            if iteration >= self.iteration:
                self.folder.training_simtrace(iteration).unlink(missing_ok=True)
        path = self.folder.training_metrics
        if path.exists():
            data = read_json(path)
            # Rows of later iterations carry larger episode numbers (evaluation rows carry the last
            # training episode of their iteration), so this keeps exactly the checkpoint's history.
            data["metrics"] = [row for row in data.get("metrics", []) if int(row.get("episode", 0)) <= self.episodes]
            atomic_write_json(path, data, indent=None)

    # -- one iteration -------------------------------------------------------------------------

    def _policy(self, deterministic: bool):
        learner = self.learner
        if isinstance(learner, SACLearner):
            def act(obs):
                action = learner.act(obs, deterministic)
                zeros = np.zeros(action.shape[0], np.float32)
                return action, action, zeros, zeros
            return act

        def act(obs):  # greedy evaluation laps need no values: the value network does not run
            step = learner.act(obs, deterministic, with_value=not deterministic)
            return step.action, step.env_action, step.log_prob, step.value
        return act

    def _collect(self, should_abort) -> EpisodeBatch:
        value_fn = self.learner.values if isinstance(self.learner, PPOLearner) else None
        return collect_episodes(self.sim, self.observations, self.params, self.reward_fn,
                                self.metadata.action_space, self._policy(False), value_fn,
                                should_abort=should_abort)

    def _learn(self, batch: EpisodeBatch) -> dict[str, float]:
        if isinstance(self.learner, PPOLearner):
            rollout = Rollout(batch.observations, batch.actions, batch.log_probs, batch.values, batch.rewards,
                              batch.terminated, batch.truncated, batch.bootstrap_values, None, batch.valid)
            return self.learner.update(rollout)
        obs, valid = batch.observations, batch.valid
        t_idx, e_idx = np.nonzero(valid)
        nxt = np.minimum(t_idx + 1, valid.shape[0] - 1)
        pick = (lambda o, t: {k: v[t, e_idx] for k, v in o.items()}) if isinstance(obs, dict) else (lambda o, t: o[t, e_idx])
        done = batch.terminated[t_idx, e_idx] | batch.truncated[t_idx, e_idx]
        # The observation after a car's last step is never recorded (the car stops); its target is not
        # bootstrapped (terminated), so any placeholder works: use the same observation.
        next_t = np.where(done, t_idx, nxt)
        # A truncated episode's final observation is not recorded either; SAC treats the cut as an end
        # (time_up only fires at the 100,000-step cap, so the bias this causes is negligible).
        self.learner.observe(pick(obs, t_idx), batch.actions[t_idx, e_idx], batch.rewards[t_idx, e_idx],
                             pick(obs, next_t), done)
        return self.learner.update(self.learner.gradient_steps_for(int(valid.sum())))

    def _evaluate(self) -> EpisodeBatch:
        starts = np.arange(self.config.eval_episodes) / self.config.eval_episodes
        return collect_episodes(self.eval_sim, self.eval_observations, self.eval_params, self.reward_fn,
                                self.metadata.action_space, self._policy(True), keep_observations=False,
                                ndist=starts)

    def _write_iteration(self, batch: EpisodeBatch, evaluation: EpisodeBatch, losses: dict | None = None) -> None:
        trace = dict(batch.trace)
        trace["episode"] = trace["episode"] + self.episodes
        # deepracer-for-cloud numbers simtrace files from 0: iteration k (1-based) -> (k-1)-iteration.csv
        with SimtraceWriter(self.folder.training_simtrace(self.iteration - 1), fsync=False) as writer:
            writer.write_rows(trace)
        self.robomaker_log.write_iteration(self.iteration - 1, trace, batch, evaluation, self.episodes,
                                           self.env_steps - batch.env_steps, losses, self.hp.lr)
        for append, b in ((self.metrics.append_training, batch), (self.metrics.append_evaluation, evaluation)):
            append(reward_score=b.total_reward, start_time=np.zeros(len(b.status)), metric_time=b.duration,
                   completion_percentage=b.progress, episode_status=b.status_names())

    @property
    def iterations_log(self):
        """laplab's per-iteration log (losses, entropy, rates), beside DeepRacer's metrics."""
        return self.folder.metrics_dir / "laplab-iterations.json"

    def _read_iteration_log(self) -> list[dict]:
        """The log's rows up to the checkpoint this job starts from (read once, kept in memory)."""
        from laplab.store.atomic import read_json
        path = self.iterations_log
        rows = read_json(path)["iterations"] if path.exists() else []
        return [r for r in rows if r["iteration"] <= self.iteration]

    def _log_iteration(self, report: IterationReport) -> None:
        from dataclasses import asdict

        from laplab.store.atomic import atomic_write_json
        self._iteration_rows.append(asdict(report))
        atomic_write_json(self.iterations_log, {"iterations": self._iteration_rows}, indent=None)

    def _save_checkpoint(self, evaluation: EpisodeBatch) -> None:
        """Checkpoint this iteration; its metric is the mean progress of the evaluation laps, and when
        they all lapped their mean lap time breaks ties (the faster of two lapping checkpoints is best)."""
        payload = checkpoint_writer(self.learner, self.iteration, self.env_steps, self.episodes, self.best_lap)
        lap_time = float(evaluation.lap_time.mean()) if evaluation.completed.all() else None
        self.checkpoints.save(payload, iteration=self.iteration, steps=self.env_steps,
                              metric=float(evaluation.progress.mean()), lap_time=lap_time)

    def save_initial_checkpoint(self) -> None:
        """Checkpoint 0 (untrained weights): a brand-new folder is loadable from the start."""
        self.checkpoints.save(checkpoint_writer(self.learner, 0, 0, 0, None), iteration=0, steps=0, metric=None)

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
                losses = self._learn(batch)
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
                self.folder.write_error(error)
                break
            self._write_iteration(batch, evaluation, losses)
            self.episodes += len(batch.status)
            eval_progress = float(evaluation.progress.mean())
            laps = np.concatenate([batch.lap_time, evaluation.lap_time])
            if np.isfinite(laps).any():
                best = float(np.nanmin(laps))
                self.best_lap = best if self.best_lap is None else min(self.best_lap, best)
            self._save_checkpoint(evaluation)
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
                seconds=seconds)
            self._log_iteration(report)
            for callback in callbacks:
                callback(report)
            if batch.total_reward.mean() >= hp.term_cond_avg_score:
                reason = "avg_score"
                break
        return TrainResult(self.iteration, self.episodes, self.env_steps, time.perf_counter() - started,
                           reason, self.best_lap, error)
