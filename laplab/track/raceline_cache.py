"""Race lines solved once and kept in ``$LAPLAB_HOME/cache``, so "gap to optimal" is cheap to ask for.

A line depends on the track's arrays, the car, the margin and the solver's settings, and on the
solver itself: the cache key is a SHA-256 of all of these, the last as the source text of
:mod:`laplab.track.raceline`, :mod:`laplab.track.box_qp` and :mod:`laplab.track.speed_profile`
(a changed solver never serves stale lines). Each entry is one ``.npz`` (every :class:`RaceLine`
array and number, plus a JSON description of what it was solved for), written atomically; an
unreadable entry is solved again and replaced. Entries also stay in memory for the life of the process.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from laplab.settings import current_settings
from laplab.store.atomic import atomic_write_with
from laplab.track import box_qp as box_qp_module
from laplab.track import raceline as raceline_module
from laplab.track import speed_profile as speed_profile_module
from laplab.track.geometry import Track
from laplab.track.raceline import RaceLine, RaceLineSettings, compute_raceline_for_track
from laplab.track.registry import load_track
from laplab.track.speed_profile import standing_start_lap_time
from laplab.vehicle.params import DEEPRACER, VehicleParams

CACHE_FORMAT = 1
_ARRAYS = ("points", "speeds", "curvature", "arc_length", "times", "offsets")
_NUMBERS = ("lap_time", "centerline_lap_time", "solve_seconds")
_memory: dict[Path, RaceLine] = {}


def cache_folder() -> Path:
    """Folder of cached race lines (``$LAPLAB_HOME/cache``)."""
    return current_settings().cache_dir


@lru_cache(maxsize=1)
def _solver_fingerprint() -> bytes:
    digest = hashlib.sha256()
    for module in (raceline_module, box_qp_module, speed_profile_module):
        digest.update(Path(module.__file__).read_bytes())
    return digest.digest()


def raceline_key(track: Track, vehicle: VehicleParams = DEEPRACER, margin: float = 0.05,
                 settings: RaceLineSettings = RaceLineSettings()) -> str:
    """Hex key (32 characters) of the race line of ``track`` for this car, margin (m) and settings."""
    digest = hashlib.sha256(f"laplab-raceline-{CACHE_FORMAT}".encode())
    for array in (track.centerline, track.inner, track.outer):
        array = np.ascontiguousarray(array, dtype="<f8")
        digest.update(str(array.shape).encode())
        digest.update(array.tobytes())
    description = {"vehicle": asdict(vehicle), "margin": float(margin), "settings": asdict(settings)}
    digest.update(json.dumps(description, sort_keys=True).encode())
    digest.update(_solver_fingerprint())
    return digest.hexdigest()[:32]


def raceline_cache_path(track: Track, vehicle: VehicleParams = DEEPRACER, margin: float = 0.05,
                        settings: RaceLineSettings = RaceLineSettings()) -> Path:
    """Where the race line of these inputs is (or would be) cached."""
    name = re.sub(r"[^A-Za-z0-9_.-]+", "-", track.name).strip("-.") or "track"
    return cache_folder() / f"raceline-{name}-{raceline_key(track, vehicle, margin, settings)}.npz"


def _write(path: Path, line: RaceLine, description: dict) -> None:
    fields = {name: np.asarray(getattr(line, name)) for name in _ARRAYS + _NUMBERS}
    fields["steering_feasible"] = np.asarray(line.steering_feasible)
    fields["description"] = np.asarray(json.dumps(description, sort_keys=True))

    def write(temporary: Path) -> None:
        with open(temporary, "wb") as handle:  # a handle: np.savez would append ".npz" to a name
            np.savez(handle, **fields)

    atomic_write_with(path, write)


def _read(path: Path) -> RaceLine | None:
    """The cached line at ``path``, or None when it is missing or unreadable."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if json.loads(str(data["description"]))["key"] not in path.name:
                return None
            arrays = {name: np.array(data[name], dtype=np.float64) for name in _ARRAYS}
            numbers = {name: float(data[name]) for name in _NUMBERS}
            feasible = bool(data["steering_feasible"])
    except (OSError, KeyError, ValueError, TypeError, json.JSONDecodeError):
        return None
    lengths = {a.shape[0] for a in arrays.values()}
    if arrays["points"].ndim != 2 or arrays["points"].shape[1] != 2 or len(lengths) != 1:
        return None
    for array in arrays.values():
        array.flags.writeable = False
    return RaceLine(**arrays, **numbers, steering_feasible=feasible)


def raceline_for(track: Track | str, vehicle: VehicleParams = DEEPRACER, margin: float = 0.05,
                 settings: RaceLineSettings = RaceLineSettings()) -> RaceLine:
    """Race line of ``track`` (a Track, or a name / path for :func:`load_track`), from the cache when
    it holds one for these inputs, else solved (about 0.1-1 s) and cached. ``margin``: m kept from
    the borders beyond the car's half width."""
    if not isinstance(track, Track):
        track = load_track(track)
    path = raceline_cache_path(track, vehicle, margin, settings)
    line = _memory.get(path)
    if line is None and path.is_file():
        line = _read(path)
    if line is None:
        line = compute_raceline_for_track(track, vehicle, margin, settings=settings)
        description = {"format": CACHE_FORMAT, "key": raceline_key(track, vehicle, margin, settings),
                       "track": track.name, "track_source": track.source, "vehicle": asdict(vehicle),
                       "margin": float(margin), "settings": asdict(settings)}
        _write(path, line, description)
    _memory[path] = line
    return line


def optimal_lap_time(track: Track | str, vehicle: VehicleParams = DEEPRACER) -> float:
    """Lap time (s) of the race line of ``track`` with the default margin and settings (cached):
    the yardstick for "gap to optimal"."""
    return raceline_for(track, vehicle).lap_time


def standing_start_optimal_lap_time(track: Track | str, vehicle: VehicleParams = DEEPRACER) -> float:
    """Lap time (s) of the race line driven from rest at its first point: the fastest possible lap
    that starts at rest, the yardstick for a trial that does (the race line's own lap is flying)."""
    line = raceline_for(track, vehicle)
    return standing_start_lap_time(line.arc_length, line.speeds, vehicle.max_acceleration)


def clear_memory_cache() -> None:
    """Forget the lines held in memory (the files stay)."""
    _memory.clear()
