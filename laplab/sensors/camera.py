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

Obstacles (DeepRacer's boxes and other cars, :mod:`laplab.sensors.obstacle_look`) are solid boxes
standing on the ground, painted by a second pass over the pixels they may cover
(:mod:`laplab.sensors.obstacle_kernel`); without obstacles that pass does not run.

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

from laplab.sensors.camera_kernel import SERIAL_BELOW_SAMPLES, render_kernel
from laplab.sensors.obstacle_kernel import obstacle_pass
from laplab.sensors.obstacle_look import (DEFAULT_OBSTACLE_LOOK, ObstacleBoxes, ObstacleLook, face_colours,
                                          obstacle_boxes)
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


class _Scene(NamedTuple):
    """Obstacles of a batch as the kernels take them: checked boxes and (N, K, 5, 4) face colours."""

    boxes: ObstacleBoxes
    colours: np.ndarray


def _scene(texture: TrackTexture, obstacles, n: int, look: ObstacleLook, caller: str) -> _Scene | None:
    packed = obstacle_boxes(obstacles, n, caller)
    return None if packed is None else _Scene(packed, face_colours(packed, texture.params.wall_lights, look))


def _render_into(texture: TrackTexture, poses: np.ndarray, params: CameraParams, variant: np.ndarray,
                 out: np.ndarray, plane: int | None, scene: _Scene | None = None) -> None:
    """Render into out (N, H, W) from the grey texture (plane None) or colour plane 0/1/2, then paint
    the scene's obstacles over it."""
    rays, prep = camera_rays(params), _prepare(params, texture)
    threads = numba.get_num_threads()
    # A frame or two takes tens of microseconds: waking the other threads costs more than it saves.
    small = poses.shape[0] * rays.ground_x.shape[0] < SERIAL_BELOW_SAMPLES
    if small:
        numba.set_num_threads(1)
    try:
        render_kernel(texture.gray if plane is None else texture.rgb[plane], prep.shift, prep.offset, prep.stride,
                       prep.geom, prep.walls, rays.ground_x, rays.ground_y, rays.dir_x, rays.dir_y, rays.slope,
                       prep.row_has_ground, params.supersample, params.bilinear, poses, variant, out)
        if scene is not None:
            camera = np.array([params.mount_forward, params.mount_lateral, params.mount_up, math.cos(params.pitch),
                               math.sin(params.pitch), params.focal_length])
            values = np.ascontiguousarray(scene.colours[..., 3 if plane is None else plane])
            obstacle_pass(scene.boxes.boxes, scene.boxes.kind, values, poses, camera, np.array(texture.room),
                          rays.dir_x, rays.dir_y, rays.slope, params.supersample, out)
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
                  out: np.ndarray | None = None, variant=None, obstacles=None,
                  obstacle_look: ObstacleLook = DEFAULT_OBSTACLE_LOOK) -> np.ndarray:
    """Render one camera for N cars: poses (N, 3) (x, y, yaw of the rear-axle origin, m / rad).

    Returns (N, H, W) uint8 grey or (N, H, W, 3) uint8 RGB (into ``out`` when given, which must
    be C-contiguous of that shape). ``variant`` (N,) or scalar picks each car's colour variant of
    ``texture`` (default 0). ``obstacles``: each car's K obstacles, seven (N, K) arrays x, y, yaw,
    half_length, half_width, height, kind (a ``laplab.sim.obstacles.Obstacles``), drawn as solid
    boxes in ``obstacle_look``'s colours lit by the texture's lights; None or all empty gives exactly
    the frames without them. Deterministic.
    """
    poses = _check_poses(poses)
    variant = _check_variant(variant, poses.shape[0], texture)
    out = _output(out, frame_shape(params, poses.shape[0]), "render_camera")
    scene = _scene(texture, obstacles, poses.shape[0], obstacle_look, "render_camera")
    for plane in [None] if params.grayscale else [0, 1, 2]:
        _render_into(texture, poses, params, variant, out if plane is None else out[..., plane], plane, scene)
    return out


def render_cameras(texture: TrackTexture, poses, cameras: tuple[CameraParams, ...],
                   out: np.ndarray | None = None, variant=None, obstacles=None,
                   obstacle_look: ObstacleLook = DEFAULT_OBSTACLE_LOOK) -> np.ndarray:
    """Render grey cameras as channels: (N, H, W, len(cameras)) uint8 (stereo: left, right).

    This is DeepRacer's observation layout: (N, 120, 160, 1) for one camera, (N, 120, 160, 2) stereo.
    ``obstacles`` and ``obstacle_look`` as in :func:`render_camera`.
    """
    if not cameras or not all(cam.grayscale for cam in cameras) or len({(c.width, c.height) for c in cameras}) != 1:
        raise ValueError("render_cameras: needs one or more grayscale CameraParams of one image size, got "
                         f"{[(cam.width, cam.height, 'gray' if cam.grayscale else 'rgb') for cam in cameras]}")
    poses = _check_poses(poses)
    variant = _check_variant(variant, poses.shape[0], texture)
    out = _output(out, (poses.shape[0], cameras[0].height, cameras[0].width, len(cameras)), "render_cameras")
    scene = _scene(texture, obstacles, poses.shape[0], obstacle_look, "render_cameras")
    for channel, cam in enumerate(cameras):
        _render_into(texture, poses, cam, variant, out[..., channel], None, scene)
    return out
