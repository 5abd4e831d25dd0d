"""SACLearner and its replay buffer: a 1-D continuous bandit, ring-buffer semantics, checkpoints."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.sac import ReplayBuffer, SACLearner

STATE = gym.spaces.Box(-1, 1, (1,), np.float32)
ONE_D = gym.spaces.Box(-1, 1, (1,))


def test_one_d_bandit_moves_to_the_optimum():
    best = 0.4
    hp = Hyperparameters(batch_size=64, lr=1e-3, sac_alpha=0.05, num_epochs=10)
    learner = SACLearner(STATE, ONE_D, hp, "MLP", seed=1, num_threads=1, buffer_capacity=5000)
    obs = np.zeros((64, 1), np.float32)
    start_error = abs(learner.act(obs[:1], deterministic=True).env_action[0, 0] - best)
    for _ in range(40):
        actions = learner.act(obs).action
        assert actions.shape == (64, 1) and np.abs(actions).max() < 1.0
        learner.observe(obs, actions, -(actions[:, 0] - best) ** 2, obs, np.ones(64))
        stats = learner.update(learner.gradient_steps_for(64))
    final = learner.act(obs[:1], deterministic=True).env_action[0, 0]
    assert abs(final - best) < 0.15 and abs(final - best) < start_error + 0.1
    assert stats["num_gradient_steps"] == 10 and np.isfinite(stats["critic_loss"])
    # the critic has learned the reward's shape: better near the optimum than at the far edge
    with torch.no_grad():
        q1, _ = learner.critic(torch.zeros(2, 1), torch.tensor([[best], [-0.9]]))
    assert q1[0] > q1[1] + 0.5


def test_replay_buffer_wraps_and_samples_dicts():
    space = gym.spaces.Dict({"FRONT_FACING_CAMERA": gym.spaces.Box(0, 255, (1, 4, 4), np.uint8),
                             "STATE": gym.spaces.Box(-1, 1, (2,), np.float32)})
    buffer = ReplayBuffer(5, space, 2)
    for start in (0, 3):  # 3 + 3 transitions into 5 slots: the oldest one is overwritten
        ids = np.arange(start, start + 3)
        obs = {"FRONT_FACING_CAMERA": np.broadcast_to(ids[:, None, None, None], (3, 1, 4, 4)).astype(np.uint8),
               "STATE": np.repeat(ids[:, None], 2, 1).astype(np.float32)}
        buffer.add(obs, np.zeros((3, 2)), ids.astype(np.float32), obs, np.zeros(3))
    assert len(buffer) == 5 and buffer.position == 1
    assert sorted(buffer.rewards.tolist()) == [1, 2, 3, 4, 5]
    batch = buffer.sample(32, np.random.default_rng(0))
    assert batch.observations["FRONT_FACING_CAMERA"].dtype == np.uint8
    np.testing.assert_array_equal(batch.observations["STATE"][:, 0], batch.rewards)
    np.testing.assert_array_equal(batch.observations["FRONT_FACING_CAMERA"][:, 0, 0, 0], batch.rewards)


def test_no_update_before_a_full_batch_and_discrete_rejected():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    learner.observe(np.zeros((8, 1)), np.zeros((8, 1)), np.zeros(8), np.zeros((8, 1)), np.zeros(8))
    assert learner.update(10)["num_gradient_steps"] == 0
    # 100 new steps, batch 32, 10 epochs: 10 * ceil(100 / 32) = 40
    assert learner.gradient_steps_for(100) == 40
    with pytest.raises(ValueError, match="continuous"):
        SACLearner(STATE, 3, Hyperparameters(), "MLP")


def test_state_dict_round_trip():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    obs = np.linspace(-1, 1, 40, dtype=np.float32)[:, None]
    learner.observe(obs, learner.act(obs).action, obs[:, 0], obs, np.ones(40))
    learner.update(3)
    restored = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=7)
    restored.load_state_dict(learner.state_dict())
    np.testing.assert_allclose(restored.act(obs, deterministic=True).env_action,
                               learner.act(obs, deterministic=True).env_action)
    assert restored.gradient_steps == 3
    with pytest.raises(ValueError, match="does not match"):
        restored.load_state_dict({**learner.state_dict(), "algorithm": "clipped_ppo"})
