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

FAR_ARC = 1.0  # m: segments at least this far apart along the loop count as "far" for the gap


class TrackArrays(NamedTuple):
    """The arrays numba kernels read (N waypoints, closing point included; N-1 segments)."""

    centerline: np.ndarray  # (N, 2) float64
    arc_length: np.ndarray  # (N,)
    left_width: np.ndarray  # (N,)
    right_width: np.ndarray  # (N,)
    length: float
    segments: np.ndarray  # (N-1, 5) per segment: start x, start y, dx, dy, 1 / length^2
    far_gap: np.ndarray  # (N-1,) distance from each segment to the nearest segment >= FAR_ARC away along the loop, m
    window: np.ndarray  # (N-1, 2) int64: segments searched before / after a hint (covering 2 x FAR_ARC of arc)
    left_border: np.ndarray  # (L, 5) the left border's segments (driving direction), as ``segments``
    right_border: np.ndarray  # (R, 5) the right border's segments
    border_anchor: np.ndarray  # (N-1, 2) int64: left / right border segment nearest each centre segment
    clearance: np.ndarray  # (N-1,) m: no border point lies nearer than this to the centre segment


class Projection(NamedTuple):
    """Result of projecting M points; every field has shape (M,)."""

    segment: np.ndarray  # int64: index i of the segment [i, i+1] holding the projection
    arc_length: np.ndarray  # float64 m from waypoint 0 along the centre line
    lateral: np.ndarray  # float64 m, signed: positive left of the centre line (driving direction)
    distance: np.ndarray  # float64 m, |lateral| up to segment-end effects (distance to the line)


def track_arrays(track: Track) -> TrackArrays:
    """Pack a track for the kernels (computes the far-segment gap once)."""
    c = track.centerline
    left, right = (track.inner, track.outer) if track.is_ccw else (track.outer, track.inner)
    mid = 0.5 * (c[:-1] + c[1:])
    anchor = np.stack([_nearest_segment(mid, left), _nearest_segment(mid, right)], axis=1)
    segments, left_border, right_border = _segment_table(c), _segment_table(left), _segment_table(right)
    return TrackArrays(c, track.arc_length, track.left_width, track.right_width, track.length, segments,
                       *_far_segment_gap(c, track.arc_length), left_border, right_border, anchor.astype(np.int64),
                       _border_clearance(segments, left_border, right_border))


def _segment_table(polyline: np.ndarray) -> np.ndarray:
    """(M-1, 5) start x, start y, dx, dy, 1/length^2 (0 for zero-length segments) of a polyline."""
    d = np.diff(polyline, axis=0)
    len_sq = (d * d).sum(axis=1)
    inv = np.where(len_sq > 1e-18, 1.0 / np.maximum(len_sq, 1e-18), 0.0)
    return np.ascontiguousarray(np.column_stack([polyline[:-1], d, inv]))


