"""The learner on a torch device (``laplab train --device cuda``): a camera training there writes a
model folder whose checkpoints hold CPU tensors (a plain ``torch.load`` reads them anywhere), which a
CPU loads and drives as the device's learner did, and the job resumes on the CPU from its resume
state (optimizer moments included).

The ``cpu`` row runs everywhere; the ``cuda`` rows run where torch sees a GPU (issue 13's learner on
a GPU), so a machine with one checks the GPU path with ``python -m pytest tests/train/test_learner_device.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from laplab.env.metadata import ModelMetadata
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training, resume_training
from laplab.train.resume_codec import map_tensors
from laplab.train.trainer import build_learner, load_checkpoint

CONTINUOUS = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 1.5}},
              "action_space_type": "continuous"}
NO_GPU = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no GPU")
ROWS = [  # the CPU row (the learner with the most state) runs everywhere, in seconds
    pytest.param("cpu", "sac", CONTINUOUS, id="sac-cpu"),
    pytest.param("cuda", "sac", CONTINUOUS, id="sac-cuda", marks=NO_GPU),
    pytest.param("cuda", "clipped_ppo", {}, id="ppo-discrete-cuda", marks=NO_GPU),
    pytest.param("cuda", "clipped_ppo", CONTINUOUS, id="ppo-continuous-cuda", marks=NO_GPU),
]


pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py


def camera_config(algorithm: str, meta: dict) -> TrainConfig:
    hyper = {**TrainConfig().hyper().to_dict(), "num_episodes_between_training": 4, "batch_size": 32,
             "num_epochs": 3}
    metadata = {**ModelMetadata().to_dict(), **meta, "training_algorithm": algorithm,
                "sensor": ["FRONT_FACING_CAMERA"]}
    return replace(TrainConfig(), hyperparameters=hyper, model_metadata=metadata, max_time_s=120, max_episodes=4)


def frames(config: TrainConfig, count: int = 6) -> np.ndarray:
    """``count`` random front-camera observations of the job's observation space (one Box)."""
    space = config.spec.observation_space
    return np.random.default_rng(0).integers(0, 256, (count, *space.shape)).astype(space.dtype)


def tensors(state) -> list[torch.Tensor]:
    """Every tensor in a checkpoint's nested dicts and lists."""
    found: list[torch.Tensor] = []
    map_tensors(state, found.append)
    return found


@pytest.mark.parametrize("device,algorithm,meta", ROWS)
def test_a_camera_model_trained_on_the_device_drives_the_same_on_the_cpu(device, algorithm, meta):
    config = camera_config(algorithm, meta)
    trainer = create_training("on-device", config, device=device)
    assert next(trainer.learner.policy_network.parameters()).device.type == device
    result = trainer.run()
    assert result.error is None and result.iterations == 1

    store = CheckpointStore(model_folder("on-device"))
    for path in (store.resolve("last"), store.resume_path(store.last().name)):
        raw = torch.load(path, weights_only=True)  # no map_location: the file's own devices
        assert all(t.device.type == "cpu" for t in tensors(raw)), f"{path.name} holds tensors on a GPU"
    state = load_checkpoint(store.resolve("last"))
    on_cpu = build_learner(config, seed=1, device="cpu")
    on_cpu.load_weights(state["learner"])
    observations = frames(config)
    driven = trainer.learner.act(observations, deterministic=True).env_action
    np.testing.assert_allclose(on_cpu.act(observations, deterministic=True).env_action, driven,
                               rtol=1e-3, atol=1e-4)

    trainer.close()  # the job is over, as `laplab train` ends it
    resumed = resume_training("on-device", max_episodes=8, device="cpu")
    assert resumed.iteration == 1
    after = resumed.run()
    assert after.error is None and after.iterations == 2 and after.episodes == 8
