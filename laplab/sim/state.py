"""Episode state of N cars, episode rules and DeepRacer's episode statuses."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

# Episode statuses (DeepRacer's names); codes index STATUS_NAMES.
IN_PROGRESS, LAP_COMPLETE, OFF_TRACK, CRASHED, REVERSED, IMMOBILIZED, TIME_UP = range(7)
STATUS_NAMES = ("in_progress", "lap_complete", "off_track", "crashed", "reversed", "immobilized", "time_up")


@dataclass(frozen=True)
class EpisodeParams:
    """How episodes start and end (reference doc section 3).

    - ``start_ndist``: where the first episode starts, as a fraction of the lap.
    - ``round_robin_advance``: the start moves by this fraction of the lap after every episode
      (0.05 in DeepRacer training; 0 for a fixed start).
    - ``alternate_direction``: drive the track the other way every other episode.
    - ``reverse``: drive the track in its reverse direction (DeepRacer's ``is_reversed``).
    - ``max_steps``: hard cap on an episode's steps (DeepRacer: 100,000); ends as ``time_up``.
    - ``reversed_steps``: progress decreasing on this many consecutive steps ends as ``reversed``.
    - ``immobilized_steps`` / ``immobilized_distance``: moving at most this far (m) per step for this
      many steps ends as ``immobilized``.
    - ``spread_starts``: in a batch, car i starts ``i * round_robin_advance`` further along, so the
      cars of one batch cover the lap as consecutive DeepRacer episodes would.
    """

    start_ndist: float = 0.0
    round_robin_advance: float = 0.05
    alternate_direction: bool = False
    reverse: bool = False
    max_steps: int = 100_000
    reversed_steps: int = 15
    immobilized_steps: int = 15
    immobilized_distance: float = 0.0003
    spread_starts: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.start_ndist < 1.0:
            raise ValueError(f"EpisodeParams.start_ndist must be in [0, 1), got {self.start_ndist}")
        if not 0.0 <= self.round_robin_advance < 1.0:
            raise ValueError(f"EpisodeParams.round_robin_advance must be in [0, 1), got {self.round_robin_advance}")
        for name in ("max_steps", "reversed_steps", "immobilized_steps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"EpisodeParams.{name} must be a positive integer")


class SimState(NamedTuple):
    """Per-car episode state; every field has shape (N,)."""

    x: np.ndarray  # m, rear-axle centre (model origin)
    y: np.ndarray
    yaw: np.ndarray  # rad
    speed: np.ndarray  # m/s, measured
    steer: np.ndarray  # rad, actual wheel angle
    cmd_steer: np.ndarray  # rad, commanded by the last action
    cmd_speed: np.ndarray  # m/s, commanded by the last action
    ref_x: np.ndarray  # m, reference point (the reward function's x, y)
    ref_y: np.ndarray
    arc: np.ndarray  # m, projection of the reference point from waypoint 0
    lateral: np.ndarray  # m, signed offset of the reference point (left positive)
    segment: np.ndarray  # int64, centre-line segment of the projection
    seg_t: np.ndarray  # position within that segment, 0..1
    travel: np.ndarray  # m, signed arc length from start_arc to the reference point's projection, unwrapped
    progress: np.ndarray  # %, 0..100
    start_arc: np.ndarray  # m, arc length of the start pose's own centre-line point (DeepRacer's start_ndist)
    lap_time: np.ndarray  # s, set when the lap completes (0 otherwise)
    steps: np.ndarray  # int64, steps taken in this episode
    reverse_count: np.ndarray  # int64, consecutive steps with decreasing progress
    immobile_count: np.ndarray  # int64, consecutive steps moving <= immobilized_distance
    status: np.ndarray  # int64, one of the status codes
    direction: np.ndarray  # int64, 0 = track's own direction, 1 = reversed
    wheels_on: np.ndarray  # int64, wheel centres on the track (0..4)
    episode: np.ndarray  # int64, episodes started by this car slot


def episodes_done_and_steps(state: SimState) -> tuple[int, int]:
    """(cars whose episode has ended, steps driven by all cars): a collection's progress."""
    return int((state.status != IN_PROGRESS).sum()), int(state.steps.sum())


_INT_FIELDS = {"segment", "steps", "reverse_count", "immobile_count", "status", "direction", "wheels_on", "episode"}


def empty_state(num_cars: int) -> SimState:
    """Zeroed state of ``num_cars`` cars."""
    return SimState(*(np.zeros(num_cars, dtype=np.int64 if f in _INT_FIELDS else np.float64)
                      for f in SimState._fields))
