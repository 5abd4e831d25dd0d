"""Frozen parameters of the simulated car.

All lengths in metres, angles in radians unless the name says ``_deg``, times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

GRAVITY = 9.81  # m/s^2


@dataclass(frozen=True)
class VehicleParams:
    """Geometry and limits of a grip-limited 1/18 car (kinematic bicycle with a grip cap).

    The ``deepracer`` preset follows the AWS DeepRacer simulator's car (reference doc section 4):

    - ``wheelbase`` 0.165 m and ``wheel_track`` 0.162 m: the distances between the wheel
      centres of the sim car's URDF (front to rear axle, left to right wheel).
    - ``body_length`` 0.324 m, ``body_width`` 0.196 m: the chassis footprint; the model origin sits
      on the rear axle, ``rear_overhang`` behind it is the part of the body behind the axle.
    - ``reference_offset`` 0.14 m: the point the reward function's ``x``, ``y`` describe lies this
      far ahead of the model origin.
    - ``max_steering_deg`` 30: the action-space limit of every DeepRacer model.
    - ``steering_rate_deg`` 360 deg/s: the servo reaches full lock in ~1/12 s, i.e. within about one
      15 Hz decision, as the Gazebo car does.
    - ``min_speed``/``max_speed`` 0.1 / 4.0 m/s: the action-space limits.
    - ``max_acceleration`` 4.0 m/s^2 and ``max_braking`` 6.0 m/s^2: the Gazebo car reaches 4 m/s
      from rest in about a second of sim time and sheds speed faster than it gains it.
    - ``max_lateral_acceleration`` 5.0 m/s^2 (about 0.5 g): above it the tyres saturate and the car
      understeers (it follows a wider circle than the steering asks for). This is what makes
      corners, not straights, decide lap times.
    - ``substeps`` 4: the dynamics integrate at 60 Hz inside each 15 Hz decision.
    """

    wheelbase: float = 0.165
    wheel_track: float = 0.162
    body_length: float = 0.324
    body_width: float = 0.196
    rear_overhang: float = 0.08
    reference_offset: float = 0.14
    max_steering_deg: float = 30.0
    steering_rate_deg: float = 360.0
    min_speed: float = 0.1
    max_speed: float = 4.0
    max_acceleration: float = 4.0
    max_braking: float = 6.0
    max_lateral_acceleration: float = 5.0
    decision_hz: float = 15.0
    substeps: int = 4

    def __post_init__(self) -> None:
        for name in ("wheelbase", "wheel_track", "body_length", "body_width", "max_speed",
                     "max_acceleration", "max_braking", "max_lateral_acceleration",
                     "decision_hz", "steering_rate_deg", "max_steering_deg"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"VehicleParams.{name} must be a positive finite number, got {value!r}")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"VehicleParams.substeps must be a positive integer, got {self.substeps!r}")
        if not 0 <= self.min_speed < self.max_speed:
            raise ValueError("VehicleParams needs 0 <= min_speed < max_speed")

    @property
    def dt(self) -> float:
        """Duration of one decision step, s (1/15 s for DeepRacer)."""
        return 1.0 / self.decision_hz

    @property
    def max_steering(self) -> float:
        """Steering limit, rad."""
        return math.radians(self.max_steering_deg)

    @property
    def steering_rate(self) -> float:
        """Steering slew-rate limit, rad/s."""
        return math.radians(self.steering_rate_deg)

    @property
    def half_width(self) -> float:
        """Half of the body width, m (what a race line must keep from a border)."""
        return 0.5 * self.body_width

    def with_(self, **changes) -> "VehicleParams":
        """A copy with some fields changed."""
        return replace(self, **changes)


DEEPRACER = VehicleParams()
PRESETS: dict[str, VehicleParams] = {"deepracer": DEEPRACER}


def vehicle_preset(name: str) -> VehicleParams:
    """Look up a named preset (``deepracer``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None
