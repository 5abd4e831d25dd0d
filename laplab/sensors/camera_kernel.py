"""The camera's numba kernel: every sample of every frame of a batch, one texel read each.

Arguments are prepared by :mod:`laplab.sensors.camera` (``_prepare`` and :func:`camera_rays`): per
sample its ground point in the car frame and the mip level to read, per camera the ``geom`` scalars
below, per texture the flat texel array of all mip levels and wall tiles. Parallel over (car, block
of ``ROWS_PER_JOB`` rows) jobs, each with its own scratch row.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# geom: float64 array of the scalars the kernel needs, in this order.
X0, Y0, INV_TEXEL, WIDTH0, HEIGHT0, X_LO, Y_LO, X_HI, Y_HI, WALL_H, INV_WALL, MOUNT_F, MOUNT_L, CAM_H = range(14)
ROWS_PER_JOB = 8  # image rows rendered by one parallel job (amortises its scratch buffer)
SERIAL_BELOW_SAMPLES = 40_000  # batches with fewer ray samples than this render on one thread
NOT_ON_GROUND = -1  # scratch marker: the sample's ray leaves the room before it meets the ground
# error_model="numpy" drops the ZeroDivisionError checks that keep LLVM from vectorising the loops.
_jit = njit(cache=True, fastmath=True, error_model="numpy")


@_jit
def _ground_index(j, u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride):
    """Texel index of ground sample j, or NOT_ON_GROUND; branch-free so that rows vectorise.

    Level-0 texel (ix, iy) of a sample at mip level ``shift`` is read at
    ``offset + (iy >> shift) * stride + (ix >> shift)``; stride 0 marks samples that miss the ground.
    Per-sample arrays (rather than per-level tables) keep the loop free of gathers, so it vectorises.
    """
    tu = u0 + a * gx[j] - b * gy[j]
    tv = v0 + b * gx[j] + a * gy[j]
    inside = (tu > np.float32(-1.0)) & (tv > np.float32(-1.0)) & (tu < w0) & (tv < h0) & (stride[j] > 0)
    # Clamping before the float -> int conversion keeps far hits finite; inside the room it equals
    # truncation, which is the floor there (coordinates > -1).
    ix = np.int32(min(max(tu, np.float32(0.0)), w0 - np.float32(1.0))) >> shift[j]
    iy = np.int32(min(max(tv, np.float32(0.0)), h0 - np.float32(1.0))) >> shift[j]
    return np.int32(offset[j] + iy * stride[j] + ix) if inside else np.int32(NOT_ON_GROUND)


@_jit
def _ground_bilinear(j, u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride):
    """(index of the lower-left texel, x weight, y weight) of ground sample j, for a 2x2 blend at
    level 0; other levels read their nearest texel (weights 0). NOT_ON_GROUND as _ground_index."""
    index = _ground_index(j, u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride)
    # Texel centres sit at i + 0.5: blend between floor(s) and floor(s) + 1 with s = coordinate - 0.5.
    su = min(max(u0 + a * gx[j] - b * gy[j] - np.float32(0.5), np.float32(0.0)), w0 - np.float32(1.0))
    sv = min(max(v0 + b * gx[j] + a * gy[j] - np.float32(0.5), np.float32(0.0)), h0 - np.float32(1.0))
    iu, iv = np.int32(su), np.int32(sv)
    level0 = (shift[j] == 0) & (index != NOT_ON_GROUND)
    corner = np.int32(offset[j] + iv * stride[j] + iu)
    zero = np.float32(0.0)
    return (corner if level0 else index), (su - np.float32(iu) if level0 else zero), (sv - np.float32(iv) if level0 else zero)


@_jit
def _wall_index(j, c, s, cx, cy, hx, hy, slope, geom, walls):
    """Texel index where the horizontal ray of sample j leaves the room: a wall texel or the sky.

    walls: int64 [wall_offset, wall_rows, wall_cols, sky_index] of the texture.
    """
    wx = c * hx[j] - s * hy[j]
    wy = s * hx[j] + c * hy[j]
    x_lo, y_lo, x_hi, y_hi = geom[X_LO], geom[Y_LO], geom[X_HI], geom[Y_HI]
    gap_x = x_hi - cx if wx > 0 else cx - x_lo
    gap_y = y_hi - cy if wy > 0 else cy - y_lo
    speed_x, speed_y = abs(wx) + 1e-12, abs(wy) + 1e-12
    hits_x_wall = gap_x * speed_y < gap_y * speed_x
    t = (gap_x if hits_x_wall else gap_y) / (speed_x if hits_x_wall else speed_y)
    px, py = cx + t * wx, cy + t * wy
    span_x, span_y = x_hi - x_lo, y_hi - y_lo
    # Position along the perimeter: south wall, east wall, north wall, west wall (counter-clockwise).
    p_x_wall = span_x + (py - y_lo) if wx > 0 else 2.0 * span_x + span_y + (y_hi - py)
    p_y_wall = span_x + span_y + (x_hi - px) if wy > 0 else px - x_lo
    p = p_x_wall if hits_x_wall else p_y_wall
    z = geom[CAM_H] + slope[j] * t
    row = min(max(np.int64(z * geom[INV_WALL]), 0), walls[1] - 1)
    col = min(max(np.int64(p * geom[INV_WALL]), 0), walls[2] - 1)
    return np.int32(walls[3]) if (z >= geom[WALL_H]) | (t < 0.0) else np.int32(walls[0] + row * walls[2] + col)


@_jit
def _ground_row(u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride, scratch):
    """Texel indices of one row's samples (arrays sliced to the row) into scratch; returns how many
    are NOT_ON_GROUND. A function of its own: LLVM vectorises the loop when compiled apart."""
    missed = 0
    for j in range(scratch.shape[0]):
        index = _ground_index(j, u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride)
        scratch[j] = index
        missed += np.int32(index == NOT_ON_GROUND)
    return missed


@_jit
def _ground_row_bilinear(u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride, scratch, weight_u, weight_v):
    """As _ground_row, plus the blend weights of level-0 samples (0 elsewhere)."""
    missed = 0
    for j in range(scratch.shape[0]):
        index, wu, wv = _ground_bilinear(j, u0, v0, a, b, w0, h0, gx, gy, shift, offset, stride)
        scratch[j] = index
        weight_u[j] = wu
        weight_v[j] = wv
        missed += np.int32(index == NOT_ON_GROUND)
    return missed


@_jit
def _gather_row_bilinear(values, scratch, weight_u, weight_v, row_stride, k2, out_row):
    """As _gather_row, blending the 2x2 texels above / right of scratch[q] with its weights."""
    for col in range(out_row.shape[0]):
        acc = np.float32(0.0)
        for q in range(col * k2, col * k2 + k2):
            i, wu, wv = scratch[q], weight_u[q], weight_v[q]
            if wu == 0 and wv == 0:  # walls, sky, coarser levels and exact texel centres
                acc += np.float32(values[i])
                continue
            low = np.float32(values[i]) + wu * (np.float32(values[i + 1]) - np.float32(values[i]))
            high = np.float32(values[i + row_stride]) + wu * (np.float32(values[i + row_stride + 1])
                                                              - np.float32(values[i + row_stride]))
            acc += low + wv * (high - low)
        out_row[col] = np.uint8(acc / np.float32(k2) + np.float32(0.5))


@_jit
def _wall_row(c, s, cx, cy, hx, hy, slope, geom, walls, scratch, only_missed):
    """Wall / sky texel indices of one row's samples into scratch (only where NOT_ON_GROUND if only_missed)."""
    if only_missed:
        for j in range(scratch.shape[0]):
            if scratch[j] == NOT_ON_GROUND:
                scratch[j] = _wall_index(j, c, s, cx, cy, hx, hy, slope, geom, walls)
    else:
        for j in range(scratch.shape[0]):
            scratch[j] = _wall_index(j, c, s, cx, cy, hx, hy, slope, geom, walls)


