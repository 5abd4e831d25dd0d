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


CAMERA_AND_STATE = gym.spaces.Dict({"FRONT_FACING_CAMERA": gym.spaces.Box(0, 255, (1, 4, 4), np.uint8),
                                     "STATE": gym.spaces.Box(-1, 1, (2,), np.float32)})


def _frames(ids):
    ids = np.asarray(ids)
    return {"FRONT_FACING_CAMERA": np.broadcast_to(ids[:, None, None, None], (len(ids), 1, 4, 4)).astype(np.uint8),
            "STATE": np.repeat(ids[:, None], 2, 1).astype(np.float32)}


def test_replay_buffer_wraps_and_samples_dicts():
    buffer = ReplayBuffer(10, CAMERA_AND_STATE, 2)
    for start in (0, 3):  # 3 + 3 independent transitions, 2 slots each, into 10 slots: the oldest is gone
        ids = np.arange(start, start + 3)
        buffer.add(_frames(ids), np.zeros((3, 2)), ids.astype(np.float32), _frames(ids + 100), np.zeros(3))
    assert len(buffer) == 5 and buffer.position == 2
    assert sorted(buffer.rewards[buffer.starts].tolist()) == [1, 2, 3, 4, 5]
    batch = buffer.sample(32, np.random.default_rng(0))
    assert batch.observations["FRONT_FACING_CAMERA"].dtype == np.uint8
    np.testing.assert_array_equal(batch.observations["STATE"][:, 0], batch.rewards)
    np.testing.assert_array_equal(batch.observations["FRONT_FACING_CAMERA"][:, 0, 0, 0], batch.rewards)
    np.testing.assert_array_equal(batch.next_observations["STATE"][:, 0], batch.rewards + 100)


def test_replay_buffer_stores_each_frame_once_and_links_next_frames():
    buffer = ReplayBuffer(8, CAMERA_AND_STATE, 2)
    assert not hasattr(buffer, "next_observations")  # no second copy of the frames
    # episode A: 4 steps, off track at the last; episode B: 5 steps, so the ring wraps (9 frames, 8 slots)
    buffer.add_episode(_frames([10, 11, 12, 13]), np.zeros((4, 2)), [10, 11, 12, 13], [0, 0, 0, 1])
    buffer.add_episode(_frames([20, 21, 22, 23, 24]), np.zeros((5, 2)), [20, 21, 22, 23, 24], [0, 0, 0, 0, 1])
    assert len(buffer) == 8  # frame 10 was overwritten by frame 24
    batch = buffer.sample(400, np.random.default_rng(1))
    frame = batch.observations["FRONT_FACING_CAMERA"][:, 0, 0, 0].astype(int)
    following = batch.next_observations["FRONT_FACING_CAMERA"][:, 0, 0, 0].astype(int)
    np.testing.assert_array_equal(frame, batch.rewards)
    assert set(frame) == {11, 12, 13, 20, 21, 22, 23, 24}  # every stored transition is drawn
    ends = batch.terminated == 1
    assert set(frame[ends]) == {13, 24}
    np.testing.assert_array_equal(following[~ends], frame[~ends] + 1)  # next frame = the following step's
    np.testing.assert_array_equal(following[ends], frame[ends])  # unused placeholder: not bootstrapped


def test_learner_learns_whole_episodes_into_the_buffer():
    from laplab.train.collect import EpisodeBatch
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32, num_epochs=3), "MLP", seed=0)
    steps, cars = 30, 2
    valid = np.ones((steps, cars), bool)
    valid[20:, 1] = False  # car 1 went off track at step 19
    terminated = np.zeros((steps, cars), bool)
    terminated[19, 1] = terminated[29, 0] = True
    obs = np.arange(steps * cars, dtype=np.float32).reshape(steps, cars, 1) / 100
    zeros = np.zeros((steps, cars), np.float32)
    batch = EpisodeBatch(obs, np.zeros((steps, cars, 1), np.float32), zeros, zeros, zeros + 1, terminated,
                         np.zeros((steps, cars), bool), valid, zeros, *(np.zeros(cars),) * 6, {}, 0.0)
    stats = learner.learn(batch)
    assert len(learner.buffer) == 50 and learner.buffer.filled == 50
    assert stats["num_gradient_steps"] == 3 * 2  # 3 epochs x ceil(50 / 32)


