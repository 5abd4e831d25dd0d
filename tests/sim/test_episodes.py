"""Episodes: starts (round robin, fixed, alternating, reversed), progress across the finish line,
every termination status, per-car vs batched parity, seeded reset determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.sim.simulator import Simulator
from laplab.sim.state import (
    IMMOBILIZED, IN_PROGRESS, LAP_COMPLETE, REVERSED, STATUS_NAMES, EpisodeParams, SimState,
)
from laplab.track.projection import project_points, track_arrays
from laplab.vehicle.params import DEEPRACER

FIXED = dict(round_robin_advance=0.0)


def run_until_done(sim: Simulator, controller, speed: float, max_steps: int = 2000) -> list[float]:
    """Step every car with ``controller(sim)`` steering at ``speed`` until all are done; car 0's progress."""
    progress = []
    for _ in range(max_steps):
        if not (sim.state.status == IN_PROGRESS).any():
            break
        sim.step(controller(sim), np.full(sim.num_cars, speed))
        progress.append(float(sim.state.progress[0]))
    return progress


def expected_start(track, ndist: float) -> tuple[np.ndarray, float]:
    """Origin position and arc length of a car started at ``ndist``: its start pose's own centre-line
    point, from which DeepRacer counts progress (``start_ndist``)."""
    s0 = ndist * track.length
    return track.point_at(s0), s0


def reference_arc(track, ndist: float) -> float:
    """Arc length of the projection of the reference point of a car started at ``ndist``."""
    s0 = ndist * track.length
    yaw = float(track.heading_at(s0))
    ref = track.point_at(s0) + DEEPRACER.reference_offset * np.array([math.cos(yaw), math.sin(yaw)])
    return float(project_points(track_arrays(track), ref[None]).arc_length[0])


# ---------------------------------------------------------------- starts


def test_reset_places_cars_at_rest_on_the_centre_line(stadium_track):
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.3, **FIXED))
    assert sim.state.status[0] == -1  # not started
    sim.reset()
    st = sim.state
    origin, start_arc = expected_start(stadium_track, 0.3)
    np.testing.assert_allclose([st.x[0], st.y[0]], origin, atol=1e-12)
    assert st.yaw[0] == pytest.approx(float(stadium_track.heading_at(0.3 * stadium_track.length)))
    assert st.start_arc[0] == pytest.approx(start_arc, abs=1e-9)
    assert st.arc[0] == pytest.approx(reference_arc(stadium_track, 0.3), abs=1e-9)
    # the reference point is 0.14 m ahead (a little less along a bend): the lap is that far along
    assert st.travel[0] == pytest.approx(st.arc[0] - start_arc, abs=1e-9) and 0.13 < st.travel[0] <= 0.14
    assert st.progress[0] == 0.0  # until the first step, as simapp's current_progress after a reset
    assert st.speed[0] == st.steer[0] == 0.0
    assert st.steps[0] == 0 and st.status[0] == IN_PROGRESS and st.wheels_on[0] == 4
    np.testing.assert_allclose([st.ref_x[0], st.ref_y[0]],
                               origin + 0.14 * np.array([math.cos(st.yaw[0]), math.sin(st.yaw[0])]), atol=1e-12)
    assert sim.obs.shape == (1, 27) and np.isfinite(sim.obs).all()


def test_round_robin_starts_advance_by_a_twentieth_of_the_lap(stadium_track):
    sim = Simulator(stadium_track, 1)
    for episode in range(25):  # wraps past the finish line after 20 episodes
        sim.reset()
        origin, start_arc = expected_start(stadium_track, (0.05 * episode) % 1.0)
        np.testing.assert_allclose([sim.state.x[0], sim.state.y[0]], origin, atol=1e-9, err_msg=f"episode {episode}")
        assert sim.state.start_arc[0] == pytest.approx(start_arc, abs=1e-9)
        assert sim.state.episode[0] == episode + 1


