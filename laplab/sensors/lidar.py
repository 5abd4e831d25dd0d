"""DeepRacer's 2-D lidar: batched ray casting against the track borders (ranges in metres).

The sim car's lidar (reference doc section 4; simapp ``markov/sensors/constants.py``) has 64 beams
spread evenly over -150..+150 deg (both ends included, beam 0 on the car's right), ranges 0.15-12 m
and Gaussian noise of sigma 0.01 m. Angles are in the car frame, counter-clockwise from the car's
front, so positive angles look left.

Walls: laplab treats the inner and outer borders as walls the beams hit. (DeepRacer's Gazebo worlds
have only painted borders; there the lidar sees objects, bot cars and the world's barriers.) Boxes
and other cars (``obstacles`` of :func:`scan`) stop the beams too.

Range semantics follow Gazebo's ray sensor: a beam starts at ``min_range``, so a surface nearer
than that is not seen; a beam that hits nothing within ``max_range`` reads ``max_range`` (Gazebo
reports +inf there, which every DeepRacer observation filter maps to the same value).

Speed: :class:`LidarWalls` keeps the wall segments in a uniform grid built once per track; each
beam walks the grid cells it crosses (Amanatides-Woo DDA) in a numba kernel, parallel over beams.
:func:`scan_reference` is the brute-force numpy version for parity tests.
What the network sees of the ranges (simapp's observation filters) is in
:mod:`laplab.sensors.lidar_observation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from laplab.sensors.obstacle_kernel import obstacle_ranges
from laplab.sensors.obstacle_look import obstacle_boxes

_PARALLEL_MIN_RAYS = 2048  # below this a serial kernel beats the thread start-up cost


@dataclass(frozen=True)
class LidarParams:
    """The lidar's geometry and noise (DeepRacer defaults).

    ``mount_x``/``mount_y``: sensor position in the car frame, metres from the model origin (rear-axle
    centre). 0.10 m ahead puts it on the chassis top behind the camera (0.09 m ahead of the axle
    centre in section 4 is the camera lens; the lidar dome sits a little behind it on the real car,
    whose rear axle is ~0.08 m behind the body's rear edge); laplab's choice, not a simapp value.
    """

    num_beams: int = 64
    min_angle: float = -2.61799  # rad, -150 deg
    max_angle: float = 2.61799   # rad, +150 deg
    min_range: float = 0.15      # m
    max_range: float = 12.0      # m
    noise_std: float = 0.01      # m
    mount_x: float = 0.10        # m
    mount_y: float = 0.0         # m

    def __post_init__(self) -> None:
        if int(self.num_beams) != self.num_beams or self.num_beams < 1:
            raise ValueError(f"LidarParams.num_beams must be a positive integer, got {self.num_beams!r}")
        for name in ("min_angle", "max_angle", "min_range", "max_range", "noise_std", "mount_x", "mount_y"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"LidarParams.{name} must be finite, got {getattr(self, name)!r}")
        if not 0.0 <= self.min_range < self.max_range:
            raise ValueError(f"LidarParams needs 0 <= min_range < max_range, got {self.min_range}, {self.max_range}")
        if self.min_angle > self.max_angle or self.noise_std < 0:
            raise ValueError("LidarParams needs min_angle <= max_angle and noise_std >= 0")

    @cached_property
    def beam_angles(self) -> np.ndarray:
        """(num_beams,) float64 beam directions in the car frame, rad (Gazebo: ends included); read-only."""
        angles = np.linspace(self.min_angle, self.max_angle, int(self.num_beams))
        angles.flags.writeable = False
        return angles


DEFAULT_LIDAR = LidarParams()


def track_borders(track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centerline, inner, outer), each (N, 2) float64, from a Track-like object or an (N, 6) route array."""
    if all(hasattr(track, name) for name in ("centerline", "inner", "outer")):
        parts = (track.centerline, track.inner, track.outer)
    else:
        route = np.asarray(track, dtype=np.float64)
        if route.ndim != 2 or route.shape[1] != 6:
            raise ValueError(f"expected a Track or an (N, 6) route array [centre | inner | outer], "
                             f"got an array of shape {route.shape}")
        parts = (route[:, 0:2], route[:, 2:4], route[:, 4:6])
    return tuple(np.ascontiguousarray(p, dtype=np.float64) for p in parts)


def polyline_segments(polyline: np.ndarray) -> np.ndarray:
    """(M, 4) segments [x0, y0, x1, y1] joining consecutive points of (M+1, 2); zero-length ones dropped."""
    p = np.asarray(polyline, dtype=np.float64)
    seg = np.hstack([p[:-1], p[1:]])
    return seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 1e-12]


