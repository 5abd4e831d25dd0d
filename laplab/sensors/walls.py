"""The room's walls as the camera sees them, and the lights of a DeepRacer world.

Two wall styles, both unrolled along the room's perimeter (south, east, north, west walls,
counter-clockwise from the room's (x_min, y_min) corner; row 0 at the floor), ``wall_texel_size`` m per
texel:
- panelled (laplab's own look): light panels with seams and a skirting board;
- lit (DeepRacer's worlds): one plain colour, each texel shaded by the world's lights as Gazebo shades
  a diffuse surface whose material has no ambient term: ``colour * sum(diffuse * max(0, n . l) *
  attenuation)`` with ``n`` the wall's inward normal. A wall that no light faces is black, as in
  DeepRacer's frames.

:class:`Light` also gives the ground's gain (normal straight up), which a look multiplies into the
ground colours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Light:
    """A Gazebo light: ``kind`` "directional" (``direction`` it shines along) or "point" / "spot"
    (``position``, m, and ``attenuation`` (constant, linear, quadratic)); ``diffuse`` RGB in 0..1.
    Spot lights are treated as point lights (their cone is ignored)."""

    kind: str
    diffuse: tuple[float, float, float]
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    attenuation: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.kind not in ("directional", "point", "spot"):
            raise ValueError(f"Light.kind must be 'directional', 'point' or 'spot', got {self.kind!r}")
        for name in ("diffuse", "direction", "position", "attenuation"):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(v) for v in value):
                raise ValueError(f"Light.{name} must be three finite numbers, got {value!r}")

    def gain(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(..., 3) RGB gain of this light on surfaces at ``points`` (..., 3) with unit ``normals`` (..., 3)."""
        if self.kind == "directional":
            towards = -np.asarray(self.direction, dtype=np.float64)
            towards = towards / (np.linalg.norm(towards) or 1.0)
            cosine = np.maximum(normals @ towards, 0.0)
            scale = np.ones_like(cosine)
        else:
            offset = np.asarray(self.position, dtype=np.float64) - points
            distance = np.maximum(np.linalg.norm(offset, axis=-1), 1e-9)
            cosine = np.maximum((normals * offset).sum(-1) / distance, 0.0)
            c, l, q = self.attenuation
            scale = 1.0 / np.maximum(c + l * distance + q * distance * distance, 1e-9)
        return (cosine * scale)[..., None] * np.asarray(self.diffuse, dtype=np.float64)


def light_gain(lights: tuple[Light, ...], points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(..., 3) summed RGB gain of ``lights`` (zeros without lights)."""
    total = np.zeros(np.broadcast_shapes(points.shape, normals.shape), dtype=np.float64)
    for light in lights:
        total = total + light.gain(points, normals)
    return total


def ground_gain(lights: tuple[Light, ...], room: tuple[float, float, float, float]) -> np.ndarray:
    """(3,) RGB gain of the floor at the room's centre (the lights hang metres above it, so it barely
    changes over the room)."""
    x_lo, y_lo, x_hi, y_hi = room
    centre = np.array([0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi), 0.0])
    return light_gain(lights, centre, np.array([0.0, 0.0, 1.0]))


def perimeter_points(room: tuple[float, float, float, float], p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) and inward unit normal (nx, ny) of perimeter positions ``p`` (m from the room's
    (x_min, y_min) corner, counter-clockwise), each (P, 2)."""
    x_lo, y_lo, x_hi, y_hi = room
    span_x, span_y = x_hi - x_lo, y_hi - y_lo
    p = np.clip(p, 0.0, 2.0 * (span_x + span_y))
    south, east, north = p < span_x, (p >= span_x) & (p < span_x + span_y), \
        (p >= span_x + span_y) & (p < 2 * span_x + span_y)
    west = ~(south | east | north)
    xy = np.empty(p.shape + (2,))
    normal = np.zeros(p.shape + (2,))
    xy[south] = np.column_stack([x_lo + p[south], np.full(south.sum(), y_lo)])
    normal[south] = (0.0, 1.0)
    xy[east] = np.column_stack([np.full(east.sum(), x_hi), y_lo + p[east] - span_x])
    normal[east] = (-1.0, 0.0)
    xy[north] = np.column_stack([x_hi - (p[north] - span_x - span_y), np.full(north.sum(), y_hi)])
    normal[north] = (0.0, -1.0)
    xy[west] = np.column_stack([np.full(west.sum(), x_lo), y_hi - (p[west] - 2 * span_x - span_y)])
    normal[west] = (1.0, 0.0)
    return xy, normal


def wall_grid(params, perimeter: float) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre heights z (rows,) and perimeter positions p (cols,) of the unrolled walls, m."""
    res = params.wall_texel_size
    rows, cols = max(int(round(params.wall_height / res)), 1), max(int(math.ceil(perimeter / res)), 1)
    return (np.arange(rows) + 0.5) * res, (np.arange(cols) + 0.5) * res


def paint_walls(params, palette, perimeter: float, room: tuple[float, float, float, float]) -> np.ndarray:
    """(rows, cols, 3) uint8 RGB of the unrolled walls: lit plain walls when ``params.wall_lights`` is
    set, else laplab's panelled walls."""
    z, p = wall_grid(params, perimeter)
    base = np.array(palette.wall, dtype=np.float64)
    if params.wall_lights:
        xy, normal = perimeter_points(room, p)
        points = np.concatenate([np.broadcast_to(xy[None], (z.size,) + xy.shape),
                                 np.broadcast_to(z[:, None, None], (z.size, p.size, 1))], axis=-1)
        normals = np.concatenate([normal, np.zeros((p.size, 1))], axis=-1)[None]
        rgb = base * light_gain(params.wall_lights, points, normals)
        return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    # A gentle vertical gradient and alternating panel tones give the wall visible structure.
    shade = 1.0 + 0.10 * (z / params.wall_height - 0.5)
    panel_tone = np.where(np.floor(p / params.panel_width) % 2 == 0, 1.0, 0.94)
    rgb = base[None, None, :] * shade[:, None, None] * panel_tone[None, :, None]
    half_seam = 0.5 * params.seam_width
    seam = np.abs((p + half_seam) % params.panel_width - half_seam) < half_seam
    rgb[:, seam] = palette.wall_seam
    rgb[z < params.skirting_height] = palette.skirting
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
