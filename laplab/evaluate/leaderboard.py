"""The leaderboard: every evaluated model ranked on a track by its best evaluation there.

Ranking (the DeepRacer league's order): average of three consecutive laps (ascending; models
without three consecutive completed laps after those with), then best lap (ascending; none last),
then average completion (descending), then off-track count (ascending). Each model is represented
by its best evaluation on the track under that same order. Evaluations without laplab's
``summary.json`` (made by other tools) carry no track and are not ranked. Race types are ranked
apart: a board is one track and one race (``"track"`` for time trials, ``"track [object avoidance:
3 boxes, evenly spaced]"`` for the others, from the evaluation's ``race_type``).

Only evaluations under the **standard rules** rank (:func:`standard_rules`): the console's off-track
penalty (2 s), the race's own collision penalty, unlimited resets, separate trials, the greedy policy,
the car the model trained with, the camera's plain look (no domain randomisation). An evaluation under other rules stays on its model's page. "Best lap"
means one thing everywhere (:func:`best_evaluated_lap`): a model's fastest evaluated lap under the
standard rules on its own training track and race; a lap of training is a "best training lap".
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from typing import Any

from laplab.evaluate.summary import EvaluationSummary, gap_to_optimal
from laplab.evaluate.trials import EvaluationError, read_evaluation_summary
from laplab.store.layout import list_models, model_folder


@dataclass(frozen=True)
class EvaluationRecord:
    """One stored evaluation: which model, when (stamp), on which track, and its summary."""

    model: str
    stamp: str
    track: str
    checkpoint: str | None
    summary: EvaluationSummary
    race: str = "time trial"  # RaceType.summary() of the evaluation's race
    standard: bool = True  # run under the standard rules (standard_rules), so it ranks

    @property
    def board(self) -> str:
        """The leaderboard this evaluation belongs to: its track, and its race unless a time trial."""
        return self.track if self.race == "time trial" else f"{self.track} [{self.race}]"


@dataclass(frozen=True)
class LeaderboardEntry:
    """A row of the leaderboard (times in s, completion in %)."""

    rank: int
    model: str
    stamp: str
    track: str
    checkpoint: str | None
    average_3: float | None
    best_lap: float | None
    completion: float
    off_track_count: int
    gap_to_optimal: float | None
    race: str = "time trial"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def load_records(root: str | os.PathLike | None = None) -> list[EvaluationRecord]:
    """Every laplab evaluation of every model under ``root`` (default: ``$LAPLAB_HOME/models``).

    A summary.json that cannot be read raises :class:`EvaluationError` naming the file.
    """
    return [record for name in list_models(root) for record in load_records_of(name, root)]


def load_records_of(name: str, root: str | os.PathLike | None = None) -> list[EvaluationRecord]:
    """The laplab evaluations of model ``name`` (see :func:`load_records`)."""
    records = []
    folder = model_folder(name, root)
    if folder.exists():
        for stamp in folder.list_evaluations():
            document = read_evaluation_summary(folder, stamp)
            if document is None:
                continue
            source = str(folder.evaluation_dir(stamp) / "summary.json")
            try:
                track = document["track"]["name"]
                summary = EvaluationSummary.from_dict(document["summary"], source)
            except (KeyError, TypeError, ValueError) as exc:
                raise EvaluationError(f"{source}: unreadable evaluation summary ({exc})") from None
            records.append(EvaluationRecord(name, stamp, str(track), document.get("checkpoint"), summary,
                                            _race_of(document.get("race_type"), source), standard_rules(document)))
    return records


def standard_rules(document: dict) -> bool:
    """Whether a summary.json's evaluation ran under the standard rules (see the module docstring)."""
    from laplab.evaluate.trials import EvaluationSettings
    settings, default = document.get("settings") or {}, EvaluationSettings()
    race = document.get("race_type") or {}
    collision = race.get("collision_penalty", default.crash_penalty) if isinstance(race, dict) else default.crash_penalty
    trained, driven = document.get("trained_car"), document.get("car")
    return (settings.get("off_track_penalty", default.off_track_penalty) == default.off_track_penalty
            and settings.get("crash_penalty", default.crash_penalty) == collision
            and settings.get("resets") is None and not settings.get("continuous") and not settings.get("stochastic")
            and not settings.get("domain_randomization")
            and (trained is None or driven is None or trained == driven))


def best_evaluated_lap(model: str, track: str | None, race: str = "time trial",
                       records: list[EvaluationRecord] | None = None,
                       root: str | os.PathLike | None = None) -> float | None:
    """Model ``model``'s best lap (s): its fastest completed lap of an evaluation under the standard
    rules on ``track`` (its training track) in ``race``; None without one."""
    records = load_records_of(model, root) if records is None else records
    laps = [r.summary.best_lap for r in records if r.model == model and r.standard and r.track == track
            and r.race == race and r.summary.best_lap is not None]
    return min(laps) if laps else None


def _race_of(data, source: str) -> str:
    from laplab.sim.race_type import RaceType, RaceTypeError
    try:
        return RaceType.from_dict(data, source).summary()
    except (RaceTypeError, TypeError) as exc:
        raise EvaluationError(f"{source}: unreadable race_type ({exc})") from None


def _sort_key(record: EvaluationRecord) -> tuple:
    s = record.summary
    return (s.average_3 is None, s.average_3 if s.average_3 is not None else math.inf,
            s.best_lap is None, s.best_lap if s.best_lap is not None else math.inf,
            -s.average_completion, s.off_track_count, record.model, record.stamp)


def rank(records: list[EvaluationRecord], track: str | None = None) -> dict[str, list[LeaderboardEntry]]:
    """Leaderboards per track and race (:attr:`EvaluationRecord.board`; only track ``track`` when
    given): each model's best evaluation there under the standard rules, ranked; boards in name order."""
    by_track: dict[str, dict[str, EvaluationRecord]] = {}
    for record in records:
        if not record.standard or (track is not None and record.track != track):
            continue
        models = by_track.setdefault(record.board, {})
        best = models.get(record.model)
        if best is None or _sort_key(record) < _sort_key(best):
            models[record.model] = record
    boards = {}
    for name in sorted(by_track):
        ordered = sorted(by_track[name].values(), key=_sort_key)
        boards[name] = [_entry(position + 1, record) for position, record in enumerate(ordered)]
    return boards


def _entry(position: int, record: EvaluationRecord) -> LeaderboardEntry:
    s = record.summary
    gap = s.gap_to_optimal
    if gap is None and s.best_lap is not None:
        gap = gap_to_optimal(s.best_lap, _optimal_for(record.track))
    return LeaderboardEntry(rank=position, model=record.model, stamp=record.stamp, track=record.track,
                            checkpoint=record.checkpoint, average_3=s.average_3, best_lap=s.best_lap,
                            completion=s.average_completion, off_track_count=s.off_track_count,
                            gap_to_optimal=gap, race=record.race)


def _optimal_for(track_name: str) -> float | None:
    """The cached optimal lap time of a track known by name (None when it cannot be loaded or solved)."""
    from laplab.evaluate.optimal import optimal_lap_time
    from laplab.track.geometry import TrackError
    from laplab.track.registry import load_track
    try:
        return optimal_lap_time(load_track(track_name))
    except (TrackError, ValueError, RuntimeError, ArithmeticError):
        return None


def leaderboard(track: str | None = None, root: str | os.PathLike | None = None) -> dict[str, list[LeaderboardEntry]]:
    """The leaderboards of the stored evaluations (see :func:`rank`)."""
    return rank(load_records(root), track)