@dataclass(frozen=True, eq=False)
class LidarWalls:
    """Wall segments and their uniform grid (CSR layout), built once per track.

    segments: (S, 4) float64 [x0, y0, x1, y1] m. Cell (ix, iy) covers
    [origin_x + ix*cell_size, +cell_size) x [origin_y + iy*cell_size, +cell_size); the segments that
    touch cell c = iy*nx + ix are ``cell_segments[cell_start[c]:cell_start[c+1]]``.
    """

    segments: np.ndarray
    origin_x: float
    origin_y: float
    cell_size: float
    nx: int
    ny: int
    cell_start: np.ndarray
    cell_segments: np.ndarray

    @classmethod
    def from_segments(cls, segments: np.ndarray, cell_size: float = 0.25, max_cells: int = 1024) -> "LidarWalls":
        """Build the grid over (S, 4) segments; ``cell_size`` m grows if a side would exceed ``max_cells``."""
        seg = np.ascontiguousarray(segments, dtype=np.float64)
        if seg.ndim != 2 or seg.shape[1] != 4 or seg.shape[0] == 0 or not np.isfinite(seg).all():
            raise ValueError(f"LidarWalls needs a non-empty finite (S, 4) array of segments, got shape {seg.shape}")
        if not cell_size > 0:
            raise ValueError(f"LidarWalls cell_size must be positive, got {cell_size!r}")
        lo = np.minimum(seg[:, 0:2], seg[:, 2:4]).min(axis=0) - 1e-3
        hi = np.maximum(seg[:, 0:2], seg[:, 2:4]).max(axis=0) + 1e-3
        cell = max(float(cell_size), float((hi - lo).max()) / max_cells)
        nx, ny = (int(v) for v in np.ceil((hi - lo) / cell).astype(np.int64))
        cell_start, cell_segments = _grid_cells(seg, lo[0], lo[1], cell, nx, ny)
        return cls(seg, float(lo[0]), float(lo[1]), cell, nx, ny, cell_start, cell_segments)

    @classmethod
    def from_track(cls, track, inner: np.ndarray | None = None, outer: np.ndarray | None = None,
                   cell_size: float = 0.25) -> "LidarWalls":
        """Walls along both borders of a Track, an (N, 6) route, or ``from_track(centerline, inner, outer)``."""
        if inner is not None and outer is not None:
            borders = (np.asarray(inner, np.float64), np.asarray(outer, np.float64))
        else:
            borders = track_borders(track)[1:]
        return cls.from_segments(np.vstack([polyline_segments(b) for b in borders]), cell_size)


@numba.njit(cache=True)
def _touches_cell(seg, j, bx0, by0, size, pad):
    """Whether segment j meets the square [bx0, bx0+size]^2 grown by ``pad`` (separating-axis test)."""
    ax, ay, bx, by = seg[j, 0], seg[j, 1], seg[j, 2], seg[j, 3]
    nx_, ny_ = ay - by, bx - ax  # segment normal
    x0, y0, x1, y1 = bx0 - pad, by0 - pad, bx0 + size + pad, by0 + size + pad
    s0 = nx_ * (x0 - ax) + ny_ * (y0 - ay)
    s1 = nx_ * (x1 - ax) + ny_ * (y0 - ay)
    s2 = nx_ * (x0 - ax) + ny_ * (y1 - ay)
    s3 = nx_ * (x1 - ax) + ny_ * (y1 - ay)
    return not ((s0 > 0 and s1 > 0 and s2 > 0 and s3 > 0) or (s0 < 0 and s1 < 0 and s2 < 0 and s3 < 0))


@numba.njit(cache=True)
def _cell_range(lo, hi, origin, size, n):
    a = int(math.floor((lo - origin) / size - 1e-9))
    b = int(math.floor((hi - origin) / size + 1e-9))
    return max(a, 0), min(b, n - 1)


