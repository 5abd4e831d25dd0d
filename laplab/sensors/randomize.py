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
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from laplab.sensors.camera import CameraParams, FRONT_FACING_CAMERA, render_camera
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

    floors = [(112, 124, 100), (120, 120, 118), (96, 112, 82), (126, 110, 92), (88, 96, 110), (150, 150, 140)]
    palettes = []
    for _ in range(count):
        palettes.append(TexturePalette(
            road=jitter(base.road, 18), border=jitter(base.border, 15), center=jitter(base.center, 20),
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


def apply_photometric(frames: np.ndarray, draw: FrameRandomization, rng: np.random.Generator) -> np.ndarray:
    """Pitch shift, blur, brightness / contrast / gamma and noise on (N, H, W[, C]) uint8 frames.

    Returns a new uint8 array of the same shape; noise is drawn from ``rng``.
    """
    n, height = frames.shape[0], frames.shape[1]
    lead = (n,) + (1,) * (frames.ndim - 1)
    rows = np.clip(np.arange(height)[None, :] + draw.row_shift[:, None], 0, height - 1)
    image = frames[np.arange(n)[:, None], rows].astype(np.float32)  # edge rows repeat at the border
    if np.any(draw.blur > 0):
        padded = np.pad(image, ((0, 0), (1, 1), (1, 1)) + ((0, 0),) * (frames.ndim - 3), mode="edge")
        box = sum(padded[:, i:i + height, j:j + frames.shape[2]] for i in range(3) for j in range(3)) / 9.0
        image += draw.blur.reshape(lead).astype(np.float32) * (box - image)
    x = np.clip(image / 255.0, 0.0, 1.0)
    x = np.clip((x - 0.5) * draw.contrast.reshape(lead) + 0.5 + draw.brightness.reshape(lead) / 255.0, 0.0, 1.0)
    image = 255.0 * x ** draw.gamma.reshape(lead)
    if np.any(draw.noise > 0):
        image += rng.standard_normal(image.shape, dtype=np.float32) * draw.noise.reshape(lead).astype(np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def is_identity(draw: FrameRandomization) -> bool:
    """True when ``draw`` changes nothing (what a disabled randomisation draws)."""
    return bool(np.all(draw.brightness == 0) and np.all(draw.contrast == 1) and np.all(draw.gamma == 1)
                and np.all(draw.noise == 0) and np.all(draw.blur == 0) and np.all(draw.row_shift == 0)
                and np.all(draw.offset_x == 0) and np.all(draw.offset_y == 0) and np.all(draw.yaw == 0))


def render_randomized(texture: TrackTexture, poses, camera: CameraParams, draw: FrameRandomization,
                      rng: np.random.Generator) -> np.ndarray:
    """:func:`render_camera` with the changes of ``draw``: (N, H, W) or (N, H, W, 3) uint8."""
    frames = render_camera(texture, jitter_poses(poses, draw), camera, variant=draw.variant)
    return frames if is_identity(draw) else apply_photometric(frames, draw, rng)
