"""Race line and speed profile: closed-form speeds, limits, parity of solvers, borders on real tracks
(DeepRacer's off-track rule: the line may cross a border by half the wheel track less the margin).

The solver's closed forms use laplab's classic car (a plain kinematic bicycle); DeepRacer's cars' limits
(understeer at the steering lock, top speed times the speed ratio) have tests of their own at the end."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from matplotlib.path import Path as PolygonPath
from scipy.optimize import minimize

from laplab.track import raceline as rl
from laplab.track.geometry import track_from_route
from laplab.track.box_qp import solve_box_qp
from laplab.track.raceline import (FAST_SETTINGS, RaceLineSettings, compute_raceline, compute_raceline_for_route,
                                   compute_raceline_for_track)
from laplab.track.speed_profile import (SpeedProfileSettings, compute_speed_profile, limit_arguments,
                                        max_path_curvature, offset_objective, offset_objective_gradient)
from laplab.track.raceline import line_clearance
from laplab.vehicle.params import CLASSIC as DEEPRACER, DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6

REPO_ROOT = Path(__file__).resolve().parents[2]
REFERENCE_DIR = REPO_ROOT.parent / "shared" / "reference-tracks"
BUILTIN_DIR = REPO_ROOT / "laplab" / "track" / "data"
REFERENCE_FILES = sorted(p for p in REFERENCE_DIR.glob("*.npy") if p.stem != "Straight_track") \
    if REFERENCE_DIR.is_dir() else []
BUILTIN_FILES = sorted(BUILTIN_DIR.glob("*.npy")) if BUILTIN_DIR.is_dir() else []


def circle(radius: float, count: int = 400) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    return radius * np.column_stack([np.cos(angle), np.sin(angle)])


def stadium_route(straight: float = 3.0, radius: float = 1.0, width: float = 1.0, step: float = 0.1) -> np.ndarray:
    """(N, 6) CCW oval: two straights joined by half circles, borders offset by width / 2."""
    s = np.arange(0.0, 2 * straight + 2 * np.pi * radius, step)
    centre, normal = np.zeros((len(s), 2)), np.zeros((len(s), 2))
    for i, d in enumerate(s):
        if d < straight:
            centre[i], normal[i] = (d, -radius), (0, 1)
        elif d < straight + np.pi * radius:
            a = -np.pi / 2 + (d - straight) / radius
            centre[i], normal[i] = (straight + radius * np.cos(a), radius * np.sin(a)), (-np.cos(a), -np.sin(a))
        elif d < 2 * straight + np.pi * radius:
            centre[i], normal[i] = (straight - (d - straight - np.pi * radius), radius), (0, -1)
        else:
            a = np.pi / 2 + (d - 2 * straight - np.pi * radius) / radius
            centre[i], normal[i] = (radius * np.cos(a), radius * np.sin(a)), (-np.cos(a), -np.sin(a))
    route = np.hstack([centre, centre + 0.5 * width * normal, centre - 0.5 * width * normal])
    return np.vstack([route, route[:1]])


def polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Exact distance from each point (P, 2) to the polyline (K, 2) (every segment, clamped projection)."""
    a, b = polyline[:-1], polyline[1:]
    seg = b - a
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-18), 0.0, 1.0)
    return np.linalg.norm(rel - t[..., None] * seg, axis=-1).min(axis=1)


def assert_inside_with_margin(line, route: np.ndarray, margin: float, vehicle=DEEPRACER) -> int:
    """The line keeps ``line_clearance`` (negative: it may cross a border by that much) from both
    borders: at least one wheel of the car on its origin's path stays on the road. Returns how many
    points lie beyond a border."""
    inner, outer = route[:, 2:4], route[:, 4:6]
    points = line.points
    need = line_clearance(vehicle, margin) - 1e-6
    outside = 0
    for name, border, on_road in (("inner", inner, ~PolygonPath(inner).contains_points(points)),
                                  ("outer", outer, PolygonPath(outer).contains_points(points))):
        signed = np.where(on_road, 1.0, -1.0) * polyline_distance(points, border)
        assert signed.min() >= need, f"race line {signed.min():.4f} m from the {name} border (needs {need:.4f})"
        outside += int((~on_road).sum())
    return outside


def assert_profile_within_limits(speeds, curvature, arc_length, vehicle=DEEPRACER) -> None:
    """speeds, curvature, arc_length: (M,) over a closed loop with the closing point repeated."""
    assert speeds.max() <= vehicle.max_speed + 1e-9
    assert (speeds ** 2 * np.abs(curvature)).max() <= vehicle.max_lateral_acceleration + 1e-6
    accel = np.diff(speeds ** 2) / (2.0 * np.diff(arc_length))
    assert accel.max() <= vehicle.max_acceleration + 1e-6
    assert accel.min() >= -vehicle.max_braking - 1e-6


