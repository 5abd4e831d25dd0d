"""DeepRacer's front camera: a pinhole camera looking at a flat textured world, batched over cars.

Every pixel's ray is cast onto the ground plane (z = 0) and samples the track texture; rays that
pass over the horizon or leave the room hit the room's walls or the sky above them. The ground is
flat and the camera is rigid on the car, so each pixel always hits the same point *in the car
frame*: :func:`camera_rays` precomputes those points once per :class:`CameraParams`, and rendering a
frame is one 2-D rotation plus one texel read per sample.

Anti-aliasing options (cost per frame, relative to one sample per pixel without mip levels):
- ``mipmap=True`` (default): each sample reads the mip level whose texel matches its ground footprint
  (precomputed per pixel). Removes shimmer of far lines and carpet grain; costs ~nothing.
- ``bilinear=True``: samples that read mip level 0 (the near road, magnified) blend the 4 nearest
  texels instead of taking the nearest one: smooth tape edges up close instead of texel steps; about
  1.5x the cost.
- ``supersample=k``: k x k rays per pixel averaged (like rendering at k times the size and
  box-downsizing, as DeepRacer renders 640x480 and resizes to 160x120); costs k**2.

Frames: ``(N, H, W)`` uint8 grey (ITU-R 601 luma of the RGB texture) or ``(N, H, W, 3)`` RGB; row 0
is the top of the image, column 0 its left. A plain-numpy version of the renderer, the parity oracle
of the numba kernel, lives in tests/sensors/test_camera.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from laplab.sensors.texture import TrackTexture

MAX_GROUND_RANGE = 1000.0  # m: ground hits farther than this are treated as horizon (wall / sky)


@dataclass(frozen=True)
class CameraParams:
    """A camera rigidly mounted on the car (metres, radians).

    Mounting defaults follow the DeepRacer simulator's URDF (deepracer_single_cam.urdf): the
    ``zed_camera_joint`` sits 0.0917 m ahead of and 0.080 m above the chassis origin, pitched 0.2618 rad
    (15 deg) down; the image sensor (``camera_link``) is a further (0.0448, 0, 0.040) m in that pitched
    frame. The chassis origin is 0.0817 m ahead of the rear axle, which is laplab's car origin, and
    0.0913 m above the wheel centres; with ~0.03 m wheels the optical centre is ~0.227 m ahead of the
    rear axle and ~0.12 m above the ground. ``mount_lateral`` is to the car's left (+y).
    """

    width: int = 160
    height: int = 120
    fov: float = 1.13
    mount_forward: float = 0.227
    mount_up: float = 0.12
    mount_lateral: float = 0.0
    pitch: float = math.radians(15.0)
    supersample: int = 1
    mipmap: bool = True
    bilinear: bool = False
    grayscale: bool = True

    def __post_init__(self) -> None:
        for name in ("width", "height", "supersample"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and 1 <= value <= 8192):
                raise ValueError(f"CameraParams.{name} must be a positive integer, got {value!r}")
        for name, low, high, meaning in (("fov", 0.0, math.pi, "a horizontal field of view, rad"),
                                         ("mount_up", 0.0, 100.0, "a height above the ground, m"),
                                         ("pitch", -0.5 * math.pi, 0.5 * math.pi, "rad, positive = down"),
                                         ("mount_forward", -100.0, 100.0, "m"), ("mount_lateral", -100.0, 100.0, "m")):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and low < value < high):
                raise ValueError(f"CameraParams.{name} must be in ({low:.4g}, {high:.4g}) ({meaning}), got {value!r}")

    @property
    def focal_length(self) -> float:
        """Focal length in pixels (square pixels, principal point at the image centre)."""
        return 0.5 * self.width / math.tan(0.5 * self.fov)

    @property
    def horizon_row(self) -> float:
        """Image row (continuous, 0 = top edge) where the ground's horizon lies."""
        return 0.5 * self.height - self.focal_length * math.tan(self.pitch)

    def with_(self, **changes) -> "CameraParams":
        return replace(self, **changes)


