"""Read a model's evaluations (``evaluation-<stamp>`` folders) into arrays for plots and reports.

Each :class:`Evaluation` holds whatever exists on disk: its simtrace (read as in
:mod:`laplab.analysis.loaders`), laplab's ``summary.json`` and DeepRacer's evaluation metrics file.
A file that exists but cannot be read is listed in ``Evaluation.problems`` rather than raised, so one
bad evaluation does not hide the others.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from laplab.analysis.loaders import LAP_COMPLETE_LABEL, ReportDataError, Trace, read_json_file, read_trace_file
from laplab.store.layout import ModelFolder

_VIDEO_SUFFIXES = (".mp4", ".webm", ".gif")


@dataclass(frozen=True)
class Trial:
    """One evaluation trial. trial: 1-based; status: how it ended (``lap_complete``, ``off_track``,
    ... or DeepRacer's label); lap_time_s: None unless the lap completed (penalties included);
    completion: %; off_track_count: times it left the track (None when unknown)."""

    trial: int
    status: str
    completion: float
    lap_time_s: float | None
    off_track_count: int | None


@dataclass(frozen=True)
class Evaluation:
    """One ``evaluation-<stamp>`` of a model: what of it exists on disk.

    trace: its simtrace (None when absent); trials: from summary.json, else from the DeepRacer
    evaluation metrics file; summary: laplab's summary.json as read (None when absent); video: the
    video file the summary names (None when absent or missing on disk); track: the track the
    summary names (None: the model's training track); reverse: its direction (None: the model's);
    optimal_lap_time: the race line's lap time the evaluator reported, s (None when it did not);
    standing_start_lap_time: the same line driven from rest, as each trial starts, s (None when not
    reported); problems: files that exist but could not be read.
    """

    stamp: str
    trace: Trace | None
    trials: tuple[Trial, ...]
    summary: dict[str, Any] | None
    video: Path | None
    track: str | None
    reverse: bool | None
    optimal_lap_time: float | None
    standing_start_lap_time: float | None
    problems: tuple[str, ...]


def _first(mapping: dict, *keys: str) -> Any:
    """The value of the first of ``keys`` present (not None) in ``mapping``, else None."""
    for key in keys:
        if isinstance(mapping, dict) and mapping.get(key) is not None:
            return mapping[key]
    return None


def _number(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) else None


def _trial_from_summary(position: int, row: dict) -> Trial:
    """A trial of laplab's summary.json (``index`` counts from 0) or a similar row."""
    status = str(_first(row, "status", "episode_status") or "?")
    completed = status.lower().replace(" ", "_") == "lap_complete"
    index = _number(row.get("index"))
    number = int(index) + 1 if index is not None else int(_number(row.get("trial")) or position + 1)
    off_track = _number(_first(row, "off_track_count", "off_track"))
    return Trial(trial=number, status=status,
                 completion=_number(_first(row, "completion", "progress", "completion_percentage")) or 0.0,
                 lap_time_s=_number(_first(row, "lap_time", "lap_time_s")) if completed else None,
                 off_track_count=None if off_track is None else int(off_track))


def _trial_from_metrics(row: dict) -> Trial:
    completed = row.get("episode_status") == LAP_COMPLETE_LABEL
    elapsed = _number(row.get("elapsed_time_in_milliseconds"))
    off_track = _number(row.get("off_track_count"))
    return Trial(trial=int(row.get("trial", 0)), status=str(row.get("episode_status", "?")),
                 completion=_number(row.get("completion_percentage")) or 0.0,
                 lap_time_s=elapsed / 1000.0 if completed and elapsed is not None else None,
                 off_track_count=None if off_track is None else int(off_track))


def _summary_value(summary: dict | None, *keys: str) -> Any:
    """A value of summary.json at its top level or inside its ``summary`` object."""
    if not summary:
        return None
    found = _first(summary, *keys)
    return found if found is not None else _first(summary.get("summary") or {}, *keys)


def _summary_video(summary: dict, evaluation_dir: Path) -> Path | None:
    candidate = _summary_value(summary, "video", "video_path", "video_file")
    if isinstance(candidate, dict):
        candidate = _first(candidate, "path", "file")
    if not isinstance(candidate, str) or not candidate:
        return None
    path = Path(candidate)
    for option in ((path,) if path.is_absolute() else (evaluation_dir / path, evaluation_dir.parent / path)):
        if option.is_file() and option.suffix.lower() in _VIDEO_SUFFIXES:
            return option
    return None


def load_evaluation(folder: ModelFolder, stamp: str) -> Evaluation:
    """Whatever exists of evaluation ``stamp``: simtrace, laplab summary.json, DeepRacer metrics file.
    Unreadable files are listed in ``problems`` rather than raised, so one bad evaluation does not
    hide the others."""
    problems: list[str] = []
    trace = summary = None
    simtrace_path = folder.evaluation_simtrace(stamp)
    if simtrace_path.is_file():
        try:
            trace = read_trace_file(simtrace_path)
        except ReportDataError as exc:
            problems.append(str(exc))
    summary_path = folder.evaluation_dir(stamp) / "summary.json"
    if summary_path.is_file():
        try:
            summary = read_json_file(summary_path)
            if not isinstance(summary, dict):
                raise ReportDataError(f"{summary_path}: expected a JSON object, got {type(summary).__name__}")
        except ReportDataError as exc:
            problems.append(str(exc))
            summary = None
    trials: list[Trial] = []
    summary_trials = _summary_value(summary, "trials", "laps")
    if isinstance(summary_trials, list) and all(isinstance(row, dict) for row in summary_trials):
        trials = [_trial_from_summary(i, row) for i, row in enumerate(summary_trials)]
    elif folder.evaluation_metrics(stamp).is_file():
        try:
            rows = read_json_file(folder.evaluation_metrics(stamp)).get("metrics", [])
            trials = [_trial_from_metrics(row) for row in rows if isinstance(row, dict)]
        except (ReportDataError, AttributeError) as exc:
            problems.append(str(exc) if isinstance(exc, ReportDataError)
                            else f"{folder.evaluation_metrics(stamp)}: expected an object with a 'metrics' list")
    # laplab evaluate writes {"settings": {"track": what the user named or None}, "track": {"name": ...}}.
    track = _first((summary or {}).get("settings") or {}, "track") or _summary_value(summary, "track", "track_name")
    if isinstance(track, dict):
        track = track.get("name")
    reverse = _summary_value(summary, "reverse", "reversed")
    return Evaluation(stamp=stamp, trace=trace, trials=tuple(trials), summary=summary,
                      video=_summary_video(summary, folder.evaluation_dir(stamp)) if summary else None,
                      track=str(track) if isinstance(track, str) else None,
                      reverse=bool(reverse) if reverse is not None else None,
                      optimal_lap_time=_number(_summary_value(summary, "optimal_lap_time")),
                      standing_start_lap_time=_number(_summary_value(summary, "standing_start_lap_time")),
                      problems=tuple(problems))


def load_evaluations(folder: ModelFolder, latest: int | None = None) -> list[Evaluation]:
    """The model's evaluations, oldest first (only the ``latest`` newest when given)."""
    stamps = folder.list_evaluations()
    if latest is not None:
        stamps = stamps[-latest:] if latest > 0 else []
    return [load_evaluation(folder, stamp) for stamp in stamps]