def test_round_robin_starts_spread_over_the_cars_of_a_batch(stadium_track):
    sim = Simulator(stadium_track, 4, episode=EpisodeParams(start_ndist=0.1))
    sim.reset()
    for car in range(4):
        origin, _ = expected_start(stadium_track, 0.1 + 0.05 * car)
        np.testing.assert_allclose([sim.state.x[car], sim.state.y[car]], origin, atol=1e-9)
    sim.reset(np.array([False, False, True, False]))  # only car 2 starts its second episode
    origin, _ = expected_start(stadium_track, 0.1 + 0.05 * (1 + 2))
    np.testing.assert_allclose([sim.state.x[2], sim.state.y[2]], origin, atol=1e-9)
    origin, _ = expected_start(stadium_track, 0.1 + 0.05 * 1)
    np.testing.assert_allclose([sim.state.x[1], sim.state.y[1]], origin, atol=1e-9)  # untouched
    np.testing.assert_array_equal(sim.state.episode, [1, 1, 2, 1])

    together = Simulator(stadium_track, 3, episode=EpisodeParams(start_ndist=0.1, spread_starts=False))
    together.reset()
    np.testing.assert_allclose(together.state.x, together.state.x[0])


def test_fixed_start(stadium_track):
    sim = Simulator(stadium_track, 2, episode=EpisodeParams(start_ndist=0.6, **FIXED))
    origin, _ = expected_start(stadium_track, 0.6)
    for _ in range(4):
        sim.reset()
        np.testing.assert_allclose(np.stack([sim.state.x, sim.state.y], axis=1), [origin, origin], atol=1e-12)


def test_explicit_start_overrides_the_schedule(stadium_track):
    sim = Simulator(stadium_track, 2)
    sim.reset(ndist=np.array([0.2, 0.7]), direction=np.array([0, 1]))
    origin, _ = expected_start(stadium_track, 0.2)
    np.testing.assert_allclose([sim.state.x[0], sim.state.y[0]], origin, atol=1e-12)
    origin, _ = expected_start(stadium_track.reversed(), 0.7)
    np.testing.assert_allclose([sim.state.x[1], sim.state.y[1]], origin, atol=1e-12)
    np.testing.assert_array_equal(sim.state.direction, [0, 1])


def test_alternate_direction(stadium_track):
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.25, alternate_direction=True, **FIXED))
    forward_yaw = float(stadium_track.heading_at(0.25 * stadium_track.length))
    for episode in range(4):
        sim.reset()
        direction = episode % 2
        assert sim.state.direction[0] == direction
        assert sim.track_of(0) is sim.tracks[direction]
        if direction == 0:
            origin, _ = expected_start(stadium_track, 0.25)
            assert sim.state.yaw[0] == pytest.approx(forward_yaw)
        else:  # the reversed lap's quarter point is the forward lap's three-quarter point, facing backwards
            origin, _ = expected_start(stadium_track.reversed(), 0.25)
            np.testing.assert_allclose(origin, stadium_track.point_at(0.75 * stadium_track.length), atol=1e-9)
        np.testing.assert_allclose([sim.state.x[0], sim.state.y[0]], origin, atol=1e-9)


# ---------------------------------------------------------------- progress and lap completion


def test_progress_keeps_increasing_across_the_finish_line(stadium_track, pure_pursuit):
    """Start 5 % before waypoint 0: the projection wraps from ~length to ~0, progress must not."""
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.95, **FIXED))
    sim.reset()
    length = stadium_track.length
    start_arc = sim.state.start_arc[0]
    assert start_arc > 0.9 * length
    arcs, progress, travel = [], [], []
    while sim.state.status[0] == IN_PROGRESS and len(progress) < 1000:
        sim.step(pure_pursuit(sim), np.array([2.0]))
        arcs.append(sim.state.arc[0])
        progress.append(sim.state.progress[0])
        travel.append(sim.state.travel[0])
    arcs, progress = np.array(arcs), np.array(progress)
    crossing = int(np.argmax(np.diff(arcs) < -0.5 * length)) + 1
    assert crossing > 1 and arcs[crossing] < 0.1 * length  # the line was crossed on the way
    assert np.all(np.diff(progress) > 0)
    np.testing.assert_allclose(progress[crossing], 100 * (length - start_arc + arcs[crossing]) / length, atol=1e-6)
    assert progress[crossing] < 10.0
    assert sim.state.status[0] == LAP_COMPLETE
    assert progress[-1] == 100.0 and progress[-2] < 100.0
    steps = int(sim.state.steps[0])
    assert steps == len(progress)
    # the lap time is interpolated to the moment the reference point crossed 100 % within the last step
    fraction = (length - travel[-2]) / (travel[-1] - travel[-2])
    assert 0 < fraction <= 1
    assert sim.state.lap_time[0] == pytest.approx((steps - 1 + fraction) * sim.dt, abs=1e-9)
    assert travel[-1] >= length > travel[-2]


