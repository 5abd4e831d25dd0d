"""DeepRacer action spaces (discrete lists and continuous ranges) and their mapping to commands."""

from __future__ import annotations

import math
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from laplab.errors import UserError
from laplab.vehicle.params import DEEPRACER, VehicleParams

# laplab's default: the DeepRacer console's largest discrete grid (steering granularity 7 up to 30
# degrees, speed granularity 3 up to 4 m/s), 21 actions. It laps far faster than deepracer-for-cloud's
# default (steering -30, -15, 0, 15, 30 degrees at 0.6 m/s); see docs/deviations.md.
DEFAULT_DISCRETE_ACTIONS = tuple((float(steer), speed) for steer in range(-30, 31, 10) for speed in (1.33, 2.67, 4.0))


class ActionSpaceError(UserError, ValueError):
    """An action space in model_metadata.json that DeepRacer would not accept."""

    default_field = "model_metadata"


@dataclass(frozen=True)
class ActionSpace:
    """A model's action space.

    Discrete: ``actions`` is a tuple of (steering_angle deg, speed m/s); the policy outputs an index.
    Continuous: ``steering`` and ``speed`` are (low, high) ranges; the policy outputs a point of
    [-1, 1]^2 (steering first), scaled linearly onto the ranges.
    """

    kind: str
    actions: tuple[tuple[float, float], ...] = ()
    steering: tuple[float, float] = (-30.0, 30.0)
    speed: tuple[float, float] = (0.5, 4.0)

    @property
    def is_discrete(self) -> bool:
        return self.kind == "discrete"

    def gym_space(self) -> gym.Space:
        if self.is_discrete:
            return gym.spaces.Discrete(len(self.actions))
        return gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def _table(self) -> np.ndarray:
        table = self.__dict__.get("_table_cache")
        if table is None:
            table = np.array(self.actions, dtype=np.float64).reshape(-1, 2)
            object.__setattr__(self, "_table_cache", table)
        return table

    def to_physical(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch of policy actions -> (steering_angle deg (N,), speed m/s (N,))."""
        if self.is_discrete:
            idx = np.asarray(actions, dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= len(self.actions)):
                raise ActionSpaceError(f"action index out of range 0..{len(self.actions) - 1}: {idx}")
            table = self._table()
            return table[idx, 0], table[idx, 1]
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(-1, 2), -1.0, 1.0)
        lo_s, hi_s = self.steering
        lo_v, hi_v = self.speed
        return lo_s + (a[:, 0] + 1.0) * 0.5 * (hi_s - lo_s), lo_v + (a[:, 1] + 1.0) * 0.5 * (hi_v - lo_v)

    def half_ranges(self) -> tuple[float, float]:
        """Continuous: half of the steering range (degrees) and of the speed range (m/s), the scales of
        DeepRacer's SAC log-probability (:func:`laplab.agents.sac_networks.deepracer_squashed_log_prob`)."""
        if self.is_discrete:
            raise ActionSpaceError("a discrete action space has no ranges")
        return 0.5 * (self.steering[1] - self.steering[0]), 0.5 * (self.speed[1] - self.speed[0])

    def to_commands(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch of policy actions -> (steering rad (N,), speed m/s (N,)) for the simulator."""
        steer_deg, speed = self.to_physical(actions)
        return np.radians(steer_deg), speed

    def sweep_actions(self) -> np.ndarray:
        """(K, 2) (steering deg, speed m/s) covering the space, for the reward validation sweep: every
        discrete action, or a 3 x 3 grid of a continuous space's ranges (ends and middles)."""
        if self.is_discrete:
            actions = np.arange(len(self.actions))
        else:
            grid = np.array([-1.0, 0.0, 1.0])
            actions = np.stack(np.meshgrid(grid, grid), axis=-1).reshape(-1, 2)
        return np.stack(self.to_physical(actions), axis=1)

    @property
    def max_speed(self) -> float:
        return float(max(s for _, s in self.actions)) if self.is_discrete else float(self.speed[1])

    def to_json(self) -> list | dict:
        """The ``action_space`` value of model_metadata.json."""
        if self.is_discrete:
            return [{"steering_angle": _num(a), "speed": _num(s)} for a, s in self.actions]
        return {"steering_angle": {"low": _num(self.steering[0]), "high": _num(self.steering[1])},
                "speed": {"low": _num(self.speed[0]), "high": _num(self.speed[1])}}


def _num(value: float) -> float | int:
    return int(value) if float(value).is_integer() else float(value)


def default_action_space() -> ActionSpace:
    return ActionSpace("discrete", DEFAULT_DISCRETE_ACTIONS)


#: The most actions a discrete action space may list (DeepRacer's console builds at most 7 x 3 = 21).
MAX_DISCRETE_ACTIONS = 64


def parse_action_space(value: object, kind: str | None, source: str,
                       vehicle: VehicleParams = DEEPRACER) -> ActionSpace:
    """Validate the ``action_space`` / ``action_space_type`` pair of a model_metadata.json."""
    if kind is None:
        kind = "continuous" if isinstance(value, dict) else "discrete"
    if kind not in ("discrete", "continuous"):
        raise ActionSpaceError(f"{source}: action_space_type must be 'discrete' or 'continuous', got {kind!r}.")
    max_steer, min_speed, max_speed = vehicle.max_steering_deg, vehicle.min_speed, vehicle.max_speed
    if kind == "discrete":
        if not isinstance(value, list) or not value:
            raise ActionSpaceError(f"{source}: a discrete action_space must be a non-empty list of "
                                   f'{{"steering_angle": deg, "speed": m/s}} objects, got {value!r:.80}.')
        if len(value) > MAX_DISCRETE_ACTIONS:
            raise ActionSpaceError(f"{source}: action_space lists {len(value):,} actions; a discrete action space "
                                   f"has 1 to {MAX_DISCRETE_ACTIONS} (DeepRacer's console offers up to 21). "
                                   "For a finer choice use a continuous action space.")
        actions = []
        for i, item in enumerate(value):
            where = f"{source}: action_space[{i}]"
            if not isinstance(item, dict) or not {"steering_angle", "speed"} <= item.keys():
                raise ActionSpaceError(f"{where} must be an object with keys steering_angle and speed, got {item!r}.")
            steer = _number(item["steering_angle"], f"{where}.steering_angle")
            speed = _number(item["speed"], f"{where}.speed")
            _check_range(steer, -max_steer, max_steer, f"{where}.steering_angle", "deg")
            _check_range(speed, min_speed, max_speed, f"{where}.speed", "m/s")
            actions.append((steer, speed))
        return ActionSpace("discrete", tuple(actions))
    if not isinstance(value, dict) or not {"steering_angle", "speed"} <= value.keys():
        raise ActionSpaceError(f'{source}: a continuous action_space must be {{"steering_angle": {{"low", "high"}}, '
                               f'"speed": {{"low", "high"}}}}, got {value!r:.80}.')
    ranges = []
    for key, lo_lim, hi_lim, unit in (("steering_angle", -max_steer, max_steer, "deg"),
                                      ("speed", min_speed, max_speed, "m/s")):
        rng = value[key]
        where = f"{source}: action_space.{key}"
        if not isinstance(rng, dict) or not {"low", "high"} <= rng.keys():
            raise ActionSpaceError(f"{where} must be an object with keys low and high, got {rng!r}.")
        low, high = _number(rng["low"], f"{where}.low"), _number(rng["high"], f"{where}.high")
        _check_range(low, lo_lim, hi_lim, f"{where}.low", unit)
        _check_range(high, lo_lim, hi_lim, f"{where}.high", unit)
        if not low < high:
            raise ActionSpaceError(f"{where}: low ({low}) must be smaller than high ({high}).")
        ranges.append((low, high))
    return ActionSpace("continuous", (), ranges[0], ranges[1])


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ActionSpaceError(f"{where} must be a finite number, got {value!r}.")
    return float(value)


def _check_range(value: float, low: float, high: float, where: str, unit: str) -> None:
    if not low - 1e-9 <= value <= high + 1e-9:
        raise ActionSpaceError(f"{where} = {value} {unit} is outside the car's range [{low}, {high}] {unit}.")
