"""Optimal race line of a closed track: minimum curvature, then refined toward minimum lap time.

The line is the path of the car's model origin (rear-axle centre), for one car (:class:`VehicleParams`:
its response folds into the speed profile's limits). Method:

1. Reference line: the centre line smoothed (route centre lines are noisy) and resampled every
   ``spacing`` m, with unit left normals ``n_i``. The line is ``p_i = c_i + alpha_i n_i``.
2. Bounds: the room on each side is the distance from ``c_i`` to that border polyline, smoothed
   without ever exceeding it; ``alpha`` keeps :func:`line_clearance` inside it (DeepRacer's off-track
   rule: the line may cross a border by half the wheel track less ``margin``, the inner wheels on the road).
3. Minimum curvature: minimise ``sum kappa_i^2`` (finite-difference curvature of the line)
   by Gauss-Newton: each step a box-constrained QP in ``alpha`` with the sparse Jacobian,
   solved by :func:`laplab.track.box_qp.solve_box_qp` (interior point on scipy's sparse LU).
4. Minimum time (``refine_min_time``): trust-region QP steps on the lap time of
   :mod:`laplab.track.speed_profile` (plus a roughness price), then a bump coordinate descent.

On this car the minimum-curvature line is often *slower* than the centre line: at the grip limit
``v = sqrt(a R)``, so the time through a turn grows like ``sqrt(R)`` and tight inside lines win
unless a long straight follows. Step 4 is what makes the line fast; step 3 is its starting point.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import CubicSpline
from scipy.sparse.linalg import splu

from laplab.track.box_qp import solve_box_qp
from laplab.track.geometry import Track, track_from_route
from laplab.track.speed_profile import (SpeedProfile, SpeedProfileSettings, closed_lap_time,
                                        compute_speed_profile, limit_arguments, offset_bump_descent,
                                        offset_objective, offset_objective_gradient, open_loop)
from laplab.vehicle.params import DEEPRACER, VehicleParams


@dataclass(frozen=True)
class RaceLineSettings:
    """Solver settings. spacing: m between resampled points; smoothing: m, Gaussian width that smooths
    the reference line (see ``reference_line``); curvature_iterations: Gauss-Newton steps
    of the minimum-curvature QP; time_iterations: lap-time steps of the refinement; gradient_step: m,
    finite-difference offset of the lap-time gradient; roughness_weight: s m^3, price of curvature
    changes in the refinement (see ``_minimum_time``); polish_sweeps: most sweeps of its bump
    coordinate descent; profile: limits used for the speeds."""

    spacing: float = 0.1
    smoothing: float = 0.25
    curvature_iterations: int = 8
    time_iterations: int = 25
    gradient_step: float = 1e-4
    roughness_weight: float = 0.03
    polish_sweeps: int = 6
    profile: SpeedProfileSettings = field(default_factory=SpeedProfileSettings)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.spacing) and 0.01 <= self.spacing <= 1.0):
            raise ValueError(f"RaceLineSettings.spacing must lie in [0.01, 1] m, got {self.spacing!r}")
        for name in ("curvature_iterations", "time_iterations", "polish_sweeps"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 0:
                raise ValueError(f"RaceLineSettings.{name} must be a non-negative integer, got {getattr(self, name)!r}")


# A quick solve (about a tenth of the default's time) for sweeps and tests.
FAST_SETTINGS = RaceLineSettings(spacing=0.2, curvature_iterations=4, time_iterations=4, polish_sweeps=1)


@dataclass(frozen=True)
class RaceLine:
    """A closed race line (M points, the closing point included: row 0 == row M-1).

    points: (M, 2) m, path of the car's model origin; speeds: (M,) m/s; curvature: (M,) 1/m, signed
    (positive = left); arc_length: (M,) m cumulative, [-1] = length; times: (M,) s at each point,
    [-1] = lap_time; offsets: (M,) m along the resampled centre line's left normal;
    centerline_lap_time: s, the same speed profile on the smoothed, resampled centre line (the
    reference line: the raw route polyline's kinks would make it slower still).
    """

    points: np.ndarray
    speeds: np.ndarray
    curvature: np.ndarray
    arc_length: np.ndarray
    times: np.ndarray
    offsets: np.ndarray
    lap_time: float
    centerline_lap_time: float
    steering_feasible: bool
    solve_seconds: float

    @property
    def length(self) -> float:
        """Length of the line, m."""
        return float(self.arc_length[-1])

    def save_npy(self, path: str | Path) -> None:
        """Write the waypoints as a float64 ``(M, 2)`` array (closed: first row == last row)."""
        np.save(Path(path), self.points)

    def save_csv(self, path: str | Path) -> None:
        """Write ``x,y,speed`` rows (m, m, m/s) with a header line."""
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["x", "y", "speed"])
            writer.writerows(np.column_stack([self.points, self.speeds]).round(6).tolist())

    def plot_png(self, path: str | Path, inner: np.ndarray | None = None, outer: np.ndarray | None = None,
                 centerline: np.ndarray | None = None, title: str | None = None) -> None:
        """Draw the line coloured by speed over the track's borders (arrays (N, 2), optional) to a PNG."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure

        figure = Figure(figsize=(9, 7), dpi=110)
        FigureCanvasAgg(figure)
        axes = figure.add_subplot()
        for border in (inner, outer):
            if border is not None:
                axes.plot(border[:, 0], border[:, 1], color="0.25", lw=1.2)
        if centerline is not None:
            axes.plot(centerline[:, 0], centerline[:, 1], color="0.6", lw=0.8, ls="--")
        segments = np.stack([self.points[:-1], self.points[1:]], axis=1)
        lines = LineCollection(segments, cmap="plasma", linewidths=2.2)
        lines.set_array(0.5 * (self.speeds[:-1] + self.speeds[1:]))
        axes.add_collection(lines)
        figure.colorbar(lines, ax=axes, label="speed (m/s)")
        axes.set_aspect("equal")
        axes.autoscale_view()
        axes.set_title(title or f"race line: lap {self.lap_time:.2f} s (centre line {self.centerline_lap_time:.2f} s)")
        figure.savefig(Path(path))


def reference_line(centerline: np.ndarray, spacing: float, smoothing: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Smooth, uniformly resampled reference line of a closed centre line.

    Route centre lines are noisy (their curvature jumps by 1/m from row to row); offsets measured from
    such a line would copy the noise. The polyline is resampled every ``spacing / 2``, smoothed with
    a periodic Gaussian of ``smoothing`` m standard deviation, and resampled every ``spacing`` along a
    periodic cubic spline. Returns points (M, 2) (no closing row), unit left normals (M, 2), the arc
    length along the input polyline each point came from (M,), and the input polyline's point there (M, 2).
    """
    path = open_loop(centerline, "centerline")
    keep = np.linalg.norm(np.diff(path, axis=0, append=path[:1]), axis=1) > 1e-9
    closed = np.vstack([path[keep], path[keep][:1]])
    raw_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    count = max(int(np.ceil(2.0 * raw_arc[-1] / spacing)), 16)
    s_raw = np.arange(count) * (raw_arc[-1] / count)
    dense = np.column_stack([np.interp(s_raw, raw_arc, closed[:, k]) for k in (0, 1)])
    if smoothing > 0:
        reach = min(int(np.ceil(4.0 * smoothing / (raw_arc[-1] / count))), (count - 1) // 2)
        kernel = np.exp(-0.5 * (np.arange(-reach, reach + 1) * (raw_arc[-1] / count) / smoothing) ** 2)
        padded = np.concatenate([dense[-reach:], dense, dense[:reach]]) if reach else dense
        dense = np.column_stack([np.convolve(padded[:, k], kernel / kernel.sum(), mode="valid") for k in (0, 1)])
    knots_pts = np.vstack([dense, dense[:1]])
    knots = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(knots_pts, axis=0), axis=1))])
    spline = CubicSpline(knots, knots_pts, bc_type="periodic")
    fine = np.linspace(0.0, knots[-1], 8 * count + 1)
    fine_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(spline(fine), axis=0), axis=1))])
    m = max(int(round(fine_arc[-1] / spacing)), 8)
    params = np.interp(np.arange(m) * (fine_arc[-1] / m), fine_arc, fine)
    tangent = spline(params, 1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    source_arc = np.interp(params, knots, np.append(s_raw, raw_arc[-1]))
    source = np.column_stack([np.interp(source_arc, raw_arc, closed[:, k]) for k in (0, 1)])
    return spline(params), normals, source_arc, source


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(P,) distance (m) from each of ``points`` (P, 2) to the polyline (K, 2), chunked to bound memory."""
    a, b = polyline[:-1], polyline[1:]
    seg = b - a
    seg_sq = np.maximum((seg * seg).sum(-1), 1e-18)
    out = np.empty(len(points))
    for start in range(0, len(points), 256):
        rel = points[start:start + 256, None, :] - a[None]
        t = np.clip((rel * seg[None]).sum(-1) / seg_sq, 0.0, 1.0)
        diff = rel - t[..., None] * seg[None]
        out[start:start + 256] = np.sqrt((diff * diff).sum(-1).min(axis=1))
    return out


def _smooth_below(values: np.ndarray, half_window: int) -> np.ndarray:
    """A smooth version of the periodic ``values`` (M,) that nowhere exceeds them.

    A running minimum over +-half_window followed by a triangular average of the same reach: every
    average only mixes minima that each lie below the centre value. Removes the ripple that straight
    border segments put into the room at each point, which a line touching the bound would copy.
    """
    size = 2 * half_window + 1
    padded = np.concatenate([values[-half_window:], values, values[:half_window]])
    running_min = np.lib.stride_tricks.sliding_window_view(padded, size).min(axis=1)
    kernel = np.concatenate([np.arange(1, half_window + 2), np.arange(half_window, 0, -1)]).astype(float)
    kernel /= kernel.sum()
    padded = np.concatenate([running_min[-half_window:], running_min, running_min[:half_window]])
    return np.convolve(padded, kernel, mode="valid")


def _fd_curvature(centre: np.ndarray, normals: np.ndarray, alpha: np.ndarray,
                  with_jacobian: bool = True) -> tuple[np.ndarray, sp.csr_matrix | None]:
    """Curvature (M,) of the line ``centre + alpha * normals`` from index finite differences, and its
    sparse Jacobian d kappa / d alpha (M, M); parameterisation-free: kappa = (x'y'' - y'x'') / |p'|^3."""
    p = centre + alpha[:, None] * normals
    d = 0.5 * (np.roll(p, -1, 0) - np.roll(p, 1, 0))
    dd = np.roll(p, -1, 0) - 2.0 * p + np.roll(p, 1, 0)
    cross = d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0]
    speed_sq = (d * d).sum(1)
    kappa = cross / speed_sq ** 1.5
    if not with_jacobian:
        return kappa, None
    m = len(alpha)
    rows, cols, values = [], [], []
    # Neighbour offset j: d p_{i+j} / d alpha_{i+j} = n_{i+j}; weights of p_{i+j} in d and dd.
    for shift, w_d, w_dd in ((-1, -0.5, 1.0), (0, 0.0, -2.0), (1, 0.5, 1.0)):
        n = np.roll(normals, -shift, 0)
        dd_d, ddd_d = w_d * n, w_dd * n
        dcross = dd_d[:, 0] * dd[:, 1] - dd_d[:, 1] * dd[:, 0] + d[:, 0] * ddd_d[:, 1] - d[:, 1] * ddd_d[:, 0]
        dspeed = 2.0 * (d * dd_d).sum(1)
        rows.append(np.arange(m))
        cols.append((np.arange(m) + shift) % m)
        values.append(dcross / speed_sq ** 1.5 - 1.5 * cross * dspeed / speed_sq ** 2.5)
    jac = sp.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
    return kappa, jac


def _minimum_curvature(centre, normals, lower, upper, iterations: int) -> np.ndarray:
    """Offsets (M,) minimising sum kappa^2 within [lower, upper] (Gauss-Newton on box QPs)."""
    alpha = np.clip(0.0, lower, upper)
    kappa, jac = _fd_curvature(centre, normals, alpha)
    for _ in range(iterations):
        hessian = (jac.T @ jac).tocsc()
        hessian = hessian + sp.identity(len(alpha), format="csc") * (1e-9 * hessian.diagonal().mean())
        step = solve_box_qp(hessian, jac.T @ kappa, lower - alpha, upper - alpha)
        objective = float(kappa @ kappa)
        for scale in (1.0, 0.5, 0.25, 0.125):
            trial = alpha + scale * step
            trial_kappa, _ = _fd_curvature(centre, normals, trial, with_jacobian=False)
            if trial_kappa @ trial_kappa < objective:
                break
        else:
            break
        alpha = np.clip(trial, lower, upper)
        kappa, jac = _fd_curvature(centre, normals, alpha)
        if np.abs(scale * step).max() < 1e-4:
            break
    return alpha


def _minimum_time(centre, normals, lower, upper, alpha, limits, settings: RaceLineSettings) -> np.ndarray:
    """Refine offsets toward a lower lap time + ``roughness_weight`` x roughness.

    Lap time alone rewards kinks (the time through a grip-limited corner grows like sqrt(|kappa|),
    which is concave), which no car steered at 15 Hz can follow; the roughness term removes them.
    First trust-region QP steps: minimise the linear model of the objective plus ``weight`` x the
    curvature Hessian (smooth steps), keep a step only when the objective falls, adapt ``weight``.
    Then Gaussian-bump coordinate descent polishes where the kinks of the lap time stall gradients.
    """
    m = len(alpha)
    cx, cy = np.ascontiguousarray(centre[:, 0]), np.ascontiguousarray(centre[:, 1])
    nx, ny = np.ascontiguousarray(normals[:, 0]), np.ascontiguousarray(normals[:, 1])
    extra = (settings.roughness_weight, settings.spacing, *limits)
    best = offset_objective(cx, cy, nx, ny, alpha, *extra)
    weight = None
    identity = sp.identity(m, format="csc")
    for _ in range(settings.time_iterations):
        grad = offset_objective_gradient(cx, cy, nx, ny, alpha, settings.gradient_step, *extra)
        _, jac = _fd_curvature(centre, normals, alpha)
        metric = (jac.T @ jac).tocsc()
        metric = metric + identity * (1e-6 * metric.diagonal().mean())
        if weight is None:  # first step: at most ~2 cm where unconstrained
            weight = np.abs(splu(metric).solve(grad)).max() / 0.02
        for _attempt in range(6):
            step = solve_box_qp(metric * weight, grad, lower - alpha, upper - alpha)
            trial = np.clip(alpha + step, lower, upper)
            value = offset_objective(cx, cy, nx, ny, trial, *extra)
            if value < best - 1e-9:
                break
            weight *= 4.0
        else:
            break
        alpha, best = trial, value
        weight *= 0.5
    if settings.polish_sweeps > 0:
        alpha = np.ascontiguousarray(alpha.copy())
        stride = max(1, int(round(0.3 / settings.spacing)))
        offset_bump_descent(cx, cy, nx, ny, alpha, lower, upper, np.array([1.0, 0.5, 0.25]),
                            np.array([0.02, -0.02, 0.005, -0.005]), stride, settings.polish_sweeps, *extra)
    return alpha


def line_clearance(vehicle: VehicleParams, margin: float) -> float:
    """How far inside a border (m; negative: outside it) the line may run under DeepRacer's off-track rule.

    A car is off the track only when none of its wheel centres is on it (simapp's
    ``off_track_reset_rule``): up to three wheels may be off. The line is the path of the car's
    origin, midway between its left and right wheels, so it may cross a border by half the wheel
    track and keep the inner wheels on the road; ``margin`` (m) is kept from that limit.
    """
    return margin - 0.5 * vehicle.wheel_track


def compute_raceline(centerline: np.ndarray, left_width: np.ndarray, right_width: np.ndarray,
                     vehicle: VehicleParams = DEEPRACER, margin: float = 0.05, refine_min_time: bool = True,
                     *, settings: RaceLineSettings = RaceLineSettings(),
                     borders: tuple[np.ndarray, np.ndarray] | None = None) -> RaceLine:
    """Race line of a closed track (see the module docstring for the method).

    centerline: (N, 2) m, closed or not; left_width, right_width: (N,) m, perpendicular distance from
    each centre point to the border on the driver's left / right. ``borders`` = (left polyline,
    right polyline), each (K, 2) closed: when given, the clearances at the resampled points are
    measured to them exactly instead of interpolated from the widths. The line keeps
    :func:`line_clearance` from both borders.
    """
    started = time.perf_counter()
    raw = np.asarray(centerline, dtype=np.float64)
    widths = [np.asarray(w, dtype=np.float64).reshape(-1) for w in (left_width, right_width)]
    for name, w in zip(("left_width", "right_width"), widths):
        if w.shape[0] != raw.shape[0] or not np.isfinite(w).all() or (w < 0).any():
            raise ValueError(f"{name}: expected {raw.shape[0]} finite non-negative widths (one per centre-line "
                             f"row, m), got shape {w.shape} with min {np.nanmin(w) if w.size else 'n/a'}")
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite non-negative distance in m, got {margin!r}")
    centre, normals, source_arc, source = reference_line(raw, settings.spacing, settings.smoothing)
    if borders is not None:
        room_left = distance_to_polyline(centre, np.asarray(borders[0], dtype=np.float64))
        room_right = distance_to_polyline(centre, np.asarray(borders[1], dtype=np.float64))
    else:  # widths hold at the raw centre line: correct them for the smoothing's sideways shift
        closed = np.vstack([raw, raw[:1]]) if not np.allclose(raw[0], raw[-1]) else raw
        raw_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
        shift = np.einsum("ij,ij->i", centre - source, normals)
        extend = lambda w: np.append(w, w[0]) if len(closed) > len(raw) else w  # noqa: E731
        room_left = np.interp(source_arc, raw_arc, extend(widths[0])) - shift
        room_right = np.interp(source_arc, raw_arc, extend(widths[1])) + shift
    window = max(1, int(round(0.4 / settings.spacing)))
    room_left, room_right = _smooth_below(room_left, window), _smooth_below(room_right, window)
    clearance = line_clearance(vehicle, margin)
    lower, upper = clearance - room_right, room_left - clearance
    if (lower >= upper).any():
        worst = int(np.argmax(lower - upper))
        raise ValueError(
            f"the track is too narrow for the car: near centre-line point ({centre[worst, 0]:.2f}, "
            f"{centre[worst, 1]:.2f}) m it is {room_left[worst] + room_right[worst]:.3f} m wide, but the line "
            f"needs 2 x {clearance:.3f} m (margin {margin:.3f} m less half the wheel track); lower the margin")
    alpha = _minimum_curvature(centre, normals, lower, upper, settings.curvature_iterations)
    limits = limit_arguments(vehicle, settings.profile)
    if refine_min_time and (settings.time_iterations > 0 or settings.polish_sweeps > 0):
        alpha = _minimum_time(centre, normals, lower, upper, alpha, limits, settings)
    profile = compute_speed_profile(centre + alpha[:, None] * normals, vehicle, settings.profile)
    centre_lap = closed_lap_time(centre, limits)
    return _assemble(centre + alpha[:, None] * normals, alpha, profile, centre_lap, time.perf_counter() - started)


def _assemble(path: np.ndarray, alpha: np.ndarray, profile: SpeedProfile, centre_lap: float,
              seconds: float) -> RaceLine:
    def close(values: np.ndarray) -> np.ndarray:  # repeat the first row at the end
        return np.concatenate([values, values[:1]])

    arc = np.concatenate([[0.0], np.cumsum(profile.segment_lengths)])
    times = np.concatenate([profile.times, [profile.lap_time]])
    line = RaceLine(points=close(path), speeds=close(profile.speeds), curvature=close(profile.curvature),
                    arc_length=arc, times=times, offsets=close(alpha), lap_time=profile.lap_time,
                    centerline_lap_time=centre_lap, steering_feasible=profile.steering_feasible,
                    solve_seconds=seconds)
    for name in ("points", "speeds", "curvature", "arc_length", "times", "offsets"):
        getattr(line, name).flags.writeable = False
    return line


def compute_raceline_for_route(route: np.ndarray, vehicle: VehicleParams = DEEPRACER, margin: float = 0.05,
                               refine_min_time: bool = True,
                               settings: RaceLineSettings = RaceLineSettings()) -> RaceLine:
    """Race line of a DeepRacer route array (N, 6) [centre | inner | outer], driven in row order."""
    return compute_raceline_for_track(track_from_route(route, "route"), vehicle, margin, refine_min_time, settings)


def compute_raceline_for_track(track: Track, vehicle: VehicleParams = DEEPRACER, margin: float = 0.05,
                               refine_min_time: bool = True,
                               settings: RaceLineSettings = RaceLineSettings()) -> RaceLine:
    """Race line of a :class:`laplab.track.geometry.Track`, in its driving direction."""
    left, right = (track.inner, track.outer) if track.is_ccw else (track.outer, track.inner)
    return compute_raceline(track.centerline, track.left_width, track.right_width, vehicle, margin,
                            refine_min_time, settings=settings, borders=(left, right))
