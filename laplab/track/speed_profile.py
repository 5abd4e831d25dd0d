"""Velocity profile of a closed path under the simulator's car limits.

The path is the one the car's pivot follows (:class:`VehicleParams`: the rear-axle centre, or
``pivot_offset`` from it). Its curvature is ``steering_gain * tan(steering) / wheelbase`` at low speed
(:func:`limit_arguments` folds the gain into an effective wheelbase), so the same curvature bounds the
steering the path needs. Limits (all from :class:`VehicleParams`):

- speed: ``v <= speed_ratio * max_speed``;
- grip: ``v^2 |kappa| <= grip_fraction * max_lateral_acceleration``;
- steering lock: ``|kappa| (1 + understeer v^2) <= k_lock`` (the car's understeer at speed);
- steering slew rate: ``|d steering/dt| <= steering_rate``, i.e.
  ``v <= steering_rate * (1 + (wheelbase kappa)^2) / (wheelbase |d kappa/ds|)``;
- acceleration ``(v_{i+1}^2 - v_i^2) / (2 ds_i) <= max_acceleration`` (forward pass) and braking
  ``>= -max_braking`` (backward pass), round the closed loop.

Points go in as ``(M, 2)`` distinct points of a closed loop (segment ``i`` runs from point ``i`` to
point ``(i + 1) % M``); a repeated closing row is dropped first. Curvature is the Menger curvature
of each point and its neighbours (exact on circles). The passes are sequential, so they are numba
kernels; the end of the module holds the lap-time objective the race-line refinement minimises.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from laplab.vehicle.params import DEEPRACER, VehicleParams

_TINY_CURVATURE = 1e-12  # 1/m: below this a segment counts as straight
_CRAWL_SPEED = 0.1  # m/s, DeepRacer's slowest action: where no speed makes a curvature, the car crawls


@dataclass(frozen=True)
class SpeedProfileSettings:
    """How much of the car's limits the profile may use.

    grip_fraction: share of ``max_lateral_acceleration`` the profile plans with (1.0 = all of it;
      a tracking controller may want a little headroom).
    limit_steering_rate: cap speed where the curvature changes faster than the steering servo can.
    """

    grip_fraction: float = 1.0
    limit_steering_rate: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.grip_fraction) and 0.0 < self.grip_fraction <= 1.0):
            raise ValueError(f"SpeedProfileSettings.grip_fraction must lie in (0, 1], got {self.grip_fraction!r}")


@dataclass(frozen=True)
class SpeedProfile:
    """Speeds along a closed path (M distinct points).

    speeds: (M,) m/s at each point; times: (M,) s at which each point is reached (times[0] = 0);
    lap_time: s for the whole loop; curvature: (M,) signed 1/m (positive = left turn);
    segment_lengths: (M,) m from point i to point (i+1) % M; speed_limit: (M,) m/s pointwise cap
    (max speed, grip, steering rate) before the acceleration passes; max_path_curvature: 1/m that
    full steering lock reaches; steering_feasible: every |curvature| is within it.
    """

    speeds: np.ndarray
    times: np.ndarray
    lap_time: float
    curvature: np.ndarray
    segment_lengths: np.ndarray
    speed_limit: np.ndarray
    max_path_curvature: float
    steering_feasible: bool


def max_path_curvature(vehicle: VehicleParams) -> float:
    """Largest curvature (1/m) the pivot's path reaches at full steering lock at low speed (either way:
    the smaller of the two when the steering has an offset)."""
    lock = vehicle.curvature(np.array([vehicle.max_steering, -vehicle.max_steering]), 0.0)
    return float(np.abs(lock).min())


def open_loop(points: np.ndarray, name: str = "points") -> np.ndarray:
    """``points`` (M, 2) as float64 with a repeated closing row removed; checks shape and values."""
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 2 or array.shape[0] < 4:
        raise ValueError(f"{name}: expected a closed path of shape (M, 2) with M >= 4 points, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: holds NaN or Inf values; every coordinate must be a finite number of metres")
    if np.allclose(array[0], array[-1], atol=1e-9, rtol=0.0):
        array = array[:-1]
    return np.ascontiguousarray(array)


@numba.njit(cache=True)
def local_curvature(x: np.ndarray, y: np.ndarray, i: int) -> float:
    """Signed Menger curvature (1/m) at point i of the closed path (x, y) (M,), from its two neighbours.

    Exact on a circle: 1/R for any spacing.
    """
    m = x.shape[0]
    ax, ay = x[i - 1], y[i - 1]
    bx, by = x[i], y[i]
    cx, cy = x[(i + 1) % m], y[(i + 1) % m]
    cross = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
    denom = math.hypot(bx - ax, by - ay) * math.hypot(cx - bx, cy - by) * math.hypot(cx - ax, cy - ay)
    return 2.0 * cross / denom if denom > 0.0 else 0.0


@numba.njit(cache=True)
def local_speed_limit(curvature: np.ndarray, seg: np.ndarray, i: int, v_max: float, lateral: float,
                      wheelbase: float, steer_rate: float, k_lock: float, understeer: float) -> float:
    """Speed cap (m/s) at point i from max speed, grip, the steering lock's curvature ``k_lock`` (1/m)
    shrinking as ``1 / (1 + understeer v^2)`` (a curvature beyond ``k_lock`` gets the minimum speed) and
    (if ``steer_rate`` > 0) the steering's rate."""
    m = curvature.shape[0]
    k = abs(curvature[i])
    v = v_max
    if k > _TINY_CURVATURE:
        v = min(v, math.sqrt(lateral / k))
        if understeer > 0.0:
            v = min(v, math.sqrt(max(k_lock / k - 1.0, 0.0) / understeer))
        v = max(v, _CRAWL_SPEED)
    if steer_rate > 0.0:
        dk = abs(curvature[(i + 1) % m] - curvature[i - 1]) / (seg[i - 1] + seg[i])
        if dk > _TINY_CURVATURE:
            lk = wheelbase * curvature[i]
            v = min(v, steer_rate * (1.0 + lk * lk) / (wheelbase * dk))
    return v


