"""Read a model folder's training logs and simtraces into arrays for plots and reports (no plotting here).

Every loader is a pure function of the files on disk. Iterations are numbered from 1, as the trainer
reports them (``laplab train`` prints iteration 1 first); the simtrace file of iteration ``k`` is
``training-simtrace/<k-1>-iteration.csv`` (deepracer-for-cloud counts files from 0).
Missing optional files give empty results; a file that exists but cannot be read raises
:class:`ReportDataError` naming the file and what is wrong with it. Evaluations are read by
:mod:`laplab.analysis.evaluations`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from laplab.store.layout import ModelFolder
from laplab.store.simtrace import read_simtrace

LAP_COMPLETE_LABEL = "Lap complete"
# Loss entries that count work rather than measure the fit; not plotted as curves.
_LOSS_COUNTERS = frozenset({"num_steps", "num_minibatches", "num_gradient_steps", "epsilon"})


class ReportDataError(ValueError):
    """A log file of the model folder exists but cannot be read."""


@dataclass(frozen=True)
class EpisodeLog:
    """Episodes of ``metrics/TrainingMetrics.json``, E rows (training and evaluation phase).

    iteration: (E,) int, 1-based; training: (E,) bool, True for training-phase rows;
    reward: (E,) total episode reward; progress: (E,) % of the lap; lap_complete: (E,) bool;
    elapsed_s: (E,) episode duration, s.
    """

    iteration: np.ndarray
    training: np.ndarray
    reward: np.ndarray
    progress: np.ndarray
    lap_complete: np.ndarray
    elapsed_s: np.ndarray

    @property
    def size(self) -> int:
        return int(self.iteration.shape[0])


@dataclass(frozen=True)
class TrainingHistory:
    """Per-iteration series, I iterations (arrays (I,), NaN where a value is unknown).

    iteration: 1-based numbers; mean_reward / mean_progress (%) / completion_rate (0-1): means over the
    iteration's training episodes; eval_progress (%), eval_completion_rate (0-1), eval_lap_time (s):
    the greedy evaluation laps run after the iteration; env_steps: training steps so far;
    losses: name -> (I,) (``policy_loss``, ``value_loss``, ``entropy``, ``approx_kl``, ... as the
    learner reported them); episodes: the per-episode rows behind the means.
    """

    iteration: np.ndarray
    mean_reward: np.ndarray
    mean_progress: np.ndarray
    completion_rate: np.ndarray
    eval_progress: np.ndarray
    eval_completion_rate: np.ndarray
    eval_lap_time: np.ndarray
    env_steps: np.ndarray
    losses: dict[str, np.ndarray] = field(default_factory=dict)
    episodes: EpisodeLog | None = None

    @property
    def size(self) -> int:
        return int(self.iteration.shape[0])


@dataclass(frozen=True)
class Trace:
    """Simtrace rows, n of them (possibly from several files), each file's rows grouped by episode
    in step order.

    iteration: (n,) int, 1-based training iteration (0 for an evaluation); episode: (n,) int;
    x, y: (n,) m; steer: (n,) deg; throttle: (n,) m/s (the action's speed); reward: (n,);
    progress: (n,) %; action: (n,) int index (discrete) or (n, 2) [steer, speed] (continuous);
    status: (n,) str episode_status codes; on_track: (n,) bool all wheels on track.
    """

    iteration: np.ndarray
    episode: np.ndarray
    x: np.ndarray
    y: np.ndarray
    steer: np.ndarray
    throttle: np.ndarray
    reward: np.ndarray
    progress: np.ndarray
    action: np.ndarray
    status: np.ndarray
    on_track: np.ndarray

    @property
    def size(self) -> int:
        return int(self.x.shape[0])


# ------------------------------------------------------------------------------ training metrics


def read_json_file(path: Path) -> Any:
    """The JSON document in ``path``; :class:`ReportDataError` naming the file when it is not UTF-8 JSON."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ReportDataError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    except UnicodeDecodeError as exc:
        raise ReportDataError(f"{path}: not a UTF-8 JSON text file ({exc.reason} at byte {exc.start})") from None


def _column(rows: list[dict], key: str, path: Path, default: Any = None) -> list:
    values = [row.get(key, default) if isinstance(row, dict) else None for row in rows]
    if default is None and any(value is None for value in values):
        bad = next(i for i, value in enumerate(values) if value is None)
        raise ReportDataError(f"{path}: metrics row {bad} lacks the key {key!r} (row: {str(rows[bad])[:200]})")
    return values


def load_episode_log(path: str | Path) -> EpisodeLog:
    """Episodes of a TrainingMetrics.json file, iterations recovered as DeepRacer numbers them:
    ``trial`` restarts at 1 with each iteration's training episodes, and evaluation-phase rows follow
    the training rows of their iteration."""
    path = Path(path)
    document = read_json_file(path)
    rows = document.get("metrics") if isinstance(document, dict) else None
    if not isinstance(rows, list):
        raise ReportDataError(f"{path}: not a DeepRacer metrics file (expected an object with a 'metrics' list)")
    training = np.array([phase == "training" for phase in _column(rows, "phase", path)], dtype=bool)
    trial = np.array(_column(rows, "trial", path), dtype=np.int64)
    iteration = _iteration_numbers(training, trial)
    return EpisodeLog(
        iteration=iteration,
        training=training,
        reward=np.array(_column(rows, "reward_score", path), dtype=np.float64),
        progress=np.array(_column(rows, "completion_percentage", path), dtype=np.float64),
        lap_complete=np.array([s == LAP_COMPLETE_LABEL for s in _column(rows, "episode_status", path)], dtype=bool),
        elapsed_s=np.array(_column(rows, "elapsed_time_in_milliseconds", path, 0), dtype=np.float64) / 1000.0,
    )


def _iteration_numbers(training: np.ndarray, trial: np.ndarray) -> np.ndarray:
    """1-based iteration of each of E rows: a training row whose trial is 1, or does not exceed the
    previous training row's trial, starts an iteration; other rows belong to the latest one (rows
    before any training row to iteration 1); shape (E,)."""
    rows = np.arange(training.size)
    trials = trial[training]
    starts = np.ones(trials.size, dtype=bool)
    starts[1:] = (trials[1:] == 1) | (trials[1:] <= trials[:-1])
    numbers = np.zeros(training.size, dtype=np.int64)
    numbers[training] = np.cumsum(starts)
    latest_training_row = np.maximum.accumulate(np.where(training, rows, -1)) if rows.size else rows
    return np.where(latest_training_row >= 0, numbers[np.maximum(latest_training_row, 0)], 1)


def _group_mean(values: np.ndarray, groups: np.ndarray, count: int) -> np.ndarray:
    """Mean of ``values`` per group id 1..count, NaN for empty groups; shape (count,)."""
    sums = np.bincount(groups - 1, weights=values, minlength=count)[:count]
    sizes = np.bincount(groups - 1, minlength=count)[:count]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(sizes > 0, sums / np.maximum(sizes, 1), np.nan)


def load_iteration_log(folder: ModelFolder) -> list[dict[str, Any]]:
    """Rows of ``metrics/laplab-iterations.json`` (the trainer's per-iteration report), [] if absent."""
    path = folder.metrics_dir / "laplab-iterations.json"
    if not path.is_file():
        return []
    document = read_json_file(path)
    rows = document.get("iterations") if isinstance(document, dict) else None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "iteration" in r for r in rows):
        raise ReportDataError(f"{path}: expected an object with an 'iterations' list of objects "
                              "that each have an 'iteration' number")
    return rows


