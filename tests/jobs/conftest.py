"""Fixtures of the reliability tests: a private LAPLAB_HOME and tiny, fast training settings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from laplab.train.config import TrainConfig

REPO_ROOT = Path(__file__).resolve().parents[2]
TINY_HP = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}


@pytest.fixture(autouse=True)
def laplab_home(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"


@pytest.fixture
def tiny_hp(tmp_path) -> Path:
    """A hyperparameters.json with 2 episodes per iteration and three epochs (iterations of ~1 s)."""
    path = tmp_path / "hyperparameters.json"
    path.write_text(json.dumps({**TrainConfig().hyper().to_dict(), **TINY_HP}))
    return path


@pytest.fixture
def laplab_cli(laplab_home):
    """Run ``python -m laplab.cli ARGS`` in a subprocess; returns a Popen (wait on it yourself)."""
    def start(*args, env: dict | None = None, **popen):
        environment = {**os.environ, "LAPLAB_HOME": str(laplab_home), "PYTHONPATH": str(REPO_ROOT), **(env or {})}
        popen.setdefault("stdout", subprocess.PIPE)
        popen.setdefault("stderr", subprocess.PIPE)
        return subprocess.Popen([sys.executable, "-m", "laplab.cli", *map(str, args)], env=environment, **popen)
    return start


@pytest.fixture
def tiny_config():
    """A TrainConfig with TINY_HP; pass changes as keyword arguments."""
    from dataclasses import replace

    def make(**changes) -> TrainConfig:
        return replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **TINY_HP}, **changes)
    return make
