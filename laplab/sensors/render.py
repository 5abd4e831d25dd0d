"""Pictures for people: a top-down view of the track and cars, and a polar plot of a lidar scan.

Nothing here is an observation. Drawing uses PIL with a world -> pixel transform; the static part
of the top-down view (grass, road, borders, dashed centre line, chequered start line, driving
direction arrow) is drawn once per track at ``supersample`` x and cached, so a frame costs only
the cars, paths, camera wedges and lidar beams (well under a millisecond for a few cars).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw

from laplab.sensors.lidar import DEFAULT_LIDAR, LidarParams, track_borders
from laplab.vehicle.params import DEEPRACER, VehicleParams

CAR_COLORS = ((230, 57, 70), (29, 129, 233), (255, 183, 3), (142, 68, 173), (46, 204, 113), (255, 255, 255))


@dataclass(frozen=True)
class RenderParams:
    """Look of the top-down view. Lengths in metres, sizes in pixels, colours RGB 0-255.

    ``camera_forward`` 0.09 m: the camera's position ahead of the model origin (reference doc
    section 4); the field-of-view wedge starts there and reaches ``fov_length`` ahead.
    """

    width_px: int = 800
    margin_m: float = 0.5
    supersample: int = 2
    grass: tuple[int, int, int] = (58, 110, 62)
    road: tuple[int, int, int] = (68, 70, 76)
    border: tuple[int, int, int] = (245, 245, 245)
    centerline: tuple[int, int, int] = (236, 196, 52)
    dash_m: float = 0.15
    camera_forward: float = 0.09
    fov_length: float = 1.5
    fov_color: tuple[int, int, int, int] = (255, 255, 180, 60)
    path_width_px: int = 2
    car_colors: tuple[tuple[int, int, int], ...] = CAR_COLORS
    vehicle: VehicleParams = field(default=DEEPRACER)

    def __post_init__(self) -> None:
        if int(self.width_px) != self.width_px or self.width_px < 32:
            raise ValueError(f"RenderParams.width_px must be an integer >= 32, got {self.width_px!r}")
        if int(self.supersample) != self.supersample or self.supersample < 1:
            raise ValueError(f"RenderParams.supersample must be a positive integer, got {self.supersample!r}")
        if not (self.margin_m >= 0 and self.dash_m > 0 and self.fov_length > 0):
            raise ValueError("RenderParams needs margin_m >= 0, dash_m > 0 and fov_length > 0")


DEFAULT_RENDER = RenderParams()


def _arc_length(line: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])


def _point_at(line: np.ndarray, arc: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points of ``line`` (N, 2) at arc lengths ``s`` (...,) -> (..., 2)."""
    return np.stack([np.interp(s, arc, line[:, 0]), np.interp(s, arc, line[:, 1])], axis=-1)


def _nearest_on_polyline(point: np.ndarray, line: np.ndarray) -> np.ndarray:
    a, b = line[:-1], line[1:]
    seg = b - a
    t = np.clip(((point - a) * seg).sum(1) / np.maximum((seg * seg).sum(1), 1e-18), 0.0, 1.0)
    candidates = a + t[:, None] * seg
    return candidates[np.argmin(((candidates - point) ** 2).sum(1))]