@numba.njit(cache=True)
def closed_speed_passes(limit: np.ndarray, seg: np.ndarray, accel: float, brake: float, out: np.ndarray) -> float:
    """Forward (acceleration) and backward (braking) passes round a closed loop; returns the lap time (s).

    Starting at the slowest point, which every feasible profile must pass at exactly its cap, one
    forward and one backward pass are consistent across the wrap-around. ``seg[i]`` is the length of
    the segment from point i to i+1; segment times assume constant acceleration: 2 ds / (v_i + v_j).
    """
    m = limit.shape[0]
    start = 0
    for i in range(m):
        out[i] = limit[i]
        if limit[i] < limit[start]:
            start = i
    for j in range(1, m):
        i = (start + j) % m
        prev = (i - 1) % m
        out[i] = min(out[i], math.sqrt(out[prev] * out[prev] + 2.0 * accel * seg[prev]))
    for j in range(1, m):
        i = (start - j) % m
        nxt = (i + 1) % m
        out[i] = min(out[i], math.sqrt(out[nxt] * out[nxt] + 2.0 * brake * seg[i]))
    lap = 0.0
    for i in range(m):
        lap += 2.0 * seg[i] / max(out[i] + out[(i + 1) % m], 1e-12)
    return lap


@numba.njit(cache=True)
def closed_profile(x: np.ndarray, y: np.ndarray, v_max: float, lateral: float, wheelbase: float,
                   steer_rate: float, accel: float, brake: float, k_lock: float, understeer: float,
                   curvature: np.ndarray, seg: np.ndarray,
                   limit: np.ndarray, speeds: np.ndarray) -> float:
    """Whole profile of the closed path (x, y) (M,): fills curvature, seg, limit, speeds; returns the lap time."""
    m = x.shape[0]
    for i in range(m):
        seg[i] = math.hypot(x[(i + 1) % m] - x[i], y[(i + 1) % m] - y[i])
        curvature[i] = local_curvature(x, y, i)
    for i in range(m):
        limit[i] = local_speed_limit(curvature, seg, i, v_max, lateral, wheelbase, steer_rate, k_lock,
                                     understeer)
    return closed_speed_passes(limit, seg, accel, brake, speeds)


def closed_lap_time(path: np.ndarray, limits: tuple[float, ...]) -> float:
    """Lap time (s) of the closed path (M, 2) (no closing row) under ``limits`` from ``limit_arguments``."""
    m = path.shape[0]
    x, y = np.ascontiguousarray(path[:, 0]), np.ascontiguousarray(path[:, 1])
    return float(closed_profile(x, y, *limits, np.empty(m), np.empty(m), np.empty(m), np.empty(m)))


