"""Domain randomisation of camera frames (off by default), batched over cars and seedable.

Three kinds of change, each drawn per car from a ``numpy.random.Generator``:
- scene: colour variants of road, floor and walls (texture variants built once with
  :func:`build_randomized_texture`, chosen per car);
- camera pose: small jitter of the camera's position and yaw (applied to the pose before rendering)
  and pitch (applied as a vertical image shift of ``focal_length * pitch`` rows);
- photometric: brightness, contrast, gamma, Gaussian blur-like 3x3 smoothing and pixel noise.

Typical use: draw a :class:`FrameRandomization` per episode with :func:`sample_randomization` and
pass it to :func:`render_randomized` every step (pixel noise is redrawn each call from ``rng``).
With ``RandomizationParams(enabled=False)`` (the default) every draw is the identity and
:func:`render_randomized` returns exactly what :func:`render_camera` returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from laplab.sensors.camera import FRONT_FACING_CAMERA, CameraParams, render_camera, render_cameras
from laplab.sensors.texture import TextureParams, TexturePalette, TrackTexture, build_track_texture


@dataclass(frozen=True)
class RandomizationParams:
    """Ranges of the random changes (grey levels are 0..255).

    brightness: max additive shift, grey levels (uniform in +-brightness).
    contrast: max relative contrast change (factor uniform in 1 +- contrast, around mid-grey).
    gamma: gamma drawn log-uniform in [1 / (1 + gamma), 1 + gamma].
    noise: max standard deviation of per-pixel Gaussian noise, grey levels (drawn per car).
    blur: max weight of a 3x3 box blur blended into the frame (0 = sharp, 1 = fully blurred).
    position_jitter: std of the camera's x / y offset, m.  yaw_jitter_deg, pitch_jitter_deg: std, deg.
    texture_variants: extra colour variants of the scene built by :func:`build_randomized_texture`.
    """

    enabled: bool = False
    brightness: float = 25.0
    contrast: float = 0.25
    gamma: float = 0.3
    noise: float = 6.0
    blur: float = 0.8
    position_jitter: float = 0.01
    yaw_jitter_deg: float = 1.0
    pitch_jitter_deg: float = 1.0
    texture_variants: int = 4

    def __post_init__(self) -> None:
        for name in ("brightness", "contrast", "gamma", "noise", "blur", "position_jitter", "yaw_jitter_deg",
                     "pitch_jitter_deg"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"RandomizationParams.{name} must be a finite number >= 0, got {value!r}")
        if self.contrast >= 1 or self.blur > 1:
            raise ValueError(f"RandomizationParams needs contrast < 1 and blur <= 1, got contrast={self.contrast!r}, "
                             f"blur={self.blur!r}")
        if not (isinstance(self.texture_variants, int) and self.texture_variants >= 0):
            raise ValueError(f"RandomizationParams.texture_variants must be an integer >= 0, "
                             f"got {self.texture_variants!r}")


DOMAIN_RANDOMIZATION = RandomizationParams(enabled=True)
"""What ``--domain-randomization`` draws, in training (``laplab train``) and in evaluation
(``laplab evaluate``): one set of ranges, so an evaluation meets the variations a model trained on."""


class FrameRandomization(NamedTuple):
    """Per-car draws, each (N,): photometric changes, pose jitter and texture variant."""

    brightness: np.ndarray  # grey levels added
    contrast: np.ndarray    # factor around mid-grey
    gamma: np.ndarray
    noise: np.ndarray       # std, grey levels
    blur: np.ndarray        # weight of the 3x3 box blur
    offset_x: np.ndarray    # camera jitter in the car frame, m
    offset_y: np.ndarray
    yaw: np.ndarray         # rad
    row_shift: np.ndarray   # int: image content moves up by this many rows (pitch down)
    variant: np.ndarray     # int: texture variant


def random_palettes(rng: np.random.Generator, count: int, base: TexturePalette = TexturePalette()) -> tuple[TexturePalette, ...]:
    """``count`` colour variants of ``base``: darker / lighter asphalt, floors from grey to green to
    brown, tinted walls, tape that is slightly off-white, more or less grain."""
    def jitter(colour, spread):
        shade = rng.uniform(-spread, spread) + rng.uniform(-spread / 3, spread / 3, size=3)
        return tuple(int(v) for v in np.clip(np.rint(np.asarray(colour) + shade), 0, 255))

    floors = [base.floor, (112, 124, 100), (120, 120, 118), (96, 112, 82), (126, 110, 92), (88, 96, 110),
              (150, 150, 140)]
    palettes = []
    for _ in range(count):
        # replace() keeps the base's other fields (the tape's grain), so a DeepRacer look stays one.
        palettes.append(replace(
            base, road=jitter(base.road, 18), border=jitter(base.border, 15), center=jitter(base.center, 20),
            floor=jitter(floors[int(rng.integers(len(floors)))], 20), wall=jitter(base.wall, 30),
            wall_seam=jitter(base.wall_seam, 20), skirting=jitter(base.skirting, 20), sky=jitter(base.sky, 25),
            grain=float(rng.uniform(0.0, 2.0 * base.grain + 2.0))))
    return tuple(palettes)


def build_randomized_texture(track, params: TextureParams, randomization: RandomizationParams,
                             rng: np.random.Generator) -> TrackTexture:
    """A texture with variant 0 = ``params.palette`` plus ``randomization.texture_variants`` random ones
    (none when randomisation is disabled)."""
    count = randomization.texture_variants if randomization.enabled else 0
    return build_track_texture(track, params, extra_palettes=random_palettes(rng, count, params.palette))


def sample_randomization(rng: np.random.Generator, n: int, params: RandomizationParams,
                         camera: CameraParams = FRONT_FACING_CAMERA, num_variants: int = 1) -> FrameRandomization:
    """Draw the changes for ``n`` cars (the identity for every car when ``params.enabled`` is False)."""
    if not params.enabled:
        zeros = np.zeros(n)
        return FrameRandomization(zeros, np.ones(n), np.ones(n), zeros, zeros, zeros, zeros, zeros,
                                  np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64))
    log_gamma = math.log1p(params.gamma)
    pitch = rng.normal(0.0, math.radians(params.pitch_jitter_deg), n)
    return FrameRandomization(
        brightness=rng.uniform(-params.brightness, params.brightness, n),
        contrast=rng.uniform(1.0 - params.contrast, 1.0 + params.contrast, n),
        gamma=np.exp(rng.uniform(-log_gamma, log_gamma, n)),
        noise=rng.uniform(0.0, params.noise, n),
        blur=rng.uniform(0.0, params.blur, n),
        offset_x=rng.normal(0.0, params.position_jitter, n),
        offset_y=rng.normal(0.0, params.position_jitter, n),
        yaw=rng.normal(0.0, math.radians(params.yaw_jitter_deg), n),
        row_shift=np.rint(camera.focal_length * np.tan(pitch)).astype(np.int64),
        variant=rng.integers(0, max(num_variants, 1), n))


def jitter_poses(poses: np.ndarray, draw: FrameRandomization) -> np.ndarray:
    """(N, 3) poses moved by the camera jitter (offsets in the car frame, m; yaw, rad)."""
    poses = np.asarray(poses, dtype=np.float64)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack([poses[:, 0] + c * draw.offset_x - s * draw.offset_y,
                            poses[:, 1] + s * draw.offset_x + c * draw.offset_y, poses[:, 2] + draw.yaw])


NOISE_BANK_SIZE = 1 << 21  # standard normals shared by all frames, each from a random offset (a power of 2)


@lru_cache(maxsize=1)
def _noise_bank() -> np.ndarray:
    return np.random.default_rng(20240518).standard_normal(NOISE_BANK_SIZE, dtype=np.float32)


@njit(parallel=True, cache=True, fastmath=True)
def _photometric_kernel(src, chans, row_shift, blur, lut, noise, bank, bank_offset, out):
    """out[n] = noise + lut[n][blurred(src[n] shifted up by row_shift[n] rows)].

    src, out: (N, H, W * chans) uint8 (channels interleaved along the last axis).
    """
    n_cars, height, span = src.shape
    for n in prange(n_cars):
        sums = np.empty(span, dtype=np.float32)  # 3-row sums of the current row
        keep, share = np.float32(1.0 - blur[n]), np.float32(blur[n] / 9.0)
        for r in range(height):
            centre = min(max(r + row_shift[n], 0), height - 1)
            row = src[n, centre]
            if blur[n] > 0:
                above, below = src[n, max(centre - 1, 0)], src[n, min(centre + 1, height - 1)]
                for j in range(span):
                    sums[j] = np.float32(above[j]) + np.float32(row[j]) + np.float32(below[j])
            base = bank_offset[n] + r * span
            for j in range(span):
                value = np.float32(row[j])
                if blur[n] > 0:
                    left = j - chans if j >= chans else j  # the edge pixel repeats
                    right = j + chans if j + chans < span else j
                    value = keep * value + share * (sums[left] + sums[j] + sums[right])
                grey = lut[n, np.int64(value + np.float32(0.5))] + noise[n] * bank[(base + j) & (NOISE_BANK_SIZE - 1)]
                out[n, r, j] = np.uint8(min(max(grey + np.float32(0.5), np.float32(0.0)), np.float32(255.0)))


def apply_photometric(frames: np.ndarray, draw: FrameRandomization, rng: np.random.Generator) -> np.ndarray:
    """Pitch shift, blur, brightness / contrast / gamma and noise on (N, H, W[, C]) uint8 frames.

    Returns a new uint8 array of the same shape; where the noise pattern starts is drawn from ``rng``.
    """
    frames = np.ascontiguousarray(frames, dtype=np.uint8)
    n = frames.shape[0]
    levels = np.arange(256, dtype=np.float64) / 255.0
    stretched = np.clip((levels[None, :] - 0.5) * draw.contrast[:, None] + 0.5 + draw.brightness[:, None] / 255.0,
                        0.0, 1.0)
    lut = (255.0 * stretched ** draw.gamma[:, None]).astype(np.float32)
    chans = int(np.prod(frames.shape[3:], dtype=np.int64))
    flat = frames.reshape(n, frames.shape[1], -1)
    out = np.empty_like(flat)
    _photometric_kernel(flat, chans, draw.row_shift.astype(np.int64), draw.blur.astype(np.float32), lut,
                        draw.noise.astype(np.float32), _noise_bank(), rng.integers(0, NOISE_BANK_SIZE, n), out)
    return out.reshape(frames.shape)


def is_identity(draw: FrameRandomization) -> bool:
    """True when ``draw`` changes nothing (what a disabled randomisation draws)."""
    return bool(np.all(draw.brightness == 0) and np.all(draw.contrast == 1) and np.all(draw.gamma == 1)
                and np.all(draw.noise == 0) and np.all(draw.blur == 0) and np.all(draw.row_shift == 0)
                and np.all(draw.offset_x == 0) and np.all(draw.offset_y == 0) and np.all(draw.yaw == 0))


def render_randomized(texture: TrackTexture, poses, camera: CameraParams | tuple[CameraParams, ...],
                      draw: FrameRandomization, rng: np.random.Generator, obstacles=None) -> np.ndarray:
    """:func:`render_camera` (or, for a tuple of cameras, :func:`render_cameras`: stereo) with the
    changes of ``draw``: (N, H, W), (N, H, W, 3) or (N, H, W, cameras) uint8. ``obstacles`` as in
    :func:`render_camera` (they keep their colours; the photometric changes apply to them too)."""
    poses = jitter_poses(poses, draw)
    if isinstance(camera, tuple):
        frames = render_cameras(texture, poses, camera, variant=draw.variant, obstacles=obstacles)
    else:
        frames = render_camera(texture, poses, camera, variant=draw.variant, obstacles=obstacles)
    return frames if is_identity(draw) else apply_photometric(frames, draw, rng)