def _nearest_segment(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(P,) index of the segment of ``polyline`` nearest each point."""
    a, seg = polyline[:-1], np.diff(polyline, axis=0)
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * seg[None]).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-18)[None], 0.0, 1.0)
    diff = rel - t[..., None] * seg[None]
    return np.argmin((diff * diff).sum(-1), axis=1)


def _arc_separation(arc_length: np.ndarray) -> np.ndarray:
    """(M, M) arc length between the nearer ends of segments i and j, along the loop (0 for neighbours)."""
    length = arc_length[-1]
    seg_len = np.diff(arc_length)
    mid = arc_length[:-1] + 0.5 * seg_len
    apart = np.abs(mid[:, None] - mid[None, :])
    apart = np.minimum(apart, length - apart)
    return np.maximum(apart - 0.5 * (seg_len[:, None] + seg_len[None, :]), 0.0)


def _far_segment_gap(centerline: np.ndarray, arc_length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per segment: the distance to the nearest segment at least FAR_ARC away along the loop (0 where
    two such segments cross), and the search window (segments before, after) that covers 2 x FAR_ARC
    of arc either side, so any segment the car can reach in one step plus FAR_ARC lies inside it."""
    a, b = centerline[:-1], centerline[1:]
    m = a.shape[0]
    separation = _arc_separation(arc_length)
    far = separation >= FAR_ARC
    window = np.empty((m, 2), dtype=np.int64)
    for side, col in ((-1, 0), (1, 1)):
        shifts = np.arange(1, m // 2 + 1)
        idx = (np.arange(m)[:, None] + side * shifts[None, :]) % m
        covered = separation[np.arange(m)[:, None], idx] < 2 * FAR_ARC
        # number of leading shifts still within 2 x FAR_ARC, plus one segment beyond
        window[:, col] = np.minimum(np.argmin(np.concatenate([covered, np.zeros((m, 1), bool)], axis=1), axis=1) + 1,
                                    m // 2)
    seg = b - a
    len_sq = np.maximum((seg * seg).sum(-1), 1e-18)
    dist = np.full((m, m), np.inf)
    for points in (a, b):  # endpoint-to-segment distances bound segment-segment distances (no crossings)
        rel = points[:, None, :] - a[None, :, :]
        t = np.clip((rel * seg[None]).sum(-1) / len_sq[None], 0.0, 1.0)
        d = np.sqrt(((rel - t[..., None] * seg[None]) ** 2).sum(-1))  # d[i, j]: endpoint of i to segment j
        dist = np.minimum(dist, np.minimum(d, d.T))
    dist = np.where(far, dist, np.inf)
    gap = dist.min(axis=1)
    return np.where(np.isfinite(gap), gap, np.inf), window


@nb.njit(cache=True)
def _border_clearance(segments, left_border, right_border):
    """(M,) per centre segment, its distance to the nearest segment of either border, m (0 where they
    cross). A disk of that radius around any point of the segment holds no border point, so it is road."""
    out = np.empty(segments.shape[0])
    for i in range(segments.shape[0]):
        best = np.inf
        for border in (left_border, right_border):
            for j in range(border.shape[0]):
                best = min(best, _segments_distance(segments, i, border, j))
        out[i] = best
    return out


@nb.njit(cache=True, inline="always")
def _segments_distance(first, i, second, j):
    """Distance between segment i of ``first`` and segment j of ``second`` (segment tables), m."""
    ax, ay, adx, ady = first[i, 0], first[i, 1], first[i, 2], first[i, 3]
    bx, by, bdx, bdy = second[j, 0], second[j, 1], second[j, 2], second[j, 3]
    # A proper crossing: each segment's ends lie strictly on both sides of the other's line.
    o1 = adx * (by - ay) - ady * (bx - ax)
    o2 = adx * (by + bdy - ay) - ady * (bx + bdx - ax)
    o3 = bdx * (ay - by) - bdy * (ax - bx)
    o4 = bdx * (ay + ady - by) - bdy * (ax + adx - bx)
    if o1 * o2 < 0.0 and o3 * o4 < 0.0:
        return 0.0
    # Otherwise the nearest pair of points includes an end of one of them.
    d2 = min(_segment_distance_sq(bx, by, first, i)[0], _segment_distance_sq(bx + bdx, by + bdy, first, i)[0],
             _segment_distance_sq(ax, ay, second, j)[0], _segment_distance_sq(ax + adx, ay + ady, second, j)[0])
    return np.sqrt(d2)


@nb.njit(cache=True, inline="always")
def _segment_distance_sq(px, py, segments, i):
    ax, ay, dx, dy, inv_len_sq = segments[i, 0], segments[i, 1], segments[i, 2], segments[i, 3], segments[i, 4]
    t = min(max(((px - ax) * dx + (py - ay) * dy) * inv_len_sq, 0.0), 1.0)
    qx, qy = ax + t * dx - px, ay + t * dy - py
    return qx * qx + qy * qy, t


@nb.njit(cache=True, inline="always")
def _arc_between(arc_length, i, j):
    """Arc length from the end of segment i forward to the start of segment j (cyclic), m; 0 when
    i == j (the window's end segment is the best one: no coverage beyond it)."""
    if i == j:
        return 0.0
    gap = arc_length[j] - arc_length[i + 1]
    return gap + arc_length[-1] if gap < 0.0 else gap


@nb.njit(cache=True)
def project_point(px, py, segments, arc_length, far_gap, window, hint):
    """Project one point; returns (segment, t in [0,1], arc length, signed lateral, distance).

    ``segments``, ``far_gap`` and ``window`` as in :class:`TrackArrays`; ``hint`` is the segment
    found last time (-1 for none). The window's best segment b is kept only when no segment outside the
    window can be nearer: the window reaches at least FAR_ARC beyond b on both sides, and the point is
    nearer to b than half of b's ``far_gap`` (every segment FAR_ARC or more away along the loop is at
    least ``far_gap`` from b). Otherwise every segment is searched.
    """
    n_seg = segments.shape[0]
    best_i, best_t, best_d2 = -1, 0.0, np.inf
    if 0 <= hint < n_seg:  # an out-of-range hint (stale, from another track) means no hint
        back, fwd = window[hint, 0], window[hint, 1]
        if back + fwd + 1 < n_seg:
            for k in range(-back, fwd + 1):
                i = hint + k
                if i < 0:
                    i += n_seg
                elif i >= n_seg:
                    i -= n_seg
                d2, t = _segment_distance_sq(px, py, segments, i)
                if d2 < best_d2:
                    best_i, best_t, best_d2 = i, t, d2
            first = hint - back if hint - back >= 0 else hint - back + n_seg
            last = hint + fwd if hint + fwd < n_seg else hint + fwd - n_seg
            gap = far_gap[best_i]
            if (4.0 * best_d2 >= gap * gap or _arc_between(arc_length, first, best_i) < FAR_ARC
                    or _arc_between(arc_length, best_i, last) < FAR_ARC):
                best_i = -1
    if best_i < 0:
        best_d2 = np.inf
        for i in range(n_seg):
            d2, t = _segment_distance_sq(px, py, segments, i)
            if d2 < best_d2:
                best_i, best_t, best_d2 = i, t, d2
    ax, ay = segments[best_i, 0], segments[best_i, 1]
    dx, dy = segments[best_i, 2], segments[best_i, 3]
    seg_len = arc_length[best_i + 1] - arc_length[best_i]
    s = arc_length[best_i] + best_t * seg_len
    dist = np.sqrt(best_d2)
    cross = dx * (py - ay) - dy * (px - ax)
    lateral = dist if cross >= 0.0 else -dist
    # At the closing point (t == 1 on the last segment) report arc length 0, as DeepRacer's ring does.
    if s >= arc_length[-1]:
        s -= arc_length[-1]
    return best_i, best_t, s, lateral, dist


BORDER_WINDOW = 4  # border segments searched either side of the anchor


@nb.njit(cache=True, inline="always")
def _inside_of_border(px, py, border, anchor, road_on_left):
    """True when the point is on the road side of the nearest segment of ``border`` near ``anchor``.

    The road lies to the left of the border (``road_on_left``) or to its right. Where the nearest point
    is a vertex, the adjacent segment with the larger perpendicular offset decides (the two agree
    unless the point is on the vertex's bisector, where either answer is as good).
    """
    m = border.shape[0]
    best_d2, best_cross, best_abs = np.inf, 0.0, -1.0
    for k in range(-BORDER_WINDOW, BORDER_WINDOW + 1):
        j = (anchor + k) % m
        inv = border[j, 4]
        if inv == 0.0:
            continue
        ax, ay, dx, dy = border[j, 0], border[j, 1], border[j, 2], border[j, 3]
        t = min(max(((px - ax) * dx + (py - ay) * dy) * inv, 0.0), 1.0)
        qx, qy = ax + t * dx - px, ay + t * dy - py
        d2 = qx * qx + qy * qy
        cross = (dx * (py - ay) - dy * (px - ax)) * np.sqrt(inv)  # signed distance to the segment's line
        if d2 < best_d2 - 1e-15 or (d2 <= best_d2 + 1e-15 and abs(cross) > best_abs):
            best_d2, best_cross, best_abs = d2, cross, abs(cross)
    return best_cross >= 0.0 if road_on_left else best_cross <= 0.0


@nb.njit(cache=True)
def point_on_track(px, py, geo, hint):
    """True when the point lies on the drivable area between the borders.

    The centre-line projection tells on which side the point lies; the point is then tested against
    that side's border polyline itself (so coarse waypoints do not move the border). ``geo`` is a
    :class:`TrackArrays`.
    """
    seg, _, _, lateral, _ = project_point(px, py, geo.segments, geo.arc_length, geo.far_gap, geo.window, hint)
    if lateral >= 0.0:
        return _inside_of_border(px, py, geo.left_border, geo.border_anchor[seg, 0], False)
    return _inside_of_border(px, py, geo.right_border, geo.border_anchor[seg, 1], True)


@nb.njit(cache=True)
def point_on_road_near(px, py, geo, segment):
    """True when the point is on the road next to centre segment ``segment``: on the road side of both
    borders there (each searched within BORDER_WINDOW of its anchor). For points near a car whose
    reference point projects on ``segment`` (its wheels): no projection needed."""
    return (_inside_of_border(px, py, geo.left_border, geo.border_anchor[segment, 0], False)
            and _inside_of_border(px, py, geo.right_border, geo.border_anchor[segment, 1], True))


PARALLEL_MIN_POINTS = 512  # below this, starting numba's thread pool costs more than it saves


def _project_loop(points, segments, arc_length, far_gap, window, hints, seg_out, s_out, lat_out, dist_out):
    for j in nb.prange(points.shape[0]):
        seg, _, s, lat, dist = project_point(points[j, 0], points[j, 1], segments, arc_length,
                                             far_gap, window, hints[j])
        seg_out[j], s_out[j], lat_out[j], dist_out[j] = seg, s, lat, dist


def _on_track_loop(points, geo, hints, out):
    for j in nb.prange(points.shape[0]):
        out[j] = point_on_track(points[j, 0], points[j, 1], geo, hints[j])


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
    loop(pts, arrays.segments, arrays.arc_length, arrays.far_gap, arrays.window, _as_hints(hints, m), *out)
    return out


def points_on_track(arrays: TrackArrays, points, hints=None) -> np.ndarray:
    """(M,) bool: each point lies on the drivable area between the borders."""
    pts = _as_points(points)
    out = np.empty(pts.shape[0], dtype=np.bool_)
    loop = _on_track_parallel if pts.shape[0] >= PARALLEL_MIN_POINTS else _on_track_serial
    loop(pts, arrays, _as_hints(hints, pts.shape[0]), out)
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
