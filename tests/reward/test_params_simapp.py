"""The params keys ``closest_waypoints``, ``track_width``, ``is_left_of_center`` and ``progress``
against an independent shapely implementation of DeepRacer's simulation application.

The reference below follows simapp's own definitions (aws-deepracer-community/deepracer-simapp,
``bundle/markov``): ``track_geom/track_data.py`` (``_sanitize_waypoints``, ``TrackLine.ndists``,
``get_norm_dist``, ``get_nearest_points``, ``is_ccw``), ``track_geom/utils.py`` (``find_prev_next``)
and ``agent_ctrl/utils.py`` (``set_reward_and_metrics``, ``compute_current_prog``). It is built on
shapely's LinearRings, as simapp is, and shares no code with laplab.

On every reference route, cars placed at sampled positions (anywhere across the road and a little off
it, and abeam waypoints on both sides) must get the same values, ties within 1e-6 m aside (a point
equally near two parts of a line, or projecting within 1e-6 m of a waypoint).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

shapely = pytest.importorskip("shapely")
from shapely.geometry import LinearRing, Point  # noqa: E402

from laplab.reward.params import ParamsBuilder  # noqa: E402
from laplab.sim.simulator import Simulator  # noqa: E402
from laplab.sim.state import IN_PROGRESS, EpisodeParams  # noqa: E402
from laplab.track.geometry import Track, load_route_file, track_from_route  # noqa: E402
from laplab.vehicle.dynamics import pose_for_reference  # noqa: E402
from laplab.vehicle.params import DEEPRACER  # noqa: E402

TIE = 1e-6  # m
OPEN_ROUTES = ("Straight_track",)


# ------------------------------------------------------------------ simapp's definitions, in shapely


def simapp_sanitize(route: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """Drop each centre point within ``eps`` of the one before it; a loop keeps its closing row."""
    body = route[:-1]
    keep = np.ones(body.shape[0], dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(body[:, 0:2], axis=0), axis=1) > eps
    return np.vstack([body[keep], route[-1:]])


class Simapp:
    """simapp's TrackData for one driving direction (``reverse``: the rings are built reversed)."""

    def __init__(self, route: np.ndarray, reverse: bool = False):
        rows = route[::-1] if reverse else route
        self.centre, self.inner, self.outer = (LinearRing(rows[:, c:c + 2]) for c in (0, 2, 4))
        coords = list(self.centre.coords)
        self.ndists = np.array([self.centre.project(Point(p), normalized=True) for p in coords[:-1]] + [1.0])
        self.is_ccw = LinearRing(route[:, 0:2]).is_ccw ^ reverse
        self.length = self.centre.length

    def ndist(self, points: np.ndarray) -> np.ndarray:
        return shapely.line_locate_point(self.centre, shapely.points(points), normalized=True)

    def params(self, points: np.ndarray) -> dict[str, np.ndarray]:
        pts = shapely.points(points)
        ndist = self.ndist(points)
        nxt = np.searchsorted(self.ndists, ndist, side="right")  # bisect.bisect_right, element-wise
        prev = nxt - 1
        prev[prev == -1] = len(self.ndists) - 1
        nxt[nxt == len(self.ndists)] = 0
        centre = shapely.line_interpolate_point(self.centre, ndist, normalized=True)
        near_in = shapely.line_interpolate_point(self.inner, shapely.line_locate_point(self.inner, centre))
        near_out = shapely.line_interpolate_point(self.outer, shapely.line_locate_point(self.outer, centre))
        d_in, d_out = shapely.distance(near_in, pts), shapely.distance(near_out, pts)
        return {"ndist": ndist, "prev": prev, "next": nxt, "centre": shapely.get_coordinates(centre),
                "track_width": shapely.distance(near_in, near_out), "d_in": d_in, "d_out": d_out,
                "is_left_of_center": (d_in < d_out) ^ (not self.is_ccw),
                "distance_from_center": shapely.distance(centre, pts)}


def simapp_progress(ndist: float, start_ndist: float, prev_progress: float) -> float:
    """compute_current_prog of ``ndist - start_ndist`` after a step that began at ``prev_progress``."""
    progress = 100.0 * (ndist - start_ndist)
    if progress <= 0.0:
        progress += 100.0
    if prev_progress > progress + 50.0:
        progress += 100.0
    if progress > prev_progress + 50.0:
        progress -= 100.0
    return min(progress, 100.0)