@numba.njit(cache=True)
def _grid_cells(seg, ox, oy, size, nx, ny):
    """(cell_start (nx*ny + 1,) int64, cell_segments int32) of the segments (S, 4) in the grid: the first
    pass counts the segments each cell touches, the second lists them (ascending) at their cell's offset."""
    counts = np.zeros(nx * ny, dtype=np.int64)
    cell_start = np.zeros(nx * ny + 1, dtype=np.int64)
    cell_segments = np.empty(0, dtype=np.int32)
    for listing in (False, True):
        if listing:
            cell_start[1:] = np.cumsum(counts)
            cell_segments = np.empty(cell_start[-1], dtype=np.int32)
            counts[:] = 0
        for j in range(seg.shape[0]):
            ix0, ix1 = _cell_range(min(seg[j, 0], seg[j, 2]), max(seg[j, 0], seg[j, 2]), ox, size, nx)
            iy0, iy1 = _cell_range(min(seg[j, 1], seg[j, 3]), max(seg[j, 1], seg[j, 3]), oy, size, ny)
            for iy in range(iy0, iy1 + 1):
                for ix in range(ix0, ix1 + 1):
                    if _touches_cell(seg, j, ox + ix * size, oy + iy * size, size, 1e-9 + 1e-6 * size):
                        c = iy * nx + ix
                        if listing:
                            cell_segments[cell_start[c] + counts[c]] = j
                        counts[c] += 1
    return cell_start, cell_segments


@numba.njit(cache=True)
def _cast_ray(px, py, dx, dy, t_min, t_max, seg, gx, gy, size, nx, ny, cell_start, cell_segments):
    """Nearest wall hit in [t_min, t_max] along p + t*d (|d| = 1), or t_max when none."""
    inv_dx = 1.0 / dx if dx != 0.0 else math.inf
    inv_dy = 1.0 / dy if dy != 0.0 else math.inf
    # Clip the ray to the grid's box (slab test) so a sensor outside the grid still works.
    gx1, gy1 = gx + nx * size, gy + ny * size
    t_enter, t_leave = 0.0, t_max
    if dx != 0.0:
        ta, tb = (gx - px) * inv_dx, (gx1 - px) * inv_dx
        t_enter, t_leave = max(t_enter, min(ta, tb)), min(t_leave, max(ta, tb))
    elif not gx <= px <= gx1:
        return t_max
    if dy != 0.0:
        ta, tb = (gy - py) * inv_dy, (gy1 - py) * inv_dy
        t_enter, t_leave = max(t_enter, min(ta, tb)), min(t_leave, max(ta, tb))
    elif not gy <= py <= gy1:
        return t_max
    if t_enter > t_leave:
        return t_max
    ix = min(max(int((px + t_enter * dx - gx) / size), 0), nx - 1)
    iy = min(max(int((py + t_enter * dy - gy) / size), 0), ny - 1)
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    next_x = (gx + (ix + (1 if dx > 0 else 0)) * size - px) * inv_dx if dx != 0.0 else math.inf
    next_y = (gy + (iy + (1 if dy > 0 else 0)) * size - py) * inv_dy if dy != 0.0 else math.inf
    delta_x, delta_y = abs(size * inv_dx), abs(size * inv_dy)
    best = math.inf
    while True:
        c = iy * nx + ix
        for k in range(cell_start[c], cell_start[c + 1]):
            j = cell_segments[k]
            ex, ey = seg[j, 2] - seg[j, 0], seg[j, 3] - seg[j, 1]
            denom = dx * ey - dy * ex
            if denom == 0.0:
                continue
            wx, wy = seg[j, 0] - px, seg[j, 1] - py
            t = (wx * ey - wy * ex) / denom
            u = (wx * dy - wy * dx) / denom
            if 0.0 <= u <= 1.0 and t_min <= t < best:
                best = t
        cell_exit = min(next_x, next_y)
        if best <= cell_exit or cell_exit >= t_leave:
            break
        if next_x < next_y:
            ix += step_x
            next_x += delta_x
            if ix < 0 or ix >= nx:
                break
        else:
            iy += step_y
            next_y += delta_y
            if iy < 0 or iy >= ny:
                break
    return best if best <= t_max else t_max


@numba.njit(cache=True)
def _scan_one(r, poses, angles, mount_x, mount_y, t_min, t_max, seg, gx, gy, size, nx, ny, cs, css, out):
    car, beam = r // angles.shape[0], r % angles.shape[0]
    x, y, yaw = poses[car, 0], poses[car, 1], poses[car, 2]
    c, s = math.cos(yaw), math.sin(yaw)
    px, py = x + c * mount_x - s * mount_y, y + s * mount_x + c * mount_y
    a = yaw + angles[beam]
    out[car, beam] = _cast_ray(px, py, math.cos(a), math.sin(a), t_min, t_max, seg, gx, gy, size, nx, ny, cs, css)


