"""Race-line solver: time per track and lap times (centre line, minimum curvature, refined).

Runs every built-in track and a few real DeepRacer routes (from ../shared/reference-tracks when it
exists) with the default settings and with ``FAST_SETTINGS``. Solver times are wall-clock seconds
of one solve after a warm-up solve (numba compiles on first use).

Usage: python bench/raceline_speed.py [--reference Oval_track Spain_track ...] [--png-dir DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from laplab.track.geometry import load_route_file
from laplab.track.raceline import FAST_SETTINGS, RaceLineSettings, compute_raceline_for_track
from laplab.track.registry import builtin_track_names, load_track
from laplab.vehicle.params import DEEPRACER

REFERENCE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "reference-tracks"
DEFAULT_REFERENCE = ("Oval_track", "reInvent2019_track", "2022_reinvent_champ_ccw", "Spain_track",
                     "2022_april_pro", "Austin")


def timed(track, refine: bool, settings: RaceLineSettings):
    start = time.perf_counter()
    line = compute_raceline_for_track(track, DEEPRACER, 0.05, refine, settings)
    return line, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", nargs="*", default=list(DEFAULT_REFERENCE),
                        help="reference route names (file stems) to include")
    parser.add_argument("--png-dir", type=Path, default=None, help="write a speed-coloured plot per track here")
    args = parser.parse_args()

    tracks = [load_track(name) for name in builtin_track_names()]
    if REFERENCE_DIR.is_dir():
        tracks += [load_route_file(REFERENCE_DIR / f"{name}.npy") for name in args.reference
                   if (REFERENCE_DIR / f"{name}.npy").is_file()]
    else:
        print(f"(no reference tracks at {REFERENCE_DIR}; built-ins only)")
    timed(tracks[0], True, FAST_SETTINGS)  # compile the numba kernels

    header = (f"{'track':26s} {'length':>7s} {'points':>6s} {'centre':>7s} {'min-curv':>8s} "
              f"{'refined':>7s} {'gain':>6s} {'solve':>6s} {'fast':>7s} {'fast s':>6s} {'k max':>6s}")
    print("lap times in s (DeepRacer car, margin 0.05 m); solve = default settings, fast = FAST_SETTINGS")
    print(header)
    print("-" * len(header))
    for track in tracks:
        curvature_only, _ = timed(track, False, RaceLineSettings())
        line, seconds = timed(track, True, RaceLineSettings())
        fast, fast_seconds = timed(track, True, FAST_SETTINGS)
        gain = 100.0 * (1.0 - line.lap_time / line.centerline_lap_time)
        print(f"{track.name:26s} {track.length:7.2f} {len(line.points) - 1:6d} {line.centerline_lap_time:7.3f} "
              f"{curvature_only.lap_time:8.3f} {line.lap_time:7.3f} {gain:5.1f}% {seconds:6.2f} "
              f"{fast.lap_time:7.3f} {fast_seconds:6.2f} {abs(line.curvature).max():6.2f}")
        if args.png_dir is not None:
            args.png_dir.mkdir(parents=True, exist_ok=True)
            line.plot_png(args.png_dir / f"{track.name}.png", track.inner, track.outer, track.centerline,
                          title=f"{track.name}: {line.lap_time:.2f} s (centre line {line.centerline_lap_time:.2f} s)")


if __name__ == "__main__":
    main()
