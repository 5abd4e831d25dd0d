"""A trained model's policy, loaded from its model folder: what evaluation and export start from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from laplab.agents.learner import Learner
from laplab.env.metadata import ModelMetadata
from laplab.env.spec import ModelSpec
from laplab.store.atomic import CorruptFileError
from laplab.store.layout import ModelFolder, model_folder
from laplab.train.checkpoint_read import read_checkpoint
from laplab.train.config import TrainConfig
from laplab.train.model_files import check_model_files
from laplab.train.trainer import build_learner


@dataclass
class ModelPolicy:
    """A model's learner with the weights of one checkpoint.

    ``act(obs, deterministic)`` maps a batch of observations (leading axis B) to env actions: (B,)
    indices for a discrete action space, (B, 2) points of [-1, 1]^2 for a continuous one (scale them
    with ``metadata.action_space.to_physical``). ``spec`` is the model's :class:`ModelSpec` (sensors,
    frame stack, network, action space): evaluation and export build everything from it.
    """

    name: str
    folder: ModelFolder
    config: TrainConfig
    spec: ModelSpec
    checkpoint: str
    learner: Learner

    @property
    def metadata(self) -> ModelMetadata:
        return self.spec.metadata

    @property
    def observation_space(self) -> gym.Space:
        return self.spec.observation_space

    def act(self, observations: Any, deterministic: bool = True) -> np.ndarray:
        return self.learner.act(observations, deterministic).env_action

    @property
    def network(self):
        """The torch module mapping observations to action probabilities / means (PPO: the actor-critic)."""
        return self.learner.policy_network


def load_model_policy(name: str, checkpoint: str = "best", seed: int = 0) -> ModelPolicy:
    """Load model ``name``'s policy at ``checkpoint`` (``best``, ``last`` or a checkpoint file name)."""
    folder = model_folder(name)
    if not folder.exists():
        raise FileNotFoundError(f"no model named {name!r} (looked in {folder.root}).")
    config = check_model_files(folder, what="load", hyperparameter_keys=("stack_size",))  # laplab.json, and DeepRacer's files agree with it
    checkpoint_name, state = read_checkpoint(folder, checkpoint)
    try:
        learner_state = state["learner"]
    except (KeyError, TypeError):
        raise CorruptFileError(f"checkpoint {str(folder.model_dir / checkpoint_name)!r} has no learner state.") from None
    return policy_from_state(name, folder, config, checkpoint_name, learner_state, seed,
                             where=str(folder.model_dir / checkpoint_name))


def policy_from_state(name: str, folder: ModelFolder | None, config: TrainConfig, checkpoint_name: str,
                      learner_state: dict, seed: int = 0, where: str | None = None) -> ModelPolicy:
    """The policy of ``config``'s network with ``learner_state`` (a checkpoint's learner state): what
    :func:`load_model_policy` returns, built where no model folder is (``folder`` None), e.g. on a Ray
    node evaluating a race submission (:mod:`laplab.cluster.evaluations`)."""
    # Driving, evaluation and export run in float32 whatever the training precision was.
    learner = build_learner(config, seed, precision="float32")
    try:
        learner.load_state_dict(learner_state)
    except (KeyError, ValueError, RuntimeError, TypeError) as exc:
        raise CorruptFileError(f"checkpoint {where or checkpoint_name!r} does not fit the model's "
                               f"network ({type(exc).__name__}: {' '.join(str(exc).split())[:200]}).") from None
    return ModelPolicy(name, folder, config, config.spec, checkpoint_name, learner)