def load_training_history(folder: ModelFolder) -> TrainingHistory:
    """Per-iteration series of a model: means from TrainingMetrics.json, losses and step counts
    from laplab-iterations.json (either file may be missing; both missing gives 0 iterations)."""
    log_rows = load_iteration_log(folder)
    episodes = load_episode_log(folder.training_metrics) if folder.training_metrics.is_file() else None
    count = max([int(r["iteration"]) for r in log_rows] + [int(episodes.iteration.max()) if episodes and episodes.size else 0])
    by_iteration = {int(r["iteration"]): r for r in log_rows}

    def from_log(key: str) -> np.ndarray:
        values = [by_iteration.get(i, {}).get(key) for i in range(1, count + 1)]
        return np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)

    if episodes is not None and episodes.size:
        train, evaluate = episodes.training, ~episodes.training
        mean_reward = _group_mean(episodes.reward[train], episodes.iteration[train], count)
        mean_progress = _group_mean(episodes.progress[train], episodes.iteration[train], count)
        completion = _group_mean(episodes.lap_complete[train].astype(float), episodes.iteration[train], count)
        eval_progress = _group_mean(episodes.progress[evaluate], episodes.iteration[evaluate], count)
        eval_completion = _group_mean(episodes.lap_complete[evaluate].astype(float),
                                      episodes.iteration[evaluate], count)
    else:
        mean_reward, mean_progress = from_log("mean_reward"), from_log("mean_progress")
        completion, eval_progress = from_log("completion_rate"), from_log("eval_progress")
        completed, run = from_log("eval_completed"), from_log("eval_episodes")
        with np.errstate(invalid="ignore", divide="ignore"):
            eval_completion = completed / run
    loss_names = sorted({name for r in log_rows for name, value in (r.get("losses") or {}).items()
                         if name not in _LOSS_COUNTERS and isinstance(value, (int, float))})
    losses = {}
    for name in loss_names:
        values = [(by_iteration.get(i, {}).get("losses") or {}).get(name) for i in range(1, count + 1)]
        losses[name] = np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    return TrainingHistory(
        iteration=np.arange(1, count + 1), mean_reward=mean_reward, mean_progress=mean_progress,
        completion_rate=completion, eval_progress=eval_progress, eval_completion_rate=eval_completion,
        eval_lap_time=from_log("eval_lap_time"), env_steps=from_log("env_steps"), losses=losses,
        episodes=episodes)


