"""The optimal lap time of a track (its race line's), cached so evaluations and the leaderboard
do not solve the race line again.

Cache files: ``$LAPLAB_HOME/cache/raceline-<track>-<key>.json`` where ``key`` hashes the route
driven (its arrays, in driving order, so each direction has its own entry), the vehicle parameters
and the race-line settings. Each holds ``{"lap_time", "track", "length", "key", ...}``.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict
from pathlib import Path

import numpy as np

from laplab.store.atomic import atomic_write_json, read_json
from laplab.track.geometry import Track
from laplab.track.registry import laplab_home
from laplab.vehicle.params import DEEPRACER, VehicleParams

CACHE_VERSION = 1
RACE_LINE_MARGIN = 0.05  # m kept between the car's body and a border (compute_raceline_for_track's default)


def cache_dir() -> Path:
    """``$LAPLAB_HOME/cache`` (not created here)."""
    return laplab_home() / "cache"


def cache_key(track: Track, vehicle: VehicleParams = DEEPRACER) -> str:
    """Hex digest naming the (route, vehicle, solver) combination."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(track.route(), dtype=np.float64).tobytes())
    digest.update(json.dumps({"vehicle": asdict(vehicle), "margin": RACE_LINE_MARGIN, "version": CACHE_VERSION},
                             sort_keys=True).encode())
    return digest.hexdigest()[:20]


def cache_path(track: Track, vehicle: VehicleParams = DEEPRACER) -> Path:
    safe_name = re.sub(r"[^A-Za-z0-9_.-]+", "_", track.name)[:60] or "track"
    return cache_dir() / f"raceline-{safe_name}-{cache_key(track, vehicle)}.json"


def optimal_lap_time(track: Track, vehicle: VehicleParams = DEEPRACER) -> float:
    """The race line's lap time on ``track`` for ``vehicle``, s: read from the cache, else solved
    (about half a second) and cached."""
    path = cache_path(track, vehicle)
    try:
        cached = read_json(path)
        if isinstance(cached, dict) and cached.get("key") == cache_key(track, vehicle):
            return float(cached["lap_time"])
    except (OSError, ValueError, KeyError, TypeError):
        pass  # missing or unreadable: solve again and rewrite it
    from laplab.track.raceline import compute_raceline_for_track
    line = compute_raceline_for_track(track, vehicle, margin=RACE_LINE_MARGIN)
    lap_time = float(line.lap_time)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"lap_time": lap_time, "track": track.name, "length": track.length,
                             "direction": track.direction, "centerline_lap_time": float(line.centerline_lap_time),
                             "key": cache_key(track, vehicle), "version": CACHE_VERSION})
    return lap_time