# --- speed profile --------------------------------------------------------------------------------

@pytest.mark.parametrize("radius", [0.3, 0.8, 2.0, 3.0, 5.0])
def test_circle_speed_is_grip_or_top_speed(radius):
    profile = compute_speed_profile(circle(radius), DEEPRACER)
    expected = min(DEEPRACER.max_speed, math.sqrt(DEEPRACER.max_lateral_acceleration * radius))
    np.testing.assert_allclose(profile.speeds, expected, rtol=1e-9)
    np.testing.assert_allclose(profile.curvature, 1.0 / radius, rtol=1e-9)
    assert profile.lap_time == pytest.approx(profile.segment_lengths.sum() / expected, rel=1e-9)


def test_steering_feasibility_follows_the_wheelbase():
    k_max = max_path_curvature(DEEPRACER)
    assert k_max == pytest.approx(math.tan(math.radians(30.0)) / 0.165)
    assert compute_speed_profile(circle(1.05 / k_max), DEEPRACER).steering_feasible
    assert not compute_speed_profile(circle(0.9 / k_max), DEEPRACER).steering_feasible


def wobbly_loop(count: int = 500) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    radius = 4.0 + 1.2 * np.sin(3 * angle) + 0.4 * np.cos(7 * angle)
    return np.column_stack([radius * np.cos(angle), 0.7 * radius * np.sin(angle)])


def test_profile_respects_every_limit_round_the_loop():
    path = wobbly_loop()
    profile = compute_speed_profile(np.vstack([path, path[:1]]), DEEPRACER)  # closing row is accepted
    closed = lambda a: np.append(a, a[0])  # noqa: E731
    arc = np.concatenate([[0.0], np.cumsum(profile.segment_lengths)])
    assert_profile_within_limits(closed(profile.speeds), closed(profile.curvature), arc)
    assert profile.speeds.min() < 2.0 and profile.speeds.max() == pytest.approx(DEEPRACER.max_speed)
    assert np.all(np.diff(profile.times) > 0)
    segment_times = 2 * profile.segment_lengths / (profile.speeds + np.roll(profile.speeds, -1))
    assert profile.lap_time == pytest.approx(segment_times.sum(), rel=1e-12)


def reference_speeds(limit: np.ndarray, seg: np.ndarray, accel: float, brake: float) -> np.ndarray:
    """Plain-Python passes repeated round the loop until nothing changes (the textbook definition)."""
    v = limit.copy()
    m = len(v)
    for _ in range(10):
        before = v.copy()
        for i in range(m):  # forward, wrapping
            v[(i + 1) % m] = min(v[(i + 1) % m], math.sqrt(v[i] ** 2 + 2 * accel * seg[i]))
        for i in range(m - 1, -1, -1):  # backward, wrapping
            v[i] = min(v[i], math.sqrt(v[(i + 1) % m] ** 2 + 2 * brake * seg[i]))
        if np.array_equal(before, v):
            return v
    raise AssertionError("reference passes did not settle")


def test_single_pass_profile_matches_iterated_passes():
    path = wobbly_loop(300)
    profile = compute_speed_profile(path, DEEPRACER)
    expected = reference_speeds(profile.speed_limit, profile.segment_lengths,
                                DEEPRACER.max_acceleration, DEEPRACER.max_braking)
    np.testing.assert_allclose(profile.speeds, expected, rtol=1e-12)


def test_grip_fraction_slows_corners():
    full = compute_speed_profile(circle(1.0), DEEPRACER)
    eased = compute_speed_profile(circle(1.0), DEEPRACER, SpeedProfileSettings(grip_fraction=0.81))
    np.testing.assert_allclose(eased.speeds, 0.9 * full.speeds, rtol=1e-9)
    with pytest.raises(ValueError, match="grip_fraction"):
        SpeedProfileSettings(grip_fraction=1.5)


def test_bad_points_are_named():
    with pytest.raises(ValueError, match=r"shape \(M, 2\)"):
        compute_speed_profile(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="repeats the next point"):
        compute_speed_profile(np.array([[0, 0], [1, 0], [1, 0], [1, 1], [0, 1.0]]))


# --- solver pieces --------------------------------------------------------------------------------

