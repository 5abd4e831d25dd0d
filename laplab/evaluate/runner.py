"""The trial loop: every trial's car in one batched Simulator, under DeepRacer's evaluation rules.

Rules (reference doc section 8; ``docs/evaluation.md``):

- Each trial starts at rest on the start line; its clock counts simulation time, penalties included.
- An incident (``off_track``, ``reversed``, ``immobilized``, ``crashed``) with resets left puts the
  car back at the progress of the previous step, its reference point in the nearer quarter-width
  lane, facing along the track, at rest, and holds it for the penalty (``crash_penalty`` for a
  crash, ``off_track_penalty`` for the others): the trial's clock runs on while the car stands.
  Without resets left the incident ends the trial with that status. Near a box (object avoidance)
  the car is put 1 m behind it in the other lane, as DeepRacer does; bots drive on while it stands.
- A trial still running when its clock reaches ``max_trial_time`` ends as ``time_up``.
- Continuous mode: one car drives the trials as consecutive laps; a lap's time runs from crossing
  the line to crossing it again. After a trial that did not finish, the next starts again at rest
  on the start line.

Cars are independent, so the hold is booked rather than simulated: the clock jumps by the penalty
and the simtrace gets ``pause`` rows for the standing time; the car resumes at the next step.
"""

from __future__ import annotations

import time
from typing import Any, Callable, NamedTuple

import numpy as np

from laplab.env.step import EpisodeStepper, simtrace_rows, trace_actions
from laplab.evaluate.summary import INCIDENTS, TrialResult
from laplab.sim.simulator import Simulator
from laplab.vehicle.dynamics import pose_for_reference
from laplab.sim.state import (CRASHED, IMMOBILIZED, IN_PROGRESS, LAP_COMPLETE, OFF_TRACK, REVERSED,
                              STATUS_NAMES, TIME_UP)
from laplab.track.geometry import Track

# Status code -> index into INCIDENTS (-1: not an incident).
_INCIDENT_INDEX = np.full(len(STATUS_NAMES), -1, dtype=np.int64)
for _code, _kind in ((OFF_TRACK, "off_track"), (REVERSED, "reversed"), (IMMOBILIZED, "immobilized"),
                     (CRASHED, "crash")):
    _INCIDENT_INDEX[_code] = INCIDENTS.index(_kind)
_ROW_STATUS = np.array(STATUS_NAMES + ("pause",))
_PAUSE = len(STATUS_NAMES)
OBSTACLES_KEY = "_obstacles"


class TrialRun(NamedTuple):
    """The trials in order and the simtrace columns of all of them (``episode`` = trial index,
    rows grouped by trial, ``tstamp`` on the evaluation clock: trials laid end to end)."""

    trials: tuple[TrialResult, ...]
    trace: dict[str, np.ndarray]
    decisions: int
    obstacles: np.ndarray | None = None  # (rows, slots, 7) the Obstacles fields at each trace row


