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

from laplab.sim.obstacles import BOT_CAR, BOX, EMPTY, MODEL_CAR
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


@nb.njit(cache=True)
def crash_check(st, stepped, ox, oy, oyaw, ohl, ohw, okind, margin, body_offset, body_hl, body_hw, hit):
    """Mark stepped cars whose body overlaps an obstacle as ``crashed`` (unless their lap just
    completed); ``hit`` (N,) gets the slot hit, -1 for none. Returns the number of crashes."""
    crashes = 0
    for i in range(st.x.shape[0]):
        hit[i] = -1
        if not stepped[i] or not (st.status[i] == IN_PROGRESS or st.status[i] == OFF_TRACK):
            continue
        c, s = math.cos(st.yaw[i]), math.sin(st.yaw[i])
        cx, cy = st.x[i] + body_offset * c, st.y[i] + body_offset * s
        for k in range(ox.shape[1]):
            kind = okind[i, k]
            if kind == EMPTY:
                continue
            m = margin[kind]
            if rectangles_overlap(cx, cy, st.yaw[i], body_hl, body_hw, ox[i, k], oy[i, k], oyaw[i, k],
                                  ohl[i, k] + m, ohw[i, k] + m):
                st.status[i] = CRASHED
                hit[i] = k
                crashes += 1
                break
    return crashes


@nb.njit(cache=True)
def write_summary(obs, first, cars, st, ox, oy, okind, ospeed, max_speed, count):
    """Fill ``obs[i, first:first + 4 * count]`` of the cars ``cars`` with their ``count`` nearest
    obstacles (from the reference point), nearest first: forward and left offsets in the car frame
    divided by SUMMARY_RANGE (clipped to +-1), 1 when present, speed / max_speed; empty slots are 0."""
    k_all = ox.shape[1]
    dist = np.empty(k_all)
    for n in range(cars.shape[0]):
        i = cars[n]
        for j in range(first, first + SUMMARY_FEATURES * count):
            obs[i, j] = 0.0
        c, s = math.cos(st.yaw[i]), math.sin(st.yaw[i])
        for k in range(k_all):
            dist[k] = math.hypot(ox[i, k] - st.ref_x[i], oy[i, k] - st.ref_y[i]) if okind[i, k] != EMPTY else np.inf
        order = np.argsort(dist)
        for rank in range(min(count, k_all)):
            k = order[rank]
            if okind[i, k] == EMPTY:
                break
            px, py = ox[i, k] - st.ref_x[i], oy[i, k] - st.ref_y[i]
            base = first + SUMMARY_FEATURES * rank
            obs[i, base] = min(max((c * px + s * py) / SUMMARY_RANGE, -1.0), 1.0)
            obs[i, base + 1] = min(max((-s * px + c * py) / SUMMARY_RANGE, -1.0), 1.0)
            obs[i, base + 2] = 1.0
            obs[i, base + 3] = ospeed[i, k] / max_speed


KIND_CODES = {"box": BOX, "bot_car": BOT_CAR, "model_car": MODEL_CAR}