@pytest.mark.parametrize("reverse", [False, True])
def test_full_lap_completes_in_either_direction(reverse, pure_pursuit):
    from laplab.track.registry import load_track
    track = load_track("oval")
    sim = Simulator(track, 1, episode=EpisodeParams(start_ndist=0.3, reverse=reverse, **FIXED))
    sim.reset()
    assert sim.state.direction[0] == int(reverse)
    progress = run_until_done(sim, pure_pursuit, 1.5)
    assert STATUS_NAMES[sim.state.status[0]] == "lap_complete"
    assert progress[-1] == 100.0 and np.all(np.diff(progress) >= 0)
    lap_time = sim.state.lap_time[0]
    speed = 1.5 * sim.vehicle.speed_ratio  # DeepRacer's cars run a little faster than commanded
    # the lap at ~1.5 m/s, plus the launch (the car may cut the corners by a few centimetres)
    assert 0.98 * track.length / speed < lap_time < track.length / speed + 1.5
    assert sim.state.direction[0] == int(reverse)


def test_finished_cars_are_not_stepped(stadium_track):
    sim = Simulator(stadium_track, 2, episode=EpisodeParams(max_steps=3, **FIXED))
    sim.reset()
    for _ in range(3):
        sim.step(np.zeros(2), np.ones(2))
    frozen = SimState(*(a.copy() for a in sim.state))
    stepped = sim.step(np.zeros(2), np.ones(2))
    assert not stepped.any()
    for name, a, b in zip(SimState._fields, sim.state, frozen):
        np.testing.assert_array_equal(a, b, err_msg=name)


# ---------------------------------------------------------------- termination statuses


def test_off_track_when_steering_hard_at_speed(stadium_track):
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.1, **FIXED))
    sim.reset()
    run_until_done(sim, lambda s: np.array([DEEPRACER.max_steering]), 3.0, max_steps=100)
    assert STATUS_NAMES[sim.state.status[0]] == "off_track"
    assert sim.state.wheels_on[0] == 0
    assert sim.state.steps[0] < 40


def test_reversed_when_driving_the_wrong_way(stadium_track):
    """Turned round on the bottom straight, the car drives back: progress falls for 15 steps."""
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.1, **FIXED))
    sim.reset()
    sim.state.yaw[0] += math.pi
    statuses = []
    for _ in range(20):
        if sim.state.status[0] != IN_PROGRESS:
            break
        sim.step(np.zeros(1), np.ones(1))
        statuses.append(int(sim.state.status[0]))
    assert statuses == [IN_PROGRESS] * 14 + [REVERSED]
    # backing over the start line: DeepRacer's progress goes negative (no floor at 0)
    assert sim.state.wheels_on[0] == 4 and sim.state.progress[0] < 0.0
    assert sim.state.progress[0] == pytest.approx(100 * sim.state.travel[0] / stadium_track.length)


def test_reversed_needs_consecutive_steps(stadium_track):
    """A wrong-way step in between resets the count: backwards 10 steps, forward 1, backwards 10 again."""
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(start_ndist=0.1, reversed_steps=12, **FIXED))
    sim.reset()
    sim.state.yaw[0] += math.pi
    for _ in range(10):
        sim.step(np.zeros(1), np.full(1, 0.5))
    assert sim.state.reverse_count[0] == 10
    sim.state.yaw[0] -= math.pi  # face forward again for one step
    sim.step(np.zeros(1), np.full(1, 0.5))
    assert sim.state.reverse_count[0] == 0
    sim.state.yaw[0] += math.pi
    for _ in range(10):
        sim.step(np.zeros(1), np.full(1, 0.5))
    assert sim.state.status[0] == IN_PROGRESS


