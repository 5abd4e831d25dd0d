"""Numba kernels that let the camera and the lidar see obstacles: vertical boxes standing on the ground.

An obstacle is a prism: a rectangle (centre, heading, half length, half width) from the ground up to
its height. A horizontal ray p + t*d (|d| = 1, t in metres along the ground) meets the rectangle on
[t_enter, t_exit] (the 2-D slab test in the box's own frame); the face it enters by is the side whose
slab gave t_enter. Rays that start inside a box do not see it (Gazebo draws no back faces).

Camera: a second pass after :func:`laplab.sensors.camera_kernel.render_kernel`, only over the samples
within each obstacle's projected silhouette (per image row, one stretch of columns). A sample whose
ray rises ``slope`` metres per metre from the camera's height ``cam_h`` hits a side if
0 <= z(t_enter) <= height (z < 0: the ground came first), else the top where z = height if that
lies before t_exit; the nearest hit nearer than the room's walls paints the face's flat colour. A
pixel's k x k samples average; samples that miss keep the pixel's ground / wall value.

Lidar: the nearest entry face along each beam.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

FAR = 1e30  # "no hit" distance (finite: no infinities in the arithmetic)
NO_HIT = -1  # a sample's value where no obstacle is hit
WALL_CHECK = 256  # added to a hit's colour when a wall may stand between the camera and the box
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
        inv = 1.0 / lx
        a, b = (-half_length - px) * inv, (half_length - px) * inv
        tx0, tx1 = min(a, b), max(a, b)
    if abs(ly) < 1e-12:
        if abs(py) > half_width:
            return FAR, -FAR, -1
        ty0, ty1 = -FAR, FAR
    else:
        inv = 1.0 / ly
        a, b = (-half_width - py) * inv, (half_width - py) * inv
        ty0, ty1 = min(a, b), max(a, b)
    if tx0 > ty0:
        return tx0, min(tx1, ty1), (0 if lx < 0 else 1)
    return ty0, min(tx1, ty1), (2 if ly < 0 else 3)


@_jit
def _wall_distance(wx, wy, cx, cy, room):
    """Horizontal distance from (cx, cy) along the world direction (wx, wy) to the room's walls."""
    gap_x = room[2] - cx if wx > 0 else cx - room[0]
    gap_y = room[3] - cy if wy > 0 else cy - room[1]
    return min(gap_x / (abs(wx) + 1e-12), gap_y / (abs(wy) + 1e-12))


@_jit
def _project_corners(ox, oy, cr, sr, half_length, half_width, height, cam_h, cp, sp, focal, width, height_px,
                     corners):
    """Image points (u, v) of the box's 8 corners into corners (8, 2); returns 0, or a positive count
    when a corner lies behind the camera (then corners is not all filled). The box's centre is (ox, oy)
    from the camera in the car frame, its heading (cr, sr)."""
    for corner in range(8):
        ex = half_length if corner & 1 else -half_length
        ey = half_width if corner & 2 else -half_width
        z = (height if corner & 4 else 0.0) - cam_h
        x, y = ox + cr * ex - sr * ey, oy + sr * ex + cr * ey
        depth = cp * x - sp * z
        if depth <= 1e-3:
            return 8 - corner
        corners[corner, 0] = 0.5 * width - focal * y / depth
        corners[corner, 1] = 0.5 * height_px - focal * (sp * x + cp * z) / depth
    return 0