def test_gradient_step_runs_each_trunk_once_and_the_target_is_the_critic_as_the_update_starts():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    obs = np.linspace(-1, 1, 40, dtype=np.float32)[:, None]
    learner.observe(obs, learner.act(obs).action, obs[:, 0], obs, np.zeros(40))
    calls = {"actor": 0, "critic": 0, "target": 0}
    for name, module in (("actor", learner.actor.trunk), ("critic", learner.critic.trunk),
                         ("target", learner.target_critic.trunk)):
        module.register_forward_hook(lambda *_, name=name: calls.__setitem__(name, calls[name] + 1))
    learner.update(2)  # the target critic moves away from the critic...
    critic_before = [p.detach().clone() for p in learner.critic.parameters()]
    target_storage = [p.data_ptr() for p in learner.target_critic.parameters()]
    calls.update(actor=0, critic=0, target=0)
    learner.update(1)
    assert calls == {"actor": 2, "critic": 1, "target": 1}  # s' and s for the actor; one critic pass for both heads
    # ...and is the critic as this update started (DeepRacer's copy per training call), copied in place
    for before, after in zip(critic_before, learner.target_critic.parameters()):
        torch.testing.assert_close(after, before)
    assert not all(torch.equal(a, b) for a, b in zip(learner.target_critic.parameters(), learner.critic.parameters()))
    assert [p.data_ptr() for p in learner.target_critic.parameters()] == target_storage


def test_update_stops_when_asked_and_reports_progress():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    obs = np.linspace(-1, 1, 40, dtype=np.float32)[:, None]
    learner.observe(obs, learner.act(obs).action, obs[:, 0], obs, np.zeros(40))
    seen = []
    stats = learner.update(10, should_stop=lambda: len(seen) >= 4, on_progress=lambda d, t: seen.append((d, t)))
    assert stats["num_gradient_steps"] == 4 and learner.gradient_steps == 4
    assert seen == [(1, 10), (2, 10), (3, 10), (4, 10)]
    assert learner.update(5, should_stop=lambda: True)["num_gradient_steps"] == 0


def test_weights_state_holds_no_optimizer_and_restores_the_policy():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    obs = np.linspace(-1, 1, 40, dtype=np.float32)[:, None]
    learner.observe(obs, learner.act(obs).action, obs[:, 0], obs, np.ones(40))
    learner.update(3)
    weights = learner.weights_state()
    assert set(weights) >= {"actor", "critic"} and not {"target_critic", "actor_optimizer"} & set(weights)
    restored = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=7)
    restored.load_state_dict(weights)  # resuming an exported (weights-only) model: fresh optimizers
    np.testing.assert_allclose(restored.act(obs, deterministic=True).env_action,
                               learner.act(obs, deterministic=True).env_action)
    for a, b in zip(restored.target_critic.parameters(), restored.critic.parameters()):
        torch.testing.assert_close(a, b)


def test_older_twin_q_layout_loads():
    learner = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=0)
    critic = learner.critic.state_dict()
    old = {}
    for key, value in critic.items():  # the former layout: a trunk per head
        if key.startswith("trunk."):
            old["q1." + key] = value
            old["q2." + key] = value + 1
        else:
            old[key[:2] + ".head" + key[2:]] = value
    state = {**learner.state_dict(), "critic": old, "target_critic": old}
    restored = SACLearner(STATE, ONE_D, Hyperparameters(batch_size=32), "MLP", seed=3)
    restored.load_state_dict(state)
    for key, value in restored.critic.state_dict().items():
        torch.testing.assert_close(value, critic[key])


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


SMALL_CAMERA = gym.spaces.Box(0, 255, (1, 40, 48), np.uint8)  # the SHALLOW convs end at 1 x 3
CONTINUOUS = {"action_space": {}, "action_space_type": "continuous"}


