"""Collecting one episode per car: only the cars still driving act, and a car's episode is the same
whether the others drive beside it or not."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from laplab.train.collect import collect_episodes
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training

STARTS = np.array([0.0, 0.13, 0.31, 0.52, 0.77])


pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py


def trainer_with(cars: int, name: str):
    base = TrainConfig(track="oval", reward_path="laplab/reward/examples/follow_centerline.py")
    config = replace(base, hyperparameters=replace(base.hyper(), num_episodes_between_training=cars))
    return create_training(name, config)


class LinearPolicy:
    """A fixed policy acting row by row (a car's action depends on its own observation only), which
    records the batch size of every call. Its values and log-probabilities are made from the action so
    the test can tell which car's numbers landed where."""

    def __init__(self, observation_size: int, actions: int):
        self.weights = np.random.default_rng(3).normal(size=(observation_size, actions))
        self.batches: list[int] = []

    def __call__(self, observations):
        action = np.argmax(np.asarray(observations).reshape(len(observations), -1) @ self.weights, axis=1)
        self.batches.append(len(action))
        return action, action, -(action + 1.0).astype(np.float32), (action + 0.5).astype(np.float32)


def test_only_driving_cars_act_and_each_episode_is_what_it_would_be_alone():
    trainer = trainer_with(len(STARTS), "together")
    size = int(np.prod(trainer.spec.observation_space.shape))
    actions = int(trainer.spec.gym_action_space.n)
    policy = LinearPolicy(size, actions)
    batch = collect_episodes(trainer.stepper, trainer.observations, policy, ndist=STARTS)

    assert len(set(batch.steps.tolist())) > 1, "the cars' episodes should end at different steps"
    driving = batch.valid.sum(axis=1)
    assert policy.batches == driving.tolist()  # a waiting car is never in the policy's batch
    assert policy.batches[-1] < len(STARTS)
    waiting = ~batch.valid
    for name in ("actions", "log_probs", "values"):
        assert not getattr(batch, name)[waiting].any(), f"{name} of waiting cars are not zero"
    acted = batch.actions[batch.valid]
    np.testing.assert_array_equal(batch.log_probs[batch.valid], -(acted + 1.0))
    np.testing.assert_array_equal(batch.values[batch.valid], acted + 0.5)

    alone = trainer_with(1, "alone")
    for car, start in enumerate(STARTS):
        single = collect_episodes(alone.stepper, alone.observations, LinearPolicy(size, actions), ndist=start[None])
        assert single.steps[0] == batch.steps[car]
        assert single.status[0] == batch.status[car]
        np.testing.assert_allclose(single.progress[0], batch.progress[car])
        np.testing.assert_allclose(single.total_reward[0], batch.total_reward[car])
        alone_actions = single.actions[:, 0][single.valid[:, 0]]
        np.testing.assert_array_equal(alone_actions, batch.actions[:, car][batch.valid[:, car]])
