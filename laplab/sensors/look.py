"""What a track looks like to the camera: DeepRacer's own world for DeepRacer's routes.

``data/camera_looks.json`` holds, for every route of DeepRacer's simulator, numbers derived from
deepracer-simapp's world, model and mesh files by ``scripts/derive_camera_looks.py``: the albedo and
texture statistics of road, border tape, centre line and field, the line widths and the centre line's
dash pattern, the walls' colour, height and rectangle, the world's lights and the background. A
:class:`CameraLook` turns one entry into :class:`TextureParams`: ground colours are the albedo times
the lights' gain on the floor (Gazebo shades the meshes' diffuse textures with no ambient term), walls
are lit texel by texel (:mod:`laplab.sensors.walls`).

Which look a track gets, by its name (``@reversed`` ignored, so an imported or fetched ``.npy`` keeps
its route's name and needs no network):
- a DeepRacer route: its own look (the room from the file when it holds the track);
- a built-in design: a look of its own in DeepRacer's style, made of one route's materials and
  lights (``DESIGN_LOOKS``) with walls around its own geometry;
- anything else: the default look (re:Invent 2018's materials) and a one-line notice naming the route.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from laplab.sensors.texture import TextureParams, TexturePalette, TrackTexture, build_track_texture, route_arrays
from laplab.sensors.walls import Light, ground_gain

LOOKS_FILE = Path(__file__).resolve().parent / "data" / "camera_looks.json"
DEFAULT_ROUTE = "reinvent_base"  # whose materials the default look and classic_2018 wear
# Built-in designs: (route whose materials and lights they wear, metres from the track to the walls).
DESIGN_LOOKS: dict[str, tuple[str, float]] = {
    "classic_2018": ("reinvent_base", 0.9),   # re:Invent 2018's mat, walls as far as on reinvent_base
    "oval": ("2022_summit_speedway", 1.5),    # the 2022 grey asphalt and olive field
    "speedway_23": ("2022_summit_speedway", 2.0),
    "technical": ("reInvent2019_track", 0.8),  # the 2019 championship mat, walls close to the track
    "grand_tour": ("2022_april_pro_ccw", 0.8),
}
MAX_ROOM_MARGIN = 5.0  # m: walls farther from the track than this are brought in (texture size)
OPEN_MARGIN = 3.0      # m: worlds without walls: field this far beyond the track, then the sky
SCENERY_HEIGHT = 2.0   # m: grandstands and buildings stand in as walls at most this high
log = logging.getLogger("laplab.camera")


@dataclass(frozen=True)
class CameraLook:
    """A track's look: ``params`` for :func:`build_track_texture`; ``source`` says where it comes
    from; ``notice`` is the one-line message of a default look (None otherwise)."""

    route: str
    source: str
    params: TextureParams
    notice: str | None = None


@lru_cache(maxsize=1)
def simapp_looks() -> dict[str, dict]:
    """The derived looks by route name (read once from ``data/camera_looks.json``)."""
    return json.loads(LOOKS_FILE.read_text(encoding="utf-8"))["routes"]


def route_name(name: str) -> str:
    return name[: -len("@reversed")] if name.endswith("@reversed") else name


def _lights(entry: dict) -> tuple[Light, ...]:
    lights = []
    for item in entry.get("lights", []):
        kind = item["type"]
        fields = {"diffuse": tuple(item["diffuse"])}
        if "direction" in item:
            fields["direction"] = tuple(item["direction"])
        if kind != "directional":
            fields["position"], fields["attenuation"] = tuple(item["position"]), tuple(item["attenuation"])
        lights.append(Light(kind, **fields))
    return tuple(lights)


def _lit(rgb, gain: np.ndarray) -> tuple[int, int, int]:
    return tuple(int(v) for v in np.clip(np.rint(np.asarray(rgb, dtype=np.float64) * gain), 0, 255))


def _extent(track) -> tuple[np.ndarray, np.ndarray]:
    points = np.vstack(route_arrays(track))
    return points.min(axis=0), points.max(axis=0)


def _room(entry: dict, low: np.ndarray, high: np.ndarray, margin: float | None) -> tuple[float, float, float, float]:
    """The walls' rectangle: the file's when it holds the track (clamped to MAX_ROOM_MARGIN), else
    ``margin`` (or the file's typical one) around the track."""
    room = (entry.get("wall") or {}).get("room")
    if margin is None and room is not None and (np.array(room[:2]) < low).all() and (np.array(room[2:]) > high).all():
        lo = np.maximum(room[:2], low - MAX_ROOM_MARGIN)
        hi = np.minimum(room[2:], high + MAX_ROOM_MARGIN)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    if margin is None:
        margin = OPEN_MARGIN if not entry.get("wall") else 1.5
    return (float(low[0] - margin), float(low[1] - margin), float(high[0] + margin), float(high[1] + margin))


def _dash_offset(entry: dict, track, reverse: bool) -> float:
    """Where a dash starts along the track's centre line; driven the other way, where one ends."""
    offset, dash, gap = entry.get("dash_offset") or 0.0, entry.get("dash_length"), entry.get("dash_gap") or 0.0
    if not dash or not reverse:
        return float(offset)
    centre = route_arrays(track)[0]
    length = float(np.linalg.norm(np.diff(centre, axis=0), axis=1).sum())
    return float((length - offset - dash) % (dash + gap))


def params_from_entry(entry: dict, track, margin: float | None = None, reverse: bool = False) -> TextureParams:
    """TextureParams of one derived look for ``track``; ``margin`` (m) overrides the file's room;
    ``reverse``: the track is the route driven the other way (its centre line runs backwards)."""
    low, high = _extent(track)
    room = _room(entry, low, high, margin)
    lights = _lights(entry) or (Light("directional", (0.8, 0.8, 0.8), (-0.5, 0.1, -0.9)),)
    gain = ground_gain(lights, room)
    mean_gain = float(gain.mean())
    road, field = entry["road"], entry.get("field") or entry["road"]
    border, center = entry["border"], entry["center"]
    wall = entry.get("wall")
    if wall is None:  # an open world: a sliver of field-coloured wall at the horizon, then the sky
        wall_rgb, wall_height, wall_lights = field["rgb"], 0.02, ()
    else:
        wall_rgb = wall["rgb"]
        wall_height = min(wall["height"], SCENERY_HEIGHT) if wall.get("scenery") else wall["height"]
        wall_lights = lights
    palette = TexturePalette(
        road=_lit(road["rgb"], gain), border=_lit(border["rgb"], gain), center=_lit(center["rgb"], gain),
        floor=_lit(field["rgb"], gain), wall=_lit(wall_rgb, gain if not wall_lights else 1.0),
        wall_seam=_lit(wall_rgb, gain), skirting=_lit(wall_rgb, gain), sky=tuple(entry["background"]),
        grain=road["std"] * mean_gain, floor_grain=field["std"] * mean_gain,
        border_grain=border["std"] * mean_gain, center_grain=center["std"] * mean_gain)
    dash, gap = entry.get("dash_length"), entry.get("dash_gap") or 0.0
    return TextureParams(border_line_width=entry["border_width"], center_line_width=entry["center_width"],
                         dash_length=dash if dash else 1.0, dash_gap=gap if dash else 0.0,
                         dash_offset=_dash_offset(entry, track, reverse),
                         wall_height=float(wall_height), palette=palette, room=room, wall_lights=wall_lights)


def look_for_track(track, name: str | None = None) -> CameraLook:
    """The look of ``track`` (a Track, or an (N, 6) route with ``name``), chosen by its route name."""
    full = name if name is not None else getattr(track, "name", "")
    name, reverse = route_name(full), full.endswith("@reversed")
    looks = simapp_looks()
    if name in DESIGN_LOOKS:
        route, margin = DESIGN_LOOKS[name]
        return CameraLook(name, f"laplab design in DeepRacer's style ({route}'s materials and lights)",
                          params_from_entry(looks[route], track, margin))
    if name in looks:
        return CameraLook(name, "deepracer-simapp", params_from_entry(looks[name], track, reverse=reverse))
    notice = (f"laplab: no DeepRacer camera look for route {name or '(unnamed)'!r}; using the default look "
              f"({DEFAULT_ROUTE}'s materials)")
    return CameraLook(name, "default", params_from_entry(looks[DEFAULT_ROUTE], track, 1.5), notice)


_announced: set[str] = set()


def announced_look(track, name: str | None = None) -> CameraLook:
    """:func:`look_for_track`, logging a default look's notice (one line on the ``laplab.camera``
    logger, once per route name and process)."""
    look = look_for_track(track, name)
    if look.notice and look.route not in _announced:
        _announced.add(look.route)
        log.warning(look.notice)
    return look


def texture_for_track(track, name: str | None = None, extra_palettes: tuple[TexturePalette, ...] = (),
                      **changes) -> TrackTexture:
    """:func:`build_track_texture` with the track's look (``changes`` override TextureParams fields);
    a default look's notice is logged (:func:`announced_look`)."""
    look = announced_look(track, name)
    params = replace(look.params, **changes) if changes else look.params
    return build_track_texture(track, params, extra_palettes=extra_palettes)
