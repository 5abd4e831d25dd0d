"""The step kernel: the parallel loop (large batches) and the serial one (small batches) compute the same
thing; its shortcut for wheels on the road agrees with the border tests."""

import numpy as np

from laplab.sim import kernel
from laplab.sim.simulator import Simulator
from laplab.track.registry import load_track


def test_parallel_and_serial_loops_agree_on_a_large_batch():
    n = kernel.PARALLEL_THRESHOLD + 44
    track = load_track("technical")
    sims = [Simulator(track, n) for _ in range(2)]
    rng = np.random.default_rng(3)
    for sim in sims:
        sim.reset()
    for _ in range(60):
        steer, speed = rng.uniform(-0.5, 0.5, n), rng.uniform(0.3, 3.0, n)
        for sim, loop in zip(sims, ("parallel", "serial")):
            args = (sim.state, steer, speed, sim.arrays[0], sim.arrays[1], sim._vc, sim._rules, sim.obs, *sim._look)
            if loop == "parallel":
                kernel._step_parallel(16, *args)
            else:
                kernel._step_range(0, n, *args)
    a, b = sims
    assert (a.state.steps > 0).all()
    for field in a.state._fields:
        np.testing.assert_array_equal(getattr(a.state, field), getattr(b.state, field), err_msg=field)
    np.testing.assert_array_equal(a.obs, b.obs)


def test_wheels_on_track_skip_the_border_tests_only_where_those_would_count_four():
    """The step counts a car's wheels on the road without testing them when its reference point lies
    well inside the segment's clearance; every count must equal the border tests' own."""
    from laplab.sim.state import IN_PROGRESS
    from laplab.track.projection import point_on_road_near
    from laplab.vehicle.dynamics import wheel_centers
    rng = np.random.default_rng(5)
    checked = shortcut = 0
    for name in ("technical", "classic_2018"):
        sim = Simulator(load_track(name), 200)
        sim.reset()
        for _ in range(50):
            was = sim.state.status == IN_PROGRESS
            sim.step(rng.uniform(-0.52, 0.52, sim.num_cars), rng.uniform(0.5, 4.0, sim.num_cars))
            st = sim.state
            cars = np.flatnonzero(was)
            wheels = wheel_centers(np.stack([st.x, st.y, st.yaw], axis=1)[cars], sim.vehicle)
            for car, points in zip(cars, wheels):
                geo = sim.arrays[st.direction[car]]
                counted = sum(point_on_road_near(x, y, geo, st.segment[car]) for x, y in points)
                assert st.wheels_on[car] == counted, (name, car, st.wheels_on[car], counted)
                checked += 1
                shortcut += abs(st.lateral[car]) + 0.12 < geo.clearance[st.segment[car]]
            sim.reset(st.status != IN_PROGRESS)
    assert checked > 12_000 and shortcut > checked // 3  # both ways taken many times
