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

from laplab.agents.networks import observation_to_tensor
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


def drive_outputs(learner, observations: np.ndarray, meta: dict) -> np.ndarray:
    """What the policy computes for ``observations``: the greedy continuous action, or every
    discrete action's log-probability and the value estimate (the argmax alone could flip between
    two near-equal actions under rounding, and greedy calls skip the value)."""
    if meta.get("action_space_type") == "continuous":
        return np.asarray(learner.act(observations, deterministic=True).env_action, dtype=np.float64).ravel()
    network = learner.policy_network
    with torch.no_grad():
        distribution, value = network(observation_to_tensor(observations, next(network.parameters()).device))
    return np.concatenate([distribution.logits.float().cpu().numpy().ravel(), value.float().cpu().numpy().ravel()])


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
    driven = drive_outputs(trainer.learner, observations, meta)
    # On a GPU the trunks compute in bfloat16 ("auto" on a bfloat16 GPU) and cuDNN convolves in TF32:
    # they round otherwise than the CPU (measured on an H200: SAC's actions up to 9e-4 apart, 2 %),
    # far closer than another network's weights drive (checked below: the tolerance hides no wrong
    # weights).
    tolerance = {"rtol": 1e-3, "atol": 1e-4} if device == "cpu" else {"rtol": 2e-2, "atol": 5e-3}
    np.testing.assert_allclose(drive_outputs(on_cpu, observations, meta), driven, **tolerance)
    stranger = drive_outputs(build_learner(config, seed=2, device="cpu"), observations, meta)
    assert np.abs(stranger - driven).max() > 10 * tolerance["atol"]

    trainer.close()  # the job is over, as `laplab train` ends it
    resumed = resume_training("on-device", max_episodes=8, device="cpu")
    assert resumed.iteration == 1
    after = resumed.run()
    assert after.error is None and after.iterations == 2 and after.episodes == 8