def test_box_qp_matches_a_general_bounded_solver():
    rng = np.random.default_rng(3)
    n = 40
    a = sp.random(n, n, density=0.15, random_state=4) + sp.identity(n)
    hessian, gradient = (a.T @ a).tocsc(), 5.0 * rng.normal(size=n)
    lower, upper = -rng.random(n), rng.random(n)
    x = solve_box_qp(hessian, gradient, lower, upper)
    ref = minimize(lambda v: 0.5 * v @ (hessian @ v) + gradient @ v, np.zeros(n),
                   jac=lambda v: hessian @ v + gradient, bounds=list(zip(lower, upper)), method="L-BFGS-B",
                   options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 5000})
    np.testing.assert_allclose(x, ref.x, atol=1e-6)
    assert ((x >= lower) & (x <= upper)).all()


def test_curvature_jacobian_matches_finite_differences():
    path = wobbly_loop(120)
    centre, normals, _, _ = rl.reference_line(path, 0.3, 0.0)
    alpha = 0.1 * np.sin(np.arange(len(centre)) * 0.2)
    _, jac = rl._fd_curvature(centre, normals, alpha)
    eps = 1e-6
    numeric = np.empty((len(alpha), len(alpha)))
    for j in range(len(alpha)):
        bump = np.zeros_like(alpha)
        bump[j] = eps
        plus, _ = rl._fd_curvature(centre, normals, alpha + bump, with_jacobian=False)
        minus, _ = rl._fd_curvature(centre, normals, alpha - bump, with_jacobian=False)
        numeric[:, j] = (plus - minus) / (2 * eps)
    np.testing.assert_allclose(jac.toarray(), numeric, atol=1e-5 * np.abs(numeric).max())


def test_lap_time_gradient_matches_whole_profile_differences():
    centre, normals, _, _ = rl.reference_line(wobbly_loop(200), 0.2, 0.0)
    cx, cy, nx, ny = (np.ascontiguousarray(a) for a in (*centre.T, *normals.T))
    alpha = 0.05 * np.cos(np.arange(len(cx)) * 0.1)
    extra = (0.03, 0.2, *limit_arguments(DEEPRACER, SpeedProfileSettings()))
    grad = offset_objective_gradient(cx, cy, nx, ny, alpha, 1e-6, *extra)
    for j in (0, 17, 60, len(alpha) - 1):
        bump = np.zeros_like(alpha)
        bump[j] = 1e-6
        numeric = (offset_objective(cx, cy, nx, ny, alpha + bump, *extra)
                   - offset_objective(cx, cy, nx, ny, alpha - bump, *extra)) / 2e-6
        assert grad[j] == pytest.approx(numeric, rel=1e-6, abs=1e-9)


# --- race line ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def oval_lines():
    route = stadium_route()
    return route, {refine: compute_raceline_for_route(route, DEEPRACER, 0.05, refine,
                                                      settings=RaceLineSettings(spacing=0.1, time_iterations=10,
                                                                                polish_sweeps=2))
                   for refine in (False, True)}


def test_min_curvature_line_on_an_oval_bends_less(oval_lines):
    route, lines = oval_lines
    line = lines[False]
    centre_curvature = compute_speed_profile(route[:, :2]).curvature
    assert np.abs(centre_curvature).max() == pytest.approx(1.0, rel=1e-6)
    assert np.abs(line.curvature).max() < 0.9 * np.abs(centre_curvature).max()
    assert_inside_with_margin(line, route, 0.05)
    assert line.steering_feasible
    # No lap-time claim here: with v = sqrt(a R) the time through a turn grows like sqrt(R), so on
    # this car the wide minimum-curvature line is often slower than the centre; the refinement is not.


def test_refined_line_is_faster_and_within_limits(oval_lines):
    route, lines = oval_lines
    refined = lines[True]
    assert refined.lap_time < lines[False].lap_time
    assert refined.lap_time < 0.9 * refined.centerline_lap_time
    assert_inside_with_margin(refined, route, 0.05)
    assert_profile_within_limits(refined.speeds, refined.curvature, refined.arc_length)
    assert refined.times[-1] == pytest.approx(refined.lap_time)
    np.testing.assert_array_equal(refined.points[0], refined.points[-1])


def test_widths_only_path_stays_inside():
    route = stadium_route(radius=1.2, width=0.7)
    centre = route[:, 0:2]
    widths = np.full(len(route), 0.35)
    line = compute_raceline(centre, widths, widths, DEEPRACER, margin=0.05, settings=FAST_SETTINGS)
    assert_inside_with_margin(line, route, 0.05 - 0.005)  # interpolated widths: within 5 mm


def test_reversed_track_is_driven_the_other_way():
    track = track_from_route(stadium_route(), "oval").reversed()
    line = compute_raceline_for_track(track, DEEPRACER, 0.05, settings=FAST_SETTINGS)
    assert_inside_with_margin(line, track.route(), 0.05)
    heading = np.diff(line.points[:2], axis=0)[0]
    assert heading @ np.diff(track.centerline[:2], axis=0)[0] > 0
    assert line.lap_time < line.centerline_lap_time


