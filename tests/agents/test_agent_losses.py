"""Losses and GAE against numbers worked out by hand."""

import numpy as np
import pytest
import torch

from laplab.agents.losses import (clipped_surrogate_loss, compute_gae, compute_gae_numpy, entropy_bonus,
                                  policy_change_stats, sac_actor_loss, sac_critic_target, value_loss)
from laplab.agents.ppo import fold_truncation

T = torch.tensor

# Two environments, three steps, gamma 0.9, lambda 0.8 (gamma * lambda = 0.72).
REWARDS = [[1.0, 0.0], [0.0, 0.0], [2.0, 1.0]]
VALUES = [[0.5, 1.0], [1.0, 1.0], [0.5, 1.0]]
DONES = [[0, 0], [0, 0], [1, 0]]
LAST_VALUES = [10.0, 2.0]
# env 0 ends with step 2, so its last value 10 is never used:
#   t=2: delta = 2 - 0.5 = 1.5                          A = 1.5
#   t=1: delta = 0 + 0.9 * 0.5 - 1.0 = -0.55            A = -0.55 + 0.72 * 1.5 = 0.53
#   t=0: delta = 1 + 0.9 * 1.0 - 0.5 = 1.4              A = 1.4 + 0.72 * 0.53 = 1.7816
# env 1 is still running, bootstrapped with V = 2:
#   t=2: delta = 1 + 0.9 * 2 - 1 = 1.8                  A = 1.8
#   t=1: delta = 0 + 0.9 * 1 - 1 = -0.1                 A = -0.1 + 0.72 * 1.8 = 1.196
#   t=0: delta = -0.1                                   A = -0.1 + 0.72 * 1.196 = 0.76112
EXPECTED_ADVANTAGES = [[1.7816, 0.76112], [0.53, 1.196], [1.5, 1.8]]


def test_gae_hand_worked():
    advantages, returns = compute_gae(T(REWARDS), T(VALUES), T(DONES), T(LAST_VALUES), 0.9, 0.8)
    np.testing.assert_allclose(advantages.numpy(), EXPECTED_ADVANTAGES, rtol=1e-6)
    np.testing.assert_allclose(returns.numpy(), np.add(EXPECTED_ADVANTAGES, VALUES), rtol=1e-6)


def test_gae_numpy_matches_hand_and_torch():
    advantages, returns = compute_gae_numpy(np.array(REWARDS), np.array(VALUES), np.array(DONES),
                                            np.array(LAST_VALUES), 0.9, 0.8)
    np.testing.assert_allclose(advantages, EXPECTED_ADVANTAGES, rtol=1e-9)
    rng = np.random.default_rng(0)
    r, v = rng.normal(size=(50, 7)), rng.normal(size=(50, 7))
    d, last = rng.random((50, 7)) < 0.1, rng.normal(size=7)
    a_np, ret_np = compute_gae_numpy(r, v, d, last, 0.99, 0.95)
    a_t, ret_t = compute_gae(T(r), T(v), T(d), T(last), 0.99, 0.95)
    np.testing.assert_allclose(a_t.numpy(), a_np, rtol=1e-10)
    np.testing.assert_allclose(ret_t.numpy(), ret_np, rtol=1e-10)


def test_gae_with_lambda_one_is_discounted_return_minus_value():
    # lambda = 1, no dones: A_0 = r0 + g r1 + g^2 r2 + g^3 V_last - V_0 = 1 + 0 + 0.81*1 + 0.729*2 - 1
    adv, _ = compute_gae(T([[1.0], [0.0], [1.0]]), T([[1.0], [5.0], [-3.0]]), T([[0], [0], [0]]),
                         T([2.0]), 0.9, 1.0)
    assert adv[0, 0].item() == pytest.approx(1 + 0.81 + 0.729 * 2 - 1)


