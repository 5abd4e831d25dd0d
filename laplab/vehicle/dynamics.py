"""Batched, pure dynamics of the grip-limited car, and its footprint.

Model: a kinematic bicycle whose origin is the rear-axle centre, with a steering servo of limited
slew rate, speed tracking toward the commanded speed under acceleration / braking limits, and a
lateral-grip cap. When the commanded curvature kappa = tan(steer) / wheelbase asks for more lateral
acceleration than ``max_lateral_acceleration`` (v^2 |kappa| > a_lat), the tyres saturate and the
car follows kappa = a_lat / v^2 instead: it understeers. Each sub-step moves the car along an exact
circular arc, so a constant steering angle drives an exact circle.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from laplab.vehicle.params import VehicleParams


class CarState(NamedTuple):
    """State of N cars; every field has shape (N,), float64."""

    x: np.ndarray  # m, rear-axle centre
    y: np.ndarray  # m
    yaw: np.ndarray  # rad, counter-clockwise from +x
    speed: np.ndarray  # m/s, >= 0
    steer: np.ndarray  # rad, actual front-wheel angle (positive = left)


def dynamics_constants(params: VehicleParams) -> tuple:
    """The floats the kernels read, in the order of :func:`advance_car`'s trailing arguments."""
    return (params.wheelbase, params.steering_rate, params.max_acceleration, params.max_braking,
            params.max_lateral_acceleration, params.max_steering, params.dt, int(params.substeps))


@nb.njit(cache=True, inline="always")
def advance_car(x, y, yaw, speed, steer, cmd_steer, cmd_speed,
                wheelbase, steer_rate, max_accel, max_brake, max_lat, max_steer, dt, substeps):
    """Advance one car by one decision step ``dt`` in ``substeps`` sub-steps; returns the new state."""
    h = dt / substeps
    cmd_steer = min(max(cmd_steer, -max_steer), max_steer)
    cmd_speed = max(cmd_speed, 0.0)
    for _ in range(substeps):
        d_steer = min(max(cmd_steer - steer, -steer_rate * h), steer_rate * h)
        steer += d_steer
        dv = cmd_speed - speed
        new_speed = speed + (min(dv, max_accel * h) if dv > 0.0 else max(dv, -max_brake * h))
        ds = 0.5 * (speed + new_speed) * h
        speed = new_speed
        kappa = math.tan(steer) / wheelbase
        v_sq = speed * speed
        if v_sq * abs(kappa) > max_lat:
            kappa = math.copysign(max_lat / v_sq, kappa)
        d_yaw = kappa * ds
        if abs(d_yaw) > 1e-9:
            x += (math.sin(yaw + d_yaw) - math.sin(yaw)) / kappa
            y += (math.cos(yaw) - math.cos(yaw + d_yaw)) / kappa
        else:
            x += ds * math.cos(yaw + 0.5 * d_yaw)
            y += ds * math.sin(yaw + 0.5 * d_yaw)
        yaw += d_yaw
    if yaw > math.pi:
        yaw -= 2.0 * math.pi
    elif yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return x, y, yaw, speed, steer


def _step_loop(x, y, yaw, speed, steer, cmd_steer, cmd_speed, consts, out_x, out_y, out_yaw, out_speed, out_steer):
    wheelbase, steer_rate, max_accel, max_brake, max_lat, max_steer, dt, substeps = consts
    for i in nb.prange(x.shape[0]):
        out_x[i], out_y[i], out_yaw[i], out_speed[i], out_steer[i] = advance_car(
            x[i], y[i], yaw[i], speed[i], steer[i], cmd_steer[i], cmd_speed[i],
            wheelbase, steer_rate, max_accel, max_brake, max_lat, max_steer, dt, substeps)


_step_serial = nb.njit(cache=True)(_step_loop)
_step_parallel = nb.njit(cache=True, parallel=True)(_step_loop)


def step(state: CarState, cmd_steer: np.ndarray, cmd_speed: np.ndarray, params: VehicleParams) -> CarState:
    """Pure batched step: ``(state, action, params) -> new state`` for N cars over ``params.dt``.

    ``cmd_steer`` (N,) rad and ``cmd_speed`` (N,) m/s are the commanded steering angle and speed.
    """
    n = state.x.shape[0]
    out = CarState(*(np.empty(n) for _ in range(5)))
    loop = _step_parallel if n >= 256 else _step_serial
    loop(*(np.ascontiguousarray(a, dtype=np.float64) for a in state),
               np.ascontiguousarray(cmd_steer, dtype=np.float64), np.ascontiguousarray(cmd_speed, dtype=np.float64),
               dynamics_constants(params), *out)
    return out


