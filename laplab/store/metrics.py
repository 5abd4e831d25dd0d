"""Per-episode metrics JSON files as the DeepRacer simapp writes them.

`metrics/TrainingMetrics.json`: `{"metrics": [row, ...], "version": 2.0, "best_model_metric":
"progress"}`, one row per training or evaluation-phase episode with reward_score, metric_time,
start_time, elapsed_time_in_milliseconds, episode, trial, phase, completion_percentage,
episode_status. Numbering follows the simapp (deepracer-utils' `TrainingMetrics` relies on it):
training episodes count from 1 over the whole run, `trial` counts 1..E within an iteration, and
an evaluation-phase row repeats the last training episode and trial numbers.

`metrics/evaluation/evaluation-<stamp>.json`: `{"metrics": [row, ...]}` (no version key, as the
simapp), one row per evaluation trial with completion_percentage, metric_time, start_time,
elapsed_time_in_milliseconds, episode_status, crash_count, immobilized_count, off_track_count,
reversed_count, reset_count (their sum) and trial (1, 2, ...).

Times are given in seconds and stored as integer milliseconds; `episode_status` may be given as
simtrace codes (`off_track`) or labels (`Off track`) and is stored as labels. Each append
rewrites the whole file atomically, so a reader never sees a torn file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from laplab.store.atomic import atomic_write_json, read_json

EPISODE_STATUS_LABELS = {
    "lap_complete": "Lap complete", "crashed": "Crashed", "off_track": "Off track",
    "immobilized": "Immobilized", "in_progress": "In progress", "pause": "Pause",
    "reversed": "Reversed", "park": "Park", "time_up": "Time Up", "prepare": "Prepare",
}
TRAINING_METRICS_VERSION = 2.0
BEST_MODEL_METRICS = ("progress", "reward", "laptime")


def episode_status_labels(statuses) -> list[str]:
    """Metric labels ('Off track') for simtrace codes ('off_track') or labels, shape (n,)."""
    known = {**EPISODE_STATUS_LABELS, **{label: label for label in EPISODE_STATUS_LABELS.values()}}
    values = [str(status) for status in np.asarray(statuses).reshape(-1).tolist()]
    unknown = sorted({status for status in values if status not in known})
    if unknown:
        raise ValueError(f"unknown episode_status value(s) {unknown[:5]}; use one of the codes "
                         f"{list(EPISODE_STATUS_LABELS)} or the labels {list(EPISODE_STATUS_LABELS.values())}")
    return [known[status] for status in values]


def _numbers(name: str, values, n_rows: int | None) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1 or (n_rows is not None and len(array) != n_rows):
        raise ValueError(f"metrics column {name!r} must be 1-D with {n_rows} rows, got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.number) or not np.all(np.isfinite(array)):
        raise ValueError(f"metrics column {name!r} needs finite real numbers, got dtype {array.dtype}")
    return array


def _milliseconds(seconds: np.ndarray) -> np.ndarray:
    return np.rint(seconds.astype(np.float64) * 1000.0).astype(np.int64)


def _episode_timing(start_time, metric_time, completion_percentage, episode_status) -> dict[str, list]:
    """Columns shared by both files; n = len(start_time)."""
    start = _numbers("start_time", start_time, None)
    n_rows = len(start)
    end = _numbers("metric_time", metric_time, n_rows)
    progress = _numbers("completion_percentage", completion_percentage, n_rows)
    labels = episode_status_labels(episode_status)
    if len(labels) != n_rows:
        raise ValueError(f"metrics column 'episode_status' must have {n_rows} rows, got {len(labels)}")
    start_ms, end_ms = _milliseconds(start), _milliseconds(end)
    return {
        "completion_percentage": np.trunc(progress).astype(np.int64).tolist(),
        "metric_time": end_ms.tolist(),
        "start_time": start_ms.tolist(),
        "elapsed_time_in_milliseconds": (end_ms - start_ms).tolist(),
        "episode_status": labels,
    }


def read_metrics(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a training or evaluation metrics file."""
    document = read_json(path)
    if not isinstance(document, dict) or not isinstance(document.get("metrics"), list):
        raise ValueError(f"{str(path)!r} is not a DeepRacer metrics file: expected an object "
                         "with a 'metrics' list")
    return document["metrics"]


