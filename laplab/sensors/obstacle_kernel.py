"""Numba kernels that let the camera and the lidar see obstacles: vertical boxes standing on the ground.

An obstacle is a prism: a rectangle (centre, heading, half length, half width) from the ground up to
its height. A horizontal ray p + t*d (|d| = 1, t in metres along the ground) meets the rectangle on
[t_enter, t_exit] (the 2-D slab test in the box's own frame); the face it enters by is the side whose
slab gave t_enter. Rays that start inside a box do not see it (Gazebo draws no back faces).

Camera: a second pass after :func:`laplab.sensors.camera_kernel.render_kernel`, only over the pixels
inside each obstacle's projected bounding rectangle. A sample whose ray rises ``slope`` metres per
metre from the camera's height ``cam_h`` hits a side if 0 <= z(t_enter) <= height (z < 0: the ground
came first), else the top where z = height if that lies before t_exit; the nearest hit nearer than the
room's walls paints the face's flat colour. A pixel's k x k samples average; samples that miss keep
the pixel's ground / wall value. Lidar: the nearest entry face of the boxes taller than the beam plane.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

FAR = 1e30  # "no hit" distance (finite: no infinities in the arithmetic)
_jit = njit(cache=True, error_model="numpy")


@_jit
def slab_hit(px, py, lx, ly, half_length, half_width):
    """(t_enter, t_exit, face) of the ray (px, py) + t (lx, ly) against the rectangle |x| <= half_length,
    |y| <= half_width (the box's frame); face 0 front (+x), 1 back, 2 left (+y), 3 right; t_enter > t_exit
    when it misses."""
    if abs(lx) < 1e-12:
        if abs(px) > half_length:
            return FAR, -FAR, -1
        tx0, tx1 = -FAR, FAR
    else:
        a, b = (-half_length - px) / lx, (half_length - px) / lx
        tx0, tx1 = min(a, b), max(a, b)
    if abs(ly) < 1e-12:
        if abs(py) > half_width:
            return FAR, -FAR, -1
        ty0, ty1 = -FAR, FAR
    else:
        a, b = (-half_width - py) / ly, (half_width - py) / ly
        ty0, ty1 = min(a, b), max(a, b)
    if tx0 > ty0:
        return tx0, min(tx1, ty1), (0 if lx < 0 else 1)
    return ty0, min(tx1, ty1), (2 if ly < 0 else 3)


@_jit
def _wall_distance(wx, wy, cx, cy, geom_room):
    """Horizontal distance from (cx, cy) along the world direction (wx, wy) to the room's walls."""
    x_lo, y_lo, x_hi, y_hi = geom_room[0], geom_room[1], geom_room[2], geom_room[3]
    gap_x = x_hi - cx if wx > 0 else cx - x_lo
    gap_y = y_hi - cy if wy > 0 else cy - y_lo
    return min(gap_x / (abs(wx) + 1e-12), gap_y / (abs(wy) + 1e-12))


@_jit
def _project_rect(ox, oy, cr, sr, half_length, half_width, height, cam_h, cp, sp, focal, width, height_px):
    """(row0, row1, col0, col1) pixel rectangle (end exclusive, clipped to the image) holding the box
    whose centre is (ox, oy) from the camera in the car frame, heading (cr, sr); empty when out of view."""
    u_lo, u_hi, v_lo, v_hi = 1e30, -1e30, 1e30, -1e30
    behind = 0
    for corner in range(8):
        ex = half_length if corner & 1 else -half_length
        ey = half_width if corner & 2 else -half_width
        z = (height if corner & 4 else 0.0) - cam_h
        x, y = ox + cr * ex - sr * ey, oy + sr * ex + cr * ey
        depth = cp * x - sp * z
        if depth <= 1e-3:
            behind += 1
            continue
        up = (sp * x + cp * z) / depth
        u, v = 0.5 * width - focal * y / depth, 0.5 * height_px - focal * up
        u_lo, u_hi, v_lo, v_hi = min(u_lo, u), max(u_hi, u), min(v_lo, v), max(v_hi, v)
    if behind == 8:
        return 0, 0, 0, 0
    if behind > 0:  # straddles the camera's plane: test the whole image
        return 0, height_px, 0, width
    row0, row1 = max(int(math.floor(v_lo)) - 1, 0), min(int(math.ceil(v_hi)) + 1, height_px)
    col0, col1 = max(int(math.floor(u_lo)) - 1, 0), min(int(math.ceil(u_hi)) + 1, width)
    if row0 >= row1 or col0 >= col1:
        return 0, 0, 0, 0
    return row0, row1, col0, col1


@njit(parallel=True, cache=True, error_model="numpy")
def obstacle_pass(boxes, kind, values, poses, camera, room, hx, hy, slope, k, out):
    """Paint obstacles over already rendered frames ``out`` (N, H, W) uint8 (may be a channel view).

    boxes (N, K, 6) [x, y, yaw, half_length, half_width, height]; kind (N, K) (0 = empty); values
    (N, K, 5) uint8 face colours (front, back, left, right, top) in out's plane; camera float64
    [mount_forward, mount_lateral, mount_up, cos(pitch), sin(pitch), focal]; room [x_lo, y_lo, x_hi,
    y_hi]; hx, hy, slope the per-sample tables of CameraRays; k the supersampling.
    """
    n_cars, height_px, width = out.shape
    n_slots = kind.shape[1]
    k2 = k * k
    cam_h, cp, sp, focal = camera[2], camera[3], camera[4], camera[5]
    for n in prange(n_cars):
        c, s = math.cos(poses[n, 2]), math.sin(poses[n, 2])
        cx = poses[n, 0] + c * camera[0] - s * camera[1]
        cy = poses[n, 1] + s * camera[0] + c * camera[1]
        # Per visible obstacle: ray origin in its frame (px, py), its heading relative to the car
        # (cr, sr), half sizes, height, pixel rectangle and slot.
        local = np.empty((n_slots, 7))
        rect = np.empty((n_slots, 4), dtype=np.int64)
        slot = np.empty(n_slots, dtype=np.int64)
        count = 0
        row_lo, row_hi, col_lo, col_hi = height_px, 0, width, 0
        for q in range(n_slots):
            if kind[n, q] == 0:
                continue
            wx, wy = boxes[n, q, 0] - cx, boxes[n, q, 1] - cy
            ox, oy = c * wx + s * wy, -s * wx + c * wy
            rel = boxes[n, q, 2] - poses[n, 2]
            cr, sr = math.cos(rel), math.sin(rel)
            hl, hw, h = boxes[n, q, 3], boxes[n, q, 4], boxes[n, q, 5]
            r0, r1, c0, c1 = _project_rect(ox, oy, cr, sr, hl, hw, h, cam_h, cp, sp, focal, width, height_px)
            if r0 >= r1:
                continue
            local[count, 0], local[count, 1] = -(cr * ox + sr * oy), -(-sr * ox + cr * oy)
            local[count, 2], local[count, 3] = cr, sr
            local[count, 4], local[count, 5], local[count, 6] = hl, hw, h
            rect[count, 0], rect[count, 1], rect[count, 2], rect[count, 3] = r0, r1, c0, c1
            slot[count] = q
            count += 1
            row_lo, row_hi, col_lo, col_hi = min(row_lo, r0), max(row_hi, r1), min(col_lo, c0), max(col_hi, c1)
        for r in range(row_lo, row_hi):
            for col in range(col_lo, col_hi):
                total, hits = 0, 0
                for sample in range(k2):
                    j = (r * width + col) * k2 + sample
                    dx, dy, dz = np.float64(hx[j]), np.float64(hy[j]), np.float64(slope[j])
                    best, best_value = FAR, -1
                    for i in range(count):
                        if r < rect[i, 0] or r >= rect[i, 1] or col < rect[i, 2] or col >= rect[i, 3]:
                            continue
                        cr, sr = local[i, 2], local[i, 3]
                        t0, t1, face = slab_hit(local[i, 0], local[i, 1], cr * dx + sr * dy, -sr * dx + cr * dy,
                                                local[i, 4], local[i, 5])
                        if t0 < 0.0 or t0 > t1 or t0 >= best:
                            continue
                        z = cam_h + dz * t0
                        if z < 0.0:
                            continue
                        if z > local[i, 6]:  # above the box where the ray enters its footprint: the top?
                            if dz >= 0.0:
                                continue
                            t0, face = (local[i, 6] - cam_h) / dz, 4
                            if t0 > t1 or t0 >= best:
                                continue
                        best, best_value = t0, np.int64(values[n, slot[i], face])
                    if best_value >= 0 and best < _wall_distance(c * dx - s * dy, s * dx + c * dy, cx, cy, room):
                        total += best_value
                        hits += 1
                if hits > 0:
                    total += (k2 - hits) * np.int64(out[n, r, col])
                    out[n, r, col] = np.uint8((total + k2 // 2) // k2)


@njit(cache=True, error_model="numpy")
def obstacle_ranges(boxes, kind, poses, angles, mount_x, mount_y, mount_z, t_min, out):
    """Lower ``out`` (N, B) float32 lidar ranges to the nearest obstacle entry face at or beyond
    ``t_min`` along each beam; only boxes taller than the beam plane ``mount_z`` (m) are seen."""
    for n in range(out.shape[0]):
        c, s = math.cos(poses[n, 2]), math.sin(poses[n, 2])
        px, py = poses[n, 0] + c * mount_x - s * mount_y, poses[n, 1] + s * mount_x + c * mount_y
        for q in range(kind.shape[1]):
            if kind[n, q] == 0 or boxes[n, q, 5] <= mount_z:
                continue
            cq, sq = math.cos(boxes[n, q, 2]), math.sin(boxes[n, q, 2])
            wx, wy = px - boxes[n, q, 0], py - boxes[n, q, 1]
            lx, ly = cq * wx + sq * wy, -sq * wx + cq * wy
            for b in range(out.shape[1]):
                a = poses[n, 2] + angles[b]
                dx, dy = math.cos(a), math.sin(a)
                t0, t1, _ = slab_hit(lx, ly, cq * dx + sq * dy, -sq * dx + cq * dy, boxes[n, q, 3], boxes[n, q, 4])
                if t_min <= t0 <= t1 and t0 < out[n, b]:
                    out[n, b] = t0