def step_reference(state: CarState, cmd_steer, cmd_speed, params: VehicleParams) -> CarState:
    """Plain numpy version of :func:`step` (vectorised over cars), the parity reference."""
    x, y, yaw, speed, steer = (np.array(a, dtype=np.float64) for a in state)
    h = params.dt / params.substeps
    cmd_steer = np.clip(np.asarray(cmd_steer, dtype=np.float64), -params.max_steering, params.max_steering)
    cmd_speed = np.maximum(np.asarray(cmd_speed, dtype=np.float64), 0.0)
    for _ in range(params.substeps):
        steer = steer + np.clip(cmd_steer - steer, -params.steering_rate * h, params.steering_rate * h)
        dv = cmd_speed - speed
        new_speed = speed + np.where(dv > 0, np.minimum(dv, params.max_acceleration * h),
                                     np.maximum(dv, -params.max_braking * h))
        ds = 0.5 * (speed + new_speed) * h
        speed = new_speed
        kappa = np.tan(steer) / params.wheelbase
        limit = params.max_lateral_acceleration / np.maximum(speed * speed, 1e-300)
        kappa = np.where(speed * speed * np.abs(kappa) > params.max_lateral_acceleration,
                         np.copysign(limit, kappa), kappa)
        d_yaw = kappa * ds
        arc = np.abs(d_yaw) > 1e-9
        safe_k = np.where(arc, kappa, 1.0)
        x = x + np.where(arc, (np.sin(yaw + d_yaw) - np.sin(yaw)) / safe_k, ds * np.cos(yaw + 0.5 * d_yaw))
        y = y + np.where(arc, (np.cos(yaw) - np.cos(yaw + d_yaw)) / safe_k, ds * np.sin(yaw + 0.5 * d_yaw))
        yaw = yaw + d_yaw
    yaw = np.where(yaw > np.pi, yaw - 2 * np.pi, np.where(yaw <= -np.pi, yaw + 2 * np.pi, yaw))
    return CarState(x, y, yaw, speed, steer)


def wheel_centers(poses: np.ndarray, params: VehicleParams) -> np.ndarray:
    """(N, 4, 2) wheel centres [front-left, front-right, rear-left, rear-right] of poses (N, 3)."""
    return _body_points(poses, np.array([[params.wheelbase, 0.5 * params.wheel_track],
                                         [params.wheelbase, -0.5 * params.wheel_track],
                                         [0.0, 0.5 * params.wheel_track],
                                         [0.0, -0.5 * params.wheel_track]]))


def body_corners(poses: np.ndarray, params: VehicleParams) -> np.ndarray:
    """(N, 4, 2) chassis corners [front-left, front-right, rear-right, rear-left] of poses (N, 3)."""
    front = params.body_length - params.rear_overhang
    half = 0.5 * params.body_width
    return _body_points(poses, np.array([[front, half], [front, -half],
                                         [-params.rear_overhang, -half], [-params.rear_overhang, half]]))


def reference_point(poses: np.ndarray, params: VehicleParams) -> np.ndarray:
    """(N, 2) the reward function's ``x, y``: ``reference_offset`` ahead of the origin."""
    return _body_points(poses, np.array([[params.reference_offset, 0.0]]))[:, 0]


def pose_for_reference(points: np.ndarray, yaw: np.ndarray, reference_offset: float) -> np.ndarray:
    """(K, 3) model-origin poses whose reference point (:func:`reference_point`, ``reference_offset`` m
    ahead of the origin) lies at ``points`` (K, 2) with headings ``yaw`` (K,) rad."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
    origin = points - reference_offset * np.column_stack([np.cos(yaw), np.sin(yaw)])
    return np.column_stack([origin, yaw])


def _body_points(poses: np.ndarray, local: np.ndarray) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    wx = poses[:, 0:1] + c * local[None, :, 0] - s * local[None, :, 1]
    wy = poses[:, 1:2] + s * local[None, :, 0] + c * local[None, :, 1]
    return np.stack([wx, wy], axis=-1)
