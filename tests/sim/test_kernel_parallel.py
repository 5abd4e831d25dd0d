"""The parallel step loop (large batches) and the serial one (small batches) compute the same thing."""

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
