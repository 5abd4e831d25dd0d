"""The math of PPO and SAC as pure functions on tensors (numpy for GAE as well).

Shapes: T time steps, N parallel environments, B samples of a minibatch. Every function returns
a scalar loss to be *minimised* (bonuses carry their minus sign).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

VALUE_LOSS_TYPES = ("huber", "mean squared error")


def compute_gae(rewards: torch.Tensor, values: torch.Tensor, dones: torch.Tensor,
                last_values: torch.Tensor, gamma: float, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation (Schulman et al. 2016).

    ``rewards``, ``values``, ``dones`` are (T, N); ``dones[t]`` means the episode ended with step
    t, so nothing after it is bootstrapped or accumulated. ``last_values`` (N,) is V of the state
    after step T-1 (used only where that episode is still running).
    ``delta_t = r_t + gamma * V_{t+1} * (1 - done_t) - V_t``,
    ``A_t = delta_t + gamma * lam * (1 - done_t) * A_{t+1}``. Returns advantages and the value
    targets ``advantages + values``, both (T, N).
    """
    not_done = 1.0 - dones.to(values.dtype)
    next_values = torch.cat([values[1:], last_values.reshape(1, -1)], dim=0)
    deltas = rewards + gamma * next_values * not_done - values
    advantages = torch.zeros_like(values)
    running = torch.zeros_like(last_values, dtype=values.dtype)
    for t in range(values.shape[0] - 1, -1, -1):  # a loop over time only, batched over N
        running = deltas[t] + gamma * lam * not_done[t] * running
        advantages[t] = running
    return advantages, advantages + values


def compute_gae_numpy(rewards: np.ndarray, values: np.ndarray, dones: np.ndarray,
                      last_values: np.ndarray, gamma: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """``compute_gae`` on numpy arrays (same shapes, float64 results)."""
    values = np.asarray(values, dtype=np.float64)
    not_done = 1.0 - np.asarray(dones, dtype=np.float64)
    next_values = np.concatenate([values[1:], np.asarray(last_values, dtype=np.float64).reshape(1, -1)])
    deltas = np.asarray(rewards, dtype=np.float64) + gamma * next_values * not_done - values
    advantages = np.zeros_like(values)
    running = np.zeros(values.shape[1])
    for t in range(values.shape[0] - 1, -1, -1):
        running = deltas[t] + gamma * lam * not_done[t] * running
        advantages[t] = running
    return advantages, advantages + values


def clipped_surrogate_loss(log_probs: torch.Tensor, old_log_probs: torch.Tensor,
                           advantages: torch.Tensor, clip_epsilon: float = 0.2) -> torch.Tensor:
    """PPO's clipped objective, negated: ``-mean(min(r * A, clip(r, 1-eps, 1+eps) * A))`` with
    ``r = exp(log_probs - old_log_probs)``; all inputs (B,)."""
    ratio = torch.exp(log_probs - old_log_probs)
    clipped = ratio.clamp(1.0 - clip_epsilon, 1.0 + clip_epsilon)
    return -torch.minimum(ratio * advantages, clipped * advantages).mean()


@torch.no_grad()
def policy_change_stats(log_probs: torch.Tensor, old_log_probs: torch.Tensor,
                        clip_epsilon: float = 0.2) -> tuple[float, float]:
    """-> (approx_kl, clip_fraction) for (B,) log-probs: ``mean((r - 1) - log r)`` (an unbiased,
    non-negative KL(old||new) estimator) and the share of samples with ``|r - 1| > eps``."""
    log_ratio = log_probs - old_log_probs
    ratio = torch.exp(log_ratio)
    approx_kl = ((ratio - 1.0) - log_ratio).mean()
    clip_fraction = ((ratio - 1.0).abs() > clip_epsilon).float().mean()
    return float(approx_kl), float(clip_fraction)


def value_loss(predicted: torch.Tensor, target: torch.Tensor, kind: str = "huber") -> torch.Tensor:
    """Value-head loss over (B,) predictions: ``"huber"`` (delta 1: ``0.5 x^2`` for ``|x| <= 1``,
    else ``|x| - 0.5``) or ``"mean squared error"`` (``mean(x^2)``, no 1/2), as rl_coach's V head."""
    if kind == "huber":
        return F.huber_loss(predicted, target, delta=1.0)
    if kind == "mean squared error":
        return F.mse_loss(predicted, target)
    raise ValueError(f"Unknown value loss_type {kind!r}; use one of {VALUE_LOSS_TYPES}.")


def entropy_bonus(entropy: torch.Tensor, beta: float) -> torch.Tensor:
    """The entropy term to add to the loss: ``-beta * mean(entropy)`` for (B,) entropies."""
    return -beta * entropy.mean()


def sac_critic_target(rewards: torch.Tensor, terminated: torch.Tensor, next_q1: torch.Tensor,
                      next_q2: torch.Tensor, next_log_probs: torch.Tensor, gamma: float,
                      alpha: float) -> torch.Tensor:
    """Soft Bellman target (B,): ``r + gamma * (1 - terminated) * (min(q1', q2') - alpha * log pi(a'|s'))``
    with ``a' ~ pi(.|s')`` and q' from the target networks; all inputs (B,)."""
    soft_next_value = torch.minimum(next_q1, next_q2) - alpha * next_log_probs
    return rewards + gamma * (1.0 - terminated.to(rewards.dtype)) * soft_next_value


def sac_actor_loss(q1: torch.Tensor, q2: torch.Tensor, log_probs: torch.Tensor, alpha: float) -> torch.Tensor:
    """SAC's policy loss ``mean(alpha * log pi(a|s) - min(q1, q2)(s, a))`` for reparameterised
    ``a ~ pi(.|s)``; all inputs (B,)."""
    return (alpha * log_probs - torch.minimum(q1, q2)).mean()
