"""DeepRacer's geometry for three reward params: ``closest_waypoints``, ``track_width``, ``is_left_of_center``.

Definitions followed (aws-deepracer-community/deepracer-simapp, ``bundle/markov``):

- ``closest_waypoints``: ``track_geom/track_data.py`` (``TrackLine.ndists``, ``find_prev_next_waypoints``)
  and ``track_geom/utils.py`` (``find_prev_next``): ``bisect_right`` of the car's normalised
  centre-line distance over the waypoints' normalised distances (the closing point's is 1.0). Where
  the car's nearest centre-line point is waypoint k itself, that gives [k, k+1]; at the closing point
  (the start) [0, 1]; a repeated waypoint is passed over to the last of its copies.
- ``track_width``: ``TrackData.get_nearest_points``: the nearest point of the inner border and of the
  outer border to the car's nearest centre-line point; the width is the distance between those two.
- ``is_left_of_center``: ``agent_ctrl/utils.py`` (``set_reward_and_metrics``): the car is nearer to
  that inner border point than to that outer border point, flipped when the driving direction is
  clockwise (``TrackData.is_ccw``, which already accounts for a reversed direction).

Every "nearest point" is the global nearest point of the polyline, as shapely's ``project`` finds it.
The kernels search only the border segments that can hold it (:func:`border_candidates` proves the
others farther), in index order with a strict comparison, so ties go to the first segment as in GEOS.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from laplab.track.geometry import Track


class ParamsGeometry(NamedTuple):
    """Arrays of one driving direction for :func:`reward_geometry` (N waypoints, closing point included)."""

    centre: np.ndarray  # (N-1, 4) per centre segment: start x, start y, dx, dy
    vertex_prev: np.ndarray  # (N,) int64: previous waypoint when the nearest centre point is waypoint k
    inner: np.ndarray  # (I-1, 5) inner border segments: start x, start y, dx, dy, 1 / length^2 (0 if empty)
    outer: np.ndarray  # (O-1, 5) outer border segments, likewise
    inner_start: np.ndarray  # (N,) int64: candidates of centre segment i are inner_ids[inner_start[i]:inner_start[i+1]]
    inner_ids: np.ndarray  # (K,) int64, ascending within each centre segment
    outer_start: np.ndarray  # (N,) int64, as inner_start for the outer border
    outer_ids: np.ndarray  # (K',) int64
    clockwise: bool  # the driving direction is clockwise (simapp flips is_left_of_center then)


def _segment_table(polyline: np.ndarray) -> np.ndarray:
    d = np.diff(polyline, axis=0)
    len_sq = (d * d).sum(axis=1)
    inv = np.where(len_sq > 0.0, 1.0 / np.where(len_sq > 0.0, len_sq, 1.0), 0.0)
    return np.ascontiguousarray(np.column_stack([polyline[:-1], d, inv]))


@nb.njit(cache=True, inline="always")
def _point_segment_distance(px, py, ax, ay, bx, by):
    dx, dy = bx - ax, by - ay
    len_sq = dx * dx + dy * dy
    t = 0.0 if len_sq == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / len_sq, 0.0), 1.0)
    qx, qy = ax + t * dx - px, ay + t * dy - py
    return np.sqrt(qx * qx + qy * qy)


@nb.njit(cache=True, inline="always")
def _orientation(ox, oy, px, py, qx, qy):
    return (px - ox) * (qy - oy) - (py - oy) * (qx - ox)


@nb.njit(cache=True)
def _candidate_mask(centre, border):
    """(M, S) bool: border segment j can hold the nearest border point of a point on centre segment i."""
    m, n = centre.shape[0] - 1, border.shape[0] - 1
    near = np.zeros((m, n), dtype=np.bool_)
    d_a, d_b = np.empty(n), np.empty(n)
    for i in range(m):
        ax, ay, bx, by = centre[i, 0], centre[i, 1], centre[i + 1, 0], centre[i + 1, 1]
        reach = np.inf
        for j in range(n):
            cx, cy, dx, dy = border[j, 0], border[j, 1], border[j + 1, 0], border[j + 1, 1]
            d_a[j] = _point_segment_distance(ax, ay, cx, cy, dx, dy)
            d_b[j] = _point_segment_distance(bx, by, cx, cy, dx, dy)
            reach = min(reach, max(d_a[j], d_b[j]))
        limit = reach * (1.0 + 1e-9) + 1e-12
        for j in range(n):
            cx, cy, dx, dy = border[j, 0], border[j, 1], border[j + 1, 0], border[j + 1, 1]
            apart = min(d_a[j], d_b[j], _point_segment_distance(cx, cy, ax, ay, bx, by),
                        _point_segment_distance(dx, dy, ax, ay, bx, by))
            crossing = (_orientation(ax, ay, bx, by, cx, cy) * _orientation(ax, ay, bx, by, dx, dy) < 0.0
                        and _orientation(cx, cy, dx, dy, ax, ay) * _orientation(cx, cy, dx, dy, bx, by) < 0.0)
            near[i, j] = apart <= limit or crossing
    return near


def border_candidates(centerline: np.ndarray, border: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR lists (start (N,), ids (K,)) of the border segments that can be nearest to a point of each
    centre segment.

    For centre segment i, no point on it is farther from the border than
    ``r_i = min_j max(d(a_i, j), d(b_i, j))`` (the distance to a segment is convex along a segment), so
    only border segments within ``r_i`` of segment i can hold a nearest point. Segment-to-segment
    distance: the least endpoint-to-segment distance, 0 where the two cross.
    """
    near = _candidate_mask(np.ascontiguousarray(centerline, dtype=np.float64),
                           np.ascontiguousarray(border, dtype=np.float64))
    rows, ids = np.nonzero(near)  # row-major: ids ascend within each row
    start = np.zeros(near.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=near.shape[0]), out=start[1:])
    return start, ids.astype(np.int64)


