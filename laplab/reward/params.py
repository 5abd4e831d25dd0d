"""The reward function's ``params`` dict, built for a batch of cars from the simulator's arrays.

Every key of DeepRacer's table is present with its meaning and units (reference doc section 2).
Each call gets a fresh dict. ``waypoints`` is a fresh list per call of shared ``(x, y)`` tuples, so
a reward function that mutates its list (append, sort, reverse, item assignment) cannot corrupt the
next call, without copying the coordinates themselves each step.
"""

from __future__ import annotations

import gc
import math
from contextlib import contextmanager
from typing import Callable

import numpy as np

from laplab.sim.simulator import Simulator
from laplab.sim.state import OFF_TRACK, CRASHED
from laplab.track.params_geometry import reward_geometry

PARAMS_KEYS = (
    "all_wheels_on_track", "x", "y", "heading", "distance_from_center", "is_left_of_center", "progress",
    "steps", "speed", "steering_angle", "track_width", "track_length", "waypoints", "closest_waypoints",
    "is_offtrack", "is_crashed", "is_reversed", "projection_distance", "closest_objects",
    "objects_location", "objects_left_of_center", "objects_speed", "objects_heading", "objects_distance",
    "objects_distance_from_center", "object_in_camera",
)


class ParamsBuilder:
    """Builds params dicts for the cars of one :class:`Simulator` (the ``objects_*`` keys from its
    obstacles when its race type has any: :mod:`laplab.reward.objects`)."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        self._waypoints = tuple(tuple(tuple(map(float, p)) for p in t.centerline) for t in sim.tracks)
        self._geometry = sim.params_geometry
        self._length = sim.track.length

    def build(self, cars: np.ndarray | None = None) -> list[dict]:
        """One params dict per car index in ``cars`` (all cars when None), from the current state."""
        st = self.sim.state
        idx = np.arange(self.sim.num_cars) if cars is None else np.asarray(cars, dtype=np.int64)
        geo = reward_geometry(self._geometry, st.direction[idx], st.segment[idx], st.seg_t[idx], st.ref_x[idx],
                              st.ref_y[idx])
        heading = np.degrees(st.yaw[idx])
        columns = (
            (st.wheels_on[idx] == 4).tolist(), st.ref_x[idx].tolist(), st.ref_y[idx].tolist(),
            heading.tolist(), np.abs(st.lateral[idx]).tolist(), geo.is_left_of_center.tolist(),
            st.progress[idx].tolist(), st.steps[idx].astype(np.float64).tolist(), st.cmd_speed[idx].tolist(),
            np.degrees(st.cmd_steer[idx]).tolist(), geo.track_width.tolist(), geo.prev_waypoint.tolist(),
            (st.status[idx] == OFF_TRACK).tolist(), (st.status[idx] == CRASHED).tolist(),
            (st.direction[idx] == 1).tolist(), st.arc[idx].tolist(),
        )
        length, waypoints = self._length, self._waypoints
        dicts = [
            {
                "all_wheels_on_track": on, "x": x, "y": y, "heading": hd, "distance_from_center": dfc,
                "is_left_of_center": left, "progress": prog, "steps": steps, "speed": speed,
                "steering_angle": steer, "track_width": w, "track_length": length,
                "waypoints": list(waypoints[rev]), "closest_waypoints": [sg, sg + 1],
                "is_offtrack": off, "is_crashed": crash, "is_reversed": rev, "projection_distance": proj,
                "closest_objects": [0, 0], "objects_location": [], "objects_left_of_center": [],
                "objects_speed": [], "objects_heading": [], "objects_distance": [],
                "objects_distance_from_center": [], "object_in_camera": False,
            }
            for on, x, y, hd, dfc, left, prog, steps, speed, steer, w, sg, off, crash, rev, proj in zip(*columns)
        ]
        if self.sim.field is not None:
            from laplab.reward.objects import object_params
            for params, objects in zip(dicts, object_params(self.sim, idx)):
                params.update(objects)
        return dicts


@contextmanager
def gc_paused():
    """Pause the cyclic garbage collector for a batch of params dicts and reward calls.

    A step builds a thousand short-lived dicts and lists; each allocation burst would trigger collections
    that walk the whole heap (7x slower per dict with torch loaded). Reference counting frees them
    all the same; cycles a reward function makes are collected once the collector resumes.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def rewards_for(builder: ParamsBuilder, reward_fn: Callable[[dict], float], cars: np.ndarray,
                keep: bool = False) -> tuple[list[float], list[dict] | None]:
    """Call ``reward_fn`` once per car in ``cars`` with a fresh params dict; returns the rewards and,
    when ``keep``, the dicts."""
    # The builder's dicts are fresh, so the reward function may have them without a defensive copy,
    # unless they are kept for the caller (info["params"]), which must not see the function's mutations.
    call = reward_fn if keep else getattr(reward_fn, "call_fresh", reward_fn)
    with gc_paused():
        params = builder.build(cars)
        rewards = [call(p) for p in params]
        if not keep:  # freed while the collector is paused, so resuming it finds no backlog to walk
            params = None
    return rewards, params



def heading_deg(yaw_rad: float) -> float:
    """DeepRacer heading in degrees, in (-180, 180]."""
    deg = math.degrees(math.atan2(math.sin(yaw_rad), math.cos(yaw_rad)))
    return 180.0 if deg == -180.0 else deg
