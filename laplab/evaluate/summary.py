"""Per-trial results of an evaluation and the figures DeepRacer reports for it.

Times are seconds of simulation time, penalties included. A *trial* is one lap attempt from the
start line (or, in continuous mode, one lap of a run that goes on without stopping).
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, fields
from typing import Any

import numpy as np

# Incident kinds, each counted separately (DeepRacer's evaluation metrics keep the same four counts).
INCIDENTS = ("off_track", "reversed", "immobilized", "crash")
LEAGUE_CONSECUTIVE_LAPS = 3


@dataclass(frozen=True)
class TrialResult:
    """One trial.

    - ``index``: 0-based trial number (the simtrace ``episode``).
    - ``status``: how it ended: ``lap_complete``, or the incident that ended it when no reset was left
      (``off_track``, ``reversed``, ``immobilized``, ``crashed``), or ``time_up`` at the time cap.
    - ``lap_time``: s from the start line to the finish, penalties included; None unless completed.
    - ``duration``: s the trial lasted (the lap time when completed), penalties included.
    - ``start_time``: s on the evaluation clock (trials laid end to end) when it started.
    - ``completion``: progress at the end, % of the lap.
    - ``*_count``: incidents of each kind, the one that ended the trial included.
    - ``reset_count``: times the car was put back on the track (incidents that did not end the trial).
    - ``penalty_time``: s of penalties served.
    - ``steps``: 15 Hz decisions driven.
    """

    index: int
    status: str
    lap_time: float | None
    duration: float
    start_time: float
    completion: float
    off_track_count: int = 0
    reversed_count: int = 0
    immobilized_count: int = 0
    crash_count: int = 0
    reset_count: int = 0
    penalty_time: float = 0.0
    steps: int = 0

    @property
    def completed(self) -> bool:
        return self.status == "lap_complete"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "summary.json") -> "TrialResult":
        return cls(**_known(cls, data, source))


@dataclass(frozen=True)
class EvaluationSummary:
    """The evaluation's headline figures.

    - ``best_lap``: fastest completed lap, s; ``average_lap``: mean of all completed laps, s.
    - ``average_3``: the league's metric: the best mean of 3 consecutive trials that all completed
      (None unless 3 completed in a row).
    - ``completed`` / ``trials``; ``completion_rate`` = completed / trials (0..1);
      ``average_completion``: mean completion, %.
    - ``off_track_count``, ``reset_count``, ``penalty_time``: totals over the trials.
    - ``optimal_lap_time``: the race line's lap time on this track and car, s (None if unknown);
      ``gap_to_optimal`` = best_lap / optimal_lap_time (1.0 = as fast as the race line).
      The race line's lap is a flying lap; ``standing_start_lap_time`` (s) is the same line driven
      from rest, the fastest possible lap for a trial that starts at rest.
    - ``identical_trials``: two or more trials that all ended alike, to the step (a greedy policy from the
      same start drives the same lap in laplab's noise-free physics; DeepRacer's trials differ by its
      simulator's noise).
    """

    trials: int
    completed: int
    best_lap: float | None
    average_lap: float | None
    average_3: float | None
    completion_rate: float
    average_completion: float
    off_track_count: int
    reset_count: int
    penalty_time: float
    optimal_lap_time: float | None = None
    gap_to_optimal: float | None = None
    standing_start_lap_time: float | None = None
    identical_trials: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "summary.json") -> "EvaluationSummary":
        return cls(**_known(cls, data, source))


def _known(cls, data: dict[str, Any], source: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a JSON object for {cls.__name__}, got {type(data).__name__}")
    names = {f.name for f in fields(cls)}
    required = {f.name for f in fields(cls) if f.default is MISSING}
    missing = sorted(required - set(data))
    if missing:
        raise ValueError(f"{source}: {cls.__name__} lacks key(s) {missing}")
    return {key: value for key, value in data.items() if key in names}


def best_consecutive_average(lap_times: list[float | None], count: int = LEAGUE_CONSECUTIVE_LAPS) -> float | None:
    """Best mean over ``count`` consecutive trials that all completed (None entries break a run)."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    times = np.array([np.nan if t is None else t for t in lap_times], dtype=np.float64)
    if times.size < count:
        return None
    windows = np.lib.stride_tricks.sliding_window_view(times, count)
    means = windows.mean(axis=1)  # NaN wherever a window holds an incomplete trial
    return None if np.all(np.isnan(means)) else float(np.nanmin(means))


def gap_to_optimal(lap_time: float | None, optimal_lap_time: float | None) -> float | None:
    """lap_time / optimal_lap_time, or None when either is unknown."""
    if lap_time is None or optimal_lap_time is None or not optimal_lap_time > 0:
        return None
    return float(lap_time) / float(optimal_lap_time)


def summarize(trials: list[TrialResult] | tuple[TrialResult, ...],
              optimal_lap_time: float | None = None, standing_start_lap_time: float | None = None) -> EvaluationSummary:
    """The summary of ``trials`` (in trial order); see :class:`EvaluationSummary`."""
    if not trials:
        raise ValueError("summarize: an evaluation needs at least one trial")
    laps = [t.lap_time if t.completed else None for t in trials]
    done = [t for t in laps if t is not None]
    best = min(done) if done else None
    return EvaluationSummary(
        trials=len(trials), completed=len(done), best_lap=best,
        average_lap=float(np.mean(done)) if done else None,
        average_3=best_consecutive_average(laps),
        completion_rate=len(done) / len(trials),
        average_completion=float(np.mean([t.completion for t in trials])),
        off_track_count=int(sum(t.off_track_count for t in trials)),
        reset_count=int(sum(t.reset_count for t in trials)),
        penalty_time=float(sum(t.penalty_time for t in trials)),
        optimal_lap_time=optimal_lap_time, gap_to_optimal=gap_to_optimal(best, optimal_lap_time),
        standing_start_lap_time=standing_start_lap_time, identical_trials=_all_alike(trials))


def _all_alike(trials) -> bool:
    """Whether two or more trials ended alike: status, steps, completion and incidents."""
    def outcome(t: TrialResult) -> tuple:
        return (t.status, t.steps, round(t.completion, 6), t.off_track_count, t.reversed_count,
                t.immobilized_count, t.crash_count, t.reset_count, round(t.penalty_time, 6))
    return len(trials) > 1 and len({outcome(t) for t in trials}) == 1


def format_seconds(value: float | None) -> str:
    """'12.345' (s) or '-' for None / NaN."""
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.3f}"


