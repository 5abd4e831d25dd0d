"""PPOLearner: learns trivial bandits, e-greedy schedule, rollouts with truncation/masks, checkpoints."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.ppo import PPOLearner, Rollout

STATE = gym.spaces.Box(-1, 1, (1,), np.float32)
FAST = Hyperparameters(batch_size=32, num_epochs=5, lr=1e-3)


def _one_step_rollout(obs, step, rewards):
    """Every episode lasts one step: T = 1, N = batch."""
    return Rollout(obs[None], step.action[None], step.log_prob[None], step.value[None],
                   rewards[None].astype(np.float32), np.ones((1, len(rewards)), bool))


def _probability(learner, obs, action):
    with torch.no_grad():
        distribution, _ = learner.model(torch.as_tensor(obs[:1]))
    return distribution.probs[0, action].item()


def test_discrete_bandit_learns_the_paying_action():
    learner = PPOLearner(STATE, 4, FAST, "MLP", seed=0, num_threads=1)
    obs = np.ones((64, 1), np.float32)
    assert _probability(learner, obs, 2) == pytest.approx(0.25, abs=0.02)
    for _ in range(10):
        step = learner.act(obs)
        stats = learner.update(_one_step_rollout(obs, step, (step.env_action == 2).astype(np.float32)))
    assert _probability(learner, obs, 2) > 0.8
    assert set(stats) >= {"policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"}
    assert all(np.isfinite(v) for v in stats.values())
    # 64 steps in minibatches of 32, 5 epochs
    assert stats["num_minibatches"] == 10 and stats["num_steps"] == 64


def test_continuous_bandit_improves():
    target = np.array([0.5, -0.3])
    hp = Hyperparameters(batch_size=64, num_epochs=4, lr=1e-3)
    learner = PPOLearner(STATE, gym.spaces.Box(-1, 1, (2,)), hp, "MLP", seed=0, num_threads=1)
    obs = np.ones((128, 1), np.float32)
    mean_rewards = []
    for _ in range(25):
        step = learner.act(obs)
        assert np.abs(step.env_action).max() <= 1.0
        rewards = -((step.env_action - target) ** 2).sum(1)
        mean_rewards.append(rewards.mean())
        learner.update(_one_step_rollout(obs, step, rewards))
    # std 1 at the start averages about -1.4; a narrower policy near the target does much better
    assert np.mean(mean_rewards[-5:]) > mean_rewards[0] + 0.4
    assert torch.all(learner.model.log_std.exp() < 0.95)


def test_e_greedy_epsilon_decays_per_env_step_and_explores():
    hp = Hyperparameters(exploration_type="e-greedy", e_greedy_value=0.1, epsilon_steps=100)
    learner = PPOLearner(STATE, 3, hp, "MLP", seed=1)
    obs = np.zeros((50, 1), np.float32)
    assert learner.epsilon == 1.0
    first = learner.act(obs)  # epsilon 1: every action uniform random
    assert set(first.action.tolist()) == {0, 1, 2}
    assert learner.epsilon == pytest.approx(0.55)
    learner.act(obs, deterministic=True)  # evaluation does not advance the schedule
    assert learner.epsilon == pytest.approx(0.55)
    learner.act(obs)
    learner.act(obs)
    assert learner.epsilon == pytest.approx(0.1)
    # at epsilon 0.1 most actions are the greedy one
    greedy = learner.act(obs, deterministic=True).action[0]
    many = learner.act(np.zeros((2000, 1), np.float32)).action
    assert 0.85 < np.mean(many == greedy) < 0.97


def test_multi_step_rollout_with_truncation_and_mask_on_camera():
    space = gym.spaces.Box(0, 255, (1, 120, 160), np.uint8)
    learner = PPOLearner(space, 3, Hyperparameters(batch_size=32, num_epochs=3), seed=0)
    steps, envs = 4, 3
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (steps, envs, 1, 120, 160), dtype=np.uint8)
    acted = [learner.act(obs[t]) for t in range(steps)]
    terminated = np.zeros((steps, envs), bool)
    terminated[1, 0] = True
    truncated = np.zeros((steps, envs), bool)
    truncated[2, 1] = True
    valid = np.ones((steps, envs), bool)
    valid[3, 2] = False
    rollout = Rollout(obs, np.stack([a.action for a in acted]), np.stack([a.log_prob for a in acted]),
                      np.stack([a.value for a in acted]), rng.normal(size=(steps, envs)), terminated,
                      truncated, np.full((steps, envs), 0.5), learner.values(obs[-1]), valid)
    before = [p.detach().clone() for p in learner.model.parameters()]
    stats = learner.update(rollout)
    assert stats["num_steps"] == 11 and stats["num_minibatches"] == 3
    assert all(np.isfinite(v) for v in stats.values())
    assert any(not torch.equal(a, b) for a, b in zip(before, learner.model.parameters()))


def test_dict_observations_update():
    space = gym.spaces.Dict({"STATE": gym.spaces.Box(-1, 1, (3,), np.float32),
                             "SECTOR_LIDAR": gym.spaces.Box(0, 1, (8,), np.float32)})
    learner = PPOLearner(space, gym.spaces.Box(-1, 1, (2,)), FAST, "MLP", seed=0)
    obs = {"STATE": np.zeros((2, 5, 3), np.float32), "SECTOR_LIDAR": np.ones((2, 5, 8), np.float32)}
    acted = [learner.act({k: v[t] for k, v in obs.items()}) for t in range(2)]
    rollout = Rollout(obs, np.stack([a.action for a in acted]), np.stack([a.log_prob for a in acted]),
                      np.stack([a.value for a in acted]), np.ones((2, 5)), np.ones((2, 5), bool))
    assert learner.update(rollout)["num_steps"] == 10


def test_state_dict_round_trip_and_mismatch(tmp_path):
    obs = np.linspace(-1, 1, 8, dtype=np.float32)[:, None]
    learner = PPOLearner(STATE, 4, FAST, "MLP", seed=0)
    step = learner.act(obs)
    learner.update(_one_step_rollout(obs, step, np.arange(8.0)))
    path = tmp_path / "checkpoint.pt"
    torch.save(learner.state_dict(), path)
    restored = PPOLearner(STATE, 4, FAST, "MLP", seed=5)
    restored.load_state_dict(torch.load(path))
    np.testing.assert_array_equal(restored.act(obs, deterministic=True).action,
                                  learner.act(obs, deterministic=True).action)
    np.testing.assert_allclose(restored.values(obs), learner.values(obs))
    assert restored.env_steps == 8 and restored.iterations == 1
    with pytest.raises(ValueError, match="action space"):
        PPOLearner(STATE, 5, FAST, "MLP").load_state_dict(learner.state_dict())


def test_rollout_shape_mismatch_is_named():
    learner = PPOLearner(STATE, 2, FAST, "MLP", seed=0)
    obs = np.zeros((4, 1), np.float32)
    step = learner.act(obs)
    rollout = _one_step_rollout(obs, step, np.zeros(4))._replace(rewards=np.zeros((4, 1)))
    with pytest.raises(ValueError, match=r"Rollout\.rewards has shape \(4, 1\)"):
        learner.update(rollout)


def test_bfloat16_learner_learns_the_bandit_and_acts_without_values():
    learner = PPOLearner(STATE, 4, FAST, "MLP", seed=0, num_threads=1, precision="bfloat16")
    assert learner.precision == "bfloat16"
    obs = np.ones((64, 1), np.float32)
    for _ in range(10):
        step = learner.act(obs)
        learner.update(_one_step_rollout(obs, step, (step.env_action == 2).astype(np.float32)))
    assert _probability(learner, obs, 2) > 0.8
    greedy = learner.act(obs[:3], deterministic=True, with_value=False)
    assert np.isnan(greedy.value).all() and greedy.value.shape == (3,)
    np.testing.assert_array_equal(greedy.action, learner.act(obs[:3], deterministic=True).action)


def test_keep_freed_memory_takes_on_glibc():
    import sys

    from laplab.agents.torch_runtime import keep_freed_memory
    took = keep_freed_memory()
    assert isinstance(took, bool)
    if sys.platform == "linux" and "glibc" in " ".join(__import__("platform").libc_ver()):
        assert took
    assert torch.ones(4_000_000).sum() == 4_000_000  # big allocations still work
