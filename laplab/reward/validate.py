"""Validate a reward function before training: run it over a sweep of realistic states.

The sweep covers the start, middle and end of the lap, both sides of the centre line, on and off the
track, the car straight and at an angle, both driving directions, and every action of the action
space (the caller gives them as (steering deg, speed m/s) pairs, e.g. ``ActionSpace.sweep_actions()``;
continuous spaces: a 3 x 3 grid of steering and speed). Every call runs under a timeout, so a
function that never returns fails validation instead of hanging it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laplab.reward.errors import RewardFunctionError
from laplab.reward.loader import RewardFunction
from laplab.reward.timeout import call_with_timeout
from laplab.reward.params import ParamsBuilder
from laplab.sim.simulator import Simulator
from laplab.sim.state import EpisodeParams
from laplab.track.geometry import Track
from laplab.vehicle.dynamics import pose_for_reference

LAP_FRACTIONS = (0.005, 0.1, 0.5, 0.75, 0.995)
LATERAL_FRACTIONS = (-1.4, -0.9, -0.5, -0.15, 0.0, 0.15, 0.5, 0.9, 1.4)  # of the half width; |x| > 1: off track
HEADING_OFFSETS_DEG = (-25.0, 0.0, 25.0)
# laplab's default action space (steering -30..30 deg by 10, speeds 1.33, 2.67, 4 m/s), as sweep actions
DEFAULT_SWEEP_ACTIONS = tuple((float(steer), speed) for steer in range(-30, 31, 10) for speed in (1.33, 2.67, 4.0))


@dataclass(frozen=True)
class ValidationReport:
    """Outcome of :func:`validate_reward_function`; ``error`` is None when every call passed."""

    calls: int
    minimum: float
    mean: float
    maximum: float
    error: RewardFunctionError | None

    @property
    def passed(self) -> bool:
        return self.error is None


def sweep_params(track: Track, actions: np.ndarray | None = None, race=None) -> list[dict]:
    """Params dicts of the validation sweep on ``track`` (both directions, every action).

    ``actions``: (K, 2) of (steering deg, speed m/s), e.g. ``ActionSpace.sweep_actions()``; default:
    laplab's default action space. ``race``: the job's :class:`~laplab.sim.race_type.RaceType` (its
    objects are on the track, so the ``objects_*`` keys are filled as in training)."""
    actions = np.asarray(DEFAULT_SWEEP_ACTIONS if actions is None else actions, dtype=np.float64).reshape(-1, 2)
    steer_deg, speed = actions[:, 0], actions[:, 1]
    combos = [(f, lat, hd, d) for d in (0, 1) for f in LAP_FRACTIONS for lat in LATERAL_FRACTIONS
              for hd in HEADING_OFFSETS_DEG]
    n_states = len(combos)
    sim = Simulator(track, n_states * len(steer_deg), episode=EpisodeParams(round_robin_advance=0.0), race=race, seed=0)
    sim.reset(ndist=0.0, direction=np.repeat([c[3] for c in combos], len(steer_deg)))
    poses = np.empty((sim.num_cars, 3))
    row = 0
    for frac, lat, heading_deg, direction in combos:
        t = sim.tracks[direction]
        s = frac * t.length
        centre = t.point_at(s)
        yaw = float(t.heading_at(s))
        seg = min(int(np.searchsorted(t.arc_length, s, side="right")) - 1, t.num_waypoints - 2)
        half = 0.5 * float(t.width[seg])
        normal = np.array([-math.sin(yaw), math.cos(yaw)])
        pose = pose_for_reference(centre + lat * half * normal, yaw, sim.vehicle.reference_offset)[0]
        pose[2] += math.radians(heading_deg)  # turned about the origin placed for the track's heading
        poses[row:row + len(steer_deg)] = pose
        row += len(steer_deg)
    cars = np.arange(sim.num_cars)
    cmd_speed = np.tile(speed, n_states)
    # progress counts from waypoint 0 of each direction
    sim.place(cars, poses, speed=cmd_speed, steer=np.tile(np.radians(steer_deg), n_states), start_arc=0.0)
    # steps: as if the car had driven there at its commanded speed from the start
    sim.set_steps(cars, np.maximum(1, np.round(sim.state.travel / np.maximum(cmd_speed, 0.1) * sim.vehicle.decision_hz)))
    return ParamsBuilder(sim).build()


def validate_reward_function(reward_fn: RewardFunction, track: Track, actions: np.ndarray | None = None,
                             timeout_s: float = 2.0, isolate: bool = False, race=None) -> ValidationReport:
    """Call ``reward_fn`` on every state of the sweep (``actions`` as in :func:`sweep_params`); stop at
    the first failure. ``isolate``: make the calls in a child process that is killed if it stops
    answering (:mod:`laplab.reward.check_process`: what the commands do before a job), so that no
    reward function can hang, kill or cripple the caller. ``race``: the job's race type (its objects
    fill the ``objects_*`` keys, see :func:`sweep_params`)."""
    from laplab.reward.check_process import call_all, can_isolate
    params_list = sweep_params(track, actions, race)
    if isolate and can_isolate() and isinstance(reward_fn, RewardFunction):
        values, error = call_all(reward_fn, params_list, timeout_s)
        arr = np.array(values) if values else np.zeros(1)
        return ValidationReport(len(values) + (error is not None), float(arr.min()), float(arr.mean()),
                                float(arr.max()), error)
    values = []
    error = None
    for params in params_list:
        try:
            values.append(call_with_timeout(reward_fn, params, timeout_s))
        except RewardFunctionError as exc:
            error = exc
            break
    arr = np.array(values) if values else np.zeros(1)
    return ValidationReport(len(values) + (error is not None), float(arr.min()), float(arr.mean()),
                            float(arr.max()), error)
