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
