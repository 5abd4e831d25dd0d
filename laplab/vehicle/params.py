"""Frozen parameters of the simulated car, and the presets of DeepRacer's physics generations.

All lengths in metres, angles in radians unless the name says ``_deg``, times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

GRAVITY = 9.81  # m/s^2


@dataclass(frozen=True)
class VehicleParams:
    """Geometry and response of a 1/18 car: a kinematic bicycle with DeepRacer's measured lags.

    Geometry (deepracer-simapp's URDF, ``urdf/deepracer``):

    - ``wheelbase`` 0.164 m and ``wheel_track`` 0.162 m: distances between the wheel joints (front to
      rear axle, left to right rear wheel); the field defaults (0.165) are laplab's first car's.
    - ``body_length`` 0.324 m, ``body_width`` 0.196 m: the chassis footprint; the model origin sits on
      the rear axle, ``rear_overhang`` behind it is the part of the body behind the axle.
    - ``reference_offset`` 0.14 m: the point the reward function's ``x``, ``y`` describe lies this far
      ahead of the model origin (simapp's ``RELATIVE_POSITION_OF_FRONT_OF_CAR``).
    - ``max_steering_deg`` 30 and ``min_speed`` / ``max_speed`` 0.1 / 4 m/s: the action limits.

    Response to a 15 Hz action (``decision_hz``), integrated in ``substeps`` sub-steps:

    - ``action_delay``: fraction of a decision step (0..1) during which the previous action still
      drives the car (the controllers act on a new command late).
    - steering: the effective steering angle follows the command with a first-order lag of
      ``steering_time_constant`` s (0: at once) and at most ``steering_rate_deg`` deg/s toward
      ``s * tanh(command / s)`` with s = ``steering_saturation_deg`` (0: the command itself); the path's
      curvature is ``steering_gain * tan(steer + steering_offset) / wheelbase / (1 + understeer *
      speed^2)``, capped at ``max_lateral_acceleration / speed^2`` (the tyres saturate).
    - ``pivot_offset``: the point of the body that moves along the heading lies this far ahead of the
      rear axle (negative: behind it; a sliding rear axle moves it).
    - speed: follows ``speed_ratio * commanded speed`` with a first-order lag of
      ``speed_time_constant`` s (0: at once) and at most ``max_acceleration`` / ``max_braking``.
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
    action_delay: float = 0.0
    steering_time_constant: float = 0.0
    steering_gain: float = 1.0
    steering_offset_deg: float = 0.0
    steering_saturation_deg: float = 0.0
    understeer: float = 0.0
    pivot_offset: float = 0.0
    speed_ratio: float = 1.0
    speed_time_constant: float = 0.0
    name: str = "custom"
    description: str = ""

    def __post_init__(self) -> None:
        for name in ("wheelbase", "wheel_track", "body_length", "body_width", "max_speed",
                     "max_acceleration", "max_braking", "max_lateral_acceleration",
                     "decision_hz", "steering_rate_deg", "max_steering_deg", "steering_gain", "speed_ratio"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"VehicleParams.{name} must be a positive finite number, got {value!r}")
        for name in ("steering_time_constant", "speed_time_constant", "understeer", "steering_saturation_deg"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"VehicleParams.{name} must be a finite number >= 0, got {value!r}")
        if not 0.0 <= self.action_delay <= 1.0:
            raise ValueError(f"VehicleParams.action_delay must be within 0..1 of a step, got {self.action_delay!r}")
        for name in ("steering_offset_deg", "pivot_offset"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"VehicleParams.{name} must be finite")
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
    def steering_offset(self) -> float:
        """Steering offset, rad."""
        return math.radians(self.steering_offset_deg)

    @property
    def half_width(self) -> float:
        """Half of the body width, m (what a race line must keep from a border)."""
        return 0.5 * self.body_width

    def curvature(self, steer, speed):
        """Steady-state path curvature (1/m) of the pivot at steering ``steer`` (rad) and ``speed`` (m/s),
        grip cap included (numpy arrays or floats)."""
        import numpy as np
        steer, speed = np.asarray(steer, dtype=np.float64), np.asarray(speed, dtype=np.float64)
        steer = np.clip(steer, -self.max_steering, self.max_steering)
        if self.steering_saturation_deg > 0:
            saturation = math.radians(self.steering_saturation_deg)
            steer = saturation * np.tanh(steer / saturation)
        kappa = self.steering_gain * np.tan(steer + self.steering_offset) / self.wheelbase
        kappa = kappa / (1.0 + self.understeer * speed * speed)
        cap = self.max_lateral_acceleration / np.maximum(speed * speed, 1e-12)
        return np.clip(kappa, -cap, cap)

    def steering_for_curvature(self, kappa, speed):
        """Steering command (rad, clipped to the lock) whose steady state drives curvature ``kappa`` (1/m)
        at ``speed`` (m/s): :meth:`curvature` inverted, the grip cap aside (numpy arrays or floats)."""
        return self.command_for_wheel(self.wheel_for_curvature(kappa, speed))

    def wheel_for_curvature(self, kappa, speed):
        """Wheel angle (rad, after the saturation) whose path curvature is ``kappa`` (1/m) at ``speed``
        (m/s): the first half of :meth:`steering_for_curvature` (numpy arrays or floats)."""
        import numpy as np
        kappa, speed = np.asarray(kappa, dtype=np.float64), np.asarray(speed, dtype=np.float64)
        wheel = np.arctan(kappa * (1.0 + self.understeer * speed * speed) * self.wheelbase / self.steering_gain)
        return wheel - self.steering_offset

    def command_for_wheel(self, wheel):
        """Steering command (rad, clipped to the lock) whose saturated target is the wheel angle
        ``wheel`` (rad): the second half of :meth:`steering_for_curvature`."""
        import numpy as np
        wheel = np.asarray(wheel, dtype=np.float64)
        if self.steering_saturation_deg > 0:
            saturation = math.radians(self.steering_saturation_deg)
            wheel = saturation * np.arctanh(np.clip(wheel / saturation, -0.999999, 0.999999))
        return np.clip(wheel, -self.max_steering, self.max_steering)

    @property
    def response_steps(self) -> float:
        """Decision steps between a steering command and most of its effect (delay plus lag), the
        preview a path-following controller needs."""
        return self.action_delay + self.steering_time_constant * self.decision_hz

    def with_(self, **changes) -> "VehicleParams":
        """A copy with some fields changed."""
        return replace(self, **changes)


# laplab's car before it was fitted to DeepRacer's logs (a kinematic bicycle, 0.5 g of grip, no lags):
# the car of every model folder trained before physics versions existed, kept for them and for comparisons.
CLASSIC = VehicleParams(name="laplab-classic",
                        description="laplab's first car (kinematic bicycle, 5 m/s^2 grip), before DeepRacer's physics")

# DeepRacer's physics generations, chosen by model_metadata.json's "version" (laplab.vehicle.physics).
# Geometry from deepracer-simapp's URDF (wheel joints 0.164 m apart, rear track 0.162 m) and its tyres'
# friction (mu 0.5: at most 0.5 g sideways); the response fitted to each simulator's own simtraces
# (../shared/real-deepracer; scripts/fit_car.py, bench/fidelity.py; BENCHMARKS.md "Car fidelity").
_URDF = dict(wheelbase=0.164, wheel_track=0.162, substeps=4, max_lateral_acceleration=4.9, steering_rate_deg=3600.0)
DEEPRACER_V4 = VehicleParams(
    name="deepracer-v4", description="DeepRacer's effort-controlled car (simapp 4, model version below 5: the "
                                     "console and deepracer-for-cloud before 2023)",
    **_URDF, action_delay=0.5, steering_time_constant=0.453, steering_gain=0.826, steering_offset_deg=1.006,
    steering_saturation_deg=39.5, understeer=0.048, pivot_offset=-0.078, speed_ratio=1.025,
    speed_time_constant=0.107, max_acceleration=4.13, max_braking=30.0)
DEEPRACER_V5 = VehicleParams(
    name="deepracer-v5", description="DeepRacer's kinematics-controller car (simapp 5, model version 5: the "
                                     "console from 2023)",
    **_URDF, action_delay=0.75, steering_time_constant=0.107, steering_gain=1.446, steering_offset_deg=0.971,
    steering_saturation_deg=15.7, understeer=0.374, pivot_offset=-0.050, speed_ratio=1.071,
    speed_time_constant=0.055, max_acceleration=4.01, max_braking=30.0)
DEEPRACER_V6 = VehicleParams(
    name="deepracer-v6", description="DeepRacer on AWS's car (simapp 6 on ROS 2: model version 6 and above, and "
                                     "models without a version)",
    **_URDF, action_delay=0.75, steering_time_constant=0.154, steering_gain=0.801, steering_offset_deg=0.045,
    steering_saturation_deg=61.0, understeer=0.043, pivot_offset=-0.045, speed_ratio=1.025,
    speed_time_constant=0.0, max_acceleration=20.0, max_braking=27.1)
DEEPRACER = DEEPRACER_V6
PRESETS: dict[str, VehicleParams] = {p.name: p for p in (DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6, CLASSIC)}


def vehicle_preset(name: str) -> VehicleParams:
    """Look up a named car (``deepracer-v4``, ``deepracer-v5``, ``deepracer-v6``, ``laplab-classic``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown car {name!r}; known: {', '.join(sorted(PRESETS))}") from None