class TopdownRenderer:
    """Top-down view of one track: ``draw(...)`` returns (H, W, 3) uint8 frames.

    ``scale`` is pixels per metre; ``to_pixels`` maps world (..., 2) m to pixel (..., 2) (y down).
    """

    def __init__(self, track, params: RenderParams = DEFAULT_RENDER, name: str | None = None):
        self.params = params
        self.centerline, self.inner, self.outer = track_borders(track)
        self.name = name if name is not None else getattr(track, "name", None)
        points = np.vstack([self.centerline, self.inner, self.outer])
        lo, hi = points.min(axis=0) - params.margin_m, points.max(axis=0) + params.margin_m
        self.scale = params.width_px / float(hi[0] - lo[0])
        self.x_min, self.y_max = float(lo[0]), float(hi[1])
        self.size = (int(params.width_px), max(int(round((hi[1] - lo[1]) * self.scale)), 1))
        self.background = self._draw_background()

    def to_pixels(self, xy: np.ndarray, factor: float = 1.0) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([(xy[..., 0] - self.x_min) * self.scale * factor,
                         (self.y_max - xy[..., 1]) * self.scale * factor], axis=-1)

    def _draw_background(self) -> Image.Image:
        p, k = self.params, self.params.supersample
        image = Image.new("RGB", (self.size[0] * k, self.size[1] * k), p.grass)
        draw = ImageDraw.Draw(image)

        def px(xy):
            return [tuple(v) for v in self.to_pixels(xy, k)]

        closed = np.allclose(self.centerline[0], self.centerline[-1])
        if closed:
            draw.polygon(px(self.outer), fill=p.road)
            draw.polygon(px(self.inner), fill=p.grass)
        else:
            draw.polygon(px(np.vstack([self.inner, self.outer[::-1]])), fill=p.road)
        line_px = max(1, round(0.03 * self.scale * k))
        for border in (self.inner, self.outer):
            draw.line(px(border), fill=p.border, width=line_px, joint="curve")
        arc = _arc_length(self.centerline)
        starts = np.arange(0.0, arc[-1] - p.dash_m, 2 * p.dash_m)
        for s0 in starts:
            s = np.linspace(s0, s0 + p.dash_m, 4)
            draw.line(px(_point_at(self.centerline, arc, s)), fill=p.centerline, width=max(1, line_px // 2))
        self._draw_start_line(draw, arc, k)
        self._draw_direction_arrow(draw, arc, k, line_px)
        return image.resize(self.size, Image.LANCZOS) if k > 1 else image

    def _draw_start_line(self, draw: ImageDraw.ImageDraw, arc: np.ndarray, k: int) -> None:
        """Chequered strip, 2 squares deep, across the road at waypoint 0."""
        start = self.centerline[0]
        a, b = _nearest_on_polyline(start, self.inner), _nearest_on_polyline(start, self.outer)
        across = b - a
        along = _point_at(self.centerline, arc, min(0.05, arc[-1])) - start
        along /= max(np.hypot(*along), 1e-12)
        n_squares = 8
        side = np.hypot(*across) / n_squares
        for row in range(2):
            for i in range(n_squares):
                corner = a + across * (i / n_squares) + along * side * (row - 1)
                quad = np.array([corner, corner + across / n_squares,
                                 corner + across / n_squares + along * side, corner + along * side])
                color = (250, 250, 250) if (i + row) % 2 == 0 else (20, 20, 20)
                draw.polygon([tuple(v) for v in self.to_pixels(quad, k)], fill=color)

    def _draw_direction_arrow(self, draw: ImageDraw.ImageDraw, arc: np.ndarray, k: int, width: int) -> None:
        """White arrow on the centre line, just past the start, pointing in the driving direction."""
        s = np.linspace(0.35, 1.0, 8) if arc[-1] > 1.5 else np.linspace(0.2, 0.6, 8) * arc[-1]
        shaft = _point_at(self.centerline, arc, s)
        tip, back = shaft[-1], shaft[-2]
        direction = (tip - back) / max(np.hypot(*(tip - back)), 1e-12)
        normal = np.array([-direction[1], direction[0]])
        head = np.array([tip + direction * 0.12, tip + normal * 0.08, tip - normal * 0.08])
        draw.line([tuple(v) for v in self.to_pixels(shaft, k)], fill=(255, 255, 255), width=2 * width)
        draw.polygon([tuple(v) for v in self.to_pixels(head, k)], fill=(255, 255, 255))

    def car_corners(self, poses: np.ndarray) -> np.ndarray:
        """(K, 4, 2) world corners of the car bodies at poses (K, 3) (model origin = rear axle)."""
        v = self.params.vehicle
        front, rear, half = v.body_length - v.rear_overhang, -v.rear_overhang, v.body_width / 2
        local = np.array([[rear, -half], [front, -half], [front, half], [rear, half]])
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        x = poses[:, 0:1] + c * local[:, 0] - s * local[:, 1]
        y = poses[:, 1:2] + s * local[:, 0] + c * local[:, 1]
        return np.stack([x, y], axis=-1)

    def draw(self, poses: np.ndarray | None = None, paths: list[np.ndarray] | None = None,
             camera_fov: float | None = 1.13, lidar_ranges: np.ndarray | None = None,
             lidar_params: LidarParams = DEFAULT_LIDAR, obstacles=None) -> np.ndarray:
        """Frame with K cars at ``poses`` (K, 3) [x, y, yaw], their ``paths`` (list of (M, 2) m),
        camera wedges of ``camera_fov`` rad (None: none) and optional ``lidar_ranges`` (K, B) m beams.
        Car i takes colour ``car_colors[i % len]``. ``obstacles`` (a
        :class:`laplab.sim.obstacles.Obstacles` of any shape) draws boxes brown, bot cars grey-blue and
        other models' cars violet, as their footprints. Returns (H, W, 3) uint8.
        """
        p = self.params
        image = self.background.copy()
        draw = ImageDraw.Draw(image, "RGBA")
        if obstacles is not None:
            self._draw_obstacles(draw, obstacles)
        poses = np.zeros((0, 3)) if poses is None else np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        colors = [p.car_colors[i % len(p.car_colors)] for i in range(max(len(poses), len(paths or ())))]
        for i, path in enumerate(paths or ()):
            path = np.asarray(path, dtype=np.float64).reshape(-1, 2)
            if len(path) >= 2:
                draw.line([tuple(v) for v in self.to_pixels(path)], fill=colors[i] + (200,),
                          width=p.path_width_px, joint="curve")
        if camera_fov is not None and len(poses):
            fan = np.linspace(-camera_fov / 2, camera_fov / 2, 9)
            for pose in poses:
                cam = pose[:2] + p.camera_forward * np.array([math.cos(pose[2]), math.sin(pose[2])])
                rim = cam + p.fov_length * np.stack([np.cos(pose[2] + fan), np.sin(pose[2] + fan)], axis=1)
                draw.polygon([tuple(v) for v in self.to_pixels(np.vstack([cam, rim]))], fill=p.fov_color)
        if lidar_ranges is not None and len(poses):
            self._draw_lidar(draw, poses, np.asarray(lidar_ranges).reshape(len(poses), -1), lidar_params)
        corners = self.to_pixels(self.car_corners(poses))
        for i, quad in enumerate(corners):
            draw.polygon([tuple(v) for v in quad], fill=colors[i], outline=(15, 15, 15))
            # Dark bar across the front quarter marks which way the car faces.
            nose = np.array([quad[1], quad[2], 0.75 * quad[2] + 0.25 * quad[3], 0.75 * quad[1] + 0.25 * quad[0]])
            draw.polygon([tuple(v) for v in nose], fill=(25, 25, 25))
        return np.asarray(image)

    def _draw_obstacles(self, draw, obstacles) -> None:
        from laplab.sim.obstacles import EMPTY
        colours = {1: (123, 97, 79), 2: (90, 110, 140), 3: (140, 80, 170)}  # box #7b614f, bot, model car
        x, y, yaw, hl, hw, kind = (np.asarray(f).reshape(-1) for f in (
            obstacles.x, obstacles.y, obstacles.yaw, obstacles.half_length, obstacles.half_width, obstacles.kind))
        for i in np.flatnonzero(kind != EMPTY):
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            local = np.array([[-hl[i], -hw[i]], [hl[i], -hw[i]], [hl[i], hw[i]], [-hl[i], hw[i]]])
            world = np.stack([x[i] + c * local[:, 0] - s * local[:, 1], y[i] + s * local[:, 0] + c * local[:, 1]], axis=1)
            draw.polygon([tuple(v) for v in self.to_pixels(world)], fill=colours.get(int(kind[i]), (120, 120, 120)),
                         outline=(20, 20, 20))

    def _draw_lidar(self, draw, poses, ranges, lidar: LidarParams) -> None:
        angles = lidar.beam_angles
        for pose, r in zip(poses, ranges):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            origin = pose[:2] + np.array([c * lidar.mount_x - s * lidar.mount_y, s * lidar.mount_x + c * lidar.mount_y])
            ends = origin + r[:, None] * np.stack([np.cos(pose[2] + angles), np.sin(pose[2] + angles)], axis=1)
            o_px, e_px = self.to_pixels(origin), self.to_pixels(ends)
            for end, hit in zip(e_px, r < lidar.max_range):
                draw.line([tuple(o_px), tuple(end)], fill=(255, 80, 80, 110 if hit else 35), width=1)
                if hit:
                    draw.ellipse([end[0] - 1.5, end[1] - 1.5, end[0] + 1.5, end[1] + 1.5], fill=(255, 60, 60, 230))


@lru_cache(maxsize=8)
def _cached_renderer(key: bytes, shape: tuple[int, int], name: str | None, params: RenderParams) -> TopdownRenderer:
    route = np.frombuffer(key, dtype=np.float64).reshape(shape)
    return TopdownRenderer(route, params, name)


def renderer_for(track, params: RenderParams = DEFAULT_RENDER) -> TopdownRenderer:
    """A :class:`TopdownRenderer` for a Track or (N, 6) route, reused while the geometry is unchanged."""
    route = np.hstack(track_borders(track))
    return _cached_renderer(route.tobytes(), route.shape, getattr(track, "name", None), params)


def draw_topdown(track, poses: np.ndarray | None = None, paths: list[np.ndarray] | None = None,
                 camera_fov: float | None = 1.13, params: RenderParams = DEFAULT_RENDER,
                 lidar_ranges: np.ndarray | None = None, lidar_params: LidarParams = DEFAULT_LIDAR,
                 obstacles=None) -> np.ndarray:
    """Top-down RGB image (H, W, 3) uint8 of a Track or (N, 6) route with cars (and ``obstacles``);
    see TopdownRenderer.draw."""
    return renderer_for(track, params).draw(poses, paths, camera_fov, lidar_ranges, lidar_params, obstacles)


def draw_lidar_polar(ranges: np.ndarray, angles: np.ndarray | None = None, size: int = 240,
                     display_range: float = 3.0, max_range: float = DEFAULT_LIDAR.max_range,
                     rings: tuple[float, ...] = (0.5, 1.0, 2.0), sectors: int = 8) -> np.ndarray:
    """Polar plot of one scan, car at the centre facing up: (size, size, 3) uint8.

    ranges (B,) m at ``angles`` (B,) rad in the car frame (default: DeepRacer's 64 beams). Beams out
    to ``display_range`` m fill the radius; longer ones end at the edge, and misses (>= ``max_range``)
    are drawn faint. Grey circles at ``rings`` m; dotted lines mark the ``sectors`` lidar sectors.
    """
    ranges = np.asarray(ranges, dtype=np.float64).reshape(-1)
    angles = DEFAULT_LIDAR.beam_angles if angles is None else np.asarray(angles, dtype=np.float64).reshape(-1)
    if ranges.shape != angles.shape:
        raise ValueError(f"draw_lidar_polar: ranges {ranges.shape} and angles {angles.shape} must match")
    image = Image.new("RGB", (size, size), (18, 20, 26))
    draw = ImageDraw.Draw(image, "RGBA")
    centre, radius = size / 2, size / 2 - 4
    scale = radius / display_range

    def at(r, a):  # front (angle 0) up, left (positive angle) to the left
        return centre - np.sin(a) * r * scale, centre - np.cos(a) * r * scale

    for ring in rings:
        if ring <= display_range:
            d = ring * scale
            draw.ellipse([centre - d, centre - d, centre + d, centre + d], outline=(90, 95, 105))
    if sectors and len(angles) % sectors == 0:
        per = len(angles) // sectors
        edges = [angles[0]] + [(angles[i * per - 1] + angles[i * per]) / 2 for i in range(1, sectors)] + [angles[-1]]
        for a in edges:
            for r in np.linspace(0.1, display_range, 12):
                x, y = at(r, a)
                draw.point((x, y), fill=(120, 125, 140))
    for r, a in zip(ranges, angles):
        hit = r < max_range
        x, y = at(min(r, display_range), a)
        draw.line([(centre, centre), (x, y)], fill=(255, 90, 90, 170 if hit else 40), width=1)
        if hit and r <= display_range:
            draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=(255, 70, 70))
    draw.polygon([(centre, centre - 8), (centre - 5, centre + 6), (centre + 5, centre + 6)], fill=(240, 240, 240))
    for ring in rings:  # labels last, in the beamless gap behind the car
        if ring <= display_range:
            draw.text((centre + 3, centre + ring * scale - 11), f"{ring:g} m", fill=(170, 175, 185))
    return np.asarray(image)