def reset_poses(track: Track, reference_offset: float, arc: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Poses (K, 3) of the model origin that put the reference point at arc lengths ``arc`` (K,) m in
    the quarter-width lane nearer to the points ``near`` (K, 2), facing along the track.

    A quarter-width lane lies midway between the centre line and a border.
    """
    arc = np.asarray(arc, dtype=np.float64).reshape(-1)
    near = np.asarray(near, dtype=np.float64).reshape(-1, 2)
    centre = track.point_at(arc)
    heading = track.heading_at(arc)
    wrapped = np.mod(arc, track.length)
    left_normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    left = centre + 0.5 * np.interp(wrapped, track.arc_length, track.left_width)[:, None] * left_normal
    right = centre - 0.5 * np.interp(wrapped, track.arc_length, track.right_width)[:, None] * left_normal
    use_left = np.hypot(*(near - left).T) <= np.hypot(*(near - right).T)
    return pose_for_reference(np.where(use_left[:, None], left, right), heading, reference_offset)


RESET_BEHIND = 1.0  # m: simapp's DEFAULT_RESET_BEHIND_DIST and CLOSEST_OBJ_GAP


def behind_objects(sim: Simulator, cars: np.ndarray, travel: np.ndarray, near: np.ndarray):
    """DeepRacer's reset near a static object (simapp ``_get_car_reset_model_state``): a car whose
    reset point lies within 1 m (along the track) of a box is put 1 m behind it, in the other lane.
    Returns the new ``travel`` (K,) and the points (K, 2) that choose the lane."""
    from laplab.sim.obstacles import BOX
    from laplab.sim.simulator import wrapped_travel
    field = sim.field
    if field is None or not (sim.obstacles.kind[cars] == BOX).any():
        return travel, near
    travel, near = travel.copy(), near.copy()
    length = sim.track.length
    st, ob = sim.state, sim.obstacles
    gap = wrapped_travel(field.arc[cars] - (st.start_arc[cars] + travel)[:, None], length)
    gap = np.where(ob.kind[cars] == BOX, gap, np.inf)
    nearest = np.abs(gap).argmin(axis=1)
    rows = np.arange(cars.size)
    close = np.abs(gap[rows, nearest]) < RESET_BEHIND
    if close.any():
        travel[close] += gap[rows, nearest][close] - RESET_BEHIND
        arc = st.start_arc[cars[close]] + travel[close]
        centre = sim.track.point_at(arc)
        box = np.column_stack([ob.x[cars[close], nearest[close]], ob.y[cars[close], nearest[close]]])
        near[close] = 2.0 * centre - box  # the lane away from the box
    return travel, near


def put_back(sim: Simulator, cars: np.ndarray, travel: np.ndarray) -> None:
    """Put ``cars`` back on the track at the distances ``travel`` (K,) m from their start (DeepRacer's
    reset after an incident): quarter-width lane nearer to where each car is, at rest, counters cleared;
    near a box, 1 m behind it in the other lane (:func:`behind_objects`).
    """
    st = sim.state
    track = sim.track
    near = np.column_stack([st.ref_x[cars], st.ref_y[cars]])
    travel, near = behind_objects(sim, cars, np.asarray(travel, dtype=np.float64), near)
    arc = st.start_arc[cars] + travel
    sim.place(cars, reset_poses(track, sim.vehicle.reference_offset, arc, near))
    stranded = cars[st.status[cars] != IN_PROGRESS]
    if stranded.size:  # a lane off the road (a freak border): use the centre line
        arc_c = st.start_arc[stranded] + travel[np.isin(cars, stranded)]
        sim.place(stranded, pose_for_reference(track.point_at(arc_c), track.heading_at(arc_c),
                                                 sim.vehicle.reference_offset))
        if (st.status[stranded] != IN_PROGRESS).any():
            raise RuntimeError(f"cannot put cars {stranded.tolist()} back on track {track.name!r}")
    sim.set_travel(cars, travel)


def _rows(sim: Simulator, cars: np.ndarray, trials: np.ndarray, clock: np.ndarray, steps: np.ndarray,
          status: np.ndarray, done: np.ndarray, action: np.ndarray, penalty: np.ndarray,
          crashes: np.ndarray, wall: float) -> dict[str, np.ndarray]:
    """Simtrace columns of K rows, one per car of ``cars`` (its current state); ``status`` holds row
    status indices into ``_ROW_STATUS``; ``clock`` is trial time, shifted onto the evaluation clock later."""
    k = cars.size
    rows = simtrace_rows(sim, cars, action, np.zeros(k), episode=trials, steps=steps, tstamp=clock, done=done,
                         episode_status=status, pause_duration=penalty.astype(np.float64),
                         obstacle_crash_counter=crashes.astype(np.int64), wall_clock=np.full(k, wall))
    if sim.field is not None:  # each row's obstacles (K, slots, 6), for videos; not a simtrace column
        rows[OBSTACLES_KEY] = np.stack(list(sim.obstacles.rows(cars)), axis=-1)
    return rows


def run_trials(stepper: EpisodeStepper, observe: Callable[[np.ndarray], Any], act: Callable[[Any], np.ndarray],
               settings: Any) -> TrialRun:
    """Drive ``settings.trials`` trials on ``stepper.sim`` (one car per trial, or one car for all of them
    when ``settings.continuous``) and return them.

    ``observe(cars)`` gives the observations of the cars (K,) as a batch; ``act(obs)`` the env actions
    for that batch (indices, or points of [-1, 1]^2). ``settings`` supplies trials, continuous,
    off_track_penalty, crash_penalty, resets (None: unlimited) and max_trial_time (s).
    """
    sim, action_space = stepper.sim, stepper.action_space
    n_trials, slots, dt = int(settings.trials), sim.num_cars, sim.dt
    if slots != (1 if settings.continuous else n_trials):
        raise ValueError(f"run_trials: {slots} cars for {n_trials} trials (continuous={settings.continuous})")
    st = sim.state
    reset_budget = -1 if settings.resets is None else int(settings.resets)  # -1: unlimited
    trial_of = np.arange(slots)
    clock, trial_steps = np.zeros(slots), np.zeros(slots, np.int64)
    resets_left = np.full(slots, reset_budget, np.int64)
    counts = np.zeros((n_trials, len(INCIDENTS)), np.int64)
    resets, penalties = np.zeros(n_trials, np.int64), np.zeros(n_trials)
    finished: dict[int, dict[str, Any]] = {}
    parts: list[dict[str, np.ndarray]] = []
    decisions = 0
    sim.reset(ndist=np.zeros(slots))
    while True:
        active = np.flatnonzero(st.status == IN_PROGRESS)
        if active.size == 0:
            break
        env_actions = np.asarray(act(observe(active)))
        prev_travel = st.travel.copy()
        stepper.step(env_actions, active)
        decisions += active.size
        clock[active] += dt
        trial_steps[active] += 1
        code = st.status[active].copy()
        trial = trial_of[active]
        lap = code == LAP_COMPLETE
        kind = _INCIDENT_INDEX[code]
        incident = kind >= 0
        time_up = (code == IN_PROGRESS) & (clock[active] >= settings.max_trial_time)
        np.add.at(counts, (trial[incident], kind[incident]), 1)
        reset = incident & (resets_left[active] != 0)
        ends = lap | time_up | (incident & ~reset)
        row_status = np.where(time_up, TIME_UP, code)
        trace_action = trace_actions(action_space, env_actions)
        crash_so_far = counts[trial, INCIDENTS.index("crash")]
        wall = time.time()
        parts.append(_rows(sim, active, trial, clock[active], trial_steps[active], row_status, ends, trace_action,
                           penalties[trial], crash_so_far, wall))
        if reset.any():
            cars, owners = active[reset], trial[reset]
            penalty = np.where(code[reset] == CRASHED, settings.crash_penalty, settings.off_track_penalty)
            put_back(sim, cars, prev_travel[cars])
            sim.let_obstacles_drive(cars, penalty)  # bots drive on while the car stands
            resets[owners] += 1
            penalties[owners] += penalty
            resets_left[cars] -= resets_left[cars] > 0
            parts.append(_pause_rows(sim, cars, owners, clock[cars], penalty, trial_steps[cars],
                                     trace_action[reset], penalties[owners], crash_so_far[reset], wall))
            clock[cars] += penalty
        for car, status in zip(active[ends], row_status[ends]):
            finished[int(trial_of[car])] = _finish(st, car, int(status), clock[car], dt, trial_steps[car])
            index = int(trial_of[car])
            if settings.continuous and index + 1 < n_trials:
                if status == LAP_COMPLETE:  # flying start: the rest of this step belongs to the next lap
                    clock[car] -= finished[index]["lap_time"]
                    sim.continue_lap(np.array([car]))
                else:
                    sim.reset(np.arange(slots) == car, ndist=np.zeros(1))
                    clock[car] = 0.0
                trial_of[car] += 1
                trial_steps[car] = 0
                resets_left[car] = reset_budget
            elif status == TIME_UP:
                sim.end_episodes(np.array([car]), TIME_UP)
    return _assemble(finished, counts, resets, penalties, parts, decisions)


def _pause_rows(sim, cars, owners, clock, penalty, steps, action, penalty_total, crashes, wall):
    """Rows of the standing time after a reset: ceil(penalty / dt) per car, status ``pause``."""
    per_car = np.ceil(penalty / sim.dt - 1e-9).astype(np.int64)
    if per_car.sum() == 0:
        return _rows(sim, cars[:0], owners[:0], clock[:0], steps[:0], np.zeros(0, np.int64), np.zeros(0, bool),
                     action[:0], penalty_total[:0], crashes[:0], wall)
    repeat = np.repeat(np.arange(cars.size), per_car)
    within = np.arange(repeat.size) - np.repeat(np.cumsum(per_car) - per_car, per_car) + 1
    times = clock[repeat] + penalty[repeat] * within / per_car[repeat]
    return _rows(sim, cars[repeat], owners[repeat], times, steps[repeat], np.full(repeat.size, _PAUSE),
                 np.zeros(repeat.size, bool), action[repeat], penalty_total[repeat], crashes[repeat], wall)


def _finish(st, car: int, status: int, clock: float, dt: float, steps: int) -> dict[str, Any]:
    if status == LAP_COMPLETE:
        # The kernel interpolates the crossing within the step: st.lap_time counts from the car's
        # last sim reset, so only its part within the final step is used here.
        within_step = st.lap_time[car] - (st.steps[car] - 1) * dt
        lap_time = clock - dt + min(max(within_step, 0.0), dt)
        return {"status": "lap_complete", "lap_time": float(lap_time), "duration": float(lap_time),
                "completion": 100.0, "steps": int(steps)}
    return {"status": STATUS_NAMES[status], "lap_time": None, "duration": float(clock),
            "completion": float(st.progress[car]), "steps": int(steps)}


def _assemble(finished, counts, resets, penalties, parts, decisions) -> TrialRun:
    n_trials = counts.shape[0]
    if sorted(finished) != list(range(n_trials)):
        raise RuntimeError(f"evaluation loop ended with trials {sorted(finished)} of {n_trials} finished")
    durations = np.array([finished[i]["duration"] for i in range(n_trials)])
    starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    trials = tuple(TrialResult(
        index=i, status=finished[i]["status"], lap_time=finished[i]["lap_time"], duration=float(durations[i]),
        start_time=float(starts[i]), completion=finished[i]["completion"],
        off_track_count=int(counts[i, 0]), reversed_count=int(counts[i, 1]), immobilized_count=int(counts[i, 2]),
        crash_count=int(counts[i, 3]), reset_count=int(resets[i]), penalty_time=float(penalties[i]),
        steps=finished[i]["steps"]) for i in range(n_trials))
    trace = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    order = np.argsort(trace["episode"], kind="stable")
    trace = {name: values[order] for name, values in trace.items()}
    trace["tstamp"] = trace["tstamp"] + starts[trace["episode"]]
    trace["episode_status"] = _ROW_STATUS[trace["episode_status"]]
    return TrialRun(trials, trace, decisions, trace.pop(OBSTACLES_KEY, None))

