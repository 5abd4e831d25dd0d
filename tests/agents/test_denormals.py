"""Learners compute as TensorFlow does on the CPU: denormal floats flush to zero, in the learner's
thread, in torch's worker threads and on a learner's second stream. (Trained camera networks carry
denormals that made gradient steps ~1.3x slower.) Checked in a fresh process, as a job runs: x86's
flags are per thread, and the worker threads exist before the learner when numba's parallel
simulator ran first (it shares torch's OpenMP runtime), as it does in every training."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

PROBE = """
import gymnasium as gym, numba, numpy as np, torch
from laplab.agents.ppo import PPOLearner
from laplab.agents.sac import SACLearner

def denormals():  # 1e-30 * 1e-10 = 1e-40 is a denormal float32 unless the thread flushes it
    return int(((torch.full((1 << 20,), 1e-30) * 1e-10) != 0).sum())

@numba.njit(parallel=True)
def simulate(x):  # the simulator's parallel steps start the OpenMP team before any learner exists
    for i in numba.prange(x.size):
        x[i] += 1.0

if {simulator_first}:
    simulate(np.zeros(1 << 16))
camera = gym.spaces.Box(0, 255, (2, 40, 48), np.uint8)
learner = {algorithm}(camera, {{"action_space": {{}}, "action_space_type": "continuous"}}, num_threads=2)
print(torch.get_num_threads(), denormals(), end=" ")
stream = getattr(learner, "value_stream", None)
if stream is not None:
    with stream() as side:
        print(side(denormals).result(), end=" ")
print(float(torch.tensor(1e-30) * 1e-10))
"""


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="FTZ/DAZ are x86's flags")
@pytest.mark.parametrize("algorithm,simulator_first", [("PPOLearner", True), ("SACLearner", True),
                                                     ("PPOLearner", False)])
def test_a_learner_flushes_denormals_on_every_thread_it_computes_on(algorithm, simulator_first):
    done = subprocess.run([sys.executable, "-c", PROBE.format(algorithm=algorithm, simulator_first=simulator_first)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    threads, *nonzero, smallest = done.stdout.split()
    assert int(threads) >= 1
    assert [int(n) for n in nonzero] == [0] * len(nonzero)  # the main thread (and its workers), the side stream
    assert float(smallest) == 0.0
