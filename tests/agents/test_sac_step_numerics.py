"""One SAC gradient step on a camera network equals a plain, sequential reference of the same math.

The references below are the learner's steps written out without any speed-ups (the actor's and the
critic's halves one after the other, two backward passes), for separate trunks and for the actor on
the critic's trunk, with the target critic copied from the critic as the update starts: losses, the
critic, the actor and the target critic after a few steps must agree up to float32 rounding,
whatever the learner does to go faster (threads, fused conversions, one backward pass).
"""

import copy

import gymnasium as gym
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import sac_actor_loss, sac_critic_target
from laplab.agents.sac import SACLearner

CAMERA = gym.spaces.Box(0, 255, (2, 40, 48), np.uint8)  # two stacked frames: the SHALLOW convs end at 1 x 3
CONTINUOUS = {"action_space": {}, "action_space_type": "continuous"}
STEPS = 3


def _reference_step(actor, critic, target_critic, actor_optimizer, critic_optimizer, batch, hp):
    """rl_coach's order: the target from the networks before the step, each network's own loss."""
    obs = torch.as_tensor(batch.observations)
    next_obs = torch.as_tensor(batch.next_observations)
    actions, rewards, terminated = (torch.as_tensor(x) for x in (batch.actions, batch.rewards, batch.terminated))
    with torch.no_grad():
        next_actions, next_log_probs = actor(next_obs)
        target = sac_critic_target(rewards, terminated, *target_critic(next_obs, next_actions), next_log_probs,
                                   hp.discount_factor, hp.sac_alpha)
    q1, q2 = critic(obs, actions)
    critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
    new_actions, log_probs = actor(obs)
    frozen = copy.deepcopy(critic).requires_grad_(False)
    actor_loss = sac_actor_loss(*frozen(obs, new_actions), log_probs, hp.sac_alpha)
    critic_optimizer.zero_grad()
    actor_optimizer.zero_grad()
    critic_loss.backward()
    actor_loss.backward()
    critic_optimizer.step()
    actor_optimizer.step()
    return critic_loss.item(), actor_loss.item(), q1.mean().item(), -log_probs.mean().item()


def _reference_shared_step(actor, critic, target_critic, actor_optimizer, critic_optimizer, batch, hp):
    """The actor's heads on the critic's trunk (``actor.trunk is critic.trunk``), its features detached."""
    obs = torch.as_tensor(batch.observations)
    next_obs = torch.as_tensor(batch.next_observations)
    actions, rewards, terminated = (torch.as_tensor(x) for x in (batch.actions, batch.rewards, batch.terminated))
    with torch.no_grad():
        next_actions, next_log_probs = actor(next_obs)
        target = sac_critic_target(rewards, terminated, *target_critic(next_obs, next_actions), next_log_probs,
                                   hp.discount_factor, hp.sac_alpha)
    q1, q2 = critic(obs, actions)
    critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
    features = critic.trunk(obs).detach()
    new_actions, log_probs = actor.from_features(features)
    frozen = copy.deepcopy(critic).requires_grad_(False)
    actor_loss = sac_actor_loss(*frozen.heads(features, new_actions), log_probs, hp.sac_alpha)
    critic_optimizer.zero_grad()
    actor_optimizer.zero_grad()
    critic_loss.backward()
    actor_loss.backward()
    assert all(p.grad is None for p in frozen.parameters())
    critic_optimizer.step()
    actor_optimizer.step()
    return critic_loss.item(), actor_loss.item(), q1.mean().item(), -log_probs.mean().item()


@pytest.mark.parametrize("shared", [False, True], ids=["separate-trunks", "shared-trunk"])
@pytest.mark.parametrize("threads", [1, 2])
def test_camera_gradient_steps_match_the_sequential_reference(threads, shared, restore_torch_threads):
    hp = Hyperparameters(batch_size=32)
    learner = SACLearner(CAMERA, CONTINUOUS, hp, seed=3, num_threads=threads, buffer_capacity=200,
                         shared_trunk=shared)
    assert (learner.actor.trunk is learner.critic.trunk) == shared
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (80, *CAMERA.shape), dtype=np.uint8)
    learner.observe(frames[:40], rng.uniform(-1, 1, (40, 2)).astype(np.float32),
                    rng.normal(size=40).astype(np.float32), frames[40:], (rng.random(40) < 0.2).astype(np.float32))
    actor, critic = copy.deepcopy(learner.actor), copy.deepcopy(learner.critic)
    target_critic = copy.deepcopy(learner.target_critic)
    if shared:
        actor.trunk = critic.trunk
    trained = [*actor.mean.parameters(), *actor.log_std.parameters()] if shared else actor.parameters()
    actor_optimizer = torch.optim.Adam(trained, lr=hp.lr)
    reference_step = _reference_shared_step if shared else _reference_step
    critic_optimizer = torch.optim.Adam(critic.parameters(), lr=hp.lr)
    sampler = np.random.default_rng(7)
    learner.rng = np.random.default_rng(7)
    torch.manual_seed(100)
    target_critic.load_state_dict(critic.state_dict())  # the update's target: the critic as it starts
    expected = np.mean([reference_step(actor, critic, target_critic, actor_optimizer, critic_optimizer,
                                       learner.buffer.sample(hp.batch_size, sampler), hp)
                        for _ in range(STEPS)], axis=0)
    torch.manual_seed(100)
    stats = learner.update(STEPS)
    got = (stats["critic_loss"], stats["actor_loss"], stats["q_mean"], stats["entropy"])
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)
    for name, mine, theirs in (("actor", learner.actor, actor), ("critic", learner.critic, critic),
                               ("target", learner.target_critic, target_critic)):
        for (key, value), reference in zip(mine.state_dict().items(), theirs.state_dict().values()):
            torch.testing.assert_close(value, reference, rtol=1e-4, atol=1e-5, msg=f"{name}.{key}")
    assert torch.get_num_threads() == threads  # the step leaves torch's thread count as it found it


def test_a_failure_on_the_critic_thread_reaches_the_caller_and_restores_the_threads(restore_torch_threads):
    learner = SACLearner(CAMERA, CONTINUOUS, Hyperparameters(batch_size=32), seed=0, num_threads=2,
                         buffer_capacity=100, shared_trunk=False)
    frames = np.zeros((40, *CAMERA.shape), np.uint8)
    learner.observe(frames[:20], np.zeros((20, 2), np.float32), np.zeros(20, np.float32), frames[20:],
                    np.zeros(20, np.float32))
    learner.observe(frames[:20], np.zeros((20, 2), np.float32), np.zeros(20, np.float32), frames[20:],
                    np.zeros(20, np.float32))
    critic_before = [p.detach().clone() for p in learner.critic.parameters()]

    def broken(*_):
        raise RuntimeError("broken critic trunk")

    hook = learner.critic.trunk.register_forward_hook(broken)
    with pytest.raises(RuntimeError, match="broken critic trunk"):
        learner.update(2)
    assert torch.get_num_threads() == 2 and learner.gradient_steps == 0
    assert all(torch.equal(a, b) for a, b in zip(critic_before, learner.critic.parameters()))
    hook.remove()
    assert learner.update(1)["num_gradient_steps"] == 1  # the thread still serves the next update
