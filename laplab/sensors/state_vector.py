"""laplab's ``STATE`` sensor: a small float vector describing the car and the road ahead.

DeepRacer has no such sensor; laplab adds it so that policies can be trained in seconds without
rendering. Layout of one observation, float32, shape ``(7 + 2 * lookahead_count,)``:

====  ==========================================================================
0     measured speed / max_speed (0..1)
1     actual steering angle / max_steering (-1..1, positive = left)
2     signed offset of the reference point from the centre line / local half width
      (positive = left of centre; beyond +-1 means past a border)
3     distance from the reference point to the left border, m (negative = outside)
4     distance from the reference point to the right border, m (negative = outside)
5, 6  sin and cos of (car yaw - centre-line direction)
7...  ``lookahead_count`` centre-line points ahead at ``spacing`` m intervals of arc length,
      as (forward, left) coordinates in the car frame relative to the reference point,
      divided by ``lookahead_count * spacing``
====  ==========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb


@dataclass(frozen=True)
class StateSensorParams:
    """How far and how densely the STATE sensor looks ahead (count points, ``spacing`` m apart)."""

    lookahead_count: int = 10
    spacing: float = 0.3

    @property
    def size(self) -> int:
        return 7 + 2 * self.lookahead_count

    def __post_init__(self) -> None:
        if self.lookahead_count < 1 or not self.spacing > 0:
            raise ValueError("StateSensorParams needs lookahead_count >= 1 and spacing > 0")


@nb.njit(cache=True, inline="always")
def write_state_vector(out, speed, steer, ref_x, ref_y, yaw, segment, seg_t, arc, lateral,
                       centerline, arc_length, left_width, right_width, max_speed, max_steer,
                       lookahead_count, spacing):
    """Fill ``out`` (size 7 + 2 * lookahead_count) for one car; see the module docstring."""
    lw = left_width[segment] + seg_t * (left_width[segment + 1] - left_width[segment])
    rw = right_width[segment] + seg_t * (right_width[segment + 1] - right_width[segment])
    dx = centerline[segment + 1, 0] - centerline[segment, 0]
    dy = centerline[segment + 1, 1] - centerline[segment, 1]
    rel_yaw = yaw - math.atan2(dy, dx)
    out[0] = speed / max_speed
    out[1] = steer / max_steer
    out[2] = lateral / max(0.5 * (lw + rw), 1e-6)
    out[3] = lw - lateral
    out[4] = rw + lateral
    out[5] = math.sin(rel_yaw)
    out[6] = math.cos(rel_yaw)
    length = arc_length[-1]
    n_seg = centerline.shape[0] - 1
    c, s = math.cos(yaw), math.sin(yaw)
    scale = 1.0 / (lookahead_count * spacing)
    seg = segment
    for k in range(lookahead_count):
        target = arc + (k + 1) * spacing
        laps = math.floor(target / length)
        target -= laps * length
        # Walk forward from the last segment (targets increase, so this is amortised O(1)).
        steps = 0
        while not (arc_length[seg] <= target <= arc_length[seg + 1]) and steps <= n_seg:
            seg = (seg + 1) % n_seg
            steps += 1
        seg_len = arc_length[seg + 1] - arc_length[seg]
        u = (target - arc_length[seg]) / seg_len if seg_len > 0 else 0.0
        px = centerline[seg, 0] + u * (centerline[seg + 1, 0] - centerline[seg, 0]) - ref_x
        py = centerline[seg, 1] + u * (centerline[seg + 1, 1] - centerline[seg, 1]) - ref_y
        out[7 + 2 * k] = (c * px + s * py) * scale
        out[8 + 2 * k] = (-s * px + c * py) * scale