def format_gap(value: float | None) -> str:
    """'x1.234' or '-'."""
    return "-" if value is None else f"x{value:.3f}"


def trials_table(trials, optimal_lap_time: float | None = None, title: str | None = None):
    """A rich Table with one row per trial (incident counts: off track, reversed, immobilized, crash)."""
    from rich import box
    from rich.table import Table
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    for name in ("#", "status", "lap s", "done %", "off", "rev", "imm", "crash", "resets", "pen s", "gap"):
        table.add_column(name, justify="left" if name == "status" else "right", no_wrap=True)
    for t in trials:
        table.add_row(str(t.index + 1), t.status, format_seconds(t.lap_time), f"{t.completion:.1f}",
                      str(t.off_track_count), str(t.reversed_count), str(t.immobilized_count),
                      str(t.crash_count), str(t.reset_count), f"{t.penalty_time:g}",
                      format_gap(gap_to_optimal(t.lap_time, optimal_lap_time)))
    return table


def summary_lines(summary: EvaluationSummary) -> list[str]:
    """The summary as a few printable lines."""
    optimal = ("unknown" if summary.optimal_lap_time is None
               else f"{summary.optimal_lap_time:.3f} s (race line, flying")
    if summary.optimal_lap_time is not None:
        standing = summary.standing_start_lap_time
        optimal += ")" if standing is None else f"; {standing:.3f} s from a standing start)"
    return [
        f"best lap {format_seconds(summary.best_lap)} s   average {format_seconds(summary.average_lap)} s   "
        f"average of 3 consecutive {format_seconds(summary.average_3)} s",
        f"completed {summary.completed}/{summary.trials} ({100 * summary.completion_rate:.0f} %)   "
        f"average completion {summary.average_completion:.1f} %   off track {summary.off_track_count}   "
        f"resets {summary.reset_count}   penalties {summary.penalty_time:g} s",
        f"optimal lap {optimal}   gap to optimal {format_gap(summary.gap_to_optimal)}",
    ] + ([f"the {summary.trials} trials were identical: the greedy policy drives the same lap from the same "
          "start in laplab's noise-free physics (DeepRacer's trials differ by its simulator's noise); "
          "--stochastic samples the actions"] if summary.identical_trials else [])