STEREO_BASELINE = 0.06  # m: the simulator's zed_camera_link_leftcam / _rightcam sit at y = +-0.03
FRONT_FACING_CAMERA = CameraParams()
LEFT_CAMERA = CameraParams(mount_lateral=0.5 * STEREO_BASELINE)
RIGHT_CAMERA = CameraParams(mount_lateral=-0.5 * STEREO_BASELINE)
STEREO_CAMERAS = (LEFT_CAMERA, RIGHT_CAMERA)
HUMAN_CAMERA = CameraParams(width=640, height=480, supersample=2, bilinear=True, grayscale=False)
SENSOR_CAMERAS: dict[str, tuple[CameraParams, ...]] = {
    "FRONT_FACING_CAMERA": (FRONT_FACING_CAMERA,),
    "OBSERVATION": (FRONT_FACING_CAMERA,),  # the 2018 simapp's name for the front camera
    "LEFT_CAMERA": (LEFT_CAMERA,),
    "STEREO_CAMERAS": STEREO_CAMERAS,
}


def camera_for_sensor(name: str) -> tuple[CameraParams, ...]:
    """Cameras of a DeepRacer ``model_metadata.json`` sensor name, in observation channel order."""
    try:
        return SENSOR_CAMERAS[name]
    except KeyError:
        raise ValueError(f"unknown camera sensor {name!r} in model_metadata 'sensor'; "
                         f"known camera sensors: {', '.join(SENSOR_CAMERAS)}") from None


class CameraRays(NamedTuple):
    """Per-sample geometry, S = height * width * supersample**2 samples ordered (row, col, sub_row, sub_col).

    ground_x, ground_y: (S,) float32 ground hit in the car frame (from the car origin), m.
    level0_footprint: (S,) float32 ground size of the sample (m, geometric mean of its extents across
        and along the ray); 0 where the ray misses the ground.
    hits_ground: (S,) bool.  dir_x, dir_y: (S,) float32 unit horizontal ray direction, car frame.
    slope: (S,) float32 dz per metre travelled horizontally.
    """

    ground_x: np.ndarray
    ground_y: np.ndarray
    level0_footprint: np.ndarray
    hits_ground: np.ndarray
    dir_x: np.ndarray
    dir_y: np.ndarray
    slope: np.ndarray


