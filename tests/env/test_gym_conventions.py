"""Gymnasium conventions: registration (entry point and function), rgb_array rendering, check_env."""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys
import tomllib
import warnings
import zipfile
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


def _installed_site_packages() -> Path | None:
    """The site-packages folder laplab is pip-installed in, or None (a bare checkout on PYTHONPATH)."""
    try:
        dist = importlib.metadata.distribution("laplab")
    except importlib.metadata.PackageNotFoundError:
        return None
    return Path(dist.locate_file(""))


def test_plain_make_works_in_a_fresh_interpreter_that_never_imports_laplab():
    """Installing laplab installs laplab-gymnasium.pth: gym.make("laplab/TimeTrial-v0") as
    Gymnasium's docs write it, with no laplab import in the user's code (and none before the make)."""
    site_packages = _installed_site_packages()
    if site_packages is None:
        pytest.skip("laplab is not pip-installed here (the hook comes with the install)")
    assert (site_packages / "laplab-gymnasium.pth").is_file(), f"no laplab-gymnasium.pth in {site_packages}"
    code = ("import sys, gymnasium as gym; assert 'laplab' not in sys.modules; "
            "assert 'laplab/TimeTrial-v0' in gym.registry; "
            "env = gym.make('laplab/TimeTrial-v0', track='oval'); obs, _ = env.reset(seed=0); "
            "print(type(env.unwrapped).__name__, obs.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/",
                         env={"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/")}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[0] == "TimeTrialEnv"


def test_the_hook_waits_for_gymnasium_and_registers_once():
    code = ("import sys; import laplab_gymnasium_hook as h; h.install(); h.install(); "
            "finders = [f for f in sys.meta_path if type(f).__name__ == '_GymnasiumFinder']; "
            "import gymnasium as gym; import laplab.env; "
            "print(len(finders), gym.registry['laplab/TimeTrial-v0'].entry_point, "
            "any(type(f).__name__ == '_GymnasiumFinder' for f in sys.meta_path))")
    out = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=REPO_ROOT,
                         env={"PYTHONPATH": os.pathsep.join([str(REPO_ROOT), *sys.path[1:]]),
                              "PATH": "/usr/bin:/bin"}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["1", "laplab.env.time_trial:TimeTrialEnv", "False"]


def test_a_moved_install_does_not_break_python_start_up(tmp_path):
    """If the hook module cannot be found (a source tree moved or deleted under an editable
    install), the .pth stays silent: no "Error processing line" at every Python start-up."""
    (tmp_path / "laplab-gymnasium.pth").write_text((REPO_ROOT / "laplab-gymnasium.pth").read_text())
    code = f"import site; site.addsitedir({str(tmp_path)!r}); print('started')"
    out = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=tmp_path,
                         env={"PATH": "/usr/bin:/bin"}, timeout=60)
    assert (out.returncode, out.stdout.strip(), out.stderr) == (0, "started", "")


@pytest.mark.parametrize("kind", ["wheel", "editable"])
def test_both_kinds_of_install_carry_the_hook(kind, tmp_path):
    """setup.py puts laplab-gymnasium.pth at the top of regular and editable wheels alike."""
    pytest.importorskip("setuptools")
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE", "laplab-gymnasium.pth",
                 "laplab_gymnasium_hook.py"):
        shutil.copy(REPO_ROOT / name, source / name)
    shutil.copytree(REPO_ROOT / "laplab", source / "laplab", ignore=shutil.ignore_patterns("__pycache__"))
    build = "build_wheel" if kind == "wheel" else "build_editable"
    code = f"from setuptools import build_meta; print(build_meta.{build}({str(tmp_path / 'dist')!r}))"
    (tmp_path / "dist").mkdir()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=source, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    wheel_name = out.stdout.strip().splitlines()[-1]
    with zipfile.ZipFile(tmp_path / "dist" / wheel_name) as wheel:
        names = wheel.namelist()
        assert "laplab-gymnasium.pth" in names
        assert wheel.read("laplab-gymnasium.pth").decode() == (REPO_ROOT / "laplab-gymnasium.pth").read_text()
        if kind == "wheel":
            assert "laplab_gymnasium_hook.py" in names


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
