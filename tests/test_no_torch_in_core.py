"""The simulator core runs with numpy and numba alone: a reward-function author never loads torch."""

import subprocess
import sys

CODE = """
import sys
import laplab.env, laplab.sim.simulator, laplab.track.registry, laplab.reward.validate
import laplab.sensors.camera, laplab.sensors.lidar, laplab.sensors.render, laplab.cli
from laplab.cli import main
assert main(['reward', 'validate', '/nonexistent/reward_function.py']) == 2  # the CLI's error path too
from laplab.env.vector import DEFAULT_REWARD
assert main(['reward', 'validate', str(DEFAULT_REWARD), '--track', 'oval']) == 0
env = laplab.env.TimeTrialVectorEnv(4, model_metadata={'sensor': ['FRONT_FACING_CAMERA', 'LIDAR']})
env.reset(seed=0)
env.step([2, 2, 2, 2])
print('torch' in sys.modules)
"""


def test_core_and_reward_validation_never_import_torch():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False", out.stdout + out.stderr
