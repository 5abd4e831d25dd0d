"""Shared helpers of the evaluation tests."""

from __future__ import annotations

from dataclasses import replace

from laplab.env.metadata import ModelMetadata
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training

TINY_HYPERPARAMETERS = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}


def train_tiny_model(name: str, max_episodes: int = 8, max_time_s: float = 120, **changes) -> None:
    """Train model ``name`` for a few episodes with laplab's default metadata (``changes``: other
    TrainConfig fields, e.g. ``vehicle``) into ``$LAPLAB_HOME``."""
    hyper = {**TrainConfig().hyper().to_dict(), **TINY_HYPERPARAMETERS}
    config = replace(TrainConfig(), hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(),
                     max_episodes=max_episodes, max_time_s=max_time_s, **changes)
    create_training(name, config).run()
