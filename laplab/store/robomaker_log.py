"""Training logs in the format of DeepRacer's RoboMaker simulation log, for the community's tools.

deepracer-for-cloud keeps the simulation container's log as ``logs/training/<time>-robomaker.log``;
deepracer-utils (``SimulationLogsIO.load_data`` + ``convert_to_pandas``, and
``DeepRacerLog.load_robomaker_logs`` for console downloads), deepracer-log-guru and the
deepracer-analysis notebooks read it. laplab writes the lines those readers parse, in the simapp's
and rl_coach's formats:

- header: `` * /JOB_TYPE``, `` * /RACE_TYPE``, `` * /WORLD_NAME: <track>`` (roslaunch's parameter
  dump), ``Using the following hyper-parameters`` followed by hyperparameters.json (indent 2, one
  key a line, as log-guru reads it), ``Loaded action space from file: [...]`` (Python repr, as the
  simapp logs it), ``Sensor list [...], network ..., simapp_version ..., training_algorithm ...,
  action_space_type ...`` (log-guru takes a continuous action space from the last);
- one ``SIM_TRACE_LOG:`` line per step, the 19 simtrace columns in the simapp's order
  (``markov/metrics/s3_metrics.py``): episode, steps, X, Y, yaw, steer, throttle, action, reward,
  done, all_wheels_on_track, progress, closest_waypoint, track_len, tstamp, episode_status,
  pause_duration, obstacle_crash_counter, wall_clock;
- rl_coach's per-episode screen lines ``Training> Name=main_level/agent, Worker=0, Episode=N,
  Total reward=R, Steps=S, Training iteration=I`` (``Testing>`` for the evaluation laps) and the
  learner's ``Policy training> Surrogate loss=..., KL divergence=..., Entropy=..., training
  epoch=..., learning_rate=...`` line.

Each iteration is appended with one write and flushed, like the simtrace files.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from laplab.store.simtrace import format_rows

SIMAPP_VERSION = "5.0"  # the simapp version laplab's metadata and simtrace follow
AGENT_NAME = "main_level/agent"


def robomaker_log_path(model_root: str | os.PathLike, when: float | None = None) -> Path:
    """``<model>/logs/training/<YYYYmmddHHMMSS>-robomaker.log`` (UTC); the next free second if taken."""
    stamp = int(time.time() if when is None else when)
    folder = Path(model_root) / "logs" / "training"
    while True:
        path = folder / f"{time.strftime('%Y%m%d%H%M%S', time.gmtime(stamp))}-robomaker.log"
        if not path.exists():
            return path
        stamp += 1


def header_lines(hyperparameters: Mapping[str, Any], metadata: Mapping[str, Any], track: str) -> str:
    """The lines before the first episode that deepracer-utils reads hyperparameters, action space,
    world, sensors and network from."""
    sensors = list(metadata.get("sensor", []))
    network = metadata.get("neural_network", "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")
    algorithm = metadata.get("training_algorithm", "clipped_ppo")
    kind = metadata.get("action_space_type", "discrete")
    return "".join([
        f" * /JOB_TYPE: TRAINING\n * /RACE_TYPE: TIME_TRIAL\n * /WORLD_NAME: {track}\n",
        "Using the following hyper-parameters\n",
        json.dumps(dict(hyperparameters), indent=2, sort_keys=True) + "\n",  # log-guru reads '  "key": value,'
        f"Loaded action space from file: {metadata.get('action_space')!r}\n",
        f"Sensor list {sensors!r}, network {network}, simapp_version {SIMAPP_VERSION}, "
        f"training_algorithm {algorithm}, action_space_type {kind}\n",
    ])


def simtrace_lines(trace: Mapping[str, np.ndarray]) -> list[str]:
    """``SIM_TRACE_LOG:`` + the simtrace CSV row, for every row of ``trace`` (simtrace columns), in
    the order of the rows."""
    return [f"SIM_TRACE_LOG:{row}\n" for row in format_rows(dict(trace)).splitlines()]


def episode_lines(phase: str, first_episode: int, total_rewards: np.ndarray, steps: np.ndarray,
                  steps_before: int, iteration: int) -> str:
    """rl_coach's ``<phase>> Name=..., Worker=0, Episode=N, Total reward=R, Steps=S, Training
    iteration=I`` lines; ``Steps`` is the running total of environment steps, as rl_coach counts."""
    lines, total = [], int(steps_before)
    for offset, (reward, count) in enumerate(zip(np.asarray(total_rewards, float), np.asarray(steps, int))):
        total += int(count)
        lines.append(f"{phase}> Name={AGENT_NAME}, Worker=0, Episode={first_episode + offset}, "
                     f"Total reward={round(float(reward), 2)}, Steps={total}, Training iteration={iteration}\n")
    return "".join(lines)


def policy_training_line(losses: Mapping[str, Any], learning_rate: float, epoch: int = 0) -> str:
    """rl_coach's ``Policy training>`` line from laplab's PPO losses (SAC: its actor loss and entropy)."""
    surrogate = losses.get("policy_loss", losses.get("actor_loss", float("nan")))
    kl = losses.get("approx_kl", 0.0)
    entropy = losses.get("entropy", float("nan"))
    return (f"Policy training> Surrogate loss={float(surrogate)}, KL divergence={float(kl)}, "
            f"Entropy={float(entropy)}, training epoch={epoch}, learning_rate={float(learning_rate)}\n")


class RobomakerLogWriter:
    """Appends one training job's log at ``path``; the file (with its header) is created by the
    first iteration written, so a job that never finishes an iteration leaves no log."""

    def __init__(self, path: str | os.PathLike, hyperparameters: Mapping[str, Any], metadata: Mapping[str, Any],
                 track: str):
        self.path = Path(path)
        self._header = header_lines(hyperparameters, metadata, track)

    def _append(self, text: str) -> None:
        if not self.path.exists() or self.path.stat().st_size == 0:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            text = self._header + text
        with open(self.path, "a", encoding="ascii", errors="replace") as handle:
            handle.write(text)
            handle.flush()

    def write_iteration(self, iteration: int, trace: Mapping[str, np.ndarray], training: Any, evaluation: Any,
                        first_episode: int, steps_before: int, losses: Mapping[str, Any] | None = None,
                        learning_rate: float = 3e-4) -> None:
        """One training iteration (0-based ``iteration``, as deepracer-utils numbers them): the
        training episodes' simtrace lines (``trace``: run-wide episode numbers from
        ``first_episode``), their ``Training>`` lines, the ``Policy training>`` line and the
        evaluation laps' ``Testing>`` lines. ``training`` / ``evaluation``: objects with per-episode
        ``total_reward`` and ``steps`` arrays (laplab's EpisodeBatch)."""
        # laplab steps all cars of a batch together; the simapp logs one episode after the other,
        # each followed by rl_coach's episode line: reorder the rows episode by episode
        episodes = np.asarray(trace["episode"])
        order = np.argsort(episodes, kind="stable")
        lines = simtrace_lines({key: np.asarray(value)[order] if np.ndim(value) and len(value) == len(episodes)
                                else value for key, value in trace.items()})
        ends = np.flatnonzero(np.r_[episodes[order][1:] != episodes[order][:-1], True]) + 1 if len(episodes) else []
        rewards, steps = np.asarray(training.total_reward, float), np.asarray(training.steps, int)
        text, start, total = [], 0, int(steps_before)
        for end in ends:
            index = int(episodes[order][end - 1]) - first_episode
            total += int(steps[index])
            text += lines[start:end]
            text.append(f"Training> Name={AGENT_NAME}, Worker=0, Episode={first_episode + index + 1}, "
                        f"Total reward={round(float(rewards[index]), 2)}, Steps={total}, "
                        f"Training iteration={iteration}\n")
            start = end
        if losses is not None:
            text.append(policy_training_line(losses, learning_rate))
        text.append(episode_lines("Testing", first_episode + len(rewards) + 1, evaluation.total_reward,
                                  evaluation.steps, steps_before + int(np.sum(steps)), iteration))
        self._append("".join(text))