@_jit
def _gather_row(values, scratch, k2, out_row):
    """out_row[col] = rounded mean of values[scratch[q]] over the col's k2 samples."""
    if k2 == 1:
        for col in range(out_row.shape[0]):
            out_row[col] = values[scratch[col]]
        return
    for col in range(out_row.shape[0]):
        acc = 0
        for q in range(col * k2, col * k2 + k2):
            acc += np.int32(values[scratch[q]])
        out_row[col] = (acc + k2 // 2) // k2


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def render_kernel(values, shift, offset, stride, geom, walls, gx, gy, hx, hy, slope, row_has_ground, k, bilinear,
                  poses, variant, out):
    """Fill out (N, H, W) uint8 (may be a strided channel view) for N cars from one texture plane.

    values (V, T) uint8 texels (TrackTexture layout); per-sample tables as in CameraRays and _prepare.
    Each row: a vectorised pass computing texel indices into a scratch row, a pass for the samples
    that reach the walls, then the texel reads.
    """
    n_cars, height, width = out.shape
    k2 = k * k
    row_samples = width * k2
    blocks = (height + ROWS_PER_JOB - 1) // ROWS_PER_JOB
    w0, h0 = np.float32(geom[WIDTH0]), np.float32(geom[HEIGHT0])
    for job in prange(n_cars * blocks):
        n = job // blocks
        c, s = math.cos(poses[n, 2]), math.sin(poses[n, 2])
        cx = poses[n, 0] + c * geom[MOUNT_F] - s * geom[MOUNT_L]
        cy = poses[n, 1] + s * geom[MOUNT_F] + c * geom[MOUNT_L]
        # Texel coordinates of a car-frame point (gx, gy): (u0 + a*gx - b*gy, v0 + b*gx + a*gy).
        u0 = np.float32((poses[n, 0] - geom[X0]) * geom[INV_TEXEL])
        v0 = np.float32((poses[n, 1] - geom[Y0]) * geom[INV_TEXEL])
        a, b = np.float32(c * geom[INV_TEXEL]), np.float32(s * geom[INV_TEXEL])
        scratch = np.empty(row_samples, dtype=np.int32)
        weight_u = np.zeros(row_samples if bilinear else 0, dtype=np.float32)
        weight_v = np.zeros(row_samples if bilinear else 0, dtype=np.float32)
        first_row = (job - n * blocks) * ROWS_PER_JOB
        for r in range(first_row, min(first_row + ROWS_PER_JOB, height)):
            lo, hi = r * row_samples, (r + 1) * row_samples
            missed = row_samples
            blend = bilinear and row_has_ground[r]
            if blend:
                missed = _ground_row_bilinear(u0, v0, a, b, w0, h0, gx[lo:hi], gy[lo:hi], shift[lo:hi],
                                              offset[lo:hi], stride[lo:hi], scratch, weight_u, weight_v)
            elif row_has_ground[r]:
                missed = _ground_row(u0, v0, a, b, w0, h0, gx[lo:hi], gy[lo:hi], shift[lo:hi], offset[lo:hi],
                                     stride[lo:hi], scratch)
            if missed > 0:
                _wall_row(c, s, cx, cy, hx[lo:hi], hy[lo:hi], slope[lo:hi], geom, walls, scratch,
                          missed < row_samples)
            if blend:  # samples that reach the walls kept weights 0
                _gather_row_bilinear(values[variant[n]], scratch, weight_u, weight_v, np.int64(geom[WIDTH0]), k2,
                                     out[n, r])
            else:
                _gather_row(values[variant[n]], scratch, k2, out[n, r])
