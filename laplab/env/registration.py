"""Gymnasium registration of laplab's environments.

``laplab/TimeTrial-v0`` is a single car, with the batched :class:`~laplab.env.vector.TimeTrialVectorEnv`
as its vector entry point for ``gym.make_vec``. It is registered three ways, all idempotent: by the
``laplab-gymnasium.pth`` start-up hook installed with the package (so ``gym.make("laplab/TimeTrial-v0")``
works without importing laplab; see the top-level module ``laplab_gymnasium_hook``), when :mod:`laplab.env` is imported,
and by the ``gymnasium.envs`` entry point declared in ``pyproject.toml`` for Gymnasium versions that
load plugins.
"""

from __future__ import annotations

import gymnasium as gym

from laplab_gymnasium_hook import ENV_ID, register_envs as _register

__all__ = ["ENV_ID", "register_envs"]


def register_envs() -> None:
    """Register laplab's environments with Gymnasium (idempotent). Imports no laplab module: the
    environments load when made."""
    _register(gym)