class TrainingMetricsWriter:
    """Maintains `metrics/TrainingMetrics.json`; an existing file is resumed, not overwritten."""

    def __init__(self, path: str | os.PathLike, best_model_metric: str = "progress"):
        if best_model_metric not in BEST_MODEL_METRICS:
            raise ValueError(f"best_model_metric must be one of {BEST_MODEL_METRICS}, got {best_model_metric!r}")
        self.path = Path(path)
        self.best_model_metric = best_model_metric
        self.rows: list[dict[str, Any]] = read_metrics(self.path) if self.path.exists() else []
        training = [row for row in self.rows if row.get("phase") == "training"]
        self.last_episode = int(training[-1]["episode"]) if training else 0
        self.last_trial = int(training[-1]["trial"]) if training else 0

    def append_training(self, *, reward_score, start_time, metric_time, completion_percentage,
                        episode_status) -> None:
        """Append one iteration's training episodes (arrays of E rows) and rewrite the file.

        reward_score: total episode reward; start_time, metric_time: episode start and end in
        seconds (simulation clock); completion_percentage: progress in [0, 100].
        Episodes continue the run-wide count; trials restart at 1 (one call = one iteration).
        """
        columns = _episode_timing(start_time, metric_time, completion_percentage, episode_status)
        n_rows = len(columns["start_time"])
        episodes = list(range(self.last_episode + 1, self.last_episode + n_rows + 1))
        self._append("training", reward_score, columns, episodes, list(range(1, n_rows + 1)))
        if n_rows:
            self.last_episode, self.last_trial = episodes[-1], n_rows

    def append_evaluation(self, *, reward_score, start_time, metric_time, completion_percentage,
                          episode_status) -> None:
        """Append evaluation-phase episodes run between iterations (same arrays as training)."""
        columns = _episode_timing(start_time, metric_time, completion_percentage, episode_status)
        n_rows = len(columns["start_time"])
        self._append("evaluation", reward_score, columns, [self.last_episode] * n_rows,
                     [self.last_trial] * n_rows)

    def _append(self, phase: str, reward_score, columns: dict[str, list], episodes: list[int],
                trials: list[int]) -> None:
        rewards = np.rint(_numbers("reward_score", reward_score, len(episodes))).astype(np.int64).tolist()
        for index in range(len(episodes)):
            self.rows.append({
                "reward_score": rewards[index],
                "metric_time": columns["metric_time"][index],
                "start_time": columns["start_time"][index],
                "elapsed_time_in_milliseconds": columns["elapsed_time_in_milliseconds"][index],
                "episode": episodes[index],
                "trial": trials[index],
                "phase": phase,
                "completion_percentage": columns["completion_percentage"][index],
                "episode_status": columns["episode_status"][index],
            })
        atomic_write_json(self.path, {"metrics": self.rows, "version": TRAINING_METRICS_VERSION,
                                      "best_model_metric": self.best_model_metric}, indent=None)


class EvaluationMetricsWriter:
    """Maintains one `metrics/evaluation/evaluation-<stamp>.json`; an existing file is resumed."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.rows: list[dict[str, Any]] = read_metrics(self.path) if self.path.exists() else []

    def append_trials(self, *, completion_percentage, start_time, metric_time, episode_status,
                      crash_count, immobilized_count, off_track_count, reversed_count) -> None:
        """Append trials (arrays of n rows) and rewrite the file.

        start_time, metric_time: trial start and end in seconds (simulation clock, penalties
        included); the *_count arrays: resets of each kind during the trial.
        """
        columns = _episode_timing(start_time, metric_time, completion_percentage, episode_status)
        n_rows = len(columns["start_time"])
        counts = {name: _numbers(name, values, n_rows).astype(np.int64) for name, values in (
            ("crash_count", crash_count), ("immobilized_count", immobilized_count),
            ("off_track_count", off_track_count), ("reversed_count", reversed_count))}
        counts["reset_count"] = sum(counts.values())
        counts = {name: values.tolist() for name, values in counts.items()}
        first_trial = len(self.rows) + 1
        for index in range(n_rows):
            row = {name: columns[name][index] for name in (
                "completion_percentage", "metric_time", "start_time",
                "elapsed_time_in_milliseconds", "episode_status")}
            row.update({name: values[index] for name, values in counts.items()})
            row["trial"] = first_trial + index
            self.rows.append(row)
        atomic_write_json(self.path, {"metrics": self.rows}, indent=None)
