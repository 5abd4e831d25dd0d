"""Top-down texture of a track, sampled by the camera renderer.

The track (centre line and borders, metres) is rasterised once into a class map on a square texel
grid (``TextureParams.texel_size`` m per texel), coloured like a DeepRacer mat and stored with its
mip levels (2x2 box averages) so far-away ground can be sampled without aliasing. The room around
the track is a rectangle ``margin`` metres beyond the track's bounding box: its floor is carpet,
its four walls carry a panelled texture, and above the walls is a plain sky colour.

Texel (i, j) of level 0 covers world x in ``[x0 + i*t, x0 + (i+1)*t)`` and y in
``[y0 + j*t, y0 + (j+1)*t)`` with ``t = texel_size``; level L texels are ``2**L`` level-0 texels wide
and share the same origin, so the level-L index of a point is the level-0 index shifted right by L.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from laplab.sensors.raster import BORDER, CENTER, FLOOR, ROAD, rasterise_track_coverage, route_arrays  # noqa: F401
from laplab.sensors.walls import paint_walls

MIN_MIP_SIZE = 4  # stop building mip levels when a side would drop below this many texels


def luma601(rgb) -> np.ndarray:
    """ITU-R BT.601 grey level of RGB uint8 values ``(..., 3)`` -> ``(...)`` uint8 (rounded)."""
    rgb = np.asarray(rgb, dtype=np.int64)
    return ((299 * rgb[..., 0] + 587 * rgb[..., 1] + 114 * rgb[..., 2] + 500) // 1000).astype(np.uint8)


@dataclass(frozen=True)
class TexturePalette:
    """Colours (RGB uint8 triples) of the track, floor, walls and sky.

    The defaults imitate the DeepRacer simulator: a near-black asphalt mat, white border tape, a
    yellow dashed centre line, a grey-green carpet around it, light grey wall panels and a pale sky.
    ``grain`` is the standard deviation (grey levels) of fixed per-texel noise on the road, and on the
    floor unless ``floor_grain`` is given; ``border_grain`` and ``center_grain`` add noise to the tape.
    """

    road: tuple[int, int, int] = (40, 40, 43)
    border: tuple[int, int, int] = (236, 236, 236)
    center: tuple[int, int, int] = (238, 192, 40)
    floor: tuple[int, int, int] = (112, 124, 100)
    wall: tuple[int, int, int] = (176, 176, 181)
    wall_seam: tuple[int, int, int] = (118, 118, 124)
    skirting: tuple[int, int, int] = (84, 84, 88)
    sky: tuple[int, int, int] = (206, 215, 226)
    grain: float = 2.0
    floor_grain: float | None = None
    border_grain: float = 0.0
    center_grain: float = 0.0

    def __post_init__(self) -> None:
        for name in ("road", "border", "center", "floor", "wall", "wall_seam", "skirting", "sky"):
            value = getattr(self, name)
            if len(value) != 3 or not all(isinstance(v, (int, np.integer)) and 0 <= v <= 255 for v in value):
                raise ValueError(f"TexturePalette.{name} must be three integers in 0..255 (RGB), got {value!r}")
        for name in ("grain", "floor_grain", "border_grain", "center_grain"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TexturePalette.{name} must be a finite number >= 0, got {value!r}")

    def grains(self) -> np.ndarray:
        """(4,) float32 grain of FLOOR, ROAD, BORDER and CENTER texels."""
        floor = self.grain if self.floor_grain is None else self.floor_grain
        return np.array([floor, self.grain, self.border_grain, self.center_grain], dtype=np.float32)


@dataclass(frozen=True)
class TextureParams:
    """How a track is painted (all lengths in metres).

    ``border_line_width`` white tape lies inside the road along both borders; the centre line is
    ``center_line_width`` wide, ``dash_length`` on / ``dash_gap`` off along the centre line's arc
    length, a dash starting ``dash_offset`` m from its first point. Walls are ``wall_height`` high with
    a dark seam every ``panel_width`` and a skirting board ``skirting_height`` high. Each texel's colour mixes the classes over ``antialias`` x ``antialias``
    sample points (smooth tape edges; 1 = one sample at the texel centre). ``seed`` fixes the grain.
    ``room`` (x_min, y_min, x_max, y_max), m, places the walls (it must hold the track); None puts them
    ``margin`` beyond the track's bounding box. With ``wall_lights`` (a tuple of
    :class:`laplab.sensors.walls.Light`) the walls are plain ``palette.wall`` shaded by those lights, as
    in DeepRacer's worlds; without, laplab's panelled walls.
    """

    texel_size: float = 0.005
    margin: float = 1.5
    border_line_width: float = 0.05
    center_line_width: float = 0.04
    dash_length: float = 0.15
    dash_gap: float = 0.15
    dash_offset: float = 0.0
    wall_height: float = 0.8
    wall_texel_size: float = 0.02
    panel_width: float = 1.2
    seam_width: float = 0.04
    skirting_height: float = 0.06
    antialias: int = 4
    seed: int = 0
    palette: TexturePalette = field(default_factory=TexturePalette)
    room: tuple[float, float, float, float] | None = None
    wall_lights: tuple = ()

    def __post_init__(self) -> None:
        for name in ("texel_size", "margin", "border_line_width", "center_line_width", "dash_length",
                     "wall_height", "wall_texel_size", "panel_width"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"TextureParams.{name} must be a positive number of metres, got {value!r}")
        if not (isinstance(self.antialias, int) and 1 <= self.antialias <= 15):
            raise ValueError(f"TextureParams.antialias must be an integer in 1..15, got {self.antialias!r}")
        for name in ("dash_gap", "dash_offset", "seam_width", "skirting_height"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"TextureParams.{name} must be a number of metres >= 0, got {value!r}")
        if self.room is not None and not (len(self.room) == 4 and all(math.isfinite(v) for v in self.room)
                                          and self.room[0] < self.room[2] and self.room[1] < self.room[3]):
            raise ValueError(f"TextureParams.room must be (x_min, y_min, x_max, y_max) in m with min < max, "
                             f"got {self.room!r}")


@dataclass(frozen=True, eq=False)
class TrackTexture:
    """A rasterised track with ``V`` colour variants (variant 0 = the palette of the params).

    Every texel the camera can read lives in one flat array per variant, T texels long:
      [0, wall_offset): the ground's mip levels, level L at ``level_offset[L]``, row-major with
        ``level_width[L]`` texels per row (row j = y index j).
      [wall_offset, sky_index): the walls unrolled along the room's perimeter, ``wall_rows`` x
        ``wall_cols`` texels of ``wall_texel_size`` m (row 0 at the floor; perimeter from the room's
        (x_min, y_min) corner counter-clockwise).
      sky_index: one texel, the colour above the walls.
    gray (V, T) uint8 holds ITU-R 601 grey; rgb (3, V, T) uint8 one plane per colour channel (built on
    first use: three times the memory of gray, needed only by RGB cameras).
    coverage (height, width, 4) uint8 counts, per level-0 texel, the sample points (of
    ``params.antialias ** 2``) on FLOOR, ROAD, BORDER and CENTER; ground colours mix by it.
    The room is the texture's extent: x in [x0, x0 + width * texel_size], likewise y.
    """

    x0: float
    y0: float
    texel_size: float
    width: int
    height: int
    level_offset: np.ndarray
    level_width: np.ndarray
    level_height: np.ndarray
    wall_offset: int
    wall_rows: int
    wall_cols: int
    wall_texel_size: float
    wall_height: float
    sky_index: int
    gray: np.ndarray
    coverage: np.ndarray
    params: TextureParams
    palettes: tuple[TexturePalette, ...]

    @property
    def classes(self) -> np.ndarray:
        """(height, width) uint8 class of each level-0 texel: the class covering most of it."""
        return np.argmax(self.coverage, axis=-1).astype(np.uint8)

    @cached_property
    def rgb(self) -> np.ndarray:
        variants = [_texel_planes(self.coverage, self.params, palette, self.params.seed + index, self.room)[0]
                    for index, palette in enumerate(self.palettes)]
        return np.ascontiguousarray(np.array(variants, dtype=np.uint8).transpose(1, 0, 2))

    @property
    def num_variants(self) -> int:
        return int(self.gray.shape[0])

    @property
    def num_levels(self) -> int:
        return int(self.level_offset.shape[0])

    @property
    def room(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the room, m."""
        return (self.x0, self.y0, self.x0 + self.width * self.texel_size, self.y0 + self.height * self.texel_size)

    def _image(self, start: int, rows: int, cols: int, variant: int, grayscale: bool) -> np.ndarray:
        if grayscale:
            return self.gray[variant, start:start + rows * cols].reshape(rows, cols)
        return np.ascontiguousarray(self.rgb[:, variant, start:start + rows * cols].T.reshape(rows, cols, 3))

    def level_image(self, level: int = 0, variant: int = 0, grayscale: bool = False) -> np.ndarray:
        """Top-down image of one mip level: (h, w, 3) RGB or (h, w) grey uint8; row j is y index j."""
        return self._image(int(self.level_offset[level]), int(self.level_height[level]),
                           int(self.level_width[level]), variant, grayscale)

    def wall_image(self, variant: int = 0, grayscale: bool = False) -> np.ndarray:
        """The unrolled walls, (wall_rows, wall_cols, 3) RGB or (wall_rows, wall_cols) grey; row 0 at the floor."""
        return self._image(self.wall_offset, self.wall_rows, self.wall_cols, variant, grayscale)