@numba.njit(cache=True)
def _scan_serial(poses, angles, mx, my, t_min, t_max, seg, gx, gy, size, nx, ny, cs, css, out):
    for r in range(poses.shape[0] * angles.shape[0]):
        _scan_one(r, poses, angles, mx, my, t_min, t_max, seg, gx, gy, size, nx, ny, cs, css, out)


@numba.njit(cache=True, parallel=True)
def _scan_parallel(poses, angles, mx, my, t_min, t_max, seg, gx, gy, size, nx, ny, cs, css, out):
    for r in numba.prange(poses.shape[0] * angles.shape[0]):
        _scan_one(r, poses, angles, mx, my, t_min, t_max, seg, gx, gy, size, nx, ny, cs, css, out)


def _check_poses(poses) -> np.ndarray:
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"lidar scan: poses must be an (N, 3) array of (x, y, yaw), got shape {poses.shape}")
    return poses


def _add_noise(ranges: np.ndarray, params: LidarParams, rng: np.random.Generator | None) -> np.ndarray:
    """Gazebo's model: noise on beams that hit something, then clamped to [min_range, max_range]."""
    if rng is None or params.noise_std == 0:
        return ranges
    hit = ranges < params.max_range
    noisy = ranges + params.noise_std * rng.standard_normal(ranges.shape, dtype=np.float32)
    return np.where(hit, np.clip(noisy, params.min_range, params.max_range), ranges).astype(np.float32)


def scan(walls: LidarWalls, poses: np.ndarray, params: LidarParams = DEFAULT_LIDAR,
         rng: np.random.Generator | None = None, parallel: bool | None = None, obstacles=None) -> np.ndarray:
    """Lidar ranges of N cars: poses (N, 3) [x, y, yaw] of the model origin -> (N, num_beams) float32 m.

    ``obstacles``: each car's K obstacles, seven (N, K) arrays x, y, yaw, half_length, half_width,
    height, kind (a ``laplab.sim.obstacles.Obstacles``); a beam stops at the nearest box's side
    (:func:`laplab.sensors.obstacle_kernel.obstacle_ranges`).

    Noise (``params.noise_std``) is drawn from ``rng`` only when one is given; ``rng=None`` gives the
    exact ranges. ``parallel``: use numba's threads (None: only for batches of 2048+ beams). Pass
    False in processes that already share the cores with other workers: threads that wait for a
    descheduled sibling stall for a whole time slice.
    """
    poses = _check_poses(poses)
    out = np.empty((poses.shape[0], int(params.num_beams)), dtype=np.float32)
    if parallel is None:
        parallel = out.size >= _PARALLEL_MIN_RAYS
    kernel = _scan_parallel if parallel else _scan_serial
    kernel(poses, params.beam_angles, params.mount_x, params.mount_y, params.min_range, params.max_range,
           walls.segments, walls.origin_x, walls.origin_y, walls.cell_size, walls.nx, walls.ny,
           walls.cell_start, walls.cell_segments, out)
    packed = obstacle_boxes(obstacles, poses.shape[0], "lidar scan")
    if packed is not None:
        obstacle_ranges(packed.boxes, packed.kind, poses, params.beam_angles, params.mount_x, params.mount_y,
                        params.min_range, out)
    return _add_noise(out, params, rng)


def scan_reference(segments: np.ndarray | LidarWalls, poses: np.ndarray, params: LidarParams = DEFAULT_LIDAR,
                   rng: np.random.Generator | None = None) -> np.ndarray:
    """Brute-force numpy :func:`scan` (every beam against every segment); for tests, not speed."""
    seg = segments.segments if isinstance(segments, LidarWalls) else np.asarray(segments, np.float64)
    poses = _check_poses(poses)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    origin = poses[:, :2] + np.stack([c * params.mount_x - s * params.mount_y,
                                      s * params.mount_x + c * params.mount_y], axis=1)
    world = poses[:, 2:3] + params.beam_angles[None, :]                     # (N, B)
    d = np.stack([np.cos(world), np.sin(world)], axis=-1)[:, :, None, :]    # (N, B, 1, 2)
    e = (seg[:, 2:4] - seg[:, 0:2])[None, None]                             # (1, 1, S, 2)
    w = seg[None, None, :, 0:2] - origin[:, None, None, :]                  # (N, 1, S, 2)
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
    valid = (denom != 0) & (u >= 0) & (u <= 1) & (t >= params.min_range) & (t <= params.max_range)
    ranges = np.where(valid, t, params.max_range).min(axis=-1).astype(np.float32)
    return _add_noise(ranges, params, rng)
