"""Gymnasium environments: ``laplab/TimeTrial-v0`` (one car) and the batched ``TimeTrialVectorEnv``."""

import gymnasium as gym

from laplab.env.action_space import ActionSpace, ActionSpaceError, default_action_space
from laplab.env.metadata import MetadataError, ModelMetadata, load_model_metadata, metadata_from_dict
from laplab.env.time_trial import TimeTrialEnv
from laplab.env.vector import DEFAULT_REWARD, EXAMPLES_DIR, TimeTrialVectorEnv

ENV_ID = "laplab/TimeTrial-v0"
if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="laplab.env.time_trial:TimeTrialEnv",
                 vector_entry_point="laplab.env.vector:TimeTrialVectorEnv")

__all__ = ["ActionSpace", "ActionSpaceError", "DEFAULT_REWARD", "ENV_ID", "EXAMPLES_DIR", "MetadataError",
           "ModelMetadata", "TimeTrialEnv", "TimeTrialVectorEnv", "default_action_space", "load_model_metadata",
           "metadata_from_dict"]
