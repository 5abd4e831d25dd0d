"""DeepRacer's official tracks by their display names ("re:Invent 2018", "Smile Speedway", "Forever
Raceway"...): the 62 of DeepRacer on AWS, each mapped to the deepracer-simapp route laplab drives
(``track_catalogue.json``). Routes are not shipped: ``laplab tracks fetch --names "Smile Speedway"``
downloads one (display names work there too); a fetched route is offered in Create model and Create
race under its display name.

A race's direction is driven on whatever route it uses: which way a route is drawn is read from its
geometry (the sign of the centre line's area), so "clockwise" is right for every route.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

CATALOGUE_FILE = Path(__file__).resolve().parent / "track_catalogue.json"


@dataclass(frozen=True)
class CatalogueTrack:
    """One official track: DeepRacer on AWS's ``id``, its display ``name``, the simapp ``world``, the
    ``route`` laplab drives and the simapp's ``variants`` of that world."""
    id: str
    name: str
    world: str
    route: str
    variants: tuple[str, ...]


@lru_cache(maxsize=1)
def catalogue() -> tuple[CatalogueTrack, ...]:
    document = json.loads(CATALOGUE_FILE.read_text(encoding="utf-8"))
    return tuple(CatalogueTrack(t["id"], t["name"], t["world"], t["route"], tuple(t["variants"]))
                 for t in document["tracks"])


def find(text: str) -> CatalogueTrack | None:
    """The track a display name, id, world or route names (case-insensitive), or None."""
    key = text.strip().lower()
    for track in catalogue():
        if key in (track.name.lower(), track.id.lower(), track.world.lower(), track.route.lower()) or \
                key in (v.lower() for v in track.variants):
            return track
    return None


def display_names() -> dict[str, str]:
    """Route name -> display name, for every route of the catalogue (variants included)."""
    out = {}
    for track in catalogue():
        for route in (track.route, *track.variants):
            suffix = " (clockwise)" if route.endswith("_cw") else " (counterclockwise)" if route.endswith("_ccw") \
                and route != track.route else ""
            out[route] = track.name + suffix
    return out


def route_names(names: list[str]) -> list[str]:
    """``laplab tracks fetch --names``: display names become their routes; route names stay."""
    out = []
    for name in names:
        found = find(name)
        out.append(found.route if found is not None and name not in found.variants else name)
    return out


def drawn_counterclockwise(centerline: np.ndarray) -> bool:
    """Whether a closed centre line ``(N, 2)`` (m) runs counterclockwise (positive shoelace area)."""
    x, y = centerline[:, 0], centerline[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)) > 0.0


def track_key(track: str, direction: str) -> str:
    """The evaluation's track argument that drives ``track`` in ``direction`` (``counterclockwise`` or
    ``clockwise``): the name, or ``name@reversed`` when the route is drawn the other way."""
    from laplab.track.registry import load_track
    forward = drawn_counterclockwise(np.asarray(load_track(track).centerline))
    return track if forward == (direction == "counterclockwise") else f"{track}@reversed"