def limit_arguments(vehicle: VehicleParams, settings: SpeedProfileSettings) -> tuple[float, ...]:
    """(v_max, lateral, wheelbase, steer_rate, accel, brake, k_lock, understeer) for the numba kernels.

    The car's response folds into the kinematic form: top speed ``speed_ratio * max_speed``; an
    effective wheelbase ``wheelbase / steering_gain`` (curvature = tan(steer) / that); the steering's
    rate: its slew limit or, with a lag of time constant tau, ``2 * max_steering / tau`` (lock to lock's
    initial rate), 0 = off; ``k_lock`` the curvature at full lock, ``understeer`` its fall with speed.
    The action delay is left out: the optimum is what the car can do at best.
    """
    steer_rate = float(vehicle.steering_rate)
    if vehicle.steering_time_constant > 0:
        steer_rate = min(steer_rate, 2.0 * vehicle.max_steering / vehicle.steering_time_constant)
    return (float(vehicle.max_speed * vehicle.speed_ratio),
            float(vehicle.max_lateral_acceleration * settings.grip_fraction),
            float(vehicle.wheelbase / vehicle.steering_gain), steer_rate if settings.limit_steering_rate else 0.0,
            float(vehicle.max_acceleration), float(vehicle.max_braking), max_path_curvature(vehicle),
            float(vehicle.understeer))


def standing_start_lap_time(arc_length: np.ndarray, speeds: np.ndarray, max_acceleration: float) -> float:
    """Lap time (s) of a closed speed plan when the car starts at rest at point 0 and then keeps to it.

    arc_length (M,) m with the closing point ([-1] = lap length), speeds (M,) m/s (closed plan, so
    it already meets the braking limit everywhere). Starting from rest the speed is
    ``min(plan, sqrt(2 a s))``: the plan is consistent with full acceleration from any of its points,
    so nothing but the launch itself changes; segments take ``2 ds / (v_i + v_j)``.
    """
    arc = np.asarray(arc_length, dtype=np.float64)
    launched = np.minimum(np.asarray(speeds, dtype=np.float64), np.sqrt(2.0 * max_acceleration * arc))
    return float(np.sum(2.0 * np.diff(arc) / np.maximum(launched[:-1] + launched[1:], 1e-12)))


def compute_speed_profile(points: np.ndarray, vehicle: VehicleParams = DEEPRACER,
                          settings: SpeedProfileSettings = SpeedProfileSettings()) -> SpeedProfile:
    """Fastest speeds along the closed path ``points`` (M, 2) (or (M+1, 2) with the closing row)."""
    path = open_loop(points)
    m = len(path)
    curvature, seg, limit, speeds = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    x, y = np.ascontiguousarray(path[:, 0]), np.ascontiguousarray(path[:, 1])
    lap = closed_profile(x, y, *limit_arguments(vehicle, settings), curvature, seg, limit, speeds)
    if (seg <= 1e-9).any():
        raise ValueError(f"points: row {int(np.argmax(seg <= 1e-9))} repeats the next point; "
                         "a speed profile needs distinct consecutive points")
    segment_times = 2.0 * seg / np.maximum(speeds + np.roll(speeds, -1), 1e-12)
    times = np.concatenate([[0.0], np.cumsum(segment_times)[:-1]])
    k_max = max_path_curvature(vehicle)
    return SpeedProfile(speeds=speeds, times=times, lap_time=float(lap), curvature=curvature,
                        segment_lengths=seg, speed_limit=limit, max_path_curvature=k_max,
                        steering_feasible=bool(np.abs(curvature).max() <= k_max))


# Lap time of the path ``centre + alpha * normal`` as a function of the offsets ``alpha`` (M,), plus
# ``roughness_weight`` x sum (kappa_{i+1} - kappa_i)^2 / spacing: what the race-line refinement minimises.
# ``limits`` below are the eight numbers from ``limit_arguments``.

@numba.njit(cache=True)
def _roughness_term(curvature: np.ndarray, j: int) -> float:
    d = curvature[(j + 1) % curvature.shape[0]] - curvature[j]
    return d * d


@numba.njit(cache=True)
def offset_objective(cx, cy, nx, ny, alpha, roughness_weight, spacing, v_max, lateral, wheelbase,
                     steer_rate, accel, brake, k_lock, understeer) -> float:
    """Lap time (s) + roughness_weight x roughness (1/m^3) of the line ``c + alpha n`` (all (M,))."""
    m = alpha.shape[0]
    x, y = cx + alpha * nx, cy + alpha * ny
    curvature, seg, limit, speeds = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    lap = closed_profile(x, y, v_max, lateral, wheelbase, steer_rate, accel, brake, k_lock, understeer, curvature, seg,
                         limit, speeds)
    rough = 0.0
    for j in range(m):
        rough += _roughness_term(curvature, j)
    return lap + roughness_weight * rough / spacing


