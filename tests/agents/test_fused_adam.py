"""laplab's FusedAdam against ``torch.optim.Adam(fused=True)``: the same bits after every step, state
dicts that load both ways (checkpoints written before FusedAdam resume with it and the other way
round), and a training process that never imports ``torch._dynamo``."""

import copy
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from laplab.agents.adam import FusedAdam

REPO_ROOT = Path(__file__).resolve().parents[2]


def _network(seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    return torch.nn.Sequential(torch.nn.Conv2d(2, 4, 3), torch.nn.ReLU(), torch.nn.Flatten(),
                               torch.nn.Linear(4 * 6 * 6, 5), torch.nn.Tanh(), torch.nn.Linear(5, 3))


def _backward(model: torch.nn.Module, step: int) -> None:
    generator = torch.Generator().manual_seed(100 + step)
    inputs = torch.randn(16, 2, 8, 8, generator=generator) * (10.0 ** (step % 3 - 1))
    model(inputs).pow(2).mean().backward()


def _train(model, optimizer, steps: range, frozen: str | None = None) -> None:
    for step in steps:
        optimizer.zero_grad(set_to_none=True)
        _backward(model, step)
        if frozen is not None:  # a parameter without a gradient keeps its state and value
            model.get_parameter(frozen).grad = None
        optimizer.step()


def _same_bits(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and torch.equal(a.view(torch.uint8) if a.dim() else a.reshape(1),
                                                                     b.view(torch.uint8) if b.dim() else b.reshape(1))


def _assert_same_state(ours: dict, theirs: dict) -> None:
    assert ours["param_groups"] == theirs["param_groups"]
    assert list(ours["state"]) == list(theirs["state"])
    for number, values in theirs["state"].items():
        assert set(ours["state"][number]) == set(values)
        for key, value in values.items():
            assert _same_bits(ours["state"][number][key], value), (number, key)


def _assert_same_weights(a: torch.nn.Module, b: torch.nn.Module) -> None:
    for (name, x), y in zip(a.named_parameters(), b.parameters()):
        assert _same_bits(x.detach(), y.detach()), name


@pytest.mark.parametrize("eps", [1e-8, 1e-5])
def test_steps_give_torch_adams_bits(eps):
    ours_model, torch_model = _network(0), _network(0)
    ours = FusedAdam(ours_model.parameters(), lr=3e-4, eps=eps)
    reference = torch.optim.Adam(torch_model.parameters(), lr=3e-4, eps=eps, fused=True)
    _train(ours_model, ours, range(4), frozen="3.bias")
    _train(torch_model, reference, range(4), frozen="3.bias")
    _assert_same_weights(ours_model, torch_model)
    _assert_same_state(ours.state_dict(), reference.state_dict())
    assert 3 not in ours.state_dict()["state"]  # "3.bias" never had a gradient: no state, as torch
    _train(ours_model, ours, range(4, 9))
    _train(torch_model, reference, range(4, 9))
    _assert_same_weights(ours_model, torch_model)
    _assert_same_state(ours.state_dict(), reference.state_dict())


@pytest.mark.parametrize("direction", ["torch_to_ours", "ours_to_torch"])
def test_state_dicts_load_both_ways_and_training_goes_on_identically(direction, tmp_path):
    first, second = _network(1), _network(1)
    writer = (torch.optim.Adam(first.parameters(), lr=1e-3, eps=1e-5, fused=True) if direction == "torch_to_ours"
              else FusedAdam(first.parameters(), lr=1e-3, eps=1e-5))
    _train(first, writer, range(3))
    torch.save({"weights": first.state_dict(), "optimizer": writer.state_dict()}, tmp_path / "resume.pt")
    saved = torch.load(tmp_path / "resume.pt", weights_only=True)  # as a resume state is read
    second.load_state_dict(saved["weights"])
    reader = (FusedAdam(second.parameters(), lr=1e-3, eps=1e-5) if direction == "torch_to_ours"
              else torch.optim.Adam(second.parameters(), lr=1e-3, eps=1e-5, fused=True))
    reader.load_state_dict(saved["optimizer"])
    _assert_same_state(reader.state_dict(), writer.state_dict())
    _train(first, writer, range(3, 6))
    _train(second, reader, range(3, 6))
    _assert_same_weights(first, second)
    _assert_same_state(reader.state_dict(), writer.state_dict())


def test_loading_casts_as_torch_does_and_refuses_other_parameters():
    model = _network(2).double()
    torch_state = torch.optim.Adam(_network(2).parameters(), lr=1e-3, fused=True)
    _train(_network(2), torch_state, range(1))  # float32 moments for float64 parameters
    ours = FusedAdam(model.parameters(), lr=1e-3)
    ours.load_state_dict(torch_state.state_dict())
    for values in ours.state.values():
        assert values["exp_avg"].dtype == torch.float64 and values["step"].dtype == torch.float32
    old_style = torch_state.state_dict()
    old_style["state"] = {number: {**values, "step": 1} for number, values in old_style["state"].items()}
    ours.load_state_dict(old_style)  # torch before 1.12 saved the step as a number
    assert all(_same_bits(values["step"], torch.tensor(1.0)) for values in ours.state.values())
    with pytest.raises(ValueError, match="parameter groups"):
        FusedAdam(list(model.parameters())[:2], lr=1e-3).load_state_dict(torch_state.state_dict())


def test_a_deep_copy_steps_its_own_parameters():
    model = _network(3)
    optimizer = FusedAdam(model.parameters(), lr=1e-3)
    _train(model, optimizer, range(2))
    copied_model, copied_optimizer = copy.deepcopy((model, optimizer))
    before = [p.detach().clone() for p in model.parameters()]
    _train(copied_model, copied_optimizer, range(2, 4))
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters()))
    assert not all(torch.equal(a, b) for a, b in zip(before, copied_model.parameters()))


