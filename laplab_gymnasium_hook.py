"""Registers laplab's Gymnasium environments the moment Gymnasium is imported, without importing laplab.

A top-level module (not inside the laplab package) so that running it at start-up puts nothing of
laplab in ``sys.modules``: which laplab loads is decided later, by the usual import, when an
environment is made.

Gymnasium 1.x loads no environment plugins, so ``gym.make("laplab/TimeTrial-v0")`` would not know the
id until laplab is imported. The file ``laplab-gymnasium.pth``, installed beside the package, runs
:func:`install` at interpreter start-up: it adds a finder that waits for ``import gymnasium`` and then
registers the ids with string entry points (nothing of laplab loads until an environment is made).
Start-up cost: importing this module (standard library only; about 1 ms, python -X importtime).
"""

from __future__ import annotations

import importlib.machinery
import sys

ENV_ID = "laplab/TimeTrial-v0"
ENTRY_POINT = "laplab.env.time_trial:TimeTrialEnv"
VECTOR_ENTRY_POINT = "laplab.env.vector:TimeTrialVectorEnv"


def register_envs(gym) -> None:
    """Register laplab's environments with the ``gymnasium`` module ``gym`` (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT)


class _RegisterAfterExec:
    """Gymnasium's own loader, then :func:`register_envs` on the loaded module."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        try:
            register_envs(module)
        except Exception:  # a Gymnasium without register(): laplab's own import registers later
            pass

    def __getattr__(self, name):  # resources, get_data, ...: the real loader's
        return getattr(self._loader, name)


class _GymnasiumFinder:
    """Finds ``gymnasium`` as the other finders would, and wraps its loader once."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisterAfterExec(spec.loader)
        return spec


def install() -> None:
    """Run from ``laplab-gymnasium.pth`` at start-up; does nothing when Gymnasium is already loaded."""
    if "gymnasium" in sys.modules:
        register_envs(sys.modules["gymnasium"])
    elif not any(isinstance(finder, _GymnasiumFinder) for finder in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumFinder())
