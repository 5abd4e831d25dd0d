"""Rasterising a track into texel classes: how much of each texel is floor, road, border tape or
centre line, for :mod:`laplab.sensors.texture`.

The road is the even-odd fill of the border rings; the centre line (dashed along its arc length) and
the border tape (inside the road along each border) are stamped over it. Each texel is sampled on an
``antialias`` x ``antialias`` grid, rasterised in bands of rows to bound memory.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

FLOOR, ROAD, BORDER, CENTER = 0, 1, 2, 3  # texel classes of the class map


def route_arrays(track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centerline, inner, outer), each (N, 2) float64, from a Track-like object or an (N, 6) route."""
    if all(hasattr(track, name) for name in ("centerline", "inner", "outer")):
        arrays = [np.asarray(getattr(track, name), dtype=np.float64) for name in ("centerline", "inner", "outer")]
    else:
        route = np.asarray(track, dtype=np.float64)
        if route.ndim != 2 or route.shape[1] != 6 or route.shape[0] < 2:
            raise ValueError(f"texture: expected a Track or a DeepRacer route array of shape (N, 6) with N >= 2 "
                             f"[centre x, y | inner x, y | outer x, y], got shape {route.shape}")
        arrays = [route[:, 0:2], route[:, 2:4], route[:, 4:6]]
    for name, array in zip(("centerline", "inner", "outer"), arrays):
        if array.ndim != 2 or array.shape[1] != 2 or array.shape[0] < 2 or not np.isfinite(array).all():
            raise ValueError(f"texture: track.{name} must be a finite (N, 2) array with N >= 2, got shape "
                             f"{array.shape}{'' if np.isfinite(array).all() else ' with NaN/Inf values'}")
    return arrays[0], arrays[1], arrays[2]


@njit(cache=True)
def _fill_even_odd(edges, width, height):
    """(height, width) uint8 mask of texel centres inside the even-odd union of edge rings.

    edges: (E, 4) float64 [x1, y1, x2, y2] in texel units (texel centre j at j + 0.5).
    """
    mask = np.zeros((height, width), dtype=np.uint8)
    crossings = np.empty(edges.shape[0], dtype=np.float64)
    for row in range(height):
        yc = row + 0.5
        count = 0
        for e in range(edges.shape[0]):
            x1, y1, x2, y2 = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
            if (y1 <= yc < y2) or (y2 <= yc < y1):
                crossings[count] = x1 + (yc - y1) * (x2 - x1) / (y2 - y1)
                count += 1
        xs = np.sort(crossings[:count])
        for p in range(0, count - 1, 2):
            start = max(int(math.ceil(xs[p] - 0.5)), 0)
            stop = min(int(math.ceil(xs[p + 1] - 0.5)), width)
            for col in range(start, stop):
                mask[row, col] = 1
    return mask


@njit(cache=True)
def _stamp_polyline(classes, points, half_width, replace_from, new_class, period, dash_length, offset):
    """Set texels of ``classes`` whose centre lies within ``half_width`` of the polyline ``points``
    (M, 2) (all in texel units) and whose class is in ``replace_from`` to ``new_class``. With
    ``period`` > 0 only where (the arc length of the nearest point - ``offset``) mod ``period`` <
    ``dash_length``."""
    height, width = classes.shape
    s0 = 0.0
    for i in range(points.shape[0] - 1):
        ax, ay, bx, by = points[i, 0], points[i, 1], points[i + 1, 0], points[i + 1, 1]
        dx, dy = bx - ax, by - ay
        seg_sq = dx * dx + dy * dy
        seg_len = math.sqrt(seg_sq)
        c0, c1 = max(int(min(ax, bx) - half_width), 0), min(int(max(ax, bx) + half_width) + 1, width)
        r0, r1 = max(int(min(ay, by) - half_width), 0), min(int(max(ay, by) + half_width) + 1, height)
        for row in range(r0, r1):
            py = row + 0.5
            for col in range(c0, c1):
                if classes[row, col] not in replace_from:
                    continue
                px = col + 0.5
                t = 0.0 if seg_sq == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / seg_sq, 0.0), 1.0)
                ex, ey = px - (ax + t * dx), py - (ay + t * dy)
                if ex * ex + ey * ey >= half_width * half_width:
                    continue
                if period <= 0.0 or (s0 + t * seg_len - offset) % period < dash_length:
                    classes[row, col] = new_class
        s0 += seg_len