def _ray_directions(params: CameraParams, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Car-frame ray directions (dx, dy, dz) through continuous image points (u right, v down)."""
    f = params.focal_length
    left, up = -(u - 0.5 * params.width) / f, -(v - 0.5 * params.height) / f
    cp, sp = math.cos(params.pitch), math.sin(params.pitch)
    return cp + sp * up, left, -sp + cp * up


def _ground_points(params: CameraParams, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dx, dy, dz = _ray_directions(params, u, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < 0, params.mount_up / -dz, np.inf)
        hits = np.isfinite(t) & (t * np.hypot(dx, dy) < MAX_GROUND_RANGE)
        gx = np.where(hits, params.mount_forward + t * dx, 0.0)
        gy = np.where(hits, params.mount_lateral + t * dy, 0.0)
    return gx, gy, hits


@lru_cache(maxsize=64)
def camera_rays(params: CameraParams) -> CameraRays:
    """Precompute where every sample ray of ``params`` meets the ground (cached per params)."""
    k = params.supersample
    rows, cols, sub_r, sub_c = np.meshgrid(np.arange(params.height), np.arange(params.width),
                                           np.arange(k), np.arange(k), indexing="ij")
    u = (cols + (sub_c + 0.5) / k).reshape(-1).astype(np.float64)
    v = (rows + (sub_r + 0.5) / k).reshape(-1).astype(np.float64)
    gx, gy, hits = _ground_points(params, u, v)
    # Footprint: distance to the ground points one sample step right and one step down.
    step = 1.0 / k
    gx_u, gy_u, hits_u = _ground_points(params, u + step, v)
    gx_v, gy_v, _ = _ground_points(params, u, v + step)
    across = np.where(hits_u, np.hypot(gx_u - gx, gy_u - gy), 0.0)
    along = np.hypot(gx_v - gx, gy_v - gy)
    # Geometric mean of the two extents: the mip level whose texels match the footprint's area (the
    # largest extent blurs the far road; measured against 6x6 supersampling this errs least).
    footprint = np.where(hits, np.sqrt(across * along), 0.0)
    dx, dy, dz = _ray_directions(params, u, v)
    horizontal = np.hypot(dx, dy)
    as32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)
    result = CameraRays(as32(gx), as32(gy), as32(footprint), hits, as32(dx / horizontal), as32(dy / horizontal),
                        as32(dz / horizontal))
    for array in result:
        array.flags.writeable = False
    return result


@lru_cache(maxsize=64)
def sample_levels(params: CameraParams, texel_size: float, num_levels: int) -> np.ndarray:
    """(S,) int8 mip level read by each sample; -1 marks samples that miss the ground (wall / sky).

    The level is the rounded log2 of footprint / texel size (nearest mip level), 0 without mipmap.
    """
    rays = camera_rays(params)
    if params.mipmap:
        with np.errstate(divide="ignore"):
            level = np.rint(np.log2(np.maximum(rays.level0_footprint, 1e-12) / texel_size))
        level = np.clip(level, 0, num_levels - 1)
    else:
        level = np.zeros(rays.hits_ground.shape)
    level = np.where(rays.hits_ground, level, -1).astype(np.int8)
    level.flags.writeable = False
    return level


class _Prepared(NamedTuple):
    shift: np.ndarray
    offset: np.ndarray
    stride: np.ndarray
    geom: np.ndarray
    walls: np.ndarray
    row_has_ground: np.ndarray


@lru_cache(maxsize=8)
def _prepare(params: CameraParams, texture: TrackTexture) -> _Prepared:
    """Kernel arguments of one camera on one texture (cached: textures are immutable, keyed by identity)."""
    level = sample_levels(params, texture.texel_size, texture.num_levels).astype(np.int64)
    ground = level >= 0
    safe = np.maximum(level, 0)
    x_lo, y_lo, x_hi, y_hi = texture.room
    geom = np.array([texture.x0, texture.y0, 1.0 / texture.texel_size, texture.width, texture.height,
                     x_lo, y_lo, x_hi, y_hi, texture.wall_height, 1.0 / texture.wall_texel_size,
                     params.mount_forward, params.mount_lateral, params.mount_up], dtype=np.float64)
    walls = np.array([texture.wall_offset, texture.wall_rows, texture.wall_cols, texture.sky_index], dtype=np.int64)
    return _Prepared(np.where(ground, safe, 0).astype(np.int32),
                     np.where(ground, texture.level_offset[safe], 0).astype(np.int32),
                     np.where(ground, texture.level_width[safe], 0).astype(np.int32),
                     geom, walls, ground.reshape(params.height, -1).any(axis=1))


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
def _render_kernel(values, shift, offset, stride, geom, walls, gx, gy, hx, hy, slope, row_has_ground, k, bilinear,
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


def _check_poses(poses) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or not np.isfinite(poses).all():
        raise ValueError(f"render_camera: poses must be a finite (N, 3) array of (x, y, yaw) in m and rad, "
                         f"got shape {poses.shape}{'' if np.isfinite(poses).all() else ' with NaN/Inf values'}")
    return np.ascontiguousarray(poses)


def _check_variant(variant, n: int, texture: TrackTexture) -> np.ndarray:
    if variant is None:
        return np.zeros(n, dtype=np.int64)
    variant = np.ascontiguousarray(np.broadcast_to(np.asarray(variant, dtype=np.int64), (n,)))
    if variant.size and (variant.min() < 0 or variant.max() >= texture.num_variants):
        raise ValueError(f"render_camera: variant indices must be in 0..{texture.num_variants - 1} "
                         f"(the texture has {texture.num_variants} variants), got {variant.min()}..{variant.max()}")
    return variant


def _render_into(texture: TrackTexture, poses: np.ndarray, params: CameraParams, variant: np.ndarray,
                 out: np.ndarray, plane: int | None) -> None:
    """Render into out (N, H, W) from the grey texture (plane None) or colour plane 0/1/2."""
    rays, prep = camera_rays(params), _prepare(params, texture)
    threads = numba.get_num_threads()
    # A frame or two takes tens of microseconds: waking the other threads costs more than it saves.
    small = poses.shape[0] * rays.ground_x.shape[0] < SERIAL_BELOW_SAMPLES
    if small:
        numba.set_num_threads(1)
    try:
        _render_kernel(texture.gray if plane is None else texture.rgb[plane], prep.shift, prep.offset, prep.stride,
                       prep.geom, prep.walls, rays.ground_x, rays.ground_y, rays.dir_x, rays.dir_y, rays.slope,
                       prep.row_has_ground, params.supersample, params.bilinear, poses, variant, out)
    finally:
        if small:
            numba.set_num_threads(threads)


def frame_shape(params: CameraParams, n: int) -> tuple[int, ...]:
    """Shape of ``n`` frames of ``params``: (n, H, W) grey or (n, H, W, 3) RGB."""
    return (n, params.height, params.width) + (() if params.grayscale else (3,))


def _output(out: np.ndarray | None, shape: tuple[int, ...], caller: str) -> np.ndarray:
    if out is None:
        return np.empty(shape, dtype=np.uint8)
    if out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"{caller}: out must be a C-contiguous uint8 array of shape {shape}, got {out.dtype} {out.shape}")
    return out


def render_camera(texture: TrackTexture, poses, params: CameraParams = FRONT_FACING_CAMERA,
                  out: np.ndarray | None = None, variant=None) -> np.ndarray:
    """Render one camera for N cars: poses (N, 3) (x, y, yaw of the rear-axle origin, m / rad).

    Returns (N, H, W) uint8 grey or (N, H, W, 3) uint8 RGB (into ``out`` when given, which must
    be C-contiguous of that shape). ``variant`` (N,) or scalar picks each car's colour variant of
    ``texture`` (default 0). Deterministic.
    """
    poses = _check_poses(poses)
    variant = _check_variant(variant, poses.shape[0], texture)
    out = _output(out, frame_shape(params, poses.shape[0]), "render_camera")
    for plane in [None] if params.grayscale else [0, 1, 2]:
        _render_into(texture, poses, params, variant, out if plane is None else out[..., plane], plane)
    return out


def render_cameras(texture: TrackTexture, poses, cameras: tuple[CameraParams, ...],
                   out: np.ndarray | None = None, variant=None) -> np.ndarray:
    """Render grey cameras as channels: (N, H, W, len(cameras)) uint8 (stereo: left, right).

    This is DeepRacer's observation layout: (N, 120, 160, 1) for one camera, (N, 120, 160, 2) stereo.
    """
    if not cameras or not all(cam.grayscale for cam in cameras) or len({(c.width, c.height) for c in cameras}) != 1:
        raise ValueError("render_cameras: needs one or more grayscale CameraParams of one image size, got "
                         f"{[(cam.width, cam.height, 'gray' if cam.grayscale else 'rgb') for cam in cameras]}")
    poses = _check_poses(poses)
    variant = _check_variant(variant, poses.shape[0], texture)
    out = _output(out, (poses.shape[0], cameras[0].height, cameras[0].width, len(cameras)), "render_cameras")
    for channel, cam in enumerate(cameras):
        _render_into(texture, poses, cam, variant, out[..., channel], None)
    return out