@_jit
def _silhouette_spans(corners, behind, width, spans):
    """Per image row, the columns [spans[r, 0], spans[r, 1]) that may see the box: the row's stretch
    of its silhouette (the convex hull of the projected corners, whose outline is made of projected box
    edges: over the row's band r <= v <= r + 1 the stretch runs from the leftmost to the rightmost
    point of the edges' parts within the band), one pixel wider on each side; every column of every
    row when a corner lies behind the camera.
    Returns the rows (first, end) that hold any, (0, 0) for none; rows outside are left untouched."""
    height_px = spans.shape[0]
    if behind > 0:
        spans[:, 0], spans[:, 1] = 0, width
        return 0, height_px
    v_lo, v_hi = corners[:, 1].min(), corners[:, 1].max()
    row0, row1 = max(int(math.floor(v_lo)) - 1, 0), min(int(math.ceil(v_hi)) + 1, height_px)
    first, end = height_px, 0
    for r in range(row0, row1):
        lo, hi = 1e30, -1e30
        for a in range(8):
            for bit in (1, 2, 4):  # the box's 12 edges join corners that differ in one bit
                if a & bit:
                    continue
                b = a | bit
                va, vb = corners[a, 1], corners[b, 1]
                # The part of the edge within the row's band r <= v <= r + 1 (where its samples lie).
                if abs(vb - va) < 1e-9:
                    w0, w1 = (0.0, 1.0) if r - 1e-6 <= va <= r + 1 + 1e-6 else (1.0, 0.0)
                else:
                    w0, w1 = (r - va) / (vb - va), (r + 1 - va) / (vb - va)
                    w0, w1 = max(min(w0, w1), 0.0), min(max(w0, w1), 1.0)
                if w0 <= w1:
                    ua, ub = corners[a, 0] + w0 * (corners[b, 0] - corners[a, 0]), \
                        corners[a, 0] + w1 * (corners[b, 0] - corners[a, 0])
                    lo, hi = min(lo, ua, ub), max(hi, ua, ub)
        c0, c1 = max(int(math.floor(lo)) - 1, 0), min(int(math.ceil(hi)) + 1, width)
        if lo > hi or c0 >= c1:
            spans[r, 0], spans[r, 1] = 0, 0
            continue
        spans[r, 0], spans[r, 1] = c0, c1
        first, end = min(first, r), r + 1
    return (first, end) if first < end else (0, 0)


@njit(cache=True, fastmath=True, error_model="numpy")
def _box_row(hx, hy, slope, px, py, cr, sr, half_length, half_width, height, cam_h, front, back, left, right,
             top_colour, depth, value):
    """One obstacle against a run of samples (one image row's columns): where its ray hits the box
    nearer than ``depth``, set depth and value (the colour of the face it enters: front ... top_colour).
    Branch-free and gather-free so that LLVM vectorises it (a function of its own, as camera_kernel's
    row loops); no infinities, for fastmath.

    (px, py): the camera in the box's frame; (cr, sr): the box's heading relative to the car.
    """
    tiny = 1e-12
    for j in range(depth.shape[0]):
        dx, dy, dz = np.float64(hx[j]), np.float64(hy[j]), np.float64(slope[j])
        lx, ly = cr * dx + sr * dy, -sr * dx + cr * dy
        lx = lx if abs(lx) > tiny else tiny
        ly = ly if abs(ly) > tiny else tiny
        ix, iy = 1.0 / lx, 1.0 / ly
        a, b = (-half_length - px) * ix, (half_length - px) * ix
        tx0, tx1 = min(a, b), max(a, b)
        a, b = (-half_width - py) * iy, (half_width - py) * iy
        ty0, ty1 = min(a, b), max(a, b)
        t0, t1 = max(tx0, ty0), min(tx1, ty1)
        z = cam_h + dz * t0
        t_top = (height - cam_h) / min(dz, -tiny)
        top = (z > height) & (dz < 0.0) & (t_top <= t1)
        side = (z >= 0.0) & (z <= height)
        t = t_top if top else t0
        hit = (t0 >= 0.0) & (t0 <= t1) & (side | top) & (t < depth[j])
        x_face = front if lx < 0.0 else back
        y_face = left if ly < 0.0 else right
        colour = top_colour if top else (x_face if tx0 > ty0 else y_face)
        depth[j] = t if hit else depth[j]
        value[j] = colour if hit else value[j]