def test_too_narrow_track_is_refused_clearly():
    route = stadium_route(width=0.28)
    with pytest.raises(ValueError, match="too narrow for the car"):
        compute_raceline_for_route(route, DEEPRACER, margin=0.25, refine_min_time=False, settings=FAST_SETTINGS)
    with pytest.raises(ValueError, match="left_width"):
        compute_raceline(route[:, :2], np.ones(3), np.ones(len(route)), DEEPRACER)


def test_saved_files(oval_lines, tmp_path):
    _, lines = oval_lines
    line = lines[True]
    line.save_npy(tmp_path / "line.npy")
    np.testing.assert_array_equal(np.load(tmp_path / "line.npy"), line.points)
    line.save_csv(tmp_path / "line.csv")
    table = np.loadtxt(tmp_path / "line.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "line.csv").read_text().splitlines()[0] == "x,y,speed"
    np.testing.assert_allclose(table, np.column_stack([line.points, line.speeds]), atol=1e-6)
    route = stadium_route()
    line.plot_png(tmp_path / "line.png", route[:, 2:4], route[:, 4:6], route[:, 0:2])
    assert (tmp_path / "line.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(not BUILTIN_FILES, reason="no built-in tracks in laplab/track/data yet")
@pytest.mark.parametrize("path", BUILTIN_FILES, ids=lambda p: p.stem)
def test_builtin_tracks(path):
    route = np.load(path)
    line = compute_raceline_for_route(route, DEEPRACER, 0.05, settings=FAST_SETTINGS)
    assert_inside_with_margin(line, route, 0.05)
    assert_profile_within_limits(line.speeds, line.curvature, line.arc_length)
    assert line.lap_time < line.centerline_lap_time


@pytest.mark.skipif(not REFERENCE_FILES, reason=f"reference tracks not found at {REFERENCE_DIR}")
@pytest.mark.parametrize("path", REFERENCE_FILES, ids=lambda p: p.stem)
def test_reference_tracks(path):
    route = np.load(path)
    line = compute_raceline_for_route(route, DEEPRACER, 0.05, settings=FAST_SETTINGS)
    assert_inside_with_margin(line, route, 0.05)
    assert_profile_within_limits(line.speeds, line.curvature, line.arc_length)
    assert line.lap_time < line.centerline_lap_time


# --- DeepRacer's cars -----------------------------------------------------------------------------

def test_line_clearance_is_deepracers_off_track_rule():
    """Off only when no wheel is on the road: the origin (between the wheels) may be half a track out."""
    assert line_clearance(DEEPRACER_V6, 0.05) == pytest.approx(0.05 - 0.081)
    assert line_clearance(DEEPRACER_V6, 0.0) == pytest.approx(-0.5 * DEEPRACER_V6.wheel_track)


def test_a_track_narrower_than_the_car_has_a_line_with_wheels_off():
    """0.25 m of road: the car's body (0.196 m) plus 5 cm from each border would not fit, but with up
    to three wheels off (DeepRacer's rule) the line exists and leaves the road on the outside of turns."""
    route = stadium_route(width=0.25)
    line = compute_raceline_for_route(route, DEEPRACER_V6, margin=0.05, settings=FAST_SETTINGS)
    assert assert_inside_with_margin(line, route, 0.05, DEEPRACER_V6) > 0


@pytest.mark.parametrize("radius", [0.6, 1.0, 2.0])
def test_understeer_caps_the_speed_a_car_turns_at(radius):
    """On a circle the v5 car is held by its steering lock's curvature falling with speed
    (|kappa| (1 + understeer v^2) <= k_lock) or by grip, whichever is lower."""
    car = DEEPRACER_V5
    k_lock = max_path_curvature(car)
    by_lock = math.sqrt(max(k_lock * radius - 1.0, 0.0) / car.understeer)
    expected = min(car.max_speed * car.speed_ratio, math.sqrt(car.max_lateral_acceleration * radius), by_lock)
    profile = compute_speed_profile(circle(radius), car)
    np.testing.assert_allclose(profile.speeds, expected, rtol=1e-9)


@pytest.mark.parametrize("car", [DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6], ids=lambda c: c.name)
def test_each_cars_line_on_a_builtin_track(car):
    route = np.load(BUILTIN_DIR / "classic_2018.npy")
    line = compute_raceline_for_route(route, car, 0.05, settings=FAST_SETTINGS)
    assert_inside_with_margin(line, route, 0.05, car)
    assert line.speeds.max() <= car.max_speed * car.speed_ratio + 1e-9
    assert (line.speeds ** 2 * np.abs(line.curvature)).max() <= car.max_lateral_acceleration + 1e-6
    assert line.lap_time < line.centerline_lap_time