def ambiguous_nearest(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(P,) bool: two points of ``polyline`` more than TIE apart are both within TIE of the nearest."""
    a, seg = polyline[:-1], np.diff(polyline, axis=0)
    rel = points[:, None, :] - a[None]
    len_sq = (seg * seg).sum(-1)
    t = np.clip((rel * seg[None]).sum(-1) / np.where(len_sq > 0, len_sq, 1.0)[None], 0.0, 1.0)
    foot = a[None] + t[..., None] * seg[None]
    dist = np.linalg.norm(foot - points[:, None, :], axis=-1)
    best = np.argmin(dist, axis=1)
    rows = np.arange(points.shape[0])
    close = dist <= dist[rows, best][:, None] + TIE
    apart = np.linalg.norm(foot - foot[rows, best][:, None, :], axis=-1) > TIE
    return (close & apart).any(axis=1)


def beyond_both_segments(points: np.ndarray, centerline: np.ndarray) -> np.ndarray:
    """(P,) bool: the nearest centre point is a waypoint k and the point lies more than TIE beyond the
    end of segment k-1 and before the start of segment k (outside a bend), so no rounding can move
    its foot into either segment."""
    a, seg = centerline[:-1], np.diff(centerline, axis=0)
    rel = points[:, None, :] - a[None]
    len_sq = (seg * seg).sum(-1)
    t = np.clip((rel * seg[None]).sum(-1) / len_sq[None], 0.0, 1.0)
    dist = np.linalg.norm(rel - t[..., None] * seg[None], axis=-1)
    best = np.argmin(dist, axis=1)
    k = np.where(t[np.arange(points.shape[0]), best] >= 1.0, best + 1, best) % a.shape[0]
    unit = seg / np.sqrt(len_sq)[:, None]
    rel_k = points - a[k]
    past_end = (rel_k * unit[k - 1]).sum(-1) > TIE  # k - 1 == -1 is the last segment, ending at waypoint 0
    before_start = (rel_k * unit[k]).sum(-1) < -TIE
    vertex = np.isin(t[np.arange(points.shape[0]), best], (0.0, 1.0))
    return vertex & past_end & before_start


# ------------------------------------------------------------------ laplab's side


def laplab_params(track: Track, points: np.ndarray, direction, rng) -> list[dict]:
    """Params of cars whose reference points lie at ``points`` (M, 2), driving ``direction`` (0, 1 or (M,))."""
    sim = Simulator(track, points.shape[0], episode=EpisodeParams(round_robin_advance=0.0), state_sensor=None)
    sim.reset(ndist=0.0, direction=np.broadcast_to(direction, points.shape[0]))
    yaw = rng.uniform(-math.pi, math.pi, points.shape[0])
    sim.place(np.arange(points.shape[0]), pose_for_reference(points, yaw, DEEPRACER.reference_offset))
    return ParamsBuilder(sim).build()


def sample_points(track: Track, rng, count: int = 90, abeam: int = 40) -> np.ndarray:
    """Random points across and a little beyond the road, and points on the bisector of random
    waypoints at 0.05-0.6 m on either side (outside a bend their nearest centre point is the waypoint)."""
    c = track.centerline
    s = rng.uniform(0.0, track.length, count)
    seg = np.clip(np.searchsorted(track.arc_length, s, side="right") - 1, 0, c.shape[0] - 2)
    tangent = c[seg + 1] - c[seg]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) / np.linalg.norm(tangent, axis=1)[:, None]
    lateral = rng.uniform(-0.75, 0.75, count) * track.nominal_width
    across = track.point_at(s) + lateral[:, None] * normal
    k = rng.integers(1, c.shape[0] - 1, abeam)
    before, after = c[k] - c[k - 1], c[k + 1] - c[k]
    before /= np.linalg.norm(before, axis=1)[:, None]
    after /= np.linalg.norm(after, axis=1)[:, None]
    bisector = np.column_stack([-(before + after)[:, 1], (before + after)[:, 0]])
    bisector /= np.maximum(np.linalg.norm(bisector, axis=1), 1e-12)[:, None]
    offset = rng.uniform(0.05, 0.6, abeam) * rng.choice([-1.0, 1.0], abeam)
    return np.vstack([across, c[k] + offset[:, None] * bisector])


@pytest.fixture(scope="module")
def routes(reference_tracks_dir):
    """name -> (simapp's sanitised route, laplab's Track) for every closed reference route."""
    out = {}
    for path in sorted(reference_tracks_dir.glob("*.npy")):
        if path.stem not in OPEN_ROUTES:
            out[path.stem] = (simapp_sanitize(np.load(path)), load_route_file(path))
    return out


def test_all_reference_routes_are_compared(routes):
    assert len(routes) == 126  # 127 routes, one of them open


def test_geometry_keys_match_simapp_on_every_reference_route(routes):
    rng = np.random.default_rng(10)
    compared = {"closest_waypoints": 0, "track_width": 0, "is_left_of_center": 0}
    vertex_hits = samples = 0
    for name, (route, track) in routes.items():
        np.testing.assert_array_equal(track.route(), route, err_msg=name)
        points = sample_points(track, rng)
        both = laplab_params(track, np.vstack([points, points]), np.repeat([0, 1], points.shape[0]), rng)
        for direction in (0, 1):
            ref = Simapp(route, reverse=bool(direction))
            lap = route[::-1] if direction else route
            want = ref.params(points)
            got = both[direction * points.shape[0]:(direction + 1) * points.shape[0]]
            centre_tie = ambiguous_nearest(points, lap[:, 0:2])
            border_tie = ambiguous_nearest(want["centre"], lap[:, 2:4]) | ambiguous_nearest(want["centre"], lap[:, 4:6])
            gap = np.abs(want["ndist"][:, None] - ref.ndists[None, :]).min(axis=1) * ref.length
            at_vertex = beyond_both_segments(points, lap[:, 0:2])
            vertex_hits += int(at_vertex.sum())
            samples += points.shape[0]
            for j, p in enumerate(got):
                where = f"{name} direction {direction} point {points[j].tolist()}"
                if centre_tie[j]:
                    continue
                assert abs(p["distance_from_center"] - want["distance_from_center"][j]) < 1e-9, where
                # two feet within TIE of each other on either side of a waypoint can both be "nearest"
                assert abs(p["projection_distance"] - want["ndist"][j] * ref.length) < TIE, where
                pair = [int(want["prev"][j]), int(want["next"][j])]
                if at_vertex[j] or gap[j] > TIE:
                    assert p["closest_waypoints"] == pair, where
                    compared["closest_waypoints"] += 1
                else:  # within TIE of a waypoint: either side of it
                    assert p["closest_waypoints"][0] in (pair[0], pair[0] - 1, pair[0] + 1), where
                if border_tie[j]:
                    continue
                assert abs(p["track_width"] - want["track_width"][j]) < 1e-9, where
                compared["track_width"] += 1
                if abs(want["d_in"][j] - want["d_out"][j]) > TIE:
                    assert p["is_left_of_center"] == bool(want["is_left_of_center"][j]), where
                    compared["is_left_of_center"] += 1
    assert min(compared.values()) > 0.75 * samples, compared  # ties are few
    assert vertex_hits > 0.1 * samples  # the "nearest centre point is a waypoint" case is well covered


def test_progress_matches_simapp_step_by_step_on_every_reference_route(routes, pure_pursuit):
    """Cars start at three places (one just before the finish line) in both directions and drive 30
    steps; after every step laplab's progress is simapp's, from the start pose's centre-line point."""
    starts = np.array([0.0, 0.4, 0.985, 0.0, 0.4, 0.985])
    directions = np.array([0, 0, 0, 1, 1, 1])
    for name, (route, track) in routes.items():
        refs = (Simapp(route), Simapp(route, reverse=True))
        sim = Simulator(track, starts.size, episode=EpisodeParams(round_robin_advance=0.0), state_sensor=None)
        sim.reset(ndist=starts, direction=directions)
        builder = ParamsBuilder(sim)
        prev = np.zeros(starts.size)
        for _ in range(30):
            stepped = sim.step(pure_pursuit(sim), np.full(starts.size, 3.0))
            got = np.array([p["progress"] for p in builder.build()])
            ref_points = np.column_stack([sim.state.ref_x, sim.state.ref_y])
            ndist = np.where(directions == 0, refs[0].ndist(ref_points), refs[1].ndist(ref_points))
            want = np.array([simapp_progress(*args) for args in zip(ndist, starts, prev)])
            assert (np.abs(got - want) < 1e-7)[stepped].all(), f"{name}: {got} != {want}"
            prev = np.where(stepped, want, prev)
        assert (sim.state.progress[[2, 5]] > 0.0).all() and (sim.state.progress[[2, 5]] < 50.0).all(), name


# ------------------------------------------------------------------ the four differences, by hand


def test_a_car_whose_nearest_centre_point_is_waypoint_k_gets_k_and_k_plus_one(circle_track):
    """Outside the 400-gon circle at the angle of waypoint 37, the nearest centre point is waypoint 37
    itself: bisect_right gives [37, 38] (laplab used to give [36, 37])."""
    k = 37
    angle = 2.0 * math.pi * k / 400
    for radius in (3.2, 3.45):
        point = np.array([[radius * math.cos(angle), radius * math.sin(angle)]])
        p = laplab_params(circle_track, point, 0, np.random.default_rng(0))[0]
        assert p["closest_waypoints"] == [k, k + 1]
    # at the closing point the car is at the start: [0, 1]
    p = laplab_params(circle_track, np.array([[3.3, 0.0]]), 0, np.random.default_rng(0))[0]
    assert p["closest_waypoints"] == [0, 1]
    # inside the circle the nearest point lies within a segment: the usual pair
    inside = 2.8 * np.array([[math.cos(angle + 0.001), math.sin(angle + 0.001)]])
    assert laplab_params(circle_track, inside, 0, np.random.default_rng(0))[0]["closest_waypoints"] == [k, k + 1]


def test_closest_waypoints_pass_over_a_repeated_waypoint(circle_route):
    """With the raw rows kept (a repeated waypoint 5 = 6), a car at that waypoint gets [6, 7]."""
    route = circle_route()
    route = np.vstack([route[:6], route[5:]])
    track = track_from_route(route, "repeat", remove_repeats=False)
    point = 3.3 * route[5, 0:2][None] / 3.0
    assert laplab_params(track, point, 0, np.random.default_rng(0))[0]["closest_waypoints"] == [6, 7]


def _lopsided_stadium(stadium_route) -> np.ndarray:
    """The conftest stadium with the outer border of the bottom straight moved out 0.4 m for
    0.5 <= x <= 2.5: there the road is 1.4 m wide, 0.5 m left of the centre line and 0.9 m right."""
    route = stadium_route()
    bottom = (np.abs(route[:, 1] + 2.0) < 1e-9) & (route[:, 0] >= 0.5 - 1e-9) & (route[:, 0] <= 2.5 + 1e-9)
    route[bottom, 5] -= 0.4
    return route


def test_is_left_of_center_is_the_nearer_border_not_the_side_of_the_line(stadium_route):
    track = track_from_route(_lopsided_stadium(stadium_route), "lopsided")
    point = np.array([[1.5, -2.1]])  # 0.1 m right of the centre line, 0.6 m from the inner border, 0.8 m from the outer
    p = laplab_params(track, point, 0, np.random.default_rng(0))[0]
    assert p["distance_from_center"] == pytest.approx(0.1)
    assert p["is_left_of_center"] is True  # nearer the inner border, which is on the left (CCW)
    assert p["track_width"] == pytest.approx(1.4)
    # driven the other way the inner border is on the right: the same point is right of centre
    assert laplab_params(track, point, 1, np.random.default_rng(0))[0]["is_left_of_center"] is False


def test_track_width_is_between_the_border_points_nearest_the_centre_point(stadium_route):
    """A stadium with 1 m between waypoints and a V notch in the outer border at waypoint 2, (2, -2).
    Halfway between waypoints 1 and 2, at (1.5, -2), the nearest inner border point is (1.5, -1.5) and
    the nearest outer one (1, -2.5): the width is sqrt(1.25) = 1.118 m. laplab used to interpolate the
    widths at the two waypoints (1.0 and 1.458 m): 1.229 m."""
    route = stadium_route(straight=8.0, radius=2.0, spacing=1.0)
    np.testing.assert_allclose(route[1:4, 0:2], [[1.0, -2.0], [2.0, -2.0], [3.0, -2.0]], atol=1e-12)
    route[2, 4:6] = [2.0, -3.5]
    track = track_from_route(route, "notched")
    p = laplab_params(track, np.array([[1.5, -2.0]]), 0, np.random.default_rng(0))[0]
    assert p["closest_waypoints"] == [1, 2]
    assert p["track_width"] == pytest.approx(math.sqrt(1.25), abs=1e-12)
    assert p["track_width"] == pytest.approx(Simapp(route).params(np.array([[1.5, -2.0]]))["track_width"][0], abs=1e-12)
    interpolated = 0.5 * (track.road_width[1] + track.road_width[2])
    assert interpolated == pytest.approx(0.5 * (1.0 + math.sqrt(2.125)), abs=1e-12)
    assert interpolated - p["track_width"] > 0.1


def test_progress_counts_from_the_start_pose_centre_line_point(stadium_track):
    """After a reset the reference point is 0.14 m ahead of the start: progress is that share of the
    lap from the first step on (laplab counted from the reference point, 0 %); backing over the start
    line gives negative progress, as in DeepRacer."""
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.0, round_robin_advance=0.0))
    sim.reset()
    sim.step(np.zeros(1), np.zeros(1))
    lead = 100.0 * DEEPRACER.reference_offset / stadium_track.length
    assert ParamsBuilder(sim).build()[0]["progress"] == pytest.approx(lead, abs=1e-9)
    # turned round at the same reference point, the car drives back over the start line
    ref = np.array([[sim.state.ref_x[0], sim.state.ref_y[0]]])
    sim.place([0], pose_for_reference(ref, np.array([math.pi]), DEEPRACER.reference_offset))
    values = []
    for _ in range(6):
        sim.step(np.zeros(1), np.full(1, 1.0))
        values.append(ParamsBuilder(sim).build()[0]["progress"])
    assert sim.state.status[0] == IN_PROGRESS
    assert values[0] < lead and values[-1] < 0.0 and values == sorted(values, reverse=True)
