"""Shared fixtures of laplab's test suite.

- ``reference_tracks_dir`` / ``reference_tracks``: the real DeepRacer routes in
  ``<repo>/../shared/reference-tracks`` (tests that use them skip cleanly when the folder is absent).
- ``circle_route`` / ``stadium_route``: builders of synthetic DeepRacer routes (N, 6) with known
  geometry, and ``circle_track`` / ``stadium_track``: ready-made :class:`Track` objects.
- ``pure_pursuit``: a batched steering controller that follows each car's centre line.
- ``s3_server``: a local S3 (moto) on 127.0.0.1, per test module.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from laplab.track.geometry import Track, track_from_route

REPO_ROOT = Path(__file__).resolve().parents[1]
REFERENCE_TRACKS_DIR = REPO_ROOT.parent / "shared" / "reference-tracks"
OPEN_REFERENCE_TRACKS = ("Straight_track",)  # the one open strip among the reference routes


def make_circle_route(radius: float = 3.0, width: float = 1.0, num_points: int = 400,
                      ccw: bool = True) -> np.ndarray:
    """(num_points + 1, 6) route of a circular road centred on the origin, waypoint 0 at (radius, 0).

    The centre line has radius ``radius``; the inner / outer borders radius -/+ width / 2 (m).
    ``ccw`` False drives it clockwise. The closing row is an exact copy of row 0.
    """
    sense = 1.0 if ccw else -1.0
    angle = sense * np.linspace(0.0, 2.0 * np.pi, num_points, endpoint=False)
    unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    route = np.hstack([radius * unit, (radius - 0.5 * width) * unit, (radius + 0.5 * width) * unit])
    return np.vstack([route, route[:1]])


def make_stadium_route(straight: float = 6.0, radius: float = 2.0, width: float = 1.0,
                       spacing: float = 0.1) -> np.ndarray:
    """(N, 6) counter-clockwise stadium: two straights of ``straight`` m joined by half circles.

    Waypoint 0 lies in the middle of the bottom straight, (0, -radius), heading +x. Waypoints are
    about ``spacing`` m apart; borders are exact parallels at width / 2 on each side.
    """
    half = 0.5 * straight
    n_half = max(1, int(round(half / spacing)))
    n_arc = max(4, int(round(math.pi * radius / spacing)))
    w = np.arange(n_arc) / n_arc

    def straight_piece(x_from, x_to, y, count, normal_y):  # rows (centre x, y, left normal x, y)
        x = np.linspace(x_from, x_to, count, endpoint=False)
        return np.stack([x, np.full(count, y), np.zeros(count), np.full(count, normal_y)], axis=1)

    def arc_piece(centre_x, theta):  # counter-clockwise half circle: the left normal points inward
        return np.stack([centre_x + radius * np.cos(theta), radius * np.sin(theta), -np.cos(theta),
                         -np.sin(theta)], axis=1)

    pieces = [straight_piece(0.0, half, -radius, n_half, 1.0),
              arc_piece(half, -0.5 * np.pi + np.pi * w),
              straight_piece(half, -half, radius, 2 * n_half, -1.0),
              arc_piece(-half, 0.5 * np.pi + np.pi * w),
              straight_piece(-half, 0.0, -radius, n_half, 1.0)]
    table = np.vstack(pieces)
    centre, normal = table[:, :2], table[:, 2:]
    route = np.hstack([centre, centre + 0.5 * width * normal, centre - 0.5 * width * normal])
    return np.vstack([route, route[:1]])


@pytest.fixture(scope="session")
def circle_route():
    """The builder :func:`make_circle_route` (call it with your own radius, width, direction)."""
    return make_circle_route


@pytest.fixture(scope="session")
def stadium_route():
    """The builder :func:`make_stadium_route`."""
    return make_stadium_route


@pytest.fixture(scope="session")
def circle_track() -> Track:
    """Counter-clockwise circle: centre-line radius 3 m, width 1 m, 400 segments."""
    return track_from_route(make_circle_route(), "circle")


@pytest.fixture(scope="session")
def stadium_track() -> Track:
    """Counter-clockwise stadium: 6 m straights, 2 m radius ends, width 1 m, ~0.1 m waypoints."""
    return track_from_route(make_stadium_route(), "stadium")


@pytest.fixture(scope="session")
def reference_tracks_dir() -> Path:
    """The folder of real DeepRacer routes; skips the test when it is absent."""
    if not REFERENCE_TRACKS_DIR.is_dir() or not any(REFERENCE_TRACKS_DIR.glob("*.npy")):
        pytest.skip(f"reference tracks folder {REFERENCE_TRACKS_DIR} is absent")
    return REFERENCE_TRACKS_DIR


@pytest.fixture(scope="session")
def reference_tracks(reference_tracks_dir) -> dict[str, Track]:
    """Every closed reference route, loaded once per session (name -> Track, repeats removed)."""
    from laplab.track.geometry import load_route_file
    return {path.stem: load_route_file(path) for path in sorted(reference_tracks_dir.glob("*.npy"))
            if path.stem not in OPEN_REFERENCE_TRACKS}


def pure_pursuit_steering(sim, lookahead: float = 0.6) -> np.ndarray:
    """(N,) steering angles, rad, that steer each car of ``sim`` toward its centre line.

    The target is the centre-line point ``lookahead`` m of arc length beyond the projection of the
    car's reference point, on the track in the direction the car drives.
    """
    st = sim.state
    steer = np.zeros(sim.num_cars)
    for direction in (0, 1):
        cars = np.flatnonzero(st.direction == direction)
        if cars.size == 0:
            continue
        target = sim.tracks[direction].point_at(st.arc[cars] + lookahead)
        dx, dy = target[:, 0] - st.x[cars], target[:, 1] - st.y[cars]
        c, s = np.cos(st.yaw[cars]), np.sin(st.yaw[cars])
        forward, left = c * dx + s * dy, -s * dx + c * dy
        dist_sq = np.maximum(forward * forward + left * left, 1e-9)
        steer[cars] = sim.vehicle.steering_for_curvature(2.0 * left / dist_sq, st.speed[cars])
    return np.clip(steer, -sim.vehicle.max_steering, sim.vehicle.max_steering)


@pytest.fixture(scope="session")
def pure_pursuit():
    """The controller :func:`pure_pursuit_steering` ``(sim, lookahead=0.6) -> (N,) rad``."""
    return pure_pursuit_steering


@pytest.fixture(scope="module")
def s3_server():
    """``http://127.0.0.1:PORT`` of a moto S3 server running in this process (stopped after the module)."""
    moto_server = pytest.importorskip("moto.server")
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()