@njit(cache=True, error_model="numpy")
def _paint_row(value, out_row):
    """out_row[q] = value[q] where a box was hit (value >= 0, a colour below 256)."""
    for q in range(value.shape[0]):
        out_row[q] = np.uint8(value[q]) if value[q] >= 0 else out_row[q]


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
        camera_in_room = room[0] < cx < room[2] and room[1] < cy < room[3]
        # Per visible obstacle: ray origin in its frame (px, py), its heading relative to the car
        # (cr, sr), half sizes, height, whether a wall may hide it, its rows' column spans and slot.
        local = np.empty((n_slots, 8))
        spans = np.zeros((n_slots, height_px, 2), dtype=np.int64)
        slot = np.empty(n_slots, dtype=np.int64)
        corners = np.empty((8, 2))
        count = 0
        walls_matter = False
        row_lo, row_hi = height_px, 0
        for q in range(n_slots):
            if kind[n, q] == 0:
                continue
            bx, by, byaw, hl, hw, h = boxes[n, q, 0], boxes[n, q, 1], boxes[n, q, 2], boxes[n, q, 3], \
                boxes[n, q, 4], boxes[n, q, 5]
            wx, wy = bx - cx, by - cy
            ox, oy = c * wx + s * wy, -s * wx + c * wy
            rel = byaw - poses[n, 2]
            cr, sr = math.cos(rel), math.sin(rel)
            behind = _project_corners(ox, oy, cr, sr, hl, hw, h, cam_h, cp, sp, focal, width, height_px, corners)
            r0, r1 = _silhouette_spans(corners, behind, width, spans[count])
            if r0 >= r1:
                continue
            reach_x = abs(hl * math.cos(byaw)) + abs(hw * math.sin(byaw))  # the footprint's half extents
            reach_y = abs(hl * math.sin(byaw)) + abs(hw * math.cos(byaw))
            inside = (room[0] < bx - reach_x) and (bx + reach_x < room[2]) and (room[1] < by - reach_y) \
                and (by + reach_y < room[3])
            local[count, 0], local[count, 1] = -(cr * ox + sr * oy), -(-sr * ox + cr * oy)
            local[count, 2], local[count, 3] = cr, sr
            local[count, 4], local[count, 5], local[count, 6] = hl, hw, h
            local[count, 7] = 0.0 if (inside and camera_in_room) else 1.0
            walls_matter = walls_matter or local[count, 7] > 0.0
            slot[count] = q
            count += 1
            row_lo, row_hi = min(row_lo, r0), max(row_hi, r1)
        depth = np.empty(width * k2)
        value = np.empty(width * k2, dtype=np.int32)
        colours = np.empty(5, dtype=np.int32)
        for r in range(row_lo, row_hi):
            col_lo, col_hi = width, 0
            for i in range(count):
                if spans[i, r, 0] < spans[i, r, 1]:
                    col_lo, col_hi = min(col_lo, spans[i, r, 0]), max(col_hi, spans[i, r, 1])
            if col_lo >= col_hi:
                continue
            depth[:] = FAR
            value[:] = NO_HIT
            first = r * width * k2
            for i in range(count):
                c0, c1 = spans[i, r, 0], spans[i, r, 1]
                if c0 >= c1:
                    continue
                for face in range(5):  # a colour below 256; + WALL_CHECK when a wall may hide the box
                    colours[face] = np.int32(values[n, slot[i], face]) + (WALL_CHECK if local[i, 7] > 0 else 0)
                lo, hi = first + c0 * k2, first + c1 * k2
                _box_row(hx[lo:hi], hy[lo:hi], slope[lo:hi], local[i, 0], local[i, 1], local[i, 2], local[i, 3],
                         local[i, 4], local[i, 5], local[i, 6], cam_h, colours[0], colours[1], colours[2], colours[3],
                         colours[4],
                         depth[(c0 - col_lo) * k2:(c1 - col_lo) * k2], value[(c0 - col_lo) * k2:(c1 - col_lo) * k2])
            if k2 == 1 and not walls_matter:  # one sample per pixel: the hit's colour, or the pixel as it was
                _paint_row(value[:col_hi - col_lo], out[n, r, col_lo:col_hi])
                continue
            for col in range(col_lo, col_hi):
                total, hits = 0, 0
                for sample in range(k2):
                    q = (col - col_lo) * k2 + sample
                    hit = value[q]
                    if hit == NO_HIT:
                        continue
                    if hit >= WALL_CHECK:
                        j = first + col * k2 + sample
                        dx, dy = np.float64(hx[j]), np.float64(hy[j])
                        if depth[q] >= _wall_distance(c * dx - s * dy, s * dx + c * dy, cx, cy, room):
                            continue
                        hit -= WALL_CHECK
                    total += hit
                    hits += 1
                if hits > 0:
                    total += (k2 - hits) * np.int64(out[n, r, col])
                    out[n, r, col] = np.uint8((total + k2 // 2) // k2)


@njit(cache=True, error_model="numpy")
def obstacle_ranges(boxes, kind, poses, angles, mount_x, mount_y, t_min, out):
    """Lower ``out`` (N, B) float32 lidar ranges to the nearest obstacle entry face at or beyond
    ``t_min`` along each beam (every obstacle reaches the beam plane)."""
    for n in range(out.shape[0]):
        c, s = math.cos(poses[n, 2]), math.sin(poses[n, 2])
        px, py = poses[n, 0] + c * mount_x - s * mount_y, poses[n, 1] + s * mount_x + c * mount_y
        for q in range(kind.shape[1]):
            if kind[n, q] == 0:
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
