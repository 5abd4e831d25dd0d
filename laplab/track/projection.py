"""Batched projection of points onto a track's centre line, and the on-track test.

Hot path: numba kernels that search a window of segments around each point's previous segment and
fall back to the global search when the window cannot prove it found the nearest segment. Every
public function also has a plain numpy reference (``*_reference``) used by the parity tests.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from laplab.track.geometry import Track

SEARCH_WINDOW = 12  # segments searched either side of the hint
LOCAL_SEPARATION = 6  # segments closer than this (cyclically) count as "local" for the gap


class TrackArrays(NamedTuple):
    """The arrays numba kernels read (N waypoints, closing point included; N-1 segments)."""

    centerline: np.ndarray  # (N, 2) float64
    arc_length: np.ndarray  # (N,)
    left_width: np.ndarray  # (N,)
    right_width: np.ndarray  # (N,)
    road_width: np.ndarray  # (N,)
    length: float
    far_gap: float  # min distance between centre-line segments >= LOCAL_SEPARATION apart, m


class Projection(NamedTuple):
    """Result of projecting M points; every field has shape (M,)."""

    segment: np.ndarray  # int64: index i of the segment [i, i+1] holding the projection
    arc_length: np.ndarray  # float64 m from waypoint 0 along the centre line
    lateral: np.ndarray  # float64 m, signed: positive left of the centre line (driving direction)
    distance: np.ndarray  # float64 m, |lateral| up to segment-end effects (distance to the line)


def track_arrays(track: Track) -> TrackArrays:
    """Pack a track for the kernels (computes the far-segment gap once)."""
    return TrackArrays(track.centerline, track.arc_length, track.left_width, track.right_width,
                       track.road_width, track.length, _far_segment_gap(track.centerline))


def _far_segment_gap(centerline: np.ndarray) -> float:
    """Smallest distance between two centre-line segments at least LOCAL_SEPARATION segments apart."""
    a, b = centerline[:-1], centerline[1:]
    m = a.shape[0]
    idx = np.arange(m)
    sep = np.abs(idx[:, None] - idx[None, :])
    sep = np.minimum(sep, m - sep)
    far = sep >= LOCAL_SEPARATION
    if not far.any():
        return 0.0
    best = np.inf
    for points in (a, b):  # endpoint-to-segment distances bound segment-segment distances (no crossings)
        seg = b - a
        rel = points[:, None, :] - a[None, :, :]
        t = np.clip((rel * seg[None]).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-18)[None], 0.0, 1.0)
        d = np.sqrt(((rel - t[..., None] * seg[None]) ** 2).sum(-1))
        best = min(best, float(d[far].min()), float(d.T[far].min()))
    return best


@nb.njit(cache=True, inline="always")
def _segment_distance_sq(px, py, ax, ay, bx, by):
    dx, dy = bx - ax, by - ay
    len_sq = dx * dx + dy * dy
    t = 0.0
    if len_sq > 1e-18:
        t = ((px - ax) * dx + (py - ay) * dy) / len_sq
        t = min(max(t, 0.0), 1.0)
    qx, qy = ax + t * dx - px, ay + t * dy - py
    return qx * qx + qy * qy, t


@nb.njit(cache=True)
def project_point(px, py, centerline, arc_length, far_gap, hint):
    """Project one point; returns (segment, t in [0,1], arc length, signed lateral, distance).

    ``hint`` is the segment found last time (-1 for none). The window result is kept only when no
    segment outside the window can be nearer (distance < far_gap / 2 and the best segment is not at the
    window's edge); otherwise every segment is searched.
    """
    n_seg = centerline.shape[0] - 1
    best_i, best_t, best_d2 = -1, 0.0, np.inf
    if hint >= 0 and n_seg > 2 * SEARCH_WINDOW + 1:
        best_k = 0
        for k in range(-SEARCH_WINDOW, SEARCH_WINDOW + 1):
            i = (hint + k) % n_seg
            d2, t = _segment_distance_sq(px, py, centerline[i, 0], centerline[i, 1],
                                         centerline[i + 1, 0], centerline[i + 1, 1])
            if d2 < best_d2:
                best_i, best_t, best_d2, best_k = i, t, d2, k
        if abs(best_k) > SEARCH_WINDOW - LOCAL_SEPARATION or 4.0 * best_d2 >= far_gap * far_gap:
            best_i = -1
    if best_i < 0:
        best_d2 = np.inf
        for i in range(n_seg):
            d2, t = _segment_distance_sq(px, py, centerline[i, 0], centerline[i, 1],
                                         centerline[i + 1, 0], centerline[i + 1, 1])
            if d2 < best_d2:
                best_i, best_t, best_d2 = i, t, d2
    ax, ay = centerline[best_i, 0], centerline[best_i, 1]
    dx, dy = centerline[best_i + 1, 0] - ax, centerline[best_i + 1, 1] - ay
    seg_len = np.sqrt(dx * dx + dy * dy)
    s = arc_length[best_i] + best_t * seg_len
    dist = np.sqrt(best_d2)
    cross = dx * (py - ay) - dy * (px - ax)
    lateral = dist if cross >= 0.0 else -dist
    # At the closing point (t == 1 on the last segment) report arc length 0, as DeepRacer's ring does.
    if s >= arc_length[-1]:
        s -= arc_length[-1]
    return best_i, best_t, s, lateral, dist


@nb.njit(cache=True, inline="always")
def interpolate_at_segment(values, segment, t):
    return values[segment] + t * (values[segment + 1] - values[segment])


@nb.njit(cache=True)
def point_on_track(px, py, centerline, arc_length, left_width, right_width, far_gap, hint):
    """True when the point lies between the borders (lateral offset within the local widths)."""
    seg, t, _, lateral, _ = project_point(px, py, centerline, arc_length, far_gap, hint)
    if lateral >= 0.0:
        return lateral <= interpolate_at_segment(left_width, seg, t)
    return -lateral <= interpolate_at_segment(right_width, seg, t)


PARALLEL_MIN_POINTS = 512  # below this, starting numba's thread pool costs more than it saves


def _project_loop(points, centerline, arc_length, far_gap, hints, seg_out, s_out, lat_out, dist_out):
    for j in nb.prange(points.shape[0]):
        seg, _, s, lat, dist = project_point(points[j, 0], points[j, 1], centerline, arc_length,
                                             far_gap, hints[j])
        seg_out[j], s_out[j], lat_out[j], dist_out[j] = seg, s, lat, dist


def _on_track_loop(points, centerline, arc_length, left_width, right_width, far_gap, hints, out):
    for j in nb.prange(points.shape[0]):
        out[j] = point_on_track(points[j, 0], points[j, 1], centerline, arc_length, left_width,
                                right_width, far_gap, hints[j])


# Each loop compiled twice: serial for small batches, parallel for large ones.
_project_serial = nb.njit(cache=True)(_project_loop)
_project_parallel = nb.njit(cache=True, parallel=True)(_project_loop)
_on_track_serial = nb.njit(cache=True)(_on_track_loop)
_on_track_parallel = nb.njit(cache=True, parallel=True)(_on_track_loop)


def _as_points(points) -> np.ndarray:
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (M, 2), got {pts.shape}")
    return pts


def _as_hints(hints, m: int) -> np.ndarray:
    if hints is None:
        return np.full(m, -1, dtype=np.int64)
    return np.ascontiguousarray(hints, dtype=np.int64).reshape(m)


def project_points(arrays: TrackArrays, points, hints=None) -> Projection:
    """Project points (M, 2) onto the centre line; ``hints`` (M,) previous segments or None."""
    pts = _as_points(points)
    m = pts.shape[0]
    out = Projection(np.empty(m, np.int64), np.empty(m), np.empty(m), np.empty(m))
    loop = _project_parallel if m >= PARALLEL_MIN_POINTS else _project_serial
    loop(pts, arrays.centerline, arrays.arc_length, arrays.far_gap, _as_hints(hints, m), *out)
    return out


def points_on_track(arrays: TrackArrays, points, hints=None) -> np.ndarray:
    """(M,) bool: each point lies on the drivable area between the borders."""
    pts = _as_points(points)
    out = np.empty(pts.shape[0], dtype=np.bool_)
    loop = _on_track_parallel if pts.shape[0] >= PARALLEL_MIN_POINTS else _on_track_serial
    loop(pts, arrays.centerline, arrays.arc_length, arrays.left_width, arrays.right_width,
                   arrays.far_gap, _as_hints(hints, pts.shape[0]), out)
    return out


def project_points_reference(track: Track, points) -> Projection:
    """Global nearest-segment projection in plain numpy (M x segments); the parity reference."""
    pts = _as_points(points)
    a, b = track.centerline[:-1], track.centerline[1:]
    seg = b - a
    rel = pts[:, None, :] - a[None]
    len_sq = np.maximum((seg * seg).sum(-1), 1e-18)
    t = np.clip((rel * seg[None]).sum(-1) / len_sq[None], 0.0, 1.0)
    diff = rel - t[..., None] * seg[None]
    d2 = (diff * diff).sum(-1)
    best = np.argmin(d2, axis=1)
    rows = np.arange(pts.shape[0])
    tb = t[rows, best]
    s = track.arc_length[best] + tb * np.sqrt(len_sq[best])
    s = np.where(s >= track.length, s - track.length, s)
    cross = seg[best, 0] * rel[rows, best, 1] - seg[best, 1] * rel[rows, best, 0]
    dist = np.sqrt(d2[rows, best])
    return Projection(best.astype(np.int64), s, np.where(cross >= 0, dist, -dist), dist)
