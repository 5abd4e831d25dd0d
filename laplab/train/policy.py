"""A trained model's policy, loaded from its model folder: what evaluation and export start from."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np

from laplab.env.metadata import ModelMetadata
from laplab.env.observations import ObservationBuilder
from laplab.sim.simulator import Simulator
from laplab.store.layout import ModelFolder, model_folder
from laplab.train.config import TrainConfig
from laplab.train.checkpoint_read import read_checkpoint
from laplab.train.trainer import build_learner
from laplab.track.registry import load_track
from laplab.vehicle.params import vehicle_preset


@dataclass
class ModelPolicy:
    """A model's learner with the weights of one checkpoint.

    ``act(obs, deterministic)`` maps a batch of observations (leading axis B) to env actions: (B,)
    indices for a discrete action space, (B, 2) points of [-1, 1]^2 for a continuous one (scale them
    with ``metadata.action_space.to_physical``).
    """

    name: str
    folder: ModelFolder
    config: TrainConfig
    metadata: ModelMetadata
    checkpoint: str
    learner: Any
    observation_space: gym.Space

    def act(self, observations: Any, deterministic: bool = True) -> np.ndarray:
        if hasattr(self.learner, "model"):  # PPO
            return self.learner.act(observations, deterministic, with_value=False).env_action
        return self.learner.act(observations, deterministic)  # SAC

    @property
    def network(self):
        """The torch module mapping observations to action probabilities / means (PPO: the actor-critic)."""
        return self.learner.model if hasattr(self.learner, "model") else self.learner.actor


def load_model_policy(name: str, checkpoint: str = "best", seed: int = 0) -> ModelPolicy:
    """Load model ``name``'s policy at ``checkpoint`` (``best``, ``last`` or a checkpoint file name)."""
    folder = model_folder(name)
    if not folder.exists():
        raise FileNotFoundError(f"no model named {name!r} (looked in {folder.root}).")
    config = TrainConfig.from_dict(folder.read_laplab_config(), str(folder.laplab_config))
    checkpoint_name, state = read_checkpoint(folder, checkpoint)
    metadata = config.metadata()
    sim = Simulator(load_track(config.track), 1, vehicle_preset(config.vehicle))
    space = ObservationBuilder(sim, metadata, stack_size=config.hyper().stack_size).single_space
    # Driving, evaluation and export run in float32 whatever the training precision was.
    learner = build_learner(replace(config, precision="float32"), space, seed)
    try:
        learner.load_state_dict(state["learner"])
    except (KeyError, ValueError, RuntimeError, TypeError) as exc:
        from laplab.store.atomic import CorruptFileError
        raise CorruptFileError(f"checkpoint {str(folder.model_dir / checkpoint_name)!r} does not fit the model's "
                               f"network ({type(exc).__name__}: {' '.join(str(exc).split())[:200]}).") from None
    return ModelPolicy(name, folder, config, metadata, checkpoint_name, learner, space)