def test_immobilized_when_commanded_speed_is_zero(stadium_track):
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(**FIXED))
    sim.reset()
    statuses = []
    for _ in range(15):
        sim.step(np.zeros(1), np.zeros(1))
        statuses.append(int(sim.state.status[0]))
    assert statuses == [IN_PROGRESS] * 14 + [IMMOBILIZED]
    assert sim.state.immobile_count[0] == 15


def test_time_up_at_max_steps(stadium_track):
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(max_steps=5, **FIXED))
    sim.reset()
    statuses = []
    for _ in range(5):
        sim.step(np.zeros(1), np.ones(1))
        statuses.append(STATUS_NAMES[sim.state.status[0]])
    assert statuses == ["in_progress"] * 4 + ["time_up"]


def test_first_matching_rule_wins(stadium_track):
    """Standing still for max_steps = 15 steps fires both immobilized and time_up: immobilized comes first."""
    sim = Simulator(stadium_track, 1, episode=EpisodeParams(max_steps=15, **FIXED))
    sim.reset()
    for _ in range(15):
        sim.step(np.zeros(1), np.zeros(1))
    assert sim.state.status[0] == IMMOBILIZED


def test_every_status_in_one_batch(stadium_track, pure_pursuit):
    """Five cars, five endings, in one batched simulator (statuses are per car)."""
    sim = Simulator(stadium_track, 5, episode=EpisodeParams(start_ndist=0.1, max_steps=300, **FIXED))
    sim.reset()
    sim.state.yaw[2] += math.pi

    def controller(s):
        steer = pure_pursuit(s)
        steer[1] = DEEPRACER.max_steering
        steer[2] = 0.0
        return steer

    speed = np.array([3.0, 3.0, 1.0, 0.0, 0.3])
    for _ in range(300):
        if not (sim.state.status == IN_PROGRESS).any():
            break
        sim.step(controller(sim), speed)
    assert [STATUS_NAMES[s] for s in sim.state.status] == ["lap_complete", "off_track", "reversed", "immobilized",
                                                           "time_up"]
    assert sim.state.lap_time[0] > 0 and (sim.state.lap_time[1:] == 0).all()


# ---------------------------------------------------------------- parity and determinism


def test_batched_step_matches_single_car_runs(stadium_track, pure_pursuit):
    """40 cars in one (parallel) batch evolve exactly as 40 single-car simulators."""
    count = 40
    episode = EpisodeParams(start_ndist=0.0, max_steps=60)
    batch = Simulator(stadium_track, count, episode=episode)
    batch.reset(direction=np.arange(count) % 2)
    singles = [Simulator(stadium_track, 1, episode=episode) for _ in range(count)]
    for car, single in enumerate(singles):  # the batch spreads its starts: car i at i x 0.05 of the lap
        single.reset(ndist=[0.05 * car], direction=[car % 2])
    rng = np.random.default_rng(5)
    speeds = rng.uniform(0.5, 3.5, count)
    for _ in range(40):
        steer = pure_pursuit(batch) + rng.normal(0, 0.05, count)
        batch.step(steer, speeds)
        for car, single in enumerate(singles):
            single.step(steer[car:car + 1], speeds[car:car + 1])
    for name in SimState._fields:
        if name == "episode":
            continue
        got = getattr(batch.state, name)
        want = np.concatenate([getattr(s.state, name) for s in singles])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(batch.obs, np.vstack([s.obs for s in singles]), atol=1e-6)


def test_seeded_reset_is_deterministic():
    from laplab.env import TimeTrialEnv
    actions = np.random.default_rng(0).integers(0, 5, 40)

    def rollout(env):
        obs, _ = env.reset(seed=123)
        trace = [obs]
        for a in actions:
            obs, reward, terminated, truncated, _ = env.step(int(a))
            trace.append(np.append(obs, reward))
            if terminated or truncated:
                trace.append(env.reset()[0])
        return np.concatenate(trace)

    env = TimeTrialEnv(track="oval")
    first = rollout(env)
    for _ in range(3):  # later episodes move the round-robin start ...
        env.reset()
    np.testing.assert_array_equal(rollout(env), first)  # ... and a seeded reset restarts the schedule
    np.testing.assert_array_equal(rollout(TimeTrialEnv(track="oval")), first)
