"""One model through every stage with non-default settings: train -> evaluate -> export (ONNX) ->
runtime, for a continuous SAC model on stereo cameras stacked 3 frames deep plus a lidar.

Every stage rebuilds the model from its folder, so a setting that one stage forgets (the frame stack,
the sensor order, the action ranges) fails here. Tiny budget: 2 episodes, one short evaluation trial.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from laplab.env import TimeTrialEnv  # noqa: E402
from laplab.env.metadata import metadata_from_dict  # noqa: E402
from laplab.env.spec import model_spec, observation_space  # noqa: E402
from laplab.runtime import OnnxPolicy  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402

SENSORS = ["STEREO_CAMERAS", "LIDAR"]
STACK = 3
METADATA = {"sensor": SENSORS, "training_algorithm": "sac", "action_space_type": "continuous",
            "action_space": {"steering_angle": {"low": -25, "high": 30}, "speed": {"low": 0.6, "high": 1.8}},
            "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}


def test_the_observation_space_follows_from_the_spec_alone():
    spec = model_spec(metadata_from_dict(METADATA), STACK)
    space = observation_space(spec.metadata, STACK)
    assert space == spec.observation_space
    assert space["STEREO_CAMERAS"].shape == (2 * STACK, 120, 160) and space["LIDAR"].shape == (64,)
    env = TimeTrialEnv(track="oval", model_metadata=METADATA, stack_size=STACK, reward_function=None)
    assert env.observation_space == space  # the env builds the same space with a simulator


def test_stacked_stereo_lidar_sac_model_survives_every_stage(tmp_path, monkeypatch):
    from laplab.commands.export import export_model_onnx
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model
    from laplab.train.jobs import create_training
    from laplab.train.policy import load_model_policy

    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    base = TrainConfig()
    hyper = replace(base.hyper(), num_episodes_between_training=2, batch_size=32, num_epochs=3, stack_size=STACK)
    config = replace(base, track="oval", model_metadata=metadata_from_dict(METADATA), hyperparameters=hyper,
                     max_episodes=2, eval_episodes=1, precision="float32")
    result = create_training("pipeline", config).run()
    assert result.error is None and result.iterations == 1

    policy = load_model_policy("pipeline", "last")
    assert policy.spec == config.spec and policy.spec.stack_size == STACK
    assert policy.observation_space["STEREO_CAMERAS"].shape == (2 * STACK, 120, 160)

    evaluation, _ = evaluate_model("pipeline", EvaluationSettings(trials=1, checkpoint="last", resets=0,
                                                                   max_trial_time=3.0))
    assert len(evaluation.trials) == 1 and evaluation.decisions > 0

    export_model_onnx("pipeline", "last", tmp_path / "car")
    runtime = OnnxPolicy(tmp_path / "car")
    assert runtime.camera == "STEREO_CAMERAS" and runtime.stack == STACK and runtime.vector_names == ("LIDAR",)

    # The car sees what the simulator's cameras and lidar see, one step at a time; the runtime keeps
    # its own frame stack and must agree with the trained policy on the env's stacked observation.
    env = TimeTrialEnv(track="oval", model_metadata=METADATA, stack_size=STACK, reward_function=None, seed=3)
    obs, _ = env.reset(seed=3)
    low, high = np.array([-25.0, 0.6]), np.array([30.0, 1.8])
    for _ in range(STACK + 2):
        newest = obs["STEREO_CAMERAS"][-2:]  # (left, right) of the newest frame
        car = runtime.act([newest[0], newest[1]], {"LIDAR": obs["LIDAR"]})
        batch = {name: value[None] for name, value in obs.items()}
        expected = policy.act(batch, deterministic=True)[0]
        steer, speed = policy.metadata.action_space.to_physical(expected[None])
        assert np.allclose([car.steering_angle, car.speed], [steer[0], speed[0]], atol=1e-3 * (high - low).max())
        obs, _, terminated, truncated, _ = env.step(expected)
        if terminated or truncated:
            break
