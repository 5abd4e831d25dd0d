"""Lap-time realism: DeepRacer's league records against laplab's optimum for the car of that season.

    python bench/lap_records.py [--routes DIR] [--physics V] [--margin 0.05]

For every time trial of DeepRacer's 2023-2024 virtual league in bench/data/league_records.json (the best
single lap of each race, from aws-deepracer-community/deepracer-race-data), prints the community's best
lap, laplab's optimum for the season's car (the race line of laplab.track.raceline, driven from rest at
its first point: DeepRacer's time-trial laps start from rest) and their ratio. No community lap should
beat the optimum (ratio >= 1.00) and the median ratio should be <= 1.10. Routes come from DIR
(default ../shared/reference-tracks), else laplab's track registry. The old car (laplab-classic) is
measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from host import host_line  # bench/host.py
from laplab.track.geometry import load_route_file
from laplab.track.raceline_cache import raceline_for
from laplab.track.registry import load_track
from laplab.track.speed_profile import standing_start_lap_time
from laplab.vehicle.params import CLASSIC, vehicle_preset
from laplab.vehicle.physics import resolve_physics

HERE = Path(__file__).resolve().parent
DEFAULT_ROUTES = HERE.parent.parent / "shared" / "reference-tracks"


def standing_optimum(track, car, margin: float) -> float:
    line = raceline_for(track, car, margin)
    return standing_start_lap_time(line.arc_length, line.speeds, car.max_acceleration)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", default=str(DEFAULT_ROUTES), help="folder of DeepRacer route .npy files")
    parser.add_argument("--physics", default=None, help="the car (default: the records' season's, 5)")
    parser.add_argument("--margin", type=float, default=0.05, help="race line margin, m (default 0.05)")
    args = parser.parse_args()
    document = json.loads((HERE / "data" / "league_records.json").read_text(encoding="utf-8"))
    car = vehicle_preset(resolve_physics(args.physics or document["physics"]))
    print(f"host: {host_line()}; car {car.name} (old: {CLASSIC.name}), "
          f"margin {args.margin} m, optimum from rest")
    print(f"{'route':<22} {'season':<8} {'community':>9} {'optimum':>8} {'ratio':>6} {'old opt':>8} {'ratio':>6}")
    ratios, old_ratios, started = [], [], time.perf_counter()
    for record in document["records"]:
        path = Path(args.routes) / f"{record['route']}.npy"
        try:
            track = load_route_file(path) if path.is_file() else load_track(record["route"])
        except (OSError, ValueError) as error:
            print(f"{record['route']:<22} skipped: {error}")
            continue
        best = float(record["best_lap_s"])
        optimum, old = standing_optimum(track, car, args.margin), standing_optimum(track, CLASSIC, args.margin)
        ratios.append(best / optimum)
        old_ratios.append(best / old)
        print(f"{record['route']:<22} {record['season']:<8} {best:9.3f} {optimum:8.3f} {best / optimum:6.3f} "
              f"{old:8.3f} {best / old:6.3f}")
    if not ratios:
        print("no route found: pass --routes DIR with DeepRacer's .npy routes", file=sys.stderr)
        return 2
    beaten = sum(r < 1.0 for r in ratios)
    print(f"{len(ratios)} routes in {time.perf_counter() - started:.0f} s; {car.name}: median ratio "
          f"{statistics.median(ratios):.3f}, min {min(ratios):.3f}, community laps faster than the optimum: {beaten}; "
          f"{CLASSIC.name}: median {statistics.median(old_ratios):.3f}, min {min(old_ratios):.3f}, faster: "
          f"{sum(r < 1.0 for r in old_ratios)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