def _camera_learner(seed, **kwargs):
    learner = SACLearner(SMALL_CAMERA, CONTINUOUS, Hyperparameters(batch_size=32), seed=seed, num_threads=1,
                         buffer_capacity=200, **kwargs)
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, (80, *SMALL_CAMERA.shape), dtype=np.uint8)
    learner.observe(frames[:40], rng.uniform(-1, 1, (40, 2)).astype(np.float32), rng.normal(size=40).astype(np.float32),
                    frames[40:], np.zeros(40, np.float32))
    return learner, frames


def test_a_camera_actor_reads_the_critics_trunk_and_trains_only_its_heads():
    learner, _ = _camera_learner(0)
    assert learner.shared_trunk and learner.actor.trunk is learner.critic.trunk
    trained = {id(p) for group in learner.actor_optimizer.param_groups for p in group["params"]}
    assert trained == {id(p) for m in (learner.actor.mean, learner.actor.log_std) for p in m.parameters()}
    calls = {"critic": 0, "target": 0}
    for name, module in (("critic", learner.critic.trunk), ("target", learner.target_critic.trunk)):
        module.register_forward_hook(lambda *_, name=name: calls.__setitem__(name, calls[name] + 1))
    heads_before = learner.actor.mean.weight.detach().clone()
    learner.update(1)
    assert calls == {"critic": 2, "target": 1}  # s with gradients, s' for the next actions; s' for their values
    assert not torch.equal(heads_before, learner.actor.mean.weight)
    assert not SACLearner(STATE, ONE_D, Hyperparameters(), "MLP", seed=0).shared_trunk  # vectors: rl_coach's layout


def test_a_shared_trunk_checkpoint_round_trips_and_is_saved_once(tmp_path):
    learner, frames = _camera_learner(0)
    learner.update(2)
    for state in (learner.state_dict(), learner.weights_state()):
        restored, _ = _camera_learner(5)
        restored.load_state_dict(state)
        assert restored.shared_trunk and restored.actor.trunk is restored.critic.trunk
        np.testing.assert_allclose(restored.act(frames[:8], deterministic=True).env_action,
                                   learner.act(frames[:8], deterministic=True).env_action, rtol=1e-5, atol=1e-6)
        assert restored.update(1)["num_gradient_steps"] == 1
    separate, _ = _camera_learner(0, shared_trunk=False)
    torch.save(learner.weights_state(), tmp_path / "shared.ckpt")
    torch.save(separate.weights_state(), tmp_path / "separate.ckpt")
    trunk_bytes = 4 * sum(p.numel() for p in learner.critic.trunk.parameters())
    saved = (tmp_path / "separate.ckpt").stat().st_size - (tmp_path / "shared.ckpt").stat().st_size
    assert saved > 0.9 * trunk_bytes  # the trunk is written once


def test_a_camera_checkpoint_from_before_shared_trunks_keeps_its_actors_own_trunk():
    old, frames = _camera_learner(1, shared_trunk=False)
    old.update(2)
    state = old.state_dict()
    del state["shared_trunk"]  # what laplab wrote before
    restored, _ = _camera_learner(4)
    restored.load_state_dict(state)
    assert not restored.shared_trunk and restored.actor.trunk is not restored.critic.trunk
    np.testing.assert_allclose(restored.act(frames[:8], deterministic=True).env_action,
                               old.act(frames[:8], deterministic=True).env_action, rtol=1e-5, atol=1e-6)
    assert {id(p) for g in restored.actor_optimizer.param_groups for p in g["params"]} == \
        {id(p) for p in restored.actor.parameters()}
    assert restored.update(1)["num_gradient_steps"] == 1


def test_frozen_heads_equal_the_heads_and_train_only_what_feeds_them():
    from laplab.agents.sac_networks import TwinQ
    critic = TwinQ(gym.spaces.Box(-1, 1, (6,), np.float32), 2)
    features = torch.randn(5, critic.trunk.output_dim, requires_grad=True)
    actions = torch.randn(5, 2, requires_grad=True)
    for mine, theirs in zip(critic.frozen_heads(features, actions), critic.heads(features, actions)):
        torch.testing.assert_close(mine, theirs)
    sum(critic.frozen_heads(features, actions)).sum().backward()
    assert all(parameter.grad is None for parameter in critic.parameters())  # the weights stay fixed
    assert actions.grad.abs().sum() > 0 and features.grad.abs().sum() > 0
