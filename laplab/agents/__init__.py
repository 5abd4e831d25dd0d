"""Learning algorithms: DeepRacer's networks, PPO and SAC (torch), and hyperparameters.

``Hyperparameters`` and its loaders import without torch; the torch-based names load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from laplab.agents.hyperparameters import (HyperparameterError, Hyperparameters, from_dict,
                                           load_hyperparameters, save_hyperparameters)

_LAZY = {
    "PPOLearner": "laplab.agents.ppo",
    "Rollout": "laplab.agents.ppo",
    "SACLearner": "laplab.agents.sac",
    "ReplayBuffer": "laplab.agents.replay",
    "ActorCritic": "laplab.agents.networks",
    "ActionSpec": "laplab.agents.networks",
    "PolicyStep": "laplab.agents.networks",
    "build_embedder": "laplab.agents.networks",
    "action_spec_from": "laplab.agents.networks",
    "NETWORK_SCHEMES": "laplab.agents.networks",
    "DEFAULT_NETWORK": "laplab.agents.networks",
}

__all__ = ["HyperparameterError", "Hyperparameters", "from_dict", "load_hyperparameters",
           "save_hyperparameters", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'laplab.agents' has no attribute {name!r}")
