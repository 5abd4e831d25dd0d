"""A PPO update of a camera network equals a plain reference of the same math.

The reference is DeepRacer's clipped PPO written out without speed-ups: one summed loss (clipped
surrogate + value loss + entropy bonus), one backward pass, one Adam step per minibatch. The learner
runs the value network's half on a second thread when it has two torch threads; losses and weights
after an update must agree up to float32 rounding, and a failure on that thread must reach the caller.
"""

import copy

import gymnasium as gym
import numpy as np
import pytest
import torch

from laplab.agents.hyperparameters import Hyperparameters
from laplab.agents.losses import clipped_surrogate_loss, compute_gae, entropy_bonus, value_loss
from laplab.agents.ppo import ADAM_EPSILON, ADVANTAGE_EPSILON, CLIP_EPSILON, GAE_LAMBDA, PPOLearner, Rollout

CAMERA = gym.spaces.Box(0, 255, (2, 40, 48), np.uint8)  # two stacked frames: the SHALLOW convs end at 1 x 3
CONTINUOUS = {"action_space": {}, "action_space_type": "continuous"}
STEPS, CARS = 12, 4


def _rollout(learner: PPOLearner, rng: np.random.Generator) -> Rollout:
    frames = rng.integers(0, 256, (STEPS, CARS, *CAMERA.shape), dtype=np.uint8)
    steps = [learner.act(frames[t]) for t in range(STEPS)]
    terminated = np.zeros((STEPS, CARS), bool)
    terminated[-1] = True
    return Rollout(frames, np.stack([s.action for s in steps]), np.stack([s.log_prob for s in steps]),
                   np.stack([s.value for s in steps]), rng.normal(size=(STEPS, CARS)).astype(np.float32),
                   terminated, None, None, None, None)


def _reference_update(model, optimizer, rollout: Rollout, hp: Hyperparameters, order_rng) -> np.ndarray:
    values = torch.as_tensor(rollout.values)
    advantages, returns = compute_gae(torch.as_tensor(rollout.rewards), values,
                                      torch.as_tensor(rollout.terminated, dtype=torch.float32),
                                      torch.zeros(CARS), hp.discount_factor, GAE_LAMBDA)
    advantages, returns = advantages.reshape(-1), returns.reshape(-1)
    advantages = (advantages - advantages.mean()) / (advantages.std(unbiased=False) + ADVANTAGE_EPSILON)
    obs = torch.as_tensor(rollout.observations.reshape(STEPS * CARS, *CAMERA.shape))
    actions = torch.as_tensor(rollout.actions.reshape(STEPS * CARS, -1)).float()
    old_log_probs = torch.as_tensor(rollout.log_probs.reshape(-1))
    losses = []
    for _ in range(hp.num_epochs):
        order = order_rng.permutation(STEPS * CARS)
        for start in range(0, STEPS * CARS, hp.batch_size):
            index = torch.as_tensor(order[start:start + hp.batch_size])
            log_probs, entropy, predicted = model.evaluate(obs[index], actions[index])
            policy_loss = clipped_surrogate_loss(log_probs, old_log_probs[index], advantages[index], CLIP_EPSILON)
            critic_loss = value_loss(predicted, returns[index], hp.loss_type)
            optimizer.zero_grad()
            (policy_loss + critic_loss + entropy_bonus(entropy, hp.beta_entropy)).backward()
            optimizer.step()
            losses.append((policy_loss.item(), critic_loss.item(), entropy.mean().item()))
    return np.mean(losses, axis=0)


@pytest.mark.parametrize("threads", [1, 2])
def test_camera_update_matches_the_one_graph_reference(threads, restore_torch_threads):
    hp = Hyperparameters(batch_size=32, num_epochs=3)
    learner = PPOLearner(CAMERA, CONTINUOUS, hp, seed=3, num_threads=threads)
    assert learner.model.value_trunk is not None
    rollout = _rollout(learner, np.random.default_rng(0))
    model = copy.deepcopy(learner.model)
    optimizer = torch.optim.Adam(model.parameters(), lr=hp.lr, eps=ADAM_EPSILON)
    expected = _reference_update(model, optimizer, rollout, hp, np.random.default_rng(11))
    learner.rng = np.random.default_rng(11)
    stats = learner.update(rollout)
    assert stats["num_minibatches"] == 3 * 2
    got = (stats["policy_loss"], stats["value_loss"], stats["entropy"])
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)
    for (key, value), reference in zip(learner.model.state_dict().items(), model.state_dict().values()):
        torch.testing.assert_close(value, reference, rtol=1e-4, atol=1e-5, msg=key)
    assert torch.get_num_threads() == threads  # the update leaves torch's thread count as it found it


def test_a_failure_on_the_value_thread_reaches_the_caller_and_restores_the_threads(restore_torch_threads):
    learner = PPOLearner(CAMERA, CONTINUOUS, Hyperparameters(batch_size=32, num_epochs=3), seed=0, num_threads=2)
    rollout = _rollout(learner, np.random.default_rng(1))
    before = [p.detach().clone() for p in learner.model.parameters()]

    def broken(*_):
        raise RuntimeError("broken value trunk")

    hook = learner.model.value_trunk.register_forward_hook(broken)
    with pytest.raises(RuntimeError, match="broken value trunk"):
        learner.update(rollout)
    assert torch.get_num_threads() == 2
    assert all(torch.equal(a, b) for a, b in zip(before, learner.model.parameters()))
    hook.remove()
    assert learner.update(rollout)["num_minibatches"] == 6  # the thread still serves the next update
    assert copy.deepcopy(learner).update(rollout)["num_minibatches"] == 6  # a copy makes its own thread


def test_the_adam_step_runs_on_all_of_the_learners_threads(restore_torch_threads):
    """The two halves run on one thread each; once they joined, the fused Adam step gets both (it is
    memory-bound and took twice as long on one)."""
    learner = PPOLearner(CAMERA, CONTINUOUS, Hyperparameters(batch_size=32, num_epochs=3), seed=0, num_threads=2)
    rollout = _rollout(learner, np.random.default_rng(2))
    seen = []
    adam_step = learner.optimizer.step

    def step_seen():  # the threads torch has as each Adam step starts
        seen.append(torch.get_num_threads())
        adam_step()

    learner.optimizer.step = step_seen
    learner.update(rollout)
    assert seen == [2] * 6
    assert torch.get_num_threads() == 2
