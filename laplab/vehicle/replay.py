"""Replay logged action sequences through a car (batched): how a car answers a 15 Hz action sequence.

A *window* is a logged pose and the actions around it: the ``lead`` actions before it (from which the
car's steering state is estimated) and the ``horizon`` actions after it, with their logged simulation
times. :func:`replay_windows` drives every window's car from the logged pose through its horizon and
returns the poses it reaches, to compare with the logged ones (``bench/fidelity.py``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from laplab.vehicle.dynamics import advance_car, dynamics_constants
from laplab.vehicle.params import VehicleParams

OBSERVED_WEIGHT = 0.75  # of the logged curvature's steering in the starting state (fits best on every log)


@nb.njit(cache=True, parallel=True)
def _replay(start, speed0, observed_steer, weight, commands, times, lead, dc, ref_offset, out):
    n, horizon = out.shape[0], out.shape[1]
    for w in nb.prange(n):
        # the steering state: the commands before the window from rest (a position is not needed)
        steer, speed = 0.0, 0.0
        prev_steer, prev_speed = commands[w, 0, 0], commands[w, 0, 1]
        for c in range(lead):
            dt = max(times[w, c + 1] - times[w, c], 1e-3)
            _, _, _, speed, steer = advance_car(0.0, 0.0, 0.0, speed, steer, prev_steer, prev_speed,
                                                commands[w, c, 0], commands[w, c, 1], dt, dc)
            prev_steer, prev_speed = commands[w, c, 0], commands[w, c, 1]
        if not np.isnan(observed_steer[w]):  # the car's own state, as the yaw logged just before says it
            steer = weight * observed_steer[w] + (1.0 - weight) * steer
        yaw = start[w, 2]
        x = start[w, 0] - ref_offset * np.cos(yaw)
        y = start[w, 1] - ref_offset * np.sin(yaw)
        speed = speed0[w]
        for s in range(horizon):
            c = lead + s
            dt = max(times[w, c + 1] - times[w, c], 1e-3)
            x, y, yaw, speed, steer = advance_car(x, y, yaw, speed, steer, commands[w, c - 1, 0],
                                                  commands[w, c - 1, 1], commands[w, c, 0], commands[w, c, 1],
                                                  dt, dc)
            out[w, s, 0] = x + ref_offset * np.cos(yaw)
            out[w, s, 1] = y + ref_offset * np.sin(yaw)
            out[w, s, 2] = yaw


def replay_windows(start: np.ndarray, speed0: np.ndarray, commands: np.ndarray, times: np.ndarray, lead: int,
                   vehicle: VehicleParams, curvature0: np.ndarray | None = None,
                   observed_weight: float = OBSERVED_WEIGHT) -> np.ndarray:
    """Poses (W, H, 3) (reference point x, y in m; yaw in rad) that ``vehicle`` reaches in each window.

    ``start`` (W, 3): the logged reference-point pose at the window's row; ``speed0`` (W,) m/s: its speed
    then; ``commands`` (W, lead + H, 2): (steering rad, speed m/s) of the ``lead`` actions before the row
    and of the H actions from it on; ``times`` (W, lead + H + 1) s: the simulation time of each of those
    rows and of the row after the last (so ``times[:, lead + s + 1] - times[:, lead + s]`` is the length
    of horizon step s). ``lead`` >= 1. ``curvature0`` (W,) 1/m: the path's curvature logged over the step
    before the row (NaN or None: unknown); the steering state starts at ``observed_weight`` times the
    steering that gives it plus the rest of the estimate from the lead actions.
    """
    commands = np.ascontiguousarray(commands, dtype=np.float64)
    if lead < 1 or commands.ndim != 3 or commands.shape[1] <= lead:
        raise ValueError("commands must be (W, lead + H, 2) with lead >= 1 and H >= 1")
    horizon = commands.shape[1] - lead
    out = np.empty((commands.shape[0], horizon, 3))
    if curvature0 is None:
        observed = np.full(commands.shape[0], np.nan)
    else:  # the steering whose curvature the log shows (gain and offset; NaN stays NaN)
        observed = np.arctan(np.asarray(curvature0, dtype=np.float64) * vehicle.wheelbase / vehicle.steering_gain)
        observed = np.clip(observed - vehicle.steering_offset, -vehicle.max_steering, vehicle.max_steering)
    _replay(np.ascontiguousarray(start, dtype=np.float64), np.ascontiguousarray(speed0, dtype=np.float64),
            np.ascontiguousarray(observed, dtype=np.float64), float(observed_weight), commands,
            np.ascontiguousarray(times, dtype=np.float64), int(lead), dynamics_constants(vehicle),
            float(vehicle.reference_offset), out)
    return out
