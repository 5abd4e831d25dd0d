"""The fused per-step kernel: dynamics, projection, progress, wheels on track, termination, STATE.

One call advances every car by one 15 Hz decision. Cars whose status is not ``in_progress`` are left
untouched (the caller resets them). Two compiled loops share one body: a serial one for small batches
(no thread-pool start-up, the N = 1 latency) and a parallel one for large batches.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from laplab.sensors.state_vector import write_state_vector
from laplab.sim.state import (IMMOBILIZED, IN_PROGRESS, LAP_COMPLETE, OFF_TRACK, REVERSED, TIME_UP)
from laplab.track.projection import point_on_road_near, project_point
from laplab.vehicle.dynamics import advance_car

PARALLEL_THRESHOLD = 256  # cars: below it the serial loop wins (1.8 us a car vs a thread-pool start, which stalls on busy cores)


@nb.njit(cache=True, inline="always")
def _step_car(i, st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing):
    dc = vc[:19]  # dynamics_constants(); then dt, reference offset, half track, max speed, max steering
    dt, ref_offset, half_track, max_speed, max_steer = vc[19], vc[20], vc[21], vc[22], vc[23]
    wheelbase = dc[0]
    max_steps, reversed_steps, immobilized_steps, immobilized_distance = rules
    geo = fwd if st.direction[i] == 0 else rev
    centerline, segments, arc_length = geo.centerline, geo.segments, geo.arc_length
    left_w, right_w = geo.left_width, geo.right_width
    length, far_gap, window = geo.length, geo.far_gap, geo.window

    x0, y0 = st.x[i], st.y[i]
    x, y, yaw, speed, steer = advance_car(x0, y0, st.yaw[i], st.speed[i], st.steer[i], st.cmd_steer[i],
                                          st.cmd_speed[i], cmd_steer[i], cmd_speed[i], dt, dc)
    st.x[i], st.y[i], st.yaw[i], st.speed[i], st.steer[i] = x, y, yaw, speed, steer
    st.cmd_steer[i], st.cmd_speed[i] = cmd_steer[i], cmd_speed[i]
    c, s = math.cos(yaw), math.sin(yaw)
    rx, ry = x + ref_offset * c, y + ref_offset * s
    seg, t, arc, lateral, distance = project_point(rx, ry, segments, arc_length, far_gap, window, st.segment[i])
    st.ref_x[i], st.ref_y[i] = rx, ry
    st.segment[i], st.seg_t[i], st.lateral[i] = seg, t, lateral

    # Progress: unwrap the arc-length change across the finish line.
    delta = arc - st.arc[i]
    if delta > 0.5 * length:
        delta -= length
    elif delta < -0.5 * length:
        delta += length
    st.arc[i] = arc
    st.travel[i] += delta
    # DeepRacer's progress has no floor: backing over the start line gives negative values.
    progress = min(100.0 * st.travel[i] / length, 100.0)
    st.progress[i] = progress
    st.steps[i] += 1

    # Every wheel lies within wheel_reach of the reference point, which lies ``distance`` from its
    # projection on segment ``seg``; when that sum is under the segment's clearance all four are on
    # the road and the border tests are skipped (most steps of most cars).
    wheel_reach = math.hypot(max(abs(wheelbase - ref_offset), abs(ref_offset)), half_track)
    if distance + wheel_reach < geo.clearance[seg] - 1e-6:
        wheels = 4
    else:
        wheels = 0
        for fx, fy in ((wheelbase, half_track), (wheelbase, -half_track), (0.0, half_track), (0.0, -half_track)):
            wx, wy = x + c * fx - s * fy, y + s * fx + c * fy
            if point_on_road_near(wx, wy, geo, seg):
                wheels += 1
    st.wheels_on[i] = wheels

    st.reverse_count[i] = st.reverse_count[i] + 1 if delta < -1e-9 else 0
    moved = math.hypot(x - x0, y - y0)
    st.immobile_count[i] = st.immobile_count[i] + 1 if moved <= immobilized_distance else 0

    status = IN_PROGRESS
    if st.travel[i] >= length:
        status = LAP_COMPLETE
        # Sim time at which progress crossed 100 %, interpolated within the last step.
        frac = (length - (st.travel[i] - delta)) / delta if delta > 0 else 1.0
        st.lap_time[i] = (st.steps[i] - 1 + min(max(frac, 0.0), 1.0)) * dt
    elif wheels == 0:
        status = OFF_TRACK
    elif st.reverse_count[i] >= reversed_steps:
        status = REVERSED
    elif st.immobile_count[i] >= immobilized_steps:
        status = IMMOBILIZED
    elif st.steps[i] >= max_steps:
        status = TIME_UP
    st.status[i] = status

    if obs.shape[1] > 0:
        write_state_vector(obs[i], speed, steer, rx, ry, yaw, seg, t, arc, lateral, centerline,
                           arc_length, left_w, right_w, max_speed, max_steer, look_count, look_spacing)


@nb.njit(cache=True)
def _step_range(lo, hi, st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing):
    for i in range(lo, hi):
        if st.status[i] == IN_PROGRESS:
            _step_car(i, st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing)


@nb.njit(cache=True, parallel=True)
def _step_parallel(chunks, st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing):
    # One non-inlined call per chunk: numba parfors drop writes made through NamedTuple arrays
    # inside an inlined prange body (numba#5872), and the chunk loop keeps the per-car body inlined.
    n = st.x.shape[0]
    size = (n + chunks - 1) // chunks
    for c in nb.prange(chunks):
        _step_range(min(c * size, n), min((c + 1) * size, n), st, cmd_steer, cmd_speed, fwd, rev, vc, rules,
                    obs, look_count, look_spacing)


def step_kernel(st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing) -> None:
    """Advance every in-progress car in ``st`` in place; fills ``obs`` rows (N, D) for them."""
    n = st.x.shape[0]
    if n >= PARALLEL_THRESHOLD:
        _step_parallel(8 * nb.get_num_threads(), st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing)
    else:
        _step_range(0, n, st, cmd_steer, cmd_speed, fwd, rev, vc, rules, obs, look_count, look_spacing)


@nb.njit(cache=True, inline="always")
def _observe_car(i, st, geo, vc, obs, look_count, look_spacing):
    """Write car ``i``'s STATE row ``obs[i]`` from its state in ``st`` on ``geo`` (its direction's arrays)."""
    write_state_vector(obs[i], st.speed[i], st.steer[i], st.ref_x[i], st.ref_y[i], st.yaw[i], st.segment[i],
                       st.seg_t[i], st.arc[i], st.lateral[i], geo.centerline, geo.arc_length, geo.left_width,
                       geo.right_width, vc[22], vc[23], look_count, look_spacing)


@nb.njit(cache=True)
def place_kernel(st, cars, start_arc, geo, vc, obs, look_count, look_spacing):
    """Start new episodes for ``cars`` (K,) all driving ``geo``'s direction: each at rest with its
    origin on the centre line at ``start_arc`` (K,) m, facing along it, its reference point projected,
    and its STATE row written. As in DeepRacer, the lap counts from the origin's own centre-line point
    (``start_ndist``), so the reference point starts ``reference_offset`` along it; progress stays 0
    until the first step computes it, as simapp's ``current_progress`` does after a reset."""
    centerline, arc_length, length = geo.centerline, geo.arc_length, geo.length
    ref_offset = vc[20]
    last = centerline.shape[0] - 2
    for k in range(cars.shape[0]):
        i, s0 = cars[k], start_arc[k]
        s = s0 % length
        x = np.interp(s, arc_length, centerline[:, 0])
        y = np.interp(s, arc_length, centerline[:, 1])
        seg = min(max(np.searchsorted(arc_length, s, side="right") - 1, 0), last)
        yaw = math.atan2(centerline[seg + 1, 1] - centerline[seg, 1], centerline[seg + 1, 0] - centerline[seg, 0])
        st.x[i], st.y[i], st.yaw[i] = x, y, yaw
        st.speed[i] = st.steer[i] = st.cmd_steer[i] = st.cmd_speed[i] = 0.0
        st.progress[i] = st.lap_time[i] = 0.0
        st.steps[i] = st.reverse_count[i] = st.immobile_count[i] = 0
        c, sn = math.cos(yaw), math.sin(yaw)
        rx, ry = x + ref_offset * c, y + ref_offset * sn
        seg, _, arc, lateral, _ = project_point(rx, ry, geo.segments, arc_length, geo.far_gap, geo.window, seg)
        start = arc_length[seg]
        unwrapped = arc + length if arc < start else arc
        seg_t = min(max((unwrapped - start) / max(arc_length[seg + 1] - start, 1e-12), 0.0), 1.0)
        st.ref_x[i], st.ref_y[i], st.arc[i], st.segment[i], st.lateral[i], st.seg_t[i] = rx, ry, arc, seg, lateral, seg_t
        st.start_arc[i] = s0
        st.travel[i] = (arc - s0 + 0.5 * length) % length - 0.5 * length
        st.wheels_on[i] = 4
        st.status[i] = IN_PROGRESS
        if obs.shape[1] > 0:
            _observe_car(i, st, geo, vc, obs, look_count, look_spacing)


@nb.njit(cache=True)
def observe_kernel(st, fwd, rev, vc, obs, look_count, look_spacing, mask):
    """Fill ``obs`` rows of the cars in ``mask`` from their current state (after a reset)."""
    for i in range(st.x.shape[0]):
        if mask[i] and obs.shape[1] > 0:
            _observe_car(i, st, fwd if st.direction[i] == 0 else rev, vc, obs, look_count, look_spacing)


def empty_obs(num_cars: int, size: int) -> np.ndarray:
    return np.zeros((num_cars, size), dtype=np.float32)
