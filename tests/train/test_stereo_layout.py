"""STEREO_CAMERAS with a deeper network: a new model builds deepracer-simapp's stereo embedder, and a
model folder an older laplab trained (laplab.json version 2, the camera scheme) keeps loading, training
and cloning with the layers it has (``stereo_layout`` "laplab-1")."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from torch import nn

from laplab.env.metadata import ModelMetadata
from laplab.env.vector import DEFAULT_REWARD
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.train.config import CONFIG_VERSION, ConfigError, TrainConfig
from laplab.train.trainer import build_learner, checkpoint_writer

STEREO_DEEP = {**ModelMetadata().to_dict(), "sensor": ["STEREO_CAMERAS"],
               "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_DEEP"}


def _convs(network: nn.Module) -> list[tuple[int, int, int]]:
    trunk = network.policy_trunk.sensors["observation"]
    return [(m.out_channels, m.kernel_size[0], m.stride[0]) for m in trunk.modules() if isinstance(m, nn.Conv2d)]


def test_a_new_stereo_deep_model_has_deepracers_layout_and_keeps_it():
    config = TrainConfig(model_metadata=STEREO_DEEP)
    assert config.stereo_layout == "deepracer" and config.spec.network_layout.endswith("+STEREO_CAMERAS")
    again = TrainConfig.from_dict(config.to_dict())
    assert again.stereo_layout == "deepracer" and again.to_dict()["version"] == CONFIG_VERSION == 3
    assert _convs(build_learner(config, 0, precision="float32").policy_network)[-1] == (128, 3, 1)
    with pytest.raises(ConfigError, match="stereo_layout") as error:
        TrainConfig(model_metadata=STEREO_DEEP, stereo_layout="mine")
    assert error.value.field == "stereo_layout"


def test_older_laplab_json_keeps_the_camera_scheme_only_where_it_mattered():
    old = {**TrainConfig().to_dict(), "version": 2}
    del old["stereo_layout"]
    stereo = TrainConfig.from_dict({**old, "model_metadata": STEREO_DEEP})
    assert stereo.stereo_layout == "laplab-1"
    assert TrainConfig.from_dict(stereo.to_dict()).stereo_layout == "laplab-1"  # written out, version 3
    shallow = {**STEREO_DEEP, "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}
    assert TrainConfig.from_dict({**old, "model_metadata": shallow}).stereo_layout == "deepracer"
    front = {**STEREO_DEEP, "sensor": ["FRONT_FACING_CAMERA"]}
    assert TrainConfig.from_dict({**old, "model_metadata": front}).stereo_layout == "deepracer"


def test_a_folder_trained_before_loads_and_clones_with_its_layers(monkeypatch, tmp_path):
    """An older laplab's stereo + deep model folder: its checkpoint loads (the same weights), a clone
    keeps its layers (test_console_checkpoint: the console export names why the simapp cannot restore it)."""
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    from laplab.train.jobs import clone_config
    from laplab.train.policy import load_model_policy
    config = replace(TrainConfig(), model_metadata=STEREO_DEEP, stereo_layout="laplab-1")
    learner = build_learner(config, 3, precision="float32")
    assert _convs(learner.policy_network) == [(32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)]
    folder = model_folder("old-stereo").create()
    folder.write_model_metadata(config.model_metadata.to_dict())
    folder.write_hyperparameters(config.hyper().to_dict())
    folder.write_reward_function(DEFAULT_REWARD.read_text())
    written = {**config.to_dict(), "version": 2}
    del written["stereo_layout"]  # as laplab.json version 2 had it
    folder.write_laplab_config(written)
    CheckpointStore(folder).save(checkpoint_writer(learner, 0, 0, 0, None), iteration=0, steps=0)
    policy = load_model_policy("old-stereo")
    assert policy.config.stereo_layout == "laplab-1"
    saved, loaded = learner.policy_network.state_dict(), policy.network.state_dict()
    assert saved.keys() == loaded.keys() and all(torch.equal(saved[k], loaded[k]) for k in saved)
    clone, weights = clone_config("old-stereo", {}, trust_reward=True)
    assert clone.stereo_layout == "laplab-1"
    build_learner(clone, 0, precision="float32").load_weights(weights)


def test_a_stereo_deep_model_trains_with_deepracers_stereo_layers(monkeypatch, tmp_path):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    from laplab.train.jobs import create_training
    from laplab.train.policy import load_model_policy
    hyper = {**TrainConfig().hyper().to_dict(), "num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
    config = replace(TrainConfig(), model_metadata=STEREO_DEEP, hyperparameters=hyper, max_episodes=2, max_time_s=300)
    trainer = create_training("stereo-deep", config)
    first_conv = trainer.learner.model.policy_trunk.sensors["observation"].convolutions[0].weight
    before = first_conv.detach().clone()
    assert tuple(before.shape) == (32, 2, 3, 3)
    result = trainer.run()
    assert result.episodes == 2 and not torch.equal(before, first_conv.detach())
    loaded = load_model_policy("stereo-deep")
    assert _convs(loaded.network) == [(32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1)]
    assert loaded.config.stereo_layout == "deepracer"
