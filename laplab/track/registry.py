"""Finding tracks by name: built-ins shipped with laplab, then the user's track folder, then a path."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from laplab.settings import current_settings
from laplab.track.geometry import Track, TrackError, load_route_file, read_route_file, validate_route

BUILTIN_DIR = Path(__file__).resolve().parent / "data"
DEFAULT_TRACK = "classic_2018"


def user_track_dir() -> Path:
    """Folder of imported and fetched tracks (``$LAPLAB_HOME/tracks``, laplab/settings.py)."""
    return current_settings().tracks_dir


@dataclass(frozen=True)
class TrackEntry:
    name: str
    path: Path
    source: str  # "built-in" or "user"


def builtin_track_names() -> list[str]:
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.npy"))


def available_tracks() -> list[TrackEntry]:
    """Built-in tracks, then user tracks whose names no built-in shadows."""
    entries = [TrackEntry(p.stem, p, "built-in") for p in sorted(BUILTIN_DIR.glob("*.npy"))]
    seen = {e.name for e in entries}
    folder = user_track_dir()
    if folder.is_dir():
        entries += [TrackEntry(p.stem, p, "user") for p in sorted(folder.glob("*.npy")) if p.stem not in seen]
    return entries


def resolve_track_path(name_or_path: str | os.PathLike) -> Path:
    """Path of a track given by name (built-in, then user folder) or by a path to a ``.npy`` file."""
    text = str(name_or_path)
    for candidate in (BUILTIN_DIR / f"{text}.npy", user_track_dir() / f"{text}.npy"):
        if candidate.is_file():
            return candidate
    path = Path(text).expanduser()
    if path.is_file():
        return path
    known = ", ".join(e.name for e in available_tracks()) or "none"
    raise TrackError(f"unknown track {text!r}: not a built-in, not in {user_track_dir()}, and not a file. "
                     f"Known tracks: {known}. `laplab tracks list` shows them; `laplab tracks import` adds one.")


def load_track(name_or_path: str | os.PathLike = DEFAULT_TRACK, *, reverse: bool = False,
               remove_repeats: bool = True) -> Track:
    """Load a track by name or path; ``reverse`` drives it the other way.

    ``name@reversed`` also selects the reversed direction.
    """
    text = str(name_or_path)
    if text.endswith("@reversed"):
        text, reverse = text[: -len("@reversed")], not reverse
    track = _load_cached(str(resolve_track_path(text)), remove_repeats)
    return track.reversed() if reverse else track


@lru_cache(maxsize=64)
def _load_cached(path: str, remove_repeats: bool) -> Track:
    return load_route_file(path, remove_repeats=remove_repeats)


def import_track(path: str | os.PathLike, name: str | None = None, overwrite: bool = False) -> Path:
    """Validate a route file and copy it into the user's track folder; returns the new path."""
    path = Path(path)
    validate_route(read_route_file(path), str(path))
    name = name or path.stem
    if not name.replace("_", "").replace("-", "").isalnum():
        raise TrackError(f"track name {name!r} may hold only letters, digits, '_' and '-'.")
    if (BUILTIN_DIR / f"{name}.npy").exists():
        raise TrackError(f"track name {name!r} is a built-in track; import it under another name (--name).")
    target = user_track_dir() / f"{name}.npy"
    if target.exists() and not overwrite:
        raise TrackError(f"a user track named {name!r} already exists at {target}; pass --overwrite to replace it.")
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(".npy.tmp")
    shutil.copyfile(path, tmp)
    os.replace(tmp, target)
    _load_cached.cache_clear()
    return target
