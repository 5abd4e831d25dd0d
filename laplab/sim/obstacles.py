"""Solid things on the track besides the car itself: DeepRacer's boxes, bot cars and other models' cars.

This is the one representation the simulator (placement, motion, collisions), the reward params
(``objects_*``), the sensors (camera, lidar, STATE summary) and the pictures share. Every car of a
batch has its own episode, so every car has its own K obstacle slots: all arrays are (N, K).

An obstacle is a vertical box (a prism standing on the ground): centre, heading, half length along
the heading, half width across it, height. A bot car or another model's car is drawn and collided
as the box of its body.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# kind codes: what a slot holds
EMPTY, BOX, BOT_CAR, MODEL_CAR = 0, 1, 2, 3
KIND_NAMES = ("empty", "box", "bot_car", "model_car")


class Obstacles(NamedTuple):
    """K obstacle slots for each of N cars, world frame; every field has shape (N, K)."""

    x: np.ndarray  # m, centre
    y: np.ndarray  # m, centre
    yaw: np.ndarray  # rad, heading of the long side
    half_length: np.ndarray  # m, along the heading
    half_width: np.ndarray  # m, across the heading
    height: np.ndarray  # m, above the ground
    kind: np.ndarray  # int64, EMPTY / BOX / BOT_CAR / MODEL_CAR

    @property
    def num_cars(self) -> int:
        return int(self.x.shape[0])

    @property
    def slots(self) -> int:
        return int(self.x.shape[1])

    def rows(self, cars: np.ndarray) -> "Obstacles":
        """The slots of the given cars (indices or a boolean mask), as a new Obstacles."""
        return Obstacles(*(field[cars] for field in self))


def no_obstacles(num_cars: int, slots: int = 0) -> Obstacles:
    """``slots`` empty slots for each of ``num_cars`` cars (slots=0: nothing on the track)."""
    shape = (int(num_cars), int(slots))
    return Obstacles(*(np.zeros(shape, dtype=np.int64 if name == "kind" else np.float64)
                       for name in Obstacles._fields))


def footprint_rows(obstacles: Obstacles, moving: bool, digits: int = 3,
                   limit: int = 512) -> tuple[list[list[float]], list[list[float]]]:
    """The obstacles as the console's live view draws them: ``(standing, driving)``.

    ``standing``: the distinct obstacles that stand (boxes; parked bot cars) over every car's slots,
    each ``[x, y, yaw, half_length, half_width, kind]`` (m, rad; rounded to ``digits``): cars of a fixed
    placement share one set, so it is sent once; ``driving`` (when ``moving``, head-to-bot's bots and
    other models' cars): ``[car, x, y, yaw, half_length, half_width, kind]`` for every occupied slot of
    every car, ``car`` the index of the car whose episode it drives in. At most ``limit`` rows each."""
    kind = np.asarray(obstacles.kind)
    columns = np.stack([np.asarray(f, dtype=np.float64) for f in (obstacles.x, obstacles.y, obstacles.yaw,
                                                                   obstacles.half_length, obstacles.half_width)], -1)
    columns = np.round(columns, digits)
    drives = (kind == MODEL_CAR) | (moving & (kind == BOT_CAR))
    standing, driving, seen = [], [], set()
    for car, slot in zip(*np.nonzero((kind != EMPTY) & ~drives)):
        row = (*columns[car, slot].tolist(), int(kind[car, slot]))
        if row not in seen and len(standing) < limit:
            seen.add(row)
            standing.append(list(row))
    for car, slot in zip(*np.nonzero(drives)):
        if len(driving) < limit:
            driving.append([int(car), *columns[car, slot].tolist(), int(kind[car, slot])])
    return standing, driving