@numba.njit(cache=True)
def offset_objective_gradient(cx, cy, nx, ny, alpha, eps, roughness_weight, spacing, v_max, lateral,
                              wheelbase, steer_rate, accel, brake, k_lock, understeer) -> np.ndarray:
    """Central finite-difference gradient (s/m, (M,)) of :func:`offset_objective` in each offset.

    Moving point i changes only segments i-1, i, curvature at i-1..i+1, speed caps at i-2..i+2 and
    roughness terms i-2..i+1; those are patched in place, so each probe costs one O(M) pair of passes.
    """
    m = alpha.shape[0]
    x, y = cx + alpha * nx, cy + alpha * ny
    curvature, seg, limit, speeds = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    closed_profile(x, y, v_max, lateral, wheelbase, steer_rate, accel, brake, k_lock, understeer, curvature, seg, limit,
                   speeds)
    saved = np.empty(10)
    value = np.empty(2)
    grad = np.empty(m)
    for i in range(m):
        for k in range(2):
            saved[k] = seg[(i - 1 + k) % m]
        for k in range(3):
            saved[2 + k] = curvature[(i - 1 + k) % m]
        for k in range(5):
            saved[5 + k] = limit[(i - 2 + k) % m]
        rough_before = 0.0
        for k in range(4):
            rough_before += _roughness_term(curvature, (i - 2 + k) % m)
        x0, y0 = x[i], y[i]
        for side in range(2):
            sign = 1.0 if side == 0 else -1.0
            x[i], y[i] = x0 + sign * eps * nx[i], y0 + sign * eps * ny[i]
            for k in range(2):
                j = (i - 1 + k) % m
                seg[j] = math.hypot(x[(j + 1) % m] - x[j], y[(j + 1) % m] - y[j])
            for k in range(3):
                curvature[(i - 1 + k) % m] = local_curvature(x, y, (i - 1 + k) % m)
            for k in range(5):
                j = (i - 2 + k) % m
                limit[j] = local_speed_limit(curvature, seg, j, v_max, lateral, wheelbase, steer_rate, k_lock,
                                             understeer)
            rough_after = 0.0
            for k in range(4):
                rough_after += _roughness_term(curvature, (i - 2 + k) % m)
            value[side] = (closed_speed_passes(limit, seg, accel, brake, speeds)
                           + roughness_weight * (rough_after - rough_before) / spacing)
        x[i], y[i] = x0, y0
        for k in range(2):
            seg[(i - 1 + k) % m] = saved[k]
        for k in range(3):
            curvature[(i - 1 + k) % m] = saved[2 + k]
        for k in range(5):
            limit[(i - 2 + k) % m] = saved[5 + k]
        grad[i] = (value[0] - value[1]) / (2.0 * eps)
    return grad


@numba.njit(cache=True)
def offset_bump_descent(cx, cy, nx, ny, alpha, lower, upper, widths, amplitudes, stride, sweeps,
                        roughness_weight, spacing, v_max, lateral, wheelbase, steer_rate, accel, brake, k_lock,
                        understeer) -> float:
    """Derivative-free polish of ``alpha`` (M,, in place) within [lower, upper]; returns the objective.

    Tries Gaussian bumps ``a exp(-d^2 / 2 w^2)`` (w in ``widths``, m; a in ``amplitudes``, m) centred
    every ``stride`` points, keeping each that lowers :func:`offset_objective`. Copes with the kinks
    of the lap time (the min() of the passes) where gradient steps stall.
    """
    m = alpha.shape[0]
    args = (roughness_weight, spacing, v_max, lateral, wheelbase, steer_rate, accel, brake, k_lock, understeer)
    best = offset_objective(cx, cy, nx, ny, alpha, *args)
    trial = alpha.copy()
    for _sweep in range(sweeps):
        start_best = best
        for width in widths:
            reach = min(int(3.0 * width / spacing), (m - 1) // 2)
            for centre in range(0, m, stride):
                for amplitude in amplitudes:
                    for j in range(-reach, reach + 1):
                        k = (centre + j) % m
                        bump = amplitude * math.exp(-0.5 * (j * spacing / width) ** 2)
                        trial[k] = min(max(alpha[k] + bump, lower[k]), upper[k])
                    value = offset_objective(cx, cy, nx, ny, trial, *args)
                    if value < best - 1e-9:
                        best = value
                        for j in range(-reach, reach + 1):
                            alpha[(centre + j) % m] = trial[(centre + j) % m]
                        break
                    for j in range(-reach, reach + 1):
                        trial[(centre + j) % m] = alpha[(centre + j) % m]
        if best > start_best - 1e-4:
            break
    return best
