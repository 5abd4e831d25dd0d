"""Head-to-model races: two drivers in one simulator, each with its own policy, crashes between them,
the finishing order, and the refusal of opponents on another car."""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.env.action_space import ActionSpace
from laplab.env.metadata import ModelMetadata
from laplab.env.spec import model_spec
from laplab.evaluate.race import Driver, check_same_car, race_picture, run_race
from laplab.sim.race_type import RaceTypeError
from laplab.track.geometry import track_from_route
from laplab.vehicle.params import CLASSIC

SPEC = model_spec(ModelMetadata(action_space=ActionSpace("continuous", (), (-30.0, 30.0), (0.0, 2.0))))


@pytest.fixture(scope="module")
def wide_track(stadium_route):
    return track_from_route(stadium_route(width=2.0), "wide-stadium")


def state_driver(speed: float, keep_lane: bool):
    """Steers from the STATE vector alone: toward the centre line 0.9 m ahead, shifted by the car's own
    offset when it keeps its lane; drives at ``speed`` m/s."""
    def act(obs):
        o = np.asarray(obs)[0]
        forward, left = 3.0 * o[11], 3.0 * o[12]  # lookahead point 3 (0.9 m), unscaled
        if keep_lane:
            left += 0.5 * (o[4] - o[3])  # the reference point's offset from the centre line
        steer = math.atan(2.0 * CLASSIC.wheelbase * left / max(forward ** 2 + left ** 2, 1e-9))
        steer = max(min(steer, CLASSIC.max_steering), -CLASSIC.max_steering)
        return np.array([[math.degrees(steer) / 30.0, speed - 1.0]])
    return act


def test_two_drivers_race_and_the_faster_wins(wide_track):
    drivers = [Driver("slow", state_driver(1.0, True), SPEC), Driver("fast", state_driver(1.6, True), SPEC)]
    result = run_race(drivers, wide_track, CLASSIC, laps=1, max_time=60.0)
    assert [r.name for r in result.racers] == ["fast", "slow"]
    assert all(r.laps == 1 and r.finish_time is not None for r in result.racers)
    assert result.racers[0].finish_time < result.racers[1].finish_time
    assert all(r.crash_count == 0 for r in result.racers)
    # they started side by side, in different lanes
    start = result.poses[0]
    assert np.hypot(*(start[0, :2] - start[1, :2])) > 0.4
    picture = race_picture(result, ["slow", "fast"])
    assert picture.ndim == 3 and picture.dtype == np.uint8


def test_cars_that_meet_crash_and_are_put_back(wide_track):
    drivers = [Driver("a", state_driver(1.5, False), SPEC), Driver("b", state_driver(1.5, False), SPEC)]
    result = run_race(drivers, wide_track, CLASSIC, laps=1, max_time=40.0)
    assert sum(r.crash_count for r in result.racers) >= 1
    assert all(r.penalty_time >= 5.0 * r.crash_count for r in result.racers)


def test_a_stopped_race_ends_at_the_step_it_is_asked_and_ranks_the_cars_so_far(wide_track):
    asked = []

    def stop_after_30_steps() -> bool:
        asked.append(1)
        return len(asked) > 30

    drivers = [Driver("slow", state_driver(1.0, True), SPEC), Driver("fast", state_driver(1.6, True), SPEC)]
    result = run_race(drivers, wide_track, CLASSIC, laps=1, max_time=60.0, should_stop=stop_after_30_steps)
    assert result.stopped and result.to_dict()["stopped"] is True
    assert len(result.clock) == 31 and result.clock[-1] == pytest.approx(30 * (result.clock[1] - result.clock[0]))
    assert [r.name for r in result.racers] == ["fast", "slow"] and all(r.finish_time is None for r in result.racers)
    assert not run_race(drivers, wide_track, CLASSIC, laps=1, max_time=1.0).stopped


def test_opponent_on_another_car_is_refused():
    check_same_car(["a", "b"], ["deepracer-v6", "deepracer-v6"])
    with pytest.raises(RaceTypeError, match="opponent 'b' drives deepracer-v4") as error:
        check_same_car(["a", "b"], ["deepracer-v6", "deepracer-v4"])
    assert error.value.field == "opponent"
