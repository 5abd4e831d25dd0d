"""Route validation in the user's terms and in N log N: a huge route fails fast without allocating, a
figure-eight is refused at its crossing, a zero-width road is refused saying "width"."""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest

from laplab.track.geometry import MAX_WAYPOINTS, TrackError, load_route_file, track_from_route, validate_route


def figure_eight(points: int = 400, width: float = 0.6) -> np.ndarray:
    theta = np.linspace(0.0, 2.0 * np.pi, points, endpoint=False)
    centre = np.stack([3.0 * np.sin(theta), 3.0 * np.sin(theta) * np.cos(theta)], axis=1)
    tangent = np.gradient(centre, axis=0)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    route = np.hstack([centre, centre + 0.5 * width * normal, centre - 0.5 * width * normal])
    return np.vstack([route, route[:1]])


def test_a_huge_route_fails_fast_without_allocating(tmp_path):
    path = tmp_path / "huge.npy"
    route = np.lib.format.open_memmap(path, mode="w+", dtype=np.float64, shape=(2_300_000, 6))
    route[:] = 0.0
    route.flush()
    del route
    tracemalloc.start()
    started = time.perf_counter()
    with pytest.raises(TrackError) as error:
        load_route_file(path)
    elapsed = time.perf_counter() - started
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    message = str(error.value)
    assert str(path) in message and "2,300,000 waypoints" in message and f"{MAX_WAYPOINTS:,}" in message
    assert peak < 20 << 20, peak  # the 110 MB file is never copied, let alone squared
    assert elapsed < 5.0


def test_many_waypoints_within_the_limit_build_in_n_log_n_memory(circle_route):
    route = circle_route(radius=30.0, width=1.0, num_points=MAX_WAYPOINTS - 1)
    tracemalloc.start()
    track = track_from_route(route, "dense")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 64 << 20, peak  # the old N x M arrays needed 0.5 GB here
    assert np.allclose(track.left_width, 0.5, atol=1e-3) and np.allclose(track.road_width, 1.0, atol=1e-3)


def test_figure_eight_is_refused_at_its_crossing():
    with pytest.raises(TrackError) as error:
        validate_route(figure_eight(), "eight.npy")
    message = str(error.value)
    assert "eight.npy" in message and "crosses itself at (0.000, 0.000) m" in message


def test_borders_crossing_each_other_are_refused(circle_route):
    route = circle_route()
    route[100:110, 2:4], route[100:110, 4:6] = route[100:110, 4:6].copy(), route[100:110, 2:4].copy()
    with pytest.raises(TrackError, match=r"cross"):
        validate_route(route, "twisted.npy")


def test_zero_width_route_is_refused_saying_width(circle_route):
    with pytest.raises(TrackError) as error:
        validate_route(circle_route(width=0.0), "zero.npy")
    assert "zero.npy" in str(error.value) and "width" in str(error.value)
    narrow = circle_route()
    narrow[37, 2:4] = narrow[37, 4:6] = narrow[37, 0:2]
    with pytest.raises(TrackError, match=r"no width at row 37"):
        validate_route(narrow, "pinched.npy")
