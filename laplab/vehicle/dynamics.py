"""Batched, pure dynamics of the car, and its footprint.

Model: a kinematic bicycle whose origin is the rear-axle centre, with an action delay, a steering
response (first-order lag, slew rate, gain, offset, understeer), speed tracking toward the commanded
speed (lag, acceleration / braking limits) and a lateral-grip cap (:class:`VehicleParams` documents
each; the cars fitted to DeepRacer's simulator are presets there). When the curvature asks for more
lateral acceleration than ``max_lateral_acceleration`` (v^2 |kappa| > a_lat), the tyres saturate and
the car follows kappa = a_lat / v^2 instead: it understeers. Each sub-step moves the pivot along an
exact circular arc, so a constant steering angle drives an exact circle.
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
    """The numbers the kernels read (:func:`advance_car`'s ``dc``), in a fixed order: the last three
    are the decision step and the steering's and speed's lag factors over one sub-step of it, so the
    simulator's fixed step computes no exponential."""
    h = params.dt / params.substeps
    return (params.wheelbase, params.steering_rate, params.max_acceleration, params.max_braking,
            params.max_lateral_acceleration, params.max_steering, int(params.substeps),
            params.action_delay, math.radians(params.steering_saturation_deg), params.steering_time_constant,
            params.steering_gain, params.steering_offset, params.understeer, params.pivot_offset,
            params.speed_ratio, params.speed_time_constant, params.dt,
            _lag_factor(h, params.steering_time_constant), _lag_factor(h, params.speed_time_constant))


@nb.njit(cache=True, inline="always")
def _lag_factor(h, time_constant):
    return 1.0 - math.exp(-h / time_constant) if time_constant > 0.0 else 1.0


@nb.njit(cache=True, inline="always")
def advance_car(x, y, yaw, speed, steer, prev_steer, prev_speed, cmd_steer, cmd_speed, dt, dc):
    """Advance one car by one decision step of ``dt`` s; returns the new (x, y, yaw, speed, steer).

    ``prev_*`` is the previous action's command (it still acts for ``action_delay`` of the step),
    ``cmd_*`` the new one; ``dc`` is :func:`dynamics_constants`' tuple.
    """
    (wheelbase, steer_rate, max_accel, max_brake, max_lat, max_steer, substeps, delay, saturation, steer_tau,
     steer_gain, steer_offset, understeer, pivot, speed_ratio, speed_tau, nominal_dt, a_steer, a_speed) = dc
    h = dt / substeps
    if dt != nominal_dt:  # a replayed log's step: its own lag factors
        a_steer = _lag_factor(h, steer_tau)
        a_speed = _lag_factor(h, speed_tau)
    late = delay * substeps
    prev_steer = min(max(prev_steer, -max_steer), max_steer)
    cmd_steer = min(max(cmd_steer, -max_steer), max_steer)
    if saturation > 0.0:
        prev_steer = saturation * math.tanh(prev_steer / saturation)
        cmd_steer = saturation * math.tanh(cmd_steer / saturation)
    c, s = math.cos(yaw), math.sin(yaw)
    px, py = x + pivot * c, y + pivot * s
    for j in range(substeps):
        if j + 0.5 < late:
            target_steer, target_speed = prev_steer, prev_speed
        else:
            target_steer, target_speed = cmd_steer, cmd_speed
        target_speed = max(target_speed, 0.0) * speed_ratio
        steer += min(max((target_steer - steer) * a_steer, -steer_rate * h), steer_rate * h)
        dv = (target_speed - speed) * a_speed
        new_speed = speed + (min(dv, max_accel * h) if dv > 0.0 else max(dv, -max_brake * h))
        ds = 0.5 * (speed + new_speed) * h
        speed = new_speed
        v_sq = speed * speed
        kappa = steer_gain * math.tan(steer + steer_offset) / wheelbase
        if understeer > 0.0:
            kappa /= 1.0 + understeer * v_sq
        if v_sq * abs(kappa) > max_lat:
            kappa = math.copysign(max_lat / v_sq, kappa)
        d_yaw = kappa * ds
        if abs(d_yaw) > 1e-9:  # c, s: cos and sin of the yaw, carried from sub-step to sub-step
            c_next, s_next = math.cos(yaw + d_yaw), math.sin(yaw + d_yaw)
            px += (s_next - s) / kappa
            py += (c - c_next) / kappa
            c, s = c_next, s_next
        else:
            px += ds * c
            py += ds * s
        yaw += d_yaw
    x, y = px - pivot * c, py - pivot * s
    if yaw > math.pi:
        yaw -= 2.0 * math.pi
    elif yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return x, y, yaw, speed, steer


def _step_loop(x, y, yaw, speed, steer, prev_steer, prev_speed, cmd_steer, cmd_speed, dt, dc,
               out_x, out_y, out_yaw, out_speed, out_steer):
    for i in nb.prange(x.shape[0]):
        out_x[i], out_y[i], out_yaw[i], out_speed[i], out_steer[i] = advance_car(
            x[i], y[i], yaw[i], speed[i], steer[i], prev_steer[i], prev_speed[i], cmd_steer[i], cmd_speed[i],
            dt, dc)


_step_serial = nb.njit(cache=True)(_step_loop)
_step_parallel = nb.njit(cache=True, parallel=True)(_step_loop)


def step(state: CarState, cmd_steer: np.ndarray, cmd_speed: np.ndarray, params: VehicleParams,
         previous: tuple[np.ndarray, np.ndarray] | None = None) -> CarState:
    """Pure batched step: ``(state, action, params) -> new state`` for N cars over ``params.dt``.

    ``cmd_steer`` (N,) rad and ``cmd_speed`` (N,) m/s are the commanded steering angle and speed;
    ``previous`` the (steer, speed) commands of the step before (None: the same command was held).
    """
    n = state.x.shape[0]
    out = CarState(*(np.empty(n) for _ in range(5)))
    loop = _step_parallel if n >= 256 else _step_serial
    steer_cmd = np.ascontiguousarray(np.broadcast_to(cmd_steer, (n,)), dtype=np.float64)
    speed_cmd = np.ascontiguousarray(np.broadcast_to(cmd_speed, (n,)), dtype=np.float64)
    prev_steer, prev_speed = (steer_cmd, speed_cmd) if previous is None else (
        np.ascontiguousarray(np.broadcast_to(p, (n,)), dtype=np.float64) for p in previous)
    loop(*(np.ascontiguousarray(a, dtype=np.float64) for a in state), prev_steer, prev_speed, steer_cmd, speed_cmd,
         float(params.dt), dynamics_constants(params), *out)
    return out


def step_reference(state: CarState, cmd_steer, cmd_speed, params: VehicleParams,
                   previous: tuple | None = None) -> CarState:
    """Plain numpy version of :func:`step` (vectorised over cars), the parity reference."""
    x, y, yaw, speed, steer = (np.array(a, dtype=np.float64) for a in state)
    p = params
    h = p.dt / p.substeps
    lag = lambda tau: 1.0 - math.exp(-h / tau) if tau > 0 else 1.0  # noqa: E731
    a_steer, a_speed = lag(p.steering_time_constant), lag(p.speed_time_constant)
    new_cmd = (np.asarray(cmd_steer, dtype=np.float64), np.asarray(cmd_speed, dtype=np.float64))
    old_cmd = new_cmd if previous is None else tuple(np.asarray(a, dtype=np.float64) for a in previous)
    saturation = math.radians(p.steering_saturation_deg)

    def steering_target(command):
        command = np.clip(command, -p.max_steering, p.max_steering)
        return saturation * np.tanh(command / saturation) if saturation > 0 else command

    new_cmd, old_cmd = (steering_target(new_cmd[0]), new_cmd[1]), (steering_target(old_cmd[0]), old_cmd[1])
    px, py = x + p.pivot_offset * np.cos(yaw), y + p.pivot_offset * np.sin(yaw)
    for j in range(p.substeps):
        target_steer, target_speed = old_cmd if j + 0.5 < p.action_delay * p.substeps else new_cmd
        target_speed = np.maximum(target_speed, 0.0) * p.speed_ratio
        steer = steer + np.clip((target_steer - steer) * a_steer, -p.steering_rate * h, p.steering_rate * h)
        dv = (target_speed - speed) * a_speed
        new_speed = speed + np.where(dv > 0, np.minimum(dv, p.max_acceleration * h),
                                     np.maximum(dv, -p.max_braking * h))
        ds = 0.5 * (speed + new_speed) * h
        speed = new_speed
        kappa = p.steering_gain * np.tan(steer + p.steering_offset) / p.wheelbase / (1.0 + p.understeer * speed ** 2)
        limit = p.max_lateral_acceleration / np.maximum(speed * speed, 1e-300)
        kappa = np.where(speed * speed * np.abs(kappa) > p.max_lateral_acceleration,
                         np.copysign(limit, kappa), kappa)
        d_yaw = kappa * ds
        arc = np.abs(d_yaw) > 1e-9
        safe_k = np.where(arc, kappa, 1.0)
        px = px + np.where(arc, (np.sin(yaw + d_yaw) - np.sin(yaw)) / safe_k, ds * np.cos(yaw + 0.5 * d_yaw))
        py = py + np.where(arc, (np.cos(yaw) - np.cos(yaw + d_yaw)) / safe_k, ds * np.sin(yaw + 0.5 * d_yaw))
        yaw = yaw + d_yaw
    yaw = np.where(yaw > np.pi, yaw - 2 * np.pi, np.where(yaw <= -np.pi, yaw + 2 * np.pi, yaw))
    return CarState(px - p.pivot_offset * np.cos(yaw), py - p.pivot_offset * np.sin(yaw), yaw, speed, steer)


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