def _ring_edges(points: np.ndarray) -> np.ndarray:
    closed = points if np.array_equal(points[0], points[-1]) else np.vstack([points, points[:1]])
    return np.hstack([closed[:-1], closed[1:]])


def _class_band(centre, inner, outer, origin, step, width, height, params) -> np.ndarray:
    """(height, width) class map of square cells ``step`` m wide whose corner (0, 0) is at ``origin``."""
    to_cells = lambda points: np.ascontiguousarray((points - origin) / step)
    if np.allclose(centre[0], centre[-1]):
        edges = np.vstack([_ring_edges(to_cells(inner)), _ring_edges(to_cells(outer))])
    else:  # an open strip: one ring along the inner border and back along the outer one
        edges = _ring_edges(to_cells(np.vstack([inner, outer[::-1]])))
    classes = np.where(_fill_even_odd(edges, width, height) > 0, ROAD, FLOOR).astype(np.uint8)
    period, dash = (params.dash_length + params.dash_gap) / step, params.dash_length / step
    _stamp_polyline(classes, to_cells(centre), 0.5 * params.center_line_width / step, (ROAD,), CENTER, period, dash,
                    params.dash_offset / step)
    for border in (inner, outer):  # tape inside the road along each border, over the centre line
        _stamp_polyline(classes, to_cells(border), params.border_line_width / step, (ROAD, CENTER), BORDER, 0.0, 0.0,
                        0.0)
    return classes


def rasterise_track_coverage(track, params) -> tuple[np.ndarray, float, float]:
    """How much of each texel every class covers, and the room's origin (x0, y0), m.

    Returns coverage (height, width, 4) uint8: of the ``antialias**2`` sample points of each texel,
    how many fall on FLOOR, ROAD, BORDER and CENTER. Rasterised in bands of rows to bound memory.
    """
    centre, inner, outer = route_arrays(track)
    res, sub = params.texel_size, params.antialias
    everything = np.vstack([centre, inner, outer])
    low, high = everything.min(axis=0) - params.margin, everything.max(axis=0) + params.margin
    if params.room is not None:
        low, high = np.array(params.room[:2], dtype=np.float64), np.array(params.room[2:], dtype=np.float64)
        if (everything.min(axis=0) < low).any() or (everything.max(axis=0) > high).any():
            extent = f"{everything.min(axis=0).round(3).tolist()} .. {everything.max(axis=0).round(3).tolist()}"
            raise ValueError(f"texture: TextureParams.room {params.room} does not hold the track (its extent is "
                             f"{extent})")
    lo = np.floor(low / res + 1e-9) * res
    hi = np.ceil(high / res - 1e-9) * res
    width, height = int(round((hi[0] - lo[0]) / res)), int(round((hi[1] - lo[1]) / res))
    if width * height > 64_000_000:
        raise ValueError(f"texture: the room around the track is {width} x {height} texels at texel_size={res} m; "
                         f"that is too large, raise TextureParams.texel_size")
    coverage = np.zeros((height, width, 4), dtype=np.uint8)
    band = max(1, 4_000_000 // (width * sub * sub))
    for row0 in range(0, height, band):
        rows = min(band, height - row0)
        cells = _class_band(centre, inner, outer, lo + np.array([0.0, row0 * res]), res / sub, width * sub,
                            rows * sub, params)
        _count_cells(cells, sub, coverage[row0:row0 + rows])
    return coverage, float(lo[0]), float(lo[1])


@njit(cache=True)
def _count_cells(cells, sub, coverage):
    """coverage[r, c, k] += number of cells of class k in the sub x sub block of texel (r, c)."""
    for row in range(coverage.shape[0]):
        for col in range(coverage.shape[1]):
            for i in range(row * sub, row * sub + sub):
                for j in range(col * sub, col * sub + sub):
                    coverage[row, col, cells[i, j]] += 1
