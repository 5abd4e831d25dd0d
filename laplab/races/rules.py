"""A race's rules, as pure functions: its settings and their checks, the submission window, how an
evaluation's laps score under the race's ranking method, and the ranking of submissions.

Ranking methods (DeepRacer's): ``average_consecutive`` (the best mean of N consecutive completed
laps, the league's "average of 3"), ``best_lap``, ``total_time`` (all the race's laps, summed). Times
are seconds of simulation time with penalties included. On the board each racer counts once: their
best submission; ties go to the earlier submission.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from laplab.env.metadata import ALL_SENSORS as SENSORS
from laplab.errors import UserError

RACE_TYPES = ("time_trial", "object_avoidance", "head_to_bot")  # a race's objects and bots: its ``options``
RANKING_METHODS = ("average_consecutive", "best_lap", "total_time")
DIRECTIONS = ("counterclockwise", "clockwise")
MAX_LAPS = 5  # DeepRacer's evaluations: 1 to 5 trials


class RaceError(UserError):
    """A race setting or a submission the race refuses; the message names the field or rule."""


@dataclass(frozen=True)
class RaceSettings:
    """What a facilitator sets (DeepRacer Event Manager's and DeepRacer on AWS's race settings).

    - ``track``: a track name of the catalogue or a built-in design; ``direction``: counterclockwise
      (the track as drawn) or clockwise.
    - ``opens`` / ``closes``: the submission window, Unix seconds (None: open from creation / never closes).
    - ``ranking``: one of :data:`RANKING_METHODS`; ``consecutive_laps``: N of ``average_consecutive``.
    - ``laps``: laps each submission drives (1..5); ``off_track_penalty`` / ``collision_penalty``: s;
      ``max_resets``: resets per lap (None: unlimited); ``max_submissions``: per racer.
    - ``physics``: the car every submission drives (4, 5, 6 or classic; None: each model's own car).
    - ``sensors``: the sensors a model may use (empty: any); ``options``: the race type's settings, as
      :class:`laplab.sim.race_type.RaceType` names them (``objects``, ``randomize_objects``,
      ``object_positions``, ``bots``, ``bot_speed``, ``lane_change``...); every submission drives them.
    """

    name: str
    track: str
    description: str = ""
    direction: str = "counterclockwise"
    race_type: str = "time_trial"
    opens: float | None = None
    closes: float | None = None
    ranking: str = "average_consecutive"
    consecutive_laps: int = 3
    laps: int = 3
    off_track_penalty: float = 2.0
    collision_penalty: float = 5.0
    max_resets: int | None = None
    max_submissions: int = 10
    private: bool = False
    physics: str | None = "5"
    sensors: tuple[str, ...] = ()
    options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sensors", tuple(self.sensors or ()))
        _check(isinstance(self.name, str) and 1 <= len(self.name.strip()) <= 80, "name", "1 to 80 characters")
        _check(isinstance(self.description, str) and len(self.description) <= 2000, "description",
               "at most 2,000 characters")
        _check(isinstance(self.track, str) and bool(self.track), "track", "a track name (GET /api/tracks)")
        _check(self.direction in DIRECTIONS, "direction", f"one of {', '.join(DIRECTIONS)}")
        _check(self.race_type in RACE_TYPES, "race_type",
               f"one of the race types this console runs: {', '.join(RACE_TYPES)}")
        _check(self.ranking in RANKING_METHODS, "ranking", f"one of {', '.join(RANKING_METHODS)}")
        _check(_int(self.laps) and 1 <= self.laps <= MAX_LAPS, "laps", f"an integer from 1 to {MAX_LAPS}")
        _check(_int(self.consecutive_laps) and 1 <= self.consecutive_laps <= MAX_LAPS, "consecutive_laps",
               f"an integer from 1 to {MAX_LAPS}")
        if self.ranking == "average_consecutive":
            _check(self.consecutive_laps <= self.laps, "consecutive_laps",
                   f"at most the race's laps ({self.laps}) to rank by the average of consecutive laps")
        for name in ("off_track_penalty", "collision_penalty"):
            value = getattr(self, name)
            _check(_number(value) and 0 <= value <= 60, name, "seconds from 0 to 60")
        _check(self.max_resets is None or (_int(self.max_resets) and 0 <= self.max_resets <= 100), "max_resets",
               "an integer from 0 to 100, or null for unlimited")
        _check(_int(self.max_submissions) and 1 <= self.max_submissions <= 1000, "max_submissions",
               "an integer from 1 to 1000")
        for name in ("opens", "closes"):
            value = getattr(self, name)
            _check(value is None or (_number(value) and value >= 0), name, "Unix seconds, or null")
        if self.opens is not None and self.closes is not None:
            _check(self.closes > self.opens, "closes", "after the race opens")
        _check(all(s in SENSORS for s in self.sensors), "sensors", f"a list of {', '.join(SENSORS)}")
        _check(isinstance(self.options, dict), "options", "an object of the race type's settings")
        self.race()  # the race type's options are checked (and the track's room for them when it is run)
        if self.physics is not None:
            from laplab.vehicle.physics import PhysicsError, resolve_physics
            try:
                object.__setattr__(self, "physics", resolve_physics(self.physics, option="physics"))
            except PhysicsError as exc:
                raise RaceError(str(exc), field="physics") from None

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["sensors"] = list(self.sensors)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "RaceSettings":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise RaceError(f"{unknown[0]}: not a race setting ({', '.join(sorted(known))})", field=unknown[0])
        try:
            return cls(**data)
        except TypeError as exc:
            raise RaceError(f"race: {exc}") from None

    def race(self):
        """The :class:`laplab.sim.race_type.RaceType` every submission drives (its collision penalty is
        the race's); None for a time trial. Options of another race type are refused, naming them."""
        if self.race_type == "time_trial":
            _check(not self.options, "options", "none for a time trial (objects and bots belong to object "
                                                "avoidance and head-to-bot races)")
            return None
        from laplab.sim.race_type import RaceType, RaceTypeError
        known = {"objects", "object_positions", "randomize_objects", "min_object_distance", "object_type"} \
            if self.race_type == "object_avoidance" else \
            {"bots", "bot_speed", "bot_lane", "randomize_bots", "min_bot_distance", "lane_change",
             "lane_change_min_s", "lane_change_max_s", "lane_change_distance"}
        unknown = sorted(set(self.options) - known)
        kind = "an object-avoidance" if self.race_type == "object_avoidance" else "a head-to-bot"
        _check(not unknown, "options", f"settings of {kind} race ({', '.join(sorted(known))}); "
                                       f"{unknown[0] if unknown else ''!r} is not one")
        try:
            return RaceType(kind=self.race_type, collision_penalty=float(self.collision_penalty), **self.options)
        except (RaceTypeError, TypeError, ValueError) as exc:
            raise RaceError(f"options: {str(exc).replace('--', '')}", field="options") from None

    def evaluation_params(self, track_key: str) -> dict:
        """The console's evaluate job under this race's rules: consecutive laps, with a video;
        ``track_key``: the track driven in the race's direction (:func:`laplab.races.catalogue.track_key`)."""
        params = {"track": track_key, "trials": self.laps, "off_track_penalty": float(self.off_track_penalty),
                  "crash_penalty": float(self.collision_penalty), "resets": self.max_resets, "continuous": True,
                  "video": True, "seed": 0, "checkpoint": "best", "max_trial_time": 180.0}
        if self.physics is not None:
            params["physics"] = self.physics
        race = self.race()
        if race is not None:
            params["race_type"] = race.to_dict()
        return params


def _check(ok: bool, name: str, expected: str) -> None:
    if not ok:
        raise RaceError(f"{name}: {expected}", field=name)


def _int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def window_refusal(settings: RaceSettings, closed: bool, now: float) -> str | None:
    """Why the race takes no submission at ``now`` (None when it does)."""
    if closed:
        return "window: the race is closed: it takes no more submissions"
    if settings.opens is not None and now < settings.opens:
        return "window: the race has not opened yet; it takes submissions from its opening time"
    if settings.closes is not None and now >= settings.closes:
        return "window: the race's submission window has closed"
    return None


def sensor_refusal(settings: RaceSettings, model_sensors: list[str]) -> str | None:
    """Why a model with ``model_sensors`` may not race (None when it may)."""
    if settings.sensors:
        extra = sorted(set(model_sensors) - set(settings.sensors))
        if extra:
            return (f"model: the race allows the sensors {', '.join(settings.sensors)}; this model uses "
                    f"{', '.join(extra)}")
    return None


@dataclass(frozen=True)
class Score:
    """One evaluation under a race's ranking: ``value`` (s, lower is better; None: not ranked, and
    ``reason`` says why) and the laps that made it."""
    value: float | None
    reason: str | None


def score(settings: RaceSettings, trials: list[dict]) -> Score:
    """Score an evaluation's laps (``trials``: the summary's trial dicts, in order)."""
    times = [t.get("lap_time") if t.get("status") == "lap_complete" else None for t in trials]
    done = [t for t in times if t is not None]
    if settings.ranking == "best_lap":
        return Score(min(done), None) if done else Score(None, "no lap completed")
    if settings.ranking == "total_time":
        if len(done) < settings.laps:
            return Score(None, f"{len(done)} of the race's {settings.laps} laps completed: total time ranks only "
                               "submissions that complete every lap")
        return Score(sum(done), None)
    n, best = settings.consecutive_laps, None
    for start in range(len(times) - n + 1):
        window = times[start:start + n]
        if all(t is not None for t in window):
            mean = sum(window) / n
            best = mean if best is None or mean < best else best
    if best is None:
        return Score(None, f"no {n} consecutive laps completed (the race ranks the average of {n} consecutive laps)")
    return Score(best, None)


def rank(entries: list[dict]) -> list[dict]:
    """The leaderboard: each racer's best scored entry (``user``, ``score``, ``created``), by score
    then submission time, with ``rank`` from 1; unscored entries are left out."""
    best: dict[Any, dict] = {}
    for entry in entries:
        if entry.get("score") is None:
            continue
        held = best.get(entry["user"])
        if held is None or (entry["score"], entry["created"]) < (held["score"], held["created"]):
            best[entry["user"]] = entry
    ordered = sorted(best.values(), key=lambda e: (e["score"], e["created"]))
    return [{**e, "rank": i + 1} for i, e in enumerate(ordered)]
