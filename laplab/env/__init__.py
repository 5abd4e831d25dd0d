"""Gymnasium environments: ``laplab/TimeTrial-v0`` (one car) and the batched ``TimeTrialVectorEnv``."""

from laplab.env.action_space import ActionSpace, ActionSpaceError, default_action_space
from laplab.env.metadata import MetadataError, ModelMetadata, load_model_metadata, metadata_from_dict
from laplab.env.registration import ENV_ID, register_envs
from laplab.env.spec import ModelSpec, model_spec, observation_space
from laplab.env.time_trial import TimeTrialEnv
from laplab.env.vector import DEFAULT_REWARD, EXAMPLES_DIR, TimeTrialVectorEnv

register_envs()

__all__ = ["ActionSpace", "ActionSpaceError", "DEFAULT_REWARD", "ENV_ID", "EXAMPLES_DIR", "MetadataError",
           "ModelMetadata", "ModelSpec", "TimeTrialEnv", "TimeTrialVectorEnv", "default_action_space",
           "load_model_metadata", "metadata_from_dict", "model_spec", "observation_space", "register_envs"]
