"""Lidar scans per second on a real DeepRacer track (goal: >= 50,000 scans/s on 2 cores).

    python3 bench/lidar_speed.py [--track reinvent_base] [--repeats 50]

Prints, for N = 1, 64 and 256 cars per call, the median over ``repeats`` calls of scans/s
(one scan = 64 beams of one car, noise included) and of microseconds per call, with numba's
threads (the default for big batches) and on one core. Threaded figures collapse when other
processes load the cores; check ``uptime`` first.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numba
import numpy as np

from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, scan

TRACKS = Path(__file__).resolve().parents[1].parent / "shared" / "reference-tracks"


def poses_on_track(route: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) poses near random centre-line points, heading along the track +- 0.3 rad."""
    rows = rng.integers(0, len(route) - 1, n)
    step = route[rows + 1, 0:2] - route[rows, 0:2]
    yaw = np.arctan2(step[:, 1], step[:, 0]) + rng.uniform(-0.3, 0.3, n)
    return np.column_stack([route[rows, 0:2] + rng.normal(0.0, 0.1, (n, 2)), yaw])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base", help="route name in ../shared/reference-tracks")
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    route = np.load(TRACKS / f"{args.track}.npy")
    start = time.perf_counter()
    walls = LidarWalls.from_track(route)
    print(f"track {args.track}: {len(walls.segments)} wall segments, grid {walls.nx}x{walls.ny} "
          f"cells of {walls.cell_size} m, built in {1e3 * (time.perf_counter() - start):.1f} ms "
          f"(first call includes numba load/compile); numba threads: {numba.get_num_threads()}")
    rng = np.random.default_rng(0)
    for parallel in (None, False):
        for n in (1, 64, 256):
            poses = poses_on_track(route, n, rng)
            for _ in range(3):
                scan(walls, poses, DEFAULT_LIDAR, rng, parallel)
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                scan(walls, poses, DEFAULT_LIDAR, rng, parallel)
                times.append(time.perf_counter() - t0)
            median = float(np.median(times))
            mode = "auto (threads for N >= 32)" if parallel is None else "serial (1 core)"
            print(f"N={n:4d} {mode:27s}: {n / median:10,.0f} scans/s  {1e6 * median:8.1f} us/call")


if __name__ == "__main__":
    main()