def test_a_learners_update_does_not_import_torch_dynamo():
    """Importing torch._dynamo took 1.1-1.3 s of every training process's start (torch.optim's
    optimizers import it when built and at their first step)."""
    script = textwrap.dedent("""
        import sys
        import gymnasium as gym
        import numpy as np
        from laplab.agents.hyperparameters import Hyperparameters
        from laplab.agents.ppo import PPOLearner, Rollout
        from laplab.agents.sac import SACLearner
        space = gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
        continuous = {"action_space": {}, "action_space_type": "continuous"}
        hp = Hyperparameters(batch_size=32, num_epochs=3)
        ppo = PPOLearner(space, continuous, hp, seed=0, num_threads=1)
        rng = np.random.default_rng(0)
        obs = rng.uniform(-1, 1, (5, 3, 6)).astype(np.float32)
        steps = [ppo.act(obs[t]) for t in range(5)]
        terminated = np.zeros((5, 3), bool)
        terminated[-1] = True
        ppo.update(Rollout(obs, np.stack([s.action for s in steps]), np.stack([s.log_prob for s in steps]),
                           np.stack([s.value for s in steps]), np.ones((5, 3), np.float32), terminated,
                           None, None, None, None))
        ppo.load_state_dict(ppo.state_dict())
        sac = SACLearner(space, continuous, hp, seed=0, num_threads=1, buffer_capacity=1024)
        frames = rng.uniform(-1, 1, (41, 6)).astype(np.float32)
        sac.observe(frames[:-1], rng.uniform(-1, 1, (40, 2)).astype(np.float32), np.ones(40, np.float32),
                    frames[1:], np.zeros(40, bool))
        assert sac.update(2)["num_gradient_steps"] == 2
        sac.load_state_dict(sac.state_dict())
        print("torch._dynamo" in sys.modules, len(ppo.optimizer.state) > 0, len(sac.critic_optimizer.state) > 0)
    """)
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "True", "True"]
