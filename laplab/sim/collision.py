"""Collisions between cars and obstacles, and the STATE vector's summary of the nearest obstacles.

Footprints are rectangles on the ground: the car's body (``body_length`` x ``body_width``, its centre
``body_centre_offset`` ahead of the rear axle) and each obstacle's (x, y, yaw, half_length,
half_width) grown by its kind's collision margin (DeepRacer collides a box as 0.5 x 0.4 m, its 0.4 x
0.3 m box plus 0.05 m on every side; cars as their bodies). Two rectangles collide when they overlap
(separating-axis test; DeepRacer tests the car's four corners only, which misses an object's corner
entering the car's side).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from laplab.sim.kernel import PARALLEL_THRESHOLD
from laplab.sim.obstacles import EMPTY
from laplab.sim.state import CRASHED, IN_PROGRESS, OFF_TRACK

COLLISION_MARGIN = np.array([0.0, 0.05, 0.0, 0.0])  # m per kind (EMPTY, BOX, BOT_CAR, MODEL_CAR)
SUMMARY_COUNT = 3  # nearest obstacles in the STATE vector
SUMMARY_FEATURES = 4  # forward / range, left / range, present, speed / max speed
SUMMARY_RANGE = 5.0  # m: positions are divided by it


def summary_size(count: int = SUMMARY_COUNT) -> int:
    """Values the STATE vector gains for ``count`` nearest obstacles."""
    return SUMMARY_FEATURES * count


@nb.njit(cache=True, inline="always")
def _projected_radius(ux, uy, c, s, half_length, half_width):
    # half extent of a rectangle (axes (c, s) and (-s, c)) along the unit axis (ux, uy)
    return half_length * abs(ux * c + uy * s) + half_width * abs(-ux * s + uy * c)


@nb.njit(cache=True)
def rectangles_overlap(ax, ay, ayaw, a_hl, a_hw, bx, by, byaw, b_hl, b_hw):
    """Whether two oriented rectangles (centre m, yaw rad, half length along yaw, half width) overlap
    (touching counts as overlapping)."""
    ca, sa, cb, sb = math.cos(ayaw), math.sin(ayaw), math.cos(byaw), math.sin(byaw)
    dx, dy = bx - ax, by - ay
    for ux, uy in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        gap = abs(dx * ux + dy * uy)
        if gap > _projected_radius(ux, uy, ca, sa, a_hl, a_hw) + _projected_radius(ux, uy, cb, sb, b_hl, b_hw):
            return False
    return True


def crash_check(st, stepped, ox, oy, oyaw, ohl, ohw, okind, margin, body_offset, body_hl, body_hw, hit) -> None:
    """Mark stepped cars whose body overlaps an obstacle as ``crashed`` (unless their lap just
    completed); ``hit`` (N,) gets the slot hit, -1 for none. Parallel over cars for large batches."""
    n = st.x.shape[0]
    args = (st.x, st.y, st.yaw, st.status, stepped, ox, oy, oyaw, ohl, ohw, okind, margin, body_offset, body_hl,
            body_hw, hit)
    if n >= PARALLEL_THRESHOLD:
        _crash_parallel(8 * nb.get_num_threads(), n, *args)
    else:
        _crash_range(0, n, *args)


@nb.njit(cache=True, parallel=True)
def _crash_parallel(chunks, n, car_x, car_y, car_yaw, status, stepped, ox, oy, oyaw, ohl, ohw, okind, margin,
                    body_offset, body_hl, body_hw, hit):
    size = (n + chunks - 1) // chunks
    for c in nb.prange(chunks):
        _crash_range(min(c * size, n), min((c + 1) * size, n), car_x, car_y, car_yaw, status, stepped, ox, oy, oyaw,
                     ohl, ohw, okind, margin, body_offset, body_hl, body_hw, hit)


@nb.njit(cache=True)
def _crash_range(lo, hi, car_x, car_y, car_yaw, status, stepped, ox, oy, oyaw, ohl, ohw, okind, margin, body_offset,
                 body_hl, body_hw, hit):
    for i in range(lo, hi):
        hit[i] = -1
        if not stepped[i] or not (status[i] == IN_PROGRESS or status[i] == OFF_TRACK):
            continue
        c, s = math.cos(car_yaw[i]), math.sin(car_yaw[i])
        cx, cy = car_x[i] + body_offset * c, car_y[i] + body_offset * s
        car_reach = math.hypot(body_hl, body_hw)
        for k in range(ox.shape[1]):
            kind = okind[i, k]
            if kind == EMPTY:
                continue
            m = margin[kind]
            reach = car_reach + math.hypot(ohl[i, k] + m, ohw[i, k] + m)
            if (ox[i, k] - cx) ** 2 + (oy[i, k] - cy) ** 2 > reach * reach:  # the circles around both miss
                continue
            if rectangles_overlap(cx, cy, car_yaw[i], body_hl, body_hw, ox[i, k], oy[i, k], oyaw[i, k],
                                  ohl[i, k] + m, ohw[i, k] + m):
                status[i] = CRASHED
                hit[i] = k
                break


def write_summary(obs, first, cars, st, ox, oy, okind, ospeed, max_speed, count) -> None:
    """Fill ``obs[i, first:first + 4 * count]`` of the cars ``cars`` with their ``count`` nearest
    obstacles (from the reference point), nearest first: forward and left offsets in the car frame
    divided by SUMMARY_RANGE (clipped to +-1), 1 when present, speed / max_speed; empty slots are 0."""
    n = cars.shape[0]
    args = (obs, first, cars, st.yaw, st.ref_x, st.ref_y, ox, oy, okind, ospeed, max_speed, count)
    if n >= PARALLEL_THRESHOLD:
        _summary_parallel(8 * nb.get_num_threads(), n, *args)
    else:
        _summary_range(0, n, *args)


@nb.njit(cache=True, parallel=True)
def _summary_parallel(chunks, n, obs, first, cars, yaw, ref_x, ref_y, ox, oy, okind, ospeed, max_speed, count):
    size = (n + chunks - 1) // chunks
    for c in nb.prange(chunks):
        _summary_range(min(c * size, n), min((c + 1) * size, n), obs, first, cars, yaw, ref_x, ref_y, ox, oy, okind,
                       ospeed, max_speed, count)


@nb.njit(cache=True)
def _summary_range(lo, hi, obs, first, cars, yaw, ref_x, ref_y, ox, oy, okind, ospeed, max_speed, count):
    k_all = ox.shape[1]
    dist = np.empty(k_all)
    for n in range(lo, hi):
        i = cars[n]
        for j in range(first, first + SUMMARY_FEATURES * count):
            obs[i, j] = 0.0
        c, s = math.cos(yaw[i]), math.sin(yaw[i])
        for k in range(k_all):
            dist[k] = math.hypot(ox[i, k] - ref_x[i], oy[i, k] - ref_y[i]) if okind[i, k] != EMPTY else np.inf
        for rank in range(min(count, k_all)):
            k = 0  # the nearest not yet taken (K is small: a selection, no allocation)
            for j in range(1, k_all):
                if dist[j] < dist[k]:
                    k = j
            if dist[k] == np.inf:
                break
            dist[k] = np.inf
            px, py = ox[i, k] - ref_x[i], oy[i, k] - ref_y[i]
            base = first + SUMMARY_FEATURES * rank
            obs[i, base] = min(max((c * px + s * py) / SUMMARY_RANGE, -1.0), 1.0)
            obs[i, base + 1] = min(max((-s * px + c * py) / SUMMARY_RANGE, -1.0), 1.0)
            obs[i, base + 2] = 1.0
            obs[i, base + 3] = ospeed[i, k] / max_speed


@nb.njit(cache=True, parallel=True)
def _collide_and_summarise_parallel(chunks, n, car_x, car_y, car_yaw, status, stepped, ox, oy, oyaw, ohl, ohw, okind,
                                    margin, body_offset, body_hl, body_hw, hit, obs, first, cars, ref_x, ref_y, ospeed,
                                    max_speed, count):
    size = (n + chunks - 1) // chunks
    for c in nb.prange(chunks):
        lo, hi = min(c * size, n), min((c + 1) * size, n)
        _crash_range(lo, hi, car_x, car_y, car_yaw, status, stepped, ox, oy, oyaw, ohl, ohw, okind, margin,
                     body_offset, body_hl, body_hw, hit)
        if count > 0:
            _summary_range(lo, hi, obs, first, cars, car_yaw, ref_x, ref_y, ox, oy, okind, ospeed, max_speed, count)


def collide_and_summarise(st, stepped, ob, margin, body, hit, obs, first, ospeed, max_speed, count) -> None:
    """:func:`crash_check` of the stepped cars, then :func:`write_summary` of every car (``count`` 0: no
    summary), in one pass over the cars (one thread-pool launch for large batches)."""
    n = st.x.shape[0]
    if n < PARALLEL_THRESHOLD:
        crash_check(st, stepped, ob.x, ob.y, ob.yaw, ob.half_length, ob.half_width, ob.kind, margin, *body, hit)
        if count > 0:
            write_summary(obs, first, np.flatnonzero(stepped), st, ob.x, ob.y, ob.kind, ospeed, max_speed, count)
        return
    _collide_and_summarise_parallel(8 * nb.get_num_threads(), n, st.x, st.y, st.yaw, st.status, stepped, ob.x, ob.y,
                                    ob.yaw, ob.half_length, ob.half_width, ob.kind, margin, *body, hit, obs, first,
                                    np.arange(n), st.ref_x, st.ref_y, ospeed, max_speed, count)