@njit(cache=True)
def _mix_plane(coverage, lut, noise, grain):
    """(height, width) uint8: the coverage-weighted mean of lut (4,) plus noise times the
    coverage-weighted grain (4,) of the classes."""
    height, width = coverage.shape[0], coverage.shape[1]
    total = np.float32(coverage[0, 0, 0] + coverage[0, 0, 1] + coverage[0, 0, 2] + coverage[0, 0, 3])
    plane = np.empty((height, width), dtype=np.uint8)
    for row in range(height):
        for col in range(width):
            cover = coverage[row, col]
            value = (cover[0] * lut[0] + cover[1] * lut[1] + cover[2] * lut[2] + cover[3] * lut[3]) / total
            value += noise[row, col] * (cover[0] * grain[0] + cover[1] * grain[1] + cover[2] * grain[2]
                                        + cover[3] * grain[3]) / total
            plane[row, col] = np.uint8(min(max(value + np.float32(0.5), np.float32(0.0)), np.float32(255.0)))
    return plane


def _box_halve(image: np.ndarray) -> np.ndarray:
    """2x2 box average (rounded) of an (h, w, ...) uint8 image, edge-padded to even size."""
    h, w = image.shape[:2]
    padded = np.pad(image, ((0, h % 2), (0, w % 2)) + ((0, 0),) * (image.ndim - 2), mode="edge").astype(np.uint16)
    total = padded[0::2, 0::2] + padded[1::2, 0::2] + padded[0::2, 1::2] + padded[1::2, 1::2]
    return ((total + 2) // 4).astype(np.uint8)


def _mip_chain(image: np.ndarray) -> list[np.ndarray]:
    levels = [image]
    while min(levels[-1].shape[:2]) // 2 >= MIN_MIP_SIZE:
        levels.append(_box_halve(levels[-1]))
    return levels


def _ground_channels(coverage: np.ndarray, palette: TexturePalette, seed: int) -> list[np.ndarray]:
    """R, G, B (height, width) uint8 planes of the ground: palette colours mixed by coverage, plus
    grain on road and floor."""
    grains = palette.grains()
    noise = np.random.default_rng(seed).standard_normal(coverage.shape[:2], dtype=np.float32) \
        if grains.any() else np.zeros(coverage.shape[:2], dtype=np.float32)
    lut = np.array([palette.floor, palette.road, palette.border, palette.center], dtype=np.float32)
    return [_mix_plane(coverage, np.ascontiguousarray(lut[:, channel]), noise, grains) for channel in range(3)]


@njit(cache=True)
def _luma_planes(red, green, blue):
    """ITU-R BT.601 grey (rounded) of three uint8 planes, as :func:`luma601`."""
    grey = np.empty(red.shape, dtype=np.uint8)
    for row in range(red.shape[0]):
        for col in range(red.shape[1]):
            grey[row, col] = (299 * np.int32(red[row, col]) + 587 * np.int32(green[row, col])
                              + 114 * np.int32(blue[row, col]) + 500) // 1000
    return grey


def _texel_planes(coverage: np.ndarray, params: TextureParams, palette: TexturePalette, seed: int,
                  room: tuple[float, float, float, float]) -> tuple[list[np.ndarray], np.ndarray]:
    """The R, G, B flat texel arrays (ground mip levels, walls, sky) of one palette, and the
    (L, 2) rows / columns of the ground levels."""
    ground = _ground_channels(coverage, palette, seed)
    perimeter = 2.0 * ((room[2] - room[0]) + (room[3] - room[1]))
    wall = paint_walls(params, palette, perimeter, room)
    planes = []
    for channel in range(3):
        levels = _mip_chain(ground[channel])
        planes.append(np.concatenate([level.reshape(-1) for level in levels]
                                     + [wall[..., channel].reshape(-1), np.array([palette.sky[channel]], np.uint8)]))
    return planes, np.array([level.shape for level in levels], dtype=np.int64)


def _grey_texels(coverage: np.ndarray, params: TextureParams, palette: TexturePalette, seed: int,
                 room: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Flat grey texels of one palette: mip levels of the ITU-R 601 luma, then walls, then the sky."""
    ground = _luma_planes(*_ground_channels(coverage, palette, seed))
    levels = _mip_chain(ground)
    perimeter = 2.0 * ((room[2] - room[0]) + (room[3] - room[1]))
    wall = luma601(paint_walls(params, palette, perimeter, room))
    sky = luma601(np.array(palette.sky))
    flat = np.concatenate([level.reshape(-1) for level in levels] + [wall.reshape(-1), sky.reshape(1)])
    return flat, np.array([level.shape for level in levels], dtype=np.int64), wall.shape


def build_track_texture(track, params: TextureParams = TextureParams(),
                        extra_palettes: tuple[TexturePalette, ...] = ()) -> TrackTexture:
    """Rasterise ``track`` (a Track or an (N, 6) route) into a :class:`TrackTexture`.

    Variant 0 uses ``params.palette``; each of ``extra_palettes`` adds a variant with the same
    geometry (for domain randomisation). About 0.3 s for reinvent_base at 5 mm texels; the RGB
    planes are only built when first used.
    """
    if not isinstance(params, TextureParams):
        raise TypeError(f"build_track_texture: params must be a TextureParams, got {type(params).__name__}")
    coverage, x0, y0 = rasterise_track_coverage(track, params)
    height, width = coverage.shape[:2]
    room = (x0, y0, x0 + width * params.texel_size, y0 + height * params.texel_size)
    palettes = (params.palette,) + tuple(extra_palettes)
    grey = [_grey_texels(coverage, params, palette, params.seed + index, room)
            for index, palette in enumerate(palettes)]
    sizes, (wall_rows, wall_cols) = grey[0][1], grey[0][2]
    texels = sizes[:, 0] * sizes[:, 1]
    wall_offset = int(texels.sum())
    if wall_offset + wall_rows * wall_cols + 1 >= 2**31:
        raise ValueError(f"texture: {wall_offset} texels do not fit 32-bit indices; raise TextureParams.texel_size")
    return TrackTexture(
        x0=x0, y0=y0, texel_size=float(params.texel_size), width=int(width), height=int(height),
        level_offset=np.concatenate([[0], np.cumsum(texels)[:-1]]).astype(np.int64),
        level_width=np.ascontiguousarray(sizes[:, 1]), level_height=np.ascontiguousarray(sizes[:, 0]),
        wall_offset=wall_offset, wall_rows=int(wall_rows), wall_cols=int(wall_cols),
        wall_texel_size=float(params.wall_texel_size), wall_height=float(wall_rows * params.wall_texel_size),
        sky_index=wall_offset + int(wall_rows * wall_cols), gray=np.stack([flat for flat, _, _ in grey]),
        coverage=coverage, params=params, palettes=palettes)