def test_fold_truncation():
    # env 0 truncated at step 0 (V(final obs) = 4): reward 1 + 0.5 * 4 = 3, done.
    # env 1 terminated at step 0: its bootstrap 9 is ignored.
    rewards, dones = fold_truncation(np.array([[1.0, 1.0]]), np.array([[False, True]]),
                                     np.array([[True, True]]), np.array([[4.0, 9.0]]), 0.5)
    np.testing.assert_allclose(rewards, [[3.0, 1.0]])
    assert dones.tolist() == [[True, True]]
    with pytest.raises(ValueError, match="bootstrap_values"):
        fold_truncation(np.zeros((1, 1)), np.zeros((1, 1)), np.ones((1, 1)), None, 0.5)


def test_clipped_surrogate_hand_worked():
    # ratios 1.5, 0.5, 1.1 with advantages 1, -2, 3 and eps 0.2:
    #   min(1.5 * 1, 1.2 * 1) = 1.2; min(0.5 * -2, 0.8 * -2) = -1.6; min(3.3, 3.3) = 3.3
    #   loss = -(1.2 - 1.6 + 3.3) / 3 = -0.966667
    old = T([0.0, 0.0, 0.0])
    new = torch.log(T([1.5, 0.5, 1.1]))
    adv = T([1.0, -2.0, 3.0])
    assert clipped_surrogate_loss(new, old, adv, 0.2).item() == pytest.approx(-2.9 / 3, rel=1e-6)
    approx_kl, clip_fraction = policy_change_stats(new, old, 0.2)
    # (r - 1) - log r: 0.5 - log 1.5, -0.5 - log 0.5, 0.1 - log 1.1
    expected_kl = np.mean([0.5 - np.log(1.5), -0.5 - np.log(0.5), 0.1 - np.log(1.1)])
    assert approx_kl == pytest.approx(expected_kl, rel=1e-5)
    assert clip_fraction == pytest.approx(2 / 3)


def test_clipped_surrogate_gradient_vanishes_when_clipped():
    new = torch.log(T([1.5])).requires_grad_()
    clipped_surrogate_loss(new, T([0.0]), T([1.0]), 0.2).backward()
    assert new.grad.item() == 0.0


def test_value_losses_hand_worked():
    pred, target = T([0.0, 0.0, 0.0]), T([0.5, 2.0, -3.0])
    # huber: 0.5 * 0.25 = 0.125; 2 - 0.5 = 1.5; 3 - 0.5 = 2.5 -> mean 4.125 / 3
    assert value_loss(pred, target, "huber").item() == pytest.approx(1.375)
    # mse: (0.25 + 4 + 9) / 3
    assert value_loss(pred, target, "mean squared error").item() == pytest.approx(13.25 / 3)
    with pytest.raises(ValueError, match="loss_type"):
        value_loss(pred, target, "l1")


def test_entropy_bonus_hand_worked():
    # -0.01 * mean(1, 2) = -0.015
    assert entropy_bonus(T([1.0, 2.0]), 0.01).item() == pytest.approx(-0.015)


def test_sac_critic_target_hand_worked():
    # y0 = 1 + 0.9 * (min(3, 4) - 0.2 * -1) = 1 + 0.9 * 3.2 = 3.88 ; y1 terminated = 2
    y = sac_critic_target(T([1.0, 2.0]), T([0.0, 1.0]), T([3.0, 5.0]), T([4.0, 1.0]), T([-1.0, 0.5]), 0.9, 0.2)
    np.testing.assert_allclose(y.numpy(), [3.88, 2.0], rtol=1e-6)


def test_sac_actor_loss_hand_worked():
    # 0.2 * -1 - min(1, 0.5) = -0.7 ; 0.2 * -2 - min(2, 3) = -2.4 ; mean -1.55
    assert sac_actor_loss(T([1.0, 2.0]), T([0.5, 3.0]), T([-1.0, -2.0]), 0.2).item() == pytest.approx(-1.55)
