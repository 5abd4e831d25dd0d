"""Evaluation rules on scripted drivers: lap time = driving time + penalties, resets at the previous
step's progress in the nearer quarter lane, incident counts, reset limits, time cap, continuous laps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.env.action_space import ActionSpace
from laplab.env.spec import model_spec
from laplab.env.metadata import ModelMetadata
from laplab.evaluate import EvaluationError, EvaluationSettings, evaluate_policy
from laplab.evaluate.runner import reset_poses
from laplab.sim.state import IN_PROGRESS
from laplab.track.geometry import track_from_route
from laplab.track.projection import project_points, track_arrays
from laplab.vehicle.params import CLASSIC

DEEPRACER = CLASSIC  # the scripted drivers steer laplab's classic car (no lags): the trial rules are the subject

SPEED = 1.5  # m/s
# Continuous actions: steering -30..30 deg, speed 0..2 m/s (0 lets a script stop the car).
METADATA = ModelMetadata(action_space=ActionSpace("continuous", (), (-30.0, 30.0), (0.0, 2.0)))
WINDOW = (30.0, 45.0)  # % of the lap where a scripted car misbehaves
DT = DEEPRACER.dt


@pytest.fixture(scope="module")
def wide_track(stadium_route):
    """Stadium with 6 m straights, 2 m radius ends, 2 m wide (quarter lanes 0.5 m off centre)."""
    return track_from_route(stadium_route(width=2.0), "wide-stadium")


def _steer_toward(sim, cars, targets):
    st = sim.state
    dx, dy = targets[:, 0] - st.x[cars], targets[:, 1] - st.y[cars]
    c, s = np.cos(st.yaw[cars]), np.sin(st.yaw[cars])
    forward, left = c * dx + s * dy, -s * dx + c * dy
    steer = np.arctan(2.0 * sim.vehicle.wheelbase * left / np.maximum(forward ** 2 + left ** 2, 1e-9))
    return np.clip(steer, -sim.vehicle.max_steering, sim.vehicle.max_steering)


class ScriptedDriver:
    """Follows the centre line at SPEED; car i misbehaves as ``behaviours[i]`` inside WINDOW:

    - ``off``: aims 2 m right of the road until it is reset (once); ``off-always``: every time.
    - ``stop``: commands 0 m/s until it is reset (immobilized).
    - ``uturn``: turns round and follows the centre line the wrong way until reset (reversed).
    - ``circle``: always full left lock (never finishes).
    A reset is recognised by the car jumping more than 0.15 m between two decisions.
    """

    def __init__(self, behaviours):
        self.behaviours = list(behaviours)

    def bind(self, sim):
        self.sim = sim
        n = sim.num_cars
        self.recovered = np.zeros(n, bool)
        self.turned = np.zeros(n, bool)
        self.last_xy = None  # set at the first decision (the cars are placed after binding)
        self.speeds_after_reset: list[float] = []

    def __call__(self, observations):
        sim, st = self.sim, self.sim.state
        cars = np.flatnonzero(st.status == IN_PROGRESS)
        assert len(observations) == cars.size
        xy = np.column_stack([st.x[cars], st.y[cars]])
        if self.last_xy is None:
            self.last_xy = np.column_stack([st.x, st.y])
        jumped = np.hypot(*(xy - self.last_xy[cars]).T) > 0.15
        self.speeds_after_reset += st.speed[cars][jumped].tolist()
        self.recovered[cars[jumped]] = True
        self.last_xy[cars] = xy
        track = sim.track
        steer = _steer_toward(sim, cars, track.point_at(st.arc[cars] + 0.6))
        speed = np.full(cars.size, SPEED)
        for k, car in enumerate(cars):
            behaviour = self.behaviours[car]
            inside = WINDOW[0] <= st.progress[car] <= WINDOW[1]
            if behaviour == "circle":
                steer[k] = sim.vehicle.max_steering
            elif behaviour is None or not inside or (self.recovered[car] and behaviour != "off-always"):
                continue
            elif behaviour in ("off", "off-always"):
                arc = st.arc[car] + 1.0
                heading = track.heading_at(arc)
                target = track.point_at(arc) + 2.0 * np.array([np.sin(heading), -np.cos(heading)])
                steer[k] = _steer_toward(sim, np.array([car]), target[None])[0]
            elif behaviour == "stop":
                speed[k] = 0.0
            elif behaviour == "uturn":
                rel = st.yaw[car] - track.heading_at(st.arc[car])
                self.turned[car] |= math.cos(rel) < -0.9
                if self.turned[car]:
                    steer[k] = _steer_toward(sim, np.array([car]), track.point_at(st.arc[car] - 0.6)[None])[0]
                else:
                    steer[k] = sim.vehicle.max_steering
                speed[k] = 0.8
        return np.column_stack([np.degrees(steer) / 30.0, speed - 1.0])


def _evaluate(track, behaviours, **settings):
    driver = ScriptedDriver(behaviours)
    settings.setdefault("trials", len(behaviours))
    settings.setdefault("force", True)
    result = evaluate_policy(driver, track, EvaluationSettings(**settings), spec=model_spec(METADATA),
                             vehicle=CLASSIC)
    return result, driver


BEHAVIOURS = [None, "off", "stop", "uturn"]


@pytest.fixture(scope="module")
def by_penalty(wide_track):
    """The same four scripted trials under off-track penalties of 0, 2 and 5 s."""
    return {penalty: _evaluate(wide_track, BEHAVIOURS, off_track_penalty=penalty) for penalty in (0.0, 2.0, 5.0)}


def test_each_incident_kind_is_counted_and_reset_once(by_penalty):
    result, driver = by_penalty[2.0]
    expected = [(0, 0, 0), (1, 0, 0), (0, 0, 1), (0, 1, 0)]  # (off track, reversed, immobilized)
    for trial, (off, rev, imm) in zip(result.trials, expected):
        assert trial.status == "lap_complete" and trial.completion == 100.0
        assert (trial.off_track_count, trial.reversed_count, trial.immobilized_count, trial.crash_count) == \
               (off, rev, imm, 0), trial
        assert trial.reset_count == off + rev + imm
        assert trial.penalty_time == pytest.approx(2.0 * trial.reset_count)
    assert driver.speeds_after_reset == [0.0, 0.0, 0.0]  # every reset leaves the car at rest
    assert result.summary.off_track_count == 1 and result.summary.reset_count == 3


def test_lap_time_is_driving_time_plus_penalties(by_penalty):
    clean, _ = by_penalty[0.0]
    for penalty in (2.0, 5.0):
        result, _ = by_penalty[penalty]
        for base, trial in zip(clean.trials, result.trials):
            assert trial.steps == base.steps  # the penalty changes the clock, not the driving
            assert trial.lap_time - base.lap_time == pytest.approx(penalty * trial.reset_count, abs=1e-9)
    for trial in clean.trials:  # without penalties the lap is the driving time, crossing interpolated
        assert (trial.steps - 1) * DT < trial.lap_time <= trial.steps * DT + 1e-12
    assert clean.trials[1].lap_time > clean.trials[0].lap_time  # the detour costs time


def test_reset_is_at_previous_progress_in_the_nearer_quarter_lane_facing_along(by_penalty, wide_track):
    result, driver = by_penalty[2.0]
    trace = result.trace
    rows = np.flatnonzero(trace["episode"] == 1)
    status = trace["episode_status"][rows]
    incident = rows[np.flatnonzero(status == "off_track")[0]]
    pauses = rows[status == "pause"]
    assert pauses.size == 30 and pauses[0] == incident + 1  # 2 s at 15 Hz, right after the incident
    previous_progress = trace["progress"][incident - 1]
    assert np.all(trace["progress"][pauses] == previous_progress)
    assert np.allclose(np.diff(trace["tstamp"][pauses]), DT) and \
        trace["tstamp"][pauses[-1]] == pytest.approx(trace["tstamp"][incident] + 2.0)
    # The reference point (the trace's X, Y) sits on the right quarter lane (the car left to the right)
    # at the previous step's progress, the car facing along the centre line.
    xy = np.column_stack([trace["X"][pauses[0]], trace["Y"][pauses[0]]])
    projection = project_points(track_arrays(wide_track), xy)
    assert projection.lateral[0] == pytest.approx(-0.5, abs=1e-6)
    start_arc = driver.sim.state.start_arc[1]
    progress = 100 * np.mod(projection.arc_length[0] - start_arc, wide_track.length) / wide_track.length
    assert progress == pytest.approx(previous_progress, abs=1e-6)
    heading = np.degrees(wide_track.heading_at(projection.arc_length[0]))
    assert np.mod(trace["yaw"][pauses[0]] - heading + 180, 360) - 180 == pytest.approx(0, abs=1e-6)
    # Driving resumes after the hold, one step later, from that spot.
    resumed = pauses[-1] + 1
    assert trace["episode_status"][resumed] == "in_progress"
    assert trace["tstamp"][resumed] == pytest.approx(trace["tstamp"][pauses[-1]] + DT)
    assert math.hypot(trace["X"][resumed] - xy[0, 0], trace["Y"][resumed] - xy[0, 1]) < 0.05


def test_reset_poses_pick_the_nearer_lane(stadium_track):
    # Bottom straight: waypoint 0 at (0, -2) heading +x, 1 m wide: lanes 0.25 m either side.
    near = np.array([[1.0, -2.6], [1.0, -1.9]])
    poses = reset_poses(stadium_track, 0.14, np.array([1.0, 1.0]), near)
    assert np.allclose(poses, [[0.86, -2.25, 0.0], [0.86, -1.75, 0.0]], atol=1e-9)


def test_without_resets_the_first_incident_ends_the_trial(wide_track):
    result, _ = _evaluate(wide_track, [None, "off"], resets=0)
    clean, off = result.trials
    assert clean.status == "lap_complete"
    assert off.status == "off_track" and off.lap_time is None
    assert (off.off_track_count, off.reset_count, off.penalty_time) == (1, 0, 0.0)
    assert WINDOW[0] < off.completion < WINDOW[1]
    assert off.duration == pytest.approx(off.steps * DT)
    assert result.summary.completed == 1 and result.summary.completion_rate == 0.5
    assert result.trace["done"][result.trace["episode"] == 1][-1]


def test_reset_limit_counts_every_incident(wide_track):
    result, _ = _evaluate(wide_track, ["off-always"], resets=2, off_track_penalty=2.0)
    trial = result.trials[0]
    assert trial.status == "off_track" and trial.lap_time is None
    assert (trial.off_track_count, trial.reset_count) == (3, 2)
    assert trial.penalty_time == 4.0
    assert trial.duration == pytest.approx(trial.steps * DT + 4.0)


def test_a_car_that_never_finishes_ends_at_the_time_cap(wide_track):
    result, _ = _evaluate(wide_track, ["circle"], max_trial_time=12.0)
    trial = result.trials[0]
    assert trial.status == "time_up" and trial.lap_time is None
    assert 12.0 <= trial.duration < 12.0 + DT + 2.0
    assert result.trace["episode_status"][-1] == "time_up" and result.trace["done"][-1]


def test_continuous_laps_run_on_from_the_line(wide_track):
    result, _ = _evaluate(wide_track, [None], trials=3, continuous=True)
    laps = [t.lap_time for t in result.trials]
    assert all(t.status == "lap_complete" for t in result.trials)
    # A standing start costs the acceleration (the next laps start flying), less the 0.14 m the first lap
    # starts ahead: DeepRacer counts it from the start pose's centre-line point, not the reference point.
    assert laps[0] > laps[1] + 0.05
    assert laps[1] == pytest.approx(laps[2], abs=0.02)
    starts = [t.start_time for t in result.trials]
    assert starts == pytest.approx([0.0, laps[0], laps[0] + laps[1]])
    assert np.all(np.diff(result.trace["tstamp"]) > 0)  # one clock for the whole run
    for trial in result.trials:
        # A lap's first decision ends one step after the start, plus, on a flying lap, the part of the
        # crossing step that came after the line.
        first = result.trace["tstamp"][result.trace["episode"] == trial.index][0]
        low = 0.0 if trial.index == 0 else DT
        assert low < first - trial.start_time <= low + DT + 1e-9
    assert result.summary.average_3 == pytest.approx(np.mean(laps))


def test_continuous_run_restarts_at_the_line_after_a_trial_ends(wide_track):
    standing, _ = _evaluate(wide_track, [None], trials=1)
    result, _ = _evaluate(wide_track, ["off"], trials=2, continuous=True, resets=0)
    assert [t.status for t in result.trials] == ["off_track", "lap_complete"]
    assert result.trials[1].lap_time == pytest.approx(standing.trials[0].lap_time, abs=1e-12)


def test_same_settings_same_trials(wide_track):
    first, _ = _evaluate(wide_track, BEHAVIOURS, seed=7)
    second, _ = _evaluate(wide_track, BEHAVIOURS, seed=7)
    assert first.trials == second.trials
    for name in first.trace:
        if name != "wall_clock":
            assert np.array_equal(first.trace[name], second.trace[name]), name


@pytest.mark.parametrize("changes", [{"trials": 0}, {"trials": 6}, {"trials": 101, "force": True},
                                     {"trials": 2.0}, {"resets": -1}, {"off_track_penalty": -1.0},
                                     {"crash_penalty": math.nan}, {"max_trial_time": 0.0}, {"checkpoint": ""}])
def test_settings_out_of_range_are_refused(changes):
    with pytest.raises(EvaluationError):
        EvaluationSettings(**changes)


def test_console_trial_limit_and_force():
    assert EvaluationSettings(trials=5).trials == 5
    with pytest.raises(EvaluationError, match="--force"):
        EvaluationSettings(trials=6)
    assert EvaluationSettings(trials=6, force=True).trials == 6


def test_a_summary_says_when_its_trials_were_identical():
    from laplab.evaluate.summary import TrialResult, summarize, summary_lines

    def trial(index, steps, lap=10.0):
        return TrialResult(index, "lap_complete", lap, lap, index * lap, 100.0, steps=steps)

    same = summarize([trial(0, 150), trial(1, 150), trial(2, 150)])
    assert same.identical_trials and "the 3 trials were identical" in summary_lines(same)[-1]
    varied = summarize([trial(0, 150), trial(1, 151, 10.07), trial(2, 150)])
    assert not varied.identical_trials and "identical" not in " ".join(summary_lines(varied))
    assert not summarize([trial(0, 150)]).identical_trials  # one trial is not "identical trials"
