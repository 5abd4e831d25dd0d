"""Head-to-model races: two or more trained models in one simulator, each driving its own car.

Every car starts from rest on the start line, side by side (inner lane, outer lane, in turn) and
drives ``laps`` laps; each car's obstacles are the other cars' bodies. An incident (off track,
crashed, reversed, immobilized) puts the car back as evaluation does (previous step's progress,
nearer quarter lane) and holds it for the penalty (DeepRacer's: 5 s after a crash, ``off_track_penalty``
otherwise) while the others drive on; while it stands, and until it is clear of the other cars, it
collides with nothing (DeepRacer's blinking car). A car that hits another is the one that crashed; both are
put back if both overlap. The finish order is by finishing time; cars still racing at
``max_time`` are ranked after them by laps and progress. Drivers may have different action spaces and
sensors (each reads its own observations), but must share one car (physics version). ``should_stop``
(asked once a step) ends the race early: it is ranked as at ``max_time`` and marked ``stopped``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from laplab.env.observations import ObservationBuilder
from laplab.env.spec import ModelSpec
from laplab.evaluate.runner import put_back
from laplab.sim.race_type import RaceType, RaceTypeError
from laplab.sim.simulator import Simulator
from laplab.sim.state import (
    CRASHED,
    IN_PROGRESS,
    LAP_COMPLETE,
    STATUS_NAMES,
    EpisodeParams,
)
from laplab.track.geometry import Track
from laplab.vehicle.params import VehicleParams


@dataclass(frozen=True)
class Driver:
    """One racer: a name, a policy (observations (1, ...) -> env actions (1, ...)) and its spec."""

    name: str
    act: Callable[[Any], np.ndarray]
    spec: ModelSpec
    car: str = ""


@dataclass
class RacerResult:
    """How one car did: laps completed, its finishing time (s, None if it did not finish), position."""

    name: str
    position: int = 0
    laps: int = 0
    finish_time: float | None = None
    lap_times: list[float] = field(default_factory=list)
    progress: float = 0.0
    crash_count: int = 0
    off_track_count: int = 0
    penalty_time: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class RaceResult:
    """A race: its racers in finishing order, and every step's poses (T, cars, 3) for pictures;
    ``stopped``: it was stopped before every car finished or ``max_time`` ran out."""

    track: Track
    racers: list[RacerResult]
    poses: np.ndarray = field(repr=False)
    clock: np.ndarray = field(repr=False)
    stopped: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {"track": self.track.name, "racers": [r.to_dict() for r in self.racers],
                "duration": float(self.clock[-1]) if len(self.clock) else 0.0, "stopped": self.stopped}


def check_same_car(names: list[str], cars: list[str]) -> None:
    """Refuse racers trained on different cars (physics versions), naming the opponent."""
    for name, car in zip(names[1:], cars[1:]):
        if car != cars[0]:
            raise RaceTypeError(f"opponent {name!r} drives {car} but {names[0]!r} drives {cars[0]}: a head-to-model "
                                f"race puts both in one simulator with one car physics; race models of one physics "
                                f"version (clone one with --physics to retrain it on the other car)", field="opponent")


def run_race(drivers: list[Driver], track: Track, vehicle: VehicleParams, laps: int = 1, max_time: float = 180.0,
             crash_penalty: float = 5.0, off_track_penalty: float = 2.0, seed: int = 0,
             should_stop: Callable[[], bool] | None = None) -> RaceResult:
    """Race ``drivers`` on ``track`` (see the module docstring); ``max_time`` in simulated s."""
    if len(drivers) < 2:
        raise RaceTypeError("a head-to-model race needs at least two models", field="models")
    n = len(drivers)
    race = RaceType("head_to_model", opponents=tuple(d.name for d in drivers[1:]))
    sim = Simulator(track, n, vehicle, EpisodeParams(round_robin_advance=0.0, spread_starts=False, max_steps=2**62),
                    race=race, seed=seed)
    builders = [ObservationBuilder(sim, d.spec, seed=seed + i, sensor_noise=False) for i, d in enumerate(drivers)]
    st, dt = sim.state, sim.dt
    sim.reset(ndist=np.zeros(n))
    results = [RacerResult(d.name) for d in drivers]
    hold = np.zeros(n)  # s each car still stands
    lap_start = np.zeros(n)
    finished = np.zeros(n, dtype=bool)
    clock, poses, clocks = 0.0, [sim.poses().copy()], [0.0]
    stopped = False
    while not finished.all() and clock < max_time:
        if should_stop is not None and should_stop():
            stopped = True
            break
        racing = np.flatnonzero(~finished)
        steer, speed = np.zeros(n), np.zeros(n)
        for i in racing[hold[racing] <= 0]:
            action = np.asarray(drivers[i].act(builders[i].observe(np.array([i]))))
            s, v = drivers[i].spec.action_space.to_commands(action)
            steer[i], speed[i] = s[0], v[0]
        prev_travel = st.travel.copy()
        sim.step(steer, speed)
        clock += dt
        held = racing[hold[racing] > 0]
        hold[held] -= dt
        st.immobile_count[held] = 0  # standing out a penalty is not being stuck
        # DeepRacer's blinking car: no collisions while it serves its penalty (and until it is clear of
        # the others, so that two cars put back side by side do not crash again at once)
        sim.ghost[:] = (hold > 0) | (sim.ghost & _overlapping(sim))
        for i in racing:
            code = int(st.status[i])
            if code == LAP_COMPLETE:
                lap_time = clock - lap_start[i]
                results[i].lap_times.append(float(lap_time))
                results[i].laps += 1
                lap_start[i] = clock
                if results[i].laps >= laps:
                    finished[i] = True
                    results[i].finish_time = float(clock)
                else:
                    sim.continue_lap(np.array([i]))
            elif code != IN_PROGRESS:
                penalty = crash_penalty if code == CRASHED else off_track_penalty
                results[i].crash_count += code == CRASHED
                results[i].off_track_count += STATUS_NAMES[code] == "off_track"
                results[i].penalty_time += penalty
                put_back(sim, np.array([i]), prev_travel[[i]])
                hold[i] = penalty
                sim.ghost[i] = True
        poses.append(sim.poses().copy())
        clocks.append(clock)
    for i, r in enumerate(results):
        r.progress = float(st.progress[i]) if not finished[i] else 100.0
    order = sorted(range(n), key=lambda i: (results[i].finish_time is None, results[i].finish_time or 0.0,
                                            -results[i].laps, -results[i].progress))
    ranked = [results[i] for i in order]
    for position, r in enumerate(ranked, start=1):
        r.position = position
    return RaceResult(track, ranked, np.stack(poses), np.array(clocks), stopped)


def _overlapping(sim: Simulator) -> np.ndarray:
    """(N,) whether each car's body overlaps another car's body."""
    from laplab.sim.collision import rectangles_overlap
    st, field = sim.state, sim.field
    out = np.zeros(sim.num_cars, dtype=bool)
    c, s = np.cos(st.yaw), np.sin(st.yaw)
    cx, cy = st.x + field.body_offset * c, st.y + field.body_offset * s
    for i in range(sim.num_cars):
        for j in range(i + 1, sim.num_cars):
            if rectangles_overlap(cx[i], cy[i], st.yaw[i], field.body_half_length, field.body_half_width,
                                  cx[j], cy[j], st.yaw[j], field.body_half_length, field.body_half_width):
                out[i] = out[j] = True
    return out


def race_picture(result: RaceResult, names: list[str]) -> np.ndarray:
    """A top-down picture (H, W, 3) uint8 of the race's end: every car and its path (car i in colour i,
    in the order of ``names``, the drivers' order)."""
    from laplab.sensors.render import draw_topdown
    paths = [result.poses[:, i, :2] for i in range(result.poses.shape[1])]
    return draw_topdown(result.track, result.poses[-1], paths=paths)
