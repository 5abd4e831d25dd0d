"""Gymnasium conventions: registration (entry point and function), rgb_array rendering, check_env."""

from __future__ import annotations

import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from laplab.env import ENV_ID, TimeTrialEnv, TimeTrialVectorEnv
from laplab.env.registration import register_envs

REPO_ROOT = Path(__file__).resolve().parents[2]


def test_the_gymnasium_entry_point_is_declared_and_names_the_registration_function():
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())
    target = project["project"]["entry-points"]["gymnasium.envs"]["laplab"]
    module, function = target.split(":")
    assert (module, function) == ("laplab.env.registration", "register_envs")


def test_register_envs_registers_the_env_and_its_vector_entry_point():
    gym.registry.pop(ENV_ID, None)
    register_envs()
    register_envs()  # idempotent
    spec = gym.registry[ENV_ID]
    assert spec.entry_point == "laplab.env.time_trial:TimeTrialEnv"
    assert spec.vector_entry_point == "laplab.env.vector:TimeTrialVectorEnv"


def test_make_from_a_fresh_interpreter_needs_no_laplab_import():
    code = ("import gymnasium as gym; env = gym.make('laplab.env:laplab/TimeTrial-v0', track='oval'); "
            "obs, _ = env.reset(seed=0); print(type(env.unwrapped).__name__, obs.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT,
                         env={"PYTHONPATH": str(REPO_ROOT), "PATH": "/usr/bin:/bin"}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[0] == "TimeTrialEnv"


@pytest.mark.parametrize("view,shape", [("topdown", None), ("camera", (480, 640, 3))])
def test_time_trial_renders_rgb_frames(view, shape):
    env = gym.make(ENV_ID, track="oval", render_mode="rgb_array", render_view=view, reward_function=None)
    assert env.metadata["render_fps"] == 15 and "rgb_array" in env.metadata["render_modes"]
    env.reset(seed=0)
    first = env.render()
    env.step(env.action_space.sample())
    for _ in range(5):
        env.step(9)
    later = env.render()
    for frame in (first, later):
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
        if shape is not None:
            assert frame.shape == shape
    assert not np.array_equal(first, later)  # the car moved


def test_render_mode_none_renders_nothing_and_bad_options_are_refused():
    assert TimeTrialEnv(track="oval", reward_function=None).render() is None
    with pytest.raises(ValueError, match="render_mode"):
        TimeTrialEnv(track="oval", render_mode="human")
    with pytest.raises(ValueError, match="render_view"):
        TimeTrialEnv(track="oval", render_mode="rgb_array", render_view="sideways")


def test_vector_env_renders_every_car_in_one_frame():
    env = TimeTrialVectorEnv(3, track="oval", render_mode="rgb_array", reward_function=None)
    assert env.metadata["render_fps"] == 15
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    camera = TimeTrialVectorEnv(2, track="oval", render_mode="rgb_array", render_view="camera", render_car=1,
                                reward_function=None)
    camera.reset(seed=0)
    assert camera.render().shape == (480, 640, 3)


def test_check_env_passes_with_rendering():
    env = gym.make(ENV_ID, track="oval", render_mode="rgb_array", reward_function=None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)  # check_env renders when a render mode is set
    assert not [w for w in caught if "render" in str(w.message).lower()]
