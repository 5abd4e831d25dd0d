"""laplab model folders to export in DeepRacer's layouts and import back (tests of laplab import):
written as ``laplab train`` writes an untrained model (metadata, hyperparameters, reward, laplab.json,
checkpoint 0), without the reward validation sweep, with heads spread so outputs differ by frame."""

from __future__ import annotations

from dataclasses import replace

import torch

from laplab.env.metadata import ModelMetadata
from laplab.env.vector import DEFAULT_REWARD
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.train.config import TrainConfig
from laplab.train.trainer import build_learner, checkpoint_writer

CONTINUOUS = {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 3.0}}
# name: model_metadata.json overrides
MODELS = {
    "ppo-cam-lidar": {"sensor": ["FRONT_FACING_CAMERA", "LIDAR"]},
    "ppo-stereo-continuous": {"sensor": ["STEREO_CAMERAS"], "action_space_type": "continuous",
                              "action_space": CONTINUOUS},
    "ppo-deep-cam": {"sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK"},
    # DeepRacer's own stereo embedder (five 3x3 convolutions) with the deep network's 256, 128 middleware
    "ppo-stereo-deep": {"sensor": ["STEREO_CAMERAS"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_DEEP"},
    "sac-cam-sector": {"sensor": ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"], "training_algorithm": "sac",
                       "action_space_type": "continuous", "action_space": CONTINUOUS},
}


def make_model(name: str, seed: int = 3, **meta) -> TrainConfig:
    """Model ``name`` in $LAPLAB_HOME, checkpoint 0 with random weights (every parameter drawn anew)."""
    config = replace(TrainConfig(), model_metadata={**ModelMetadata().to_dict(), "version": "5", **meta},
                     hyperparameters={**TrainConfig().hyper().to_dict(), "batch_size": 32, "num_epochs": 3})
    learner = build_learner(config, seed, precision="float32")
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in learner.policy_network.parameters():
            fan_in = parameter[0].numel() if parameter.dim() > 1 else 1
            parameter.copy_(torch.randn(parameter.shape, generator=generator) / fan_in ** 0.5)
    folder = model_folder(name).create()
    folder.write_model_metadata(config.model_metadata.to_dict())
    folder.write_hyperparameters(config.hyper().to_dict())
    folder.write_reward_function(DEFAULT_REWARD.read_text())
    folder.write_laplab_config(config.to_dict())
    CheckpointStore(folder).save(checkpoint_writer(learner, 0, 0, 0, None), iteration=0, steps=0)
    return config
