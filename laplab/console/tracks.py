"""Tracks for the console: the list with length and width, cached PNG pictures, outlines for the live view."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from laplab.jobs.db import laplab_home


def track_list() -> list[dict]:
    from laplab.races.catalogue import display_names
    from laplab.track.registry import available_tracks, load_track
    out, names = [], display_names()
    for entry in available_tracks():
        try:
            track = load_track(entry.name)
        except Exception:  # noqa: BLE001 - a broken user file is left out of the picker, not fatal
            continue
        out.append({"name": entry.name, "display_name": names.get(entry.name, entry.name), "source": entry.source,
                    "length_m": round(float(track.length), 2),
                    "width_m": round(float(np.median(track.road_width)), 3),
                    "picture": f"/api/tracks/{entry.name}/picture.png"})
    return out


def _known(name: str) -> None:
    from laplab.track.registry import available_tracks
    if name not in {t.name for t in available_tracks()}:
        raise FileNotFoundError(f"no track named {name!r}")


def picture(name: str) -> Path:
    """A PNG of the track (rendered once by laplab.track.plot, then cached under $LAPLAB_HOME/console)."""
    from laplab.track.registry import load_track, resolve_track_path
    _known(name)
    source = resolve_track_path(name)
    cache = laplab_home() / "console" / "tracks" / f"{source.stem}-{int(source.stat().st_mtime)}.png"
    if not cache.exists():
        from laplab.track.plot import TrackPlotStyle, plot_track
        cache.parent.mkdir(parents=True, exist_ok=True)
        temporary = cache.with_suffix(".tmp.png")
        plot_track(load_track(name), temporary, style=TrackPlotStyle(dpi=40))
        temporary.replace(cache)
    return cache


@lru_cache(maxsize=64)
def _outline(path: str, mtime: float) -> dict:
    from laplab.track.registry import load_track
    track = load_track(path)
    step = max(1, len(track.centerline) // 400)
    pick = lambda a: np.round(a[::step], 3).tolist()  # noqa: E731
    return {"name": track.name, "center": pick(track.centerline), "inner": pick(track.inner), "outer": pick(track.outer)}


def outline(name: str) -> dict:
    """Centre line and borders (m) of a track, at most ~400 points each, for drawing cars over it."""
    from laplab.track.registry import resolve_track_path
    _known(name)
    path = resolve_track_path(name)
    return _outline(str(path), path.stat().st_mtime)
