"""Fit a car's response to DeepRacer's own simtraces (how laplab.vehicle.params' presets were made).

    python scripts/fit_car.py --simtrace DIR [--simtrace DIR ...] [--start deepracer-v4] [--seed 0]

Replays every window of the simtraces below the folders (laplab.analysis.fidelity) and fits the
response parameters the URDF leaves open (action delay, steering lag / gain / offset / understeer,
pivot, speed ratio / lag, acceleration and braking, lateral grip) by robust least squares on the
position after 1 s, for each action delay of a grid (it acts in quarter steps). Half of the windows
fit, the other half is scored; prints both and the parameters.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import least_squares

from laplab.analysis.fidelity import build_windows, find_simtraces, score
from laplab.vehicle.params import vehicle_preset
from laplab.vehicle.replay import replay_windows

FREE = {  # name: (lower, upper)
    "steering_time_constant": (0.0, 1.5), "steering_gain": (0.1, 1.5), "steering_offset_deg": (-5.0, 5.0), "steering_saturation_deg": (0.0, 90.0),
    "understeer": (0.0, 3.0), "pivot_offset": (-0.4, 0.4), "speed_ratio": (0.8, 1.3),
    "speed_time_constant": (0.0, 1.0), "max_acceleration": (0.5, 20.0), "max_braking": (0.5, 30.0),
    "max_lateral_acceleration": (0.5, 20.0),
}


def residuals(values, names, base, windows):
    car = base.with_(**dict(zip(names, values)))
    poses = replay_windows(windows.start, windows.speed0, windows.commands, windows.times, windows.lead, car,
                           windows.curvature0)
    return (poses[:, -1, :2] - windows.logged[:, -1, :2]).ravel()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--simtrace", action="append", required=True)
    parser.add_argument("--start", default="deepracer-v4", help="preset to start from (and keep the geometry of)")
    parser.add_argument("--fit-windows", type=int, default=8000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter (e.g. max_lateral_acceleration=4.9: mu 0.5 of the URDF times g)")
    parser.add_argument("--delays", default="0,0.25,0.5,0.75,1", help="action delays to try (fractions of a step)")
    parser.add_argument("--f-scale", type=float, default=0.1, metavar="M",
                        help="soft-L1 scale, m: errors beyond it count linearly (smaller: nearer the median's fit)")
    args = parser.parse_args()
    paths = [p for folder in args.simtrace for p in find_simtraces(folder)]
    windows = build_windows(paths)
    order = np.random.default_rng(args.seed).permutation(windows.size)
    fit_rows, test_rows = order[: windows.size // 2][: args.fit_windows], order[windows.size // 2:]
    fit_set, test_set = windows.subset(fit_rows), windows.subset(test_rows)
    fixed = {name: float(value) for name, value in (item.split("=", 1) for item in args.fix)}
    base = vehicle_preset(args.start).with_(**fixed)
    names = [name for name in FREE if name not in fixed]
    lower, upper = np.array([FREE[n][0] for n in names]), np.array([FREE[n][1] for n in names])
    best = None
    for delay in [float(d) for d in args.delays.split(',')]:
        start_car = base.with_(action_delay=delay, steering_saturation_deg=base.steering_saturation_deg or 40.0)
        x0 = np.clip([getattr(start_car, n) for n in names], lower + 1e-6, upper - 1e-6)
        result = least_squares(residuals, x0, bounds=(lower, upper), loss="soft_l1", f_scale=args.f_scale,
                               args=(names, start_car, fit_set), diff_step=1e-3, max_nfev=400)
        car = start_car.with_(**dict(zip(names, result.x)))
        fitted = score(car, fit_set)
        print(f"delay {delay:.2f}: fit {fitted.summary()}")
        if best is None or np.median(fitted.position_error) < best[0]:
            best = (np.median(fitted.position_error), car)
    car = best[1]
    print("test", score(car, test_set).summary())
    print("all ", score(car, windows).summary())
    print({n: round(float(getattr(car, n)), 4) for n in ["action_delay", *FREE]})


if __name__ == "__main__":
    main()