def params_geometry(track: Track) -> ParamsGeometry:
    """The arrays of ``track`` (one driving direction) that :func:`reward_geometry` reads."""
    c = track.centerline
    arc = track.arc_length
    # bisect_right passes over repeated waypoints (equal distances) to the last copy; the closing
    # point is the start (a point there projects to distance 0 on the ring).
    n = c.shape[0]
    last_copy = np.searchsorted(arc, arc, side="right") - 1
    vertex_prev = last_copy.astype(np.int64)
    vertex_prev[-1] = last_copy[0]
    vertex_prev = np.minimum(vertex_prev, n - 2)
    inner_start, inner_ids = border_candidates(c, track.inner)
    outer_start, outer_ids = border_candidates(c, track.outer)
    return ParamsGeometry(np.ascontiguousarray(_segment_table(c)[:, :4]), vertex_prev,
                          _segment_table(track.inner), _segment_table(track.outer), inner_start, inner_ids,
                          outer_start, outer_ids, not track.is_ccw)


@nb.njit(cache=True, inline="always")
def _nearest_on(px, py, border, start, ids, row):
    """Nearest point (x, y) to (px, py) among the candidate segments ``ids[start[row]:start[row+1]]``."""
    best_d2, bx, by = np.inf, 0.0, 0.0
    for k in range(start[row], start[row + 1]):
        j = ids[k]
        ax, ay, dx, dy, inv = border[j, 0], border[j, 1], border[j, 2], border[j, 3], border[j, 4]
        t = min(max(((px - ax) * dx + (py - ay) * dy) * inv, 0.0), 1.0)
        qx, qy = ax + t * dx, ay + t * dy
        d2 = (qx - px) * (qx - px) + (qy - py) * (qy - py)
        if d2 < best_d2:
            best_d2, bx, by = d2, qx, qy
    return bx, by


@nb.njit(cache=True)
def _reward_geometry_loop(fwd, rev, direction, segment, seg_t, px, py, prev_out, next_out, width_out, left_out):
    for j in range(segment.shape[0]):
        geo = fwd if direction[j] == 0 else rev
        i, t = segment[j], seg_t[j]
        if t <= 0.0:
            prev = geo.vertex_prev[i]
        elif t >= 1.0:
            prev = geo.vertex_prev[i + 1]
        else:
            prev = i
        prev_out[j], next_out[j] = prev, prev + 1
        cx, cy = geo.centre[i, 0] + t * geo.centre[i, 2], geo.centre[i, 1] + t * geo.centre[i, 3]
        ix, iy = _nearest_on(cx, cy, geo.inner, geo.inner_start, geo.inner_ids, i)
        ox, oy = _nearest_on(cx, cy, geo.outer, geo.outer_start, geo.outer_ids, i)
        width_out[j] = np.sqrt((ix - ox) * (ix - ox) + (iy - oy) * (iy - oy))
        d_in = (px[j] - ix) * (px[j] - ix) + (py[j] - iy) * (py[j] - iy)
        d_out = (px[j] - ox) * (px[j] - ox) + (py[j] - oy) * (py[j] - oy)
        left_out[j] = (d_in < d_out) != geo.clockwise


class RewardGeometry(NamedTuple):
    """Per car, shape (M,): DeepRacer's ``closest_waypoints`` pair, ``track_width``, ``is_left_of_center``."""

    prev_waypoint: np.ndarray  # int64
    next_waypoint: np.ndarray  # int64
    track_width: np.ndarray  # float64, m
    is_left_of_center: np.ndarray  # bool


def reward_geometry(geometries: tuple[ParamsGeometry, ParamsGeometry], direction, segment, seg_t, x, y
                    ) -> RewardGeometry:
    """The three params of M cars.

    ``geometries``: the track's :class:`ParamsGeometry` driven forward and reversed; per car (M,):
    ``direction`` (0 forward, 1 reversed), the centre segment ``segment`` and fraction ``seg_t`` in
    [0, 1] of its nearest centre-line point, and its reference point ``x``, ``y`` (m).
    """
    def as_array(values, dtype):
        return np.ascontiguousarray(values, dtype=dtype).reshape(-1)

    segment = as_array(segment, np.int64)
    m = segment.shape[0]
    out = RewardGeometry(np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m), np.empty(m, np.bool_))
    _reward_geometry_loop(geometries[0], geometries[1], as_array(direction, np.int64), segment,
                          as_array(seg_t, np.float64), as_array(x, np.float64), as_array(y, np.float64), *out)
    return out
