"""The one batched episode step and the one simtrace row builder; Simulator's public setters."""

from __future__ import annotations

import numpy as np
import pytest

from laplab.env.action_space import ActionSpace, default_action_space
from laplab.env.step import EpisodeStepper, simtrace_rows, trace_actions
from laplab.sim.simulator import Simulator
from laplab.sim.state import IN_PROGRESS, LAP_COMPLETE, STATUS_NAMES, TIME_UP, EpisodeParams
from laplab.track.registry import load_track


@pytest.fixture(scope="module")
def oval():
    return load_track("oval")


def test_step_returns_rewards_ends_params_and_rows_of_the_stepped_cars(oval):
    sim = Simulator(oval, 3, episode=EpisodeParams(max_steps=4))
    stepper = EpisodeStepper(sim, default_action_space(), lambda params: params["speed"])
    sim.reset()
    sim.end_episodes(np.array([2]), TIME_UP)  # car 2 is idle: not stepped
    result = stepper.step(np.array([9, 10, 11]), keep_params=True, trace=True)
    assert result.stepped.tolist() == [True, True, False]
    assert result.rewards.tolist() == [pytest.approx(1.33), pytest.approx(2.67), 0.0]
    assert result.params[2] is None and result.params[0]["speed"] == pytest.approx(1.33)
    assert result.trace["episode"].tolist() == [0, 1] and result.trace["action"].tolist() == [9, 10]
    assert result.trace["reward"].tolist() == result.rewards[:2].tolist()
    assert not result.done.any()
    for _ in range(3):
        result = stepper.step(np.array([9, 9, 9]))
    assert result.truncated[:2].all() and not result.terminated.any()  # the step cap truncates


def test_step_of_some_cars_and_continuous_trace_actions(oval):
    space = ActionSpace("continuous", (), (-30.0, 30.0), (0.5, 1.5))
    sim = Simulator(oval, 2)
    stepper = EpisodeStepper(sim, space)  # no reward function: rewards 0, no params
    sim.reset()
    result = stepper.step(np.array([[1.0, 1.0]]), cars=np.array([1]), trace=True)
    assert result.params is None and (result.rewards == 0).all()
    assert sim.state.cmd_speed.tolist() == [0.0, 1.5]
    # car 0 was in progress and stepped with zero commands; its row's action is the zero action's
    assert result.trace["action"].shape == (2, 2)
    assert result.trace["action"][1].tolist() == [30.0, 1.5]
    np.testing.assert_array_equal(trace_actions(space, np.array([[-1.0, -1.0]])), [[-30.0, 0.5]])


def test_simtrace_rows_take_callers_clock_and_extra_columns(oval):
    sim = Simulator(oval, 2)
    sim.reset()
    rows = simtrace_rows(sim, np.array([1]), np.array([3]), np.array([0.5]), episode=np.array([7]),
                         tstamp=np.array([12.5]), episode_status=np.array(["pause"]), wall_clock=np.array([1.0]))
    assert rows["episode"].tolist() == [7] and rows["tstamp"].tolist() == [12.5]
    assert rows["episode_status"].tolist() == ["pause"] and rows["wall_clock"].tolist() == [1.0]
    assert 0 <= rows["closest_waypoint"][0] < oval.num_waypoints - 1
    default = simtrace_rows(sim, np.array([0, 1]), np.array([0, 0]), np.zeros(2))
    assert default["episode_status"].tolist() == [STATUS_NAMES[IN_PROGRESS]] * 2
    assert list(default)[:4] == ["episode", "steps", "X", "Y"]


def test_simulator_public_setters(oval):
    sim = Simulator(oval, 2, episode=EpisodeParams(round_robin_advance=0.25))
    sim.reset()
    sim.restart_schedule(2)  # as if two episodes had run: the next start is half a lap on
    sim.reset()
    fixed = Simulator(oval, 1)
    fixed.reset(ndist=0.5)
    assert sim.state.start_arc[0] == pytest.approx(fixed.state.start_arc[0])
    sim.set_travel(np.array([1]), np.array([0.25 * oval.length]))
    assert sim.state.progress[1] == pytest.approx(25.0)
    sim.set_travel(np.array([1]), np.array([1.1 * oval.length]))
    sim.state.status[1] = LAP_COMPLETE
    sim.continue_lap(np.array([1]))
    assert sim.state.status[1] == IN_PROGRESS and sim.state.progress[1] == pytest.approx(10.0)
    sim.set_steps(np.array([0]), np.array([40]))
    sim.end_episodes(np.array([0]), TIME_UP)
    assert sim.state.steps[0] == 40 and sim.state.status[0] == TIME_UP
