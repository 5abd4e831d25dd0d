"""``laplab raceline``: the optimal race line of a track, its lap time and files a reward function can load.

The line comes from the cache in ``$LAPLAB_HOME/cache`` when it was solved before. ``--drive`` drives
it in the simulator with :class:`laplab.sim.line_follower.LineFollower` to show the lap time is real.
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import numpy as np

from laplab.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "raceline", help="optimal race line of a track: lap time, .npy/.csv waypoints and a plot",
        description="Solve (or load from the cache) the fastest line round a track for the simulated car. "
                    "Prints its lap time next to the centre line's and writes <track>-raceline.npy ((M, 2) "
                    "waypoints x, y in m, first row == last row), .csv (x, y, speed) and .png (coloured by "
                    "speed).")
    parser.add_argument("track", metavar="TRACK", help="track name (laplab tracks list), name@reversed, or .npy path")
    parser.add_argument("--physics", "--vehicle", dest="physics", default="6", metavar="V",
                        help="DeepRacer's car: 4, 5 or 6 (default 6, DeepRacer on AWS's) or classic (laplab's "
                             "car before them)")
    parser.add_argument("--margin", type=float, default=0.05,
                        help="distance kept from where the car would be off the track (DeepRacer's rule: no wheel "
                             "on the road), m (default 0.05)")
    parser.add_argument("--out", type=Path, default=Path("."), help="folder for the files (default: current)")
    parser.add_argument("--fast", action="store_true", help="quicker, coarser solve (0.2 m spacing, fewer iterations)")
    parser.add_argument("--drive", action="store_true",
                        help="drive the line in the simulator and compare the lap time with the prediction")
    parser.set_defaults(func=raceline_command)


def output_stem(track_name: str) -> str:
    """File-name stem for a track's outputs (``classic_2018@reversed`` -> ``classic_2018-reversed``)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", track_name).strip("-.") or "track"


def raceline_command(args: argparse.Namespace) -> int:
    from laplab.sim.line_follower import drive_line
    from laplab.track.speed_profile import standing_start_lap_time
    from laplab.sim.state import LAP_COMPLETE, STATUS_NAMES
    from laplab.track.raceline import FAST_SETTINGS, RaceLineSettings
    from laplab.track.raceline_cache import raceline_cache_path, raceline_for
    from laplab.track.registry import load_track
    from laplab.vehicle.params import vehicle_preset
    from laplab.vehicle.physics import PhysicsError, resolve_physics

    try:
        vehicle = vehicle_preset(resolve_physics(args.physics))
    except PhysicsError as exc:
        raise UserError(str(exc)) from None
    if not (np.isfinite(args.margin) and 0.0 <= args.margin <= 1.0):
        raise UserError(f"--margin must be a distance from 0 to 1 m, got {args.margin}")
    track = load_track(args.track)
    settings = FAST_SETTINGS if args.fast else RaceLineSettings()
    cached = raceline_cache_path(track, vehicle, args.margin, settings).is_file()
    started = time.perf_counter()
    try:
        line = raceline_for(track, vehicle, args.margin, settings)
    except ValueError as exc:
        raise UserError(f"race line of {track.name}: {exc}") from None
    seconds = time.perf_counter() - started

    origin = "loaded from the cache" if cached else f"solved in {seconds:.2f} s"
    print(f"race line of {track.name} ({track.length:.2f} m, {track.nominal_width:.3f} m wide), "
          f"car {vehicle.name}, margin {args.margin:g} m, {'fast' if args.fast else 'full'} solve, {origin}")
    gain = 100.0 * (1.0 - line.lap_time / line.centerline_lap_time)
    print(f"  optimal lap time      {line.lap_time:8.3f} s")
    print(f"  centre-line lap time  {line.centerline_lap_time:8.3f} s   (race line {gain:.1f} % faster)")
    print(f"  race line length      {line.length:8.2f} m   (centre line {track.length:.2f} m, "
          f"top speed {line.speeds.max():.2f} m/s, slowest {line.speeds.min():.2f} m/s)")
    if not line.steering_feasible:
        print("  warning: the line turns tighter than full steering lock somewhere")

    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{output_stem(track.name)}-raceline"
    paths = [stem.with_suffix(".npy"), stem.with_suffix(".csv"), stem.with_suffix(".png")]
    line.save_npy(paths[0])
    line.save_csv(paths[1])
    line.plot_png(paths[2], inner=track.inner, outer=track.outer, centerline=track.centerline,
                  title=f"{track.name}: race line {line.lap_time:.2f} s (centre line {line.centerline_lap_time:.2f} s)")
    print(f"wrote {len(line.points)} waypoints (closed: first row == last row):")
    for path in paths:
        print(f"  {path}")

    if not args.drive:
        return 0
    drive = drive_line(track, line.points, line.speeds, np.array([True, False]), vehicle)
    standing = standing_start_lap_time(line.arc_length, line.speeds, vehicle.max_acceleration)
    print("driven in the simulator (LineFollower, curvature feedforward through the car's delay and lags, "
          "from the line's first point):")
    finished = True
    for car, (label, predicted) in enumerate((("flying lap    ", line.lap_time), ("standing start", standing))):
        if drive.status[car] != LAP_COMPLETE:
            finished = False
            print(f"  {label}  did not finish: {STATUS_NAMES[drive.status[car]]}")
            continue
        print(f"  {label}  {drive.lap_time[car]:8.3f} s = {drive.lap_time[car] / predicted:.4f} x predicted "
              f"{predicted:.3f} s   (max {100 * drive.max_lateral_error[car]:.1f} cm off the line)")
    return 0 if finished else 1
