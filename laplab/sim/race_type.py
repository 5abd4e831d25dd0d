"""DeepRacer's race types and their options: time trial, object avoidance, head-to-bot, head-to-model.

One frozen :class:`RaceType` holds a job's choice (``laplab.json``'s ``race_type``; a file without it
is a time trial). The options follow deepracer-for-cloud's ``DR_OA_*`` / ``DR_H2B_*`` settings and
simapp's ``markov/agent_ctrl`` (see docs/race-types.md):

- object avoidance: ``objects`` boxes (or parked bot cars, ``object_type="bot_car"``), at
  ``object_positions`` (``(fraction of the lap, lane)`` pairs, lane +1 inner / -1 outer, as
  ``DR_OA_OBJECT_POSITIONS``), else evenly spaced from ``min_object_distance`` to 1 m before the
  finish on alternating lanes, or with ``randomize_objects`` shuffled per episode keeping
  ``min_object_distance`` (m) between neighbours, on random lanes.
- head-to-bot: ``bots`` bot cars at ``bot_speed`` m/s on ``bot_lane`` (``alternate``: inner, outer,
  inner...; ``inner``, ``outer``, ``center``), ``min_bot_distance`` m apart, optionally randomised,
  changing lanes every ``lane_change_min_s``..``lane_change_max_s`` s over ``lane_change_distance`` m.
- head-to-model: ``opponents`` model names, each driving its own car (``laplab race``).

``collision_penalty`` (s) is what evaluation holds a car for after a crash (DeepRacer's 5 s).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from laplab.errors import UserError

TIME_TRIAL, OBJECT_AVOIDANCE, HEAD_TO_BOT, HEAD_TO_MODEL = "time_trial", "object_avoidance", "head_to_bot", "head_to_model"
RACE_TYPES = (TIME_TRIAL, OBJECT_AVOIDANCE, HEAD_TO_BOT, HEAD_TO_MODEL)
BOT_LANES = ("alternate", "inner", "outer", "center")
OBJECT_TYPES = ("box", "bot_car")
MAX_OBJECTS = 12  # DeepRacer on AWS offers 1-6; deepracer-for-cloud takes any number
MAX_BOTS = 6
BOT_SPEED_RANGE = (0.1, 4.0)  # m/s: DeepRacer's MIN_SPEED .. MAX_SPEED
INNER, OUTER = 1, -1  # DR_OA_OBJECT_POSITIONS lane codes


class RaceTypeError(UserError, ValueError):
    """A race-type option out of range."""

    default_field = "race_type"


@dataclass(frozen=True)
class RaceType:
    """A race type and its options (see the module docstring; lengths m, speeds m/s, times s)."""

    kind: str = TIME_TRIAL
    objects: int = 6
    object_positions: tuple[tuple[float, int], ...] = ()
    randomize_objects: bool = False
    min_object_distance: float = 2.0
    object_type: str = "box"
    bots: int = 3
    bot_speed: float = 0.2
    bot_lane: str = "alternate"
    randomize_bots: bool = False
    min_bot_distance: float = 2.0
    lane_change: bool = False
    lane_change_min_s: float = 3.0
    lane_change_max_s: float = 5.0
    lane_change_distance: float = 1.0
    collision_penalty: float = 5.0
    opponents: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in RACE_TYPES:
            raise RaceTypeError(f"--race-type: unknown race type {self.kind!r}; known: {', '.join(RACE_TYPES)}",
                                field="--race-type")
        positions = tuple((float(p[0]), int(p[1])) for p in self.object_positions)
        object.__setattr__(self, "object_positions", positions)
        object.__setattr__(self, "opponents", tuple(self.opponents))
        if positions:
            object.__setattr__(self, "objects", len(positions))
        _integer(self.objects, "--objects", 1, MAX_OBJECTS)
        _integer(self.bots, "--bots", 1, MAX_BOTS)
        for ndist, lane in positions:
            if not 0.0 <= ndist < 1.0:
                raise RaceTypeError(f"--object-positions: {ndist} is not a fraction of the lap in [0, 1) "
                                    f"(write e.g. 0.25,1;0.5,-1)", field="--object-positions")
            if lane not in (INNER, OUTER):
                raise RaceTypeError(f"--object-positions: lane {lane} does not exist; a lane is 1 (inner) or "
                                    f"-1 (outer), as DR_OA_OBJECT_POSITIONS writes it", field="--object-positions")
        if self.object_type not in OBJECT_TYPES:
            raise RaceTypeError(f"--object-type: unknown {self.object_type!r}; known: {', '.join(OBJECT_TYPES)}",
                                field="--object-type")
        if self.bot_lane not in BOT_LANES:
            raise RaceTypeError(f"--bot-lane: the lane {self.bot_lane!r} does not exist; lanes: "
                                f"{', '.join(BOT_LANES)}", field="--bot-lane")
        low, high = BOT_SPEED_RANGE
        if not (isinstance(self.bot_speed, (int, float)) and low <= self.bot_speed <= high):
            raise RaceTypeError(f"--bot-speed must be within {low}..{high} m/s (DeepRacer's speed range), got "
                                f"{self.bot_speed!r}", field="--bot-speed")
        for name, option in (("min_object_distance", "--min-object-distance"),
                             ("min_bot_distance", "--min-bot-distance"),
                             ("lane_change_distance", "--lane-change-distance"),
                             ("lane_change_min_s", "--lane-change-min"), ("lane_change_max_s", "--lane-change-max")):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise RaceTypeError(f"{option} must be a positive number, got {value!r}", field=option)
        if self.lane_change_max_s < self.lane_change_min_s:
            raise RaceTypeError(f"--lane-change-max ({self.lane_change_max_s} s) is below --lane-change-min "
                                f"({self.lane_change_min_s} s)", field="--lane-change-max")
        if not (math.isfinite(self.collision_penalty) and 0 <= self.collision_penalty <= 60):
            raise RaceTypeError(f"--collision-penalty must be within 0..60 s, got {self.collision_penalty!r}",
                                field="--collision-penalty")
        if self.kind == HEAD_TO_MODEL and not self.opponents:
            raise RaceTypeError("race type head_to_model needs an opponent model (--opponent NAME)",
                                field="--opponent")

    @property
    def has_objects(self) -> bool:
        """Whether anything besides the car is on the track (boxes, bots or other models' cars)."""
        return self.kind != TIME_TRIAL

    @property
    def slots(self) -> int:
        """Obstacle slots per car: boxes, bots or opponents' cars."""
        return {TIME_TRIAL: 0, OBJECT_AVOIDANCE: self.objects, HEAD_TO_BOT: self.bots,
                HEAD_TO_MODEL: len(self.opponents)}[self.kind]

    def check_track(self, track_length: float, track_name: str = "the track") -> None:
        """Refuse more objects or bots than fit on a lap of ``track_length`` m at the minimum distance."""
        if self.kind == OBJECT_AVOIDANCE and not self.object_positions:
            count, gap, option = self.objects, self.min_object_distance, "--objects"
        elif self.kind == HEAD_TO_BOT:
            count, gap, option = self.bots, self.min_bot_distance, "--bots"
        else:
            return
        # DeepRacer spreads them from ``gap`` to 1 m before the finish, ``gap`` apart
        room = track_length - 1.0 - gap
        if count > 1 and room < (count - 1) * gap or count == 1 and room < 0:
            fit = max(int(room // gap) + 1, 0) if room >= 0 else 0
            raise RaceTypeError(f"{option}: {count} do not fit on {track_name} ({track_length:.1f} m) at the minimum "
                                f"distance of {gap:g} m between them (they go from {gap:g} m to 1 m before the "
                                f"finish); at most {fit} fit: use fewer or a smaller minimum distance", field=option)

    def summary(self) -> str:
        """One line for a model's page and the leaderboard."""
        if self.kind == OBJECT_AVOIDANCE:
            where = ("fixed at " + "; ".join(f"{d:g},{lane}" for d, lane in self.object_positions)
                     if self.object_positions else ("randomised" if self.randomize_objects else "evenly spaced"))
            return f"object avoidance: {self.objects} {self.object_type.replace('_', ' ')}es, {where}"
        if self.kind == HEAD_TO_BOT:
            change = (f", lane changes every {self.lane_change_min_s:g}-{self.lane_change_max_s:g} s"
                      if self.lane_change else "")
            return f"head-to-bot: {self.bots} bots at {self.bot_speed:g} m/s ({self.bot_lane} lanes{change})"
        if self.kind == HEAD_TO_MODEL:
            return f"head-to-model against {', '.join(self.opponents)}"
        return "time trial"

    def to_dict(self) -> dict:
        data = asdict(self)
        data["object_positions"] = [list(p) for p in self.object_positions]
        data["opponents"] = list(self.opponents)
        return data

    @classmethod
    def from_dict(cls, data: dict | None, source: str = "laplab.json") -> RaceType:
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise RaceTypeError(f"{source}: race_type must be an object, got {type(data).__name__}")
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise RaceTypeError(f"{source}: race_type has an unknown key {unknown[0]!r}")
        return cls(**data)


def _integer(value, option: str, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise RaceTypeError(f"{option} must be an integer within {low}..{high}, got {value!r}", field=option)


def parse_object_positions(text: str) -> tuple[tuple[float, int], ...]:
    """``"0.25,1;0.5,-1"`` (DR_OA_OBJECT_POSITIONS: fraction of the lap, lane 1 inner / -1 outer) -> pairs."""
    pairs = []
    for item in str(text).replace(" ", "").split(";"):
        if not item:
            continue
        parts = item.split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            pairs.append((float(parts[0]), int(parts[1])))
        except ValueError:
            raise RaceTypeError(f"--object-positions: cannot read {item!r}; write fraction,lane pairs separated by "
                                f"';', e.g. 0.25,1;0.5,-1 (lane 1 inner, -1 outer)", field="--object-positions") from None
    return tuple(pairs)
