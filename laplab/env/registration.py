"""Gymnasium registration of laplab's environments.

:func:`register_envs` registers ``laplab/TimeTrial-v0`` (single car, with the batched
:class:`~laplab.env.vector.TimeTrialVectorEnv` as its vector entry point for ``gym.make_vec``). It runs
when :mod:`laplab.env` is imported, and it is declared as the ``gymnasium.envs`` entry point in
``pyproject.toml``, for Gymnasium versions that load environment plugins. Gymnasium 1.x no longer
loads plugins; there ``gym.make("laplab.env:laplab/TimeTrial-v0")`` imports laplab from the id itself.
"""

from __future__ import annotations

import gymnasium as gym

ENV_ID = "laplab/TimeTrial-v0"


def register_envs() -> None:
    """Register laplab's environments with Gymnasium (idempotent). Imports no laplab module: the
    environments load when made."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="laplab.env.time_trial:TimeTrialEnv",
                     vector_entry_point="laplab.env.vector:TimeTrialVectorEnv")