# ------------------------------------------------------------------------------------- simtrace


def _trace_from_columns(columns: dict[str, np.ndarray], iteration: int) -> Trace:
    n = columns["X"].shape[0]
    # A batched simulator writes one row per car and step, interleaving episodes: group them.
    order = np.argsort(columns["episode"], kind="stable")
    columns = {name: values[order] for name, values in columns.items()}
    return Trace(iteration=np.full(n, iteration, np.int64), episode=columns["episode"], x=columns["X"],
                 y=columns["Y"], steer=columns["steer"], throttle=columns["throttle"], reward=columns["reward"],
                 progress=columns["progress"], action=columns["action"], status=columns["episode_status"],
                 on_track=columns["all_wheels_on_track"])


def concatenate_traces(traces: list[Trace]) -> Trace:
    """One Trace holding the rows of ``traces`` in order (actions must all be indices or all pairs)."""
    if not traces:
        empty = np.zeros(0)
        return Trace(np.zeros(0, np.int64), np.zeros(0, np.int64), empty, empty, empty, empty, empty, empty,
                     np.zeros(0, np.int64), np.zeros(0, dtype=np.dtypes.StringDType()), np.zeros(0, bool))
    pairs = [t.action.ndim == 2 for t in traces if t.size]
    if pairs and any(pairs) != all(pairs):
        raise ReportDataError("simtrace files mix discrete action indices and continuous [steer speed] pairs")
    names = Trace.__dataclass_fields__
    kept = [t for t in traces if t.size] or traces[:1]
    return Trace(**{name: np.concatenate([getattr(t, name) for t in kept]) for name in names})


def read_trace_file(path: str | Path, iteration: int = 0) -> Trace:
    """One simtrace CSV as a Trace, every row tagged with ``iteration``."""
    try:
        columns = read_simtrace(path)
    except ValueError as exc:  # the file is named once, whatever the reader's message says
        message = " ".join(str(exc).split())
        raise ReportDataError(message if str(path) in message else f"{path}: {message}") from None
    return _trace_from_columns(columns, iteration)


def load_training_traces(folder: ModelFolder, iterations: list[int] | np.ndarray) -> Trace:
    """The training simtrace rows of the given 1-based iterations (files that do not exist are skipped)."""
    traces = []
    for iteration in iterations:
        for path in folder.training_simtrace_files(int(iteration) - 1):  # one per rollout worker
            traces.append(read_trace_file(path, int(iteration)))
    return concatenate_traces(traces)


def traced_iterations(folder: ModelFolder) -> list[int]:
    """1-based iterations that have a training simtrace file, ascending."""
    return [index + 1 for index in folder.list_training_iterations()]


def last_episodes(trace: Trace, count: int) -> Trace:
    """The rows of the last ``count`` episodes of ``trace`` (by episode number, which is run-wide)."""
    if trace.size == 0:
        return trace
    keys = trace.iteration.astype(np.int64) * 10**9 + trace.episode
    unique = np.unique(keys)
    return select_rows(trace, np.isin(keys, unique[-max(int(count), 1):]))


def select_rows(trace: Trace, keep: np.ndarray) -> Trace:
    """The rows of ``trace`` where the (n,) bool mask ``keep`` is True."""
    return Trace(**{name: getattr(trace, name)[keep] for name in Trace.__dataclass_fields__})
