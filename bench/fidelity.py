"""How closely laplab's car drives as DeepRacer's simulator did, from DeepRacer's own simtraces.

    python bench/fidelity.py --simtrace DIR --track ROUTE [--physics V] [--clock logged|fixed]

Replays every simtrace CSV found below DIR (training or evaluation; the console's, deepracer-for-cloud's
or DeepRacer on AWS's layout; discrete or continuous actions): from the logged pose at each step (speed
and steering estimated from the logged rows before it) the car drives the next 15 logged actions (1 s)
with the logged simulation times (``--clock fixed``: 1/15 s steps) and its pose is compared with the
logged one (laplab.analysis.fidelity). The car: ``--physics`` (4, 5, 6, classic), else the one the
folder's model_metadata.json ``version`` chooses, else DeepRacer on AWS's (6). ROUTE is the track the
logs ran on: the logged positions are checked against it, so a log of another track is refused. Prints
laplab's classic car on the same windows first; the last line reads

    fidelity: N windows, position error after 1 s median X cm p90 Y cm, heading error median Z deg
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from host import host_line  # bench/host.py
from laplab.analysis.fidelity import SimtraceReadError, build_windows, find_simtraces, score
from laplab.track.projection import project_points, track_arrays
from laplab.track.registry import load_track
from laplab.vehicle.params import CLASSIC, vehicle_preset
from laplab.vehicle.physics import PhysicsError, car_for_version, resolve_physics

SIMAPP_VERSION = re.compile(r"simapp_version (\d+(?:\.\d+)?)")
MAX_OFF_ROUTE = 0.5  # m: logged positions farther than this from ROUTE's centre line (median) are another track


def folder_version(root: Path) -> tuple[str | None, Path | None]:
    """The ``version`` of the first model_metadata.json below ``root``, else the ``simapp_version`` that
    DeepRacer's RoboMaker / SageMaker logs below it print (None when neither is there)."""
    for path in sorted(root.rglob("model_metadata.json")):
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(document, dict) and "version" in document:
            return str(document["version"]), path
    for path in sorted(root.rglob("*.log")):
        try:
            match = SIMAPP_VERSION.search(path.read_text(encoding="utf-8", errors="replace"))
        except OSError:
            continue
        if match:
            return match.group(1), path
    return None, None


def logged_track_length(paths: list[Path]) -> float | None:
    """The median ``track_len`` (m) of the simtraces' first rows (None when they have no such column)."""
    lengths = []
    for path in paths:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            if "track_len" not in header:
                continue
            column = header.index("track_len")
            for row, _ in zip(reader, range(50)):
                try:
                    lengths.append(float(row[column]))
                except (ValueError, IndexError):
                    pass
    return float(np.median(lengths)) if lengths else None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--simtrace", required=True, metavar="DIR", help="a folder (or one CSV) of DeepRacer simtraces")
    parser.add_argument("--track", required=True, metavar="ROUTE", help="the route the logs ran on (name or .npy)")
    parser.add_argument("--physics", default=None, metavar="V", help="the car: 4, 5, 6 or classic")
    parser.add_argument("--clock", choices=("logged", "fixed"), default="logged",
                        help="step lengths: the logged tstamp differences (default) or 1/15 s")
    parser.add_argument("--horizon", type=int, default=15, help="actions replayed per window (15 = 1 s)")
    args = parser.parse_args()
    root = Path(args.simtrace)
    try:
        if args.physics:
            car, why = resolve_physics(args.physics), "--physics"
        else:
            version, source = folder_version(root if root.is_dir() else root.parent)
            car = car_for_version(version)
            why = f"version {version} in {source}" if source else "no model_metadata.json: DeepRacer on AWS's"
        paths = find_simtraces(root)
        if not paths:
            raise SimtraceReadError(f"{root}: no simtrace CSV (with columns episode, steps, X, Y, yaw, steer, "
                                    f"throttle, tstamp) below it")
        windows = build_windows(paths, horizon=args.horizon)
        track = load_track(args.track)
    except (PhysicsError, SimtraceReadError, ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if windows.size == 0:
        print(f"error: {root}: no run of the car in these simtraces is {args.horizon + 2} steps long", file=sys.stderr)
        return 2
    logged_length = logged_track_length(paths)
    if logged_length is not None and abs(logged_length - track.length) > 0.01 * track.length:
        print(f"error: these logs ran on a track {logged_length:.2f} m long (their track_len column), "
              f"{track.name} is {track.length:.2f} m: name the route they ran on", file=sys.stderr)
        return 2
    off_route = np.median(np.abs(project_points(track_arrays(track), windows.start[:, :2]).lateral))
    if off_route > MAX_OFF_ROUTE:
        print(f"error: the logged positions lie {off_route:.2f} m (median) from {track.name}'s centre line: "
              f"these logs ran on another track", file=sys.stderr)
        return 2
    if args.clock == "fixed":  # every step 1/15 s, the starting speed's step too
        lead = windows.lead
        step_before = windows.times[:, lead] - windows.times[:, lead - 1]
        windows = replace(windows, times=windows.times[:, :1] + np.arange(windows.times.shape[1]) / 15.0,
                          speed0=windows.speed0 * step_before * 15.0)
    print(f"host: {host_line()}")
    print(f"{len(paths)} simtrace files below {root}, track {track.name} ({track.length:.2f} m), "
          f"{args.clock} clock, windows of {args.horizon} actions")
    print(f"car: {car} ({why})")
    old = score(CLASSIC, windows)
    print(f"{CLASSIC.name} (laplab's old car): {old.summary()}")
    new = score(vehicle_preset(car), windows)
    print(f"{car}: {new.summary()}")
    print(new.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
