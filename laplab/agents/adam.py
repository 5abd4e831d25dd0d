"""The learners' Adam: ``torch.optim.Adam(params, lr=lr, eps=eps, fused=True)`` without importing
``torch._dynamo``.

Every ``torch.optim.Optimizer`` imports ``torch._dynamo`` when it is built and at its first step
(``add_param_group``, ``zero_grad`` and ``step`` are wrapped by ``torch._disable_dynamo``, which
imports it on first call, whatever the ``foreach`` / ``fused`` / ``capturable`` options). That import
took 1.1-1.3 s of a training process's ~4 s start on the 2-core host; laplab never compiles, so it
bought nothing. :class:`FusedAdam` keeps torch's arithmetic and file format and leaves out the
wrapper:

- ``step`` gathers each parameter's state as ``Adam._init_group`` does and calls torch's functional
  ``torch.optim.adam.adam`` with the group's options, the function ``torch.optim.Adam.step`` calls
  (it imports ``torch._dynamo`` only under ``torch.compile``). The updates are the same bits
  (tests/agents/test_fused_adam.py).
- ``state_dict`` / ``load_state_dict`` read and write ``torch.optim.Adam``'s dicts (parameters
  numbered in group order; ``step``, ``exp_avg``, ``exp_avg_sq`` per parameter), so resume states
  written before this class load into it, and its states load into ``torch.optim.Adam``.
"""

from __future__ import annotations

from collections.abc import Iterable
from copy import deepcopy
from typing import Any

import torch
from torch.optim.adam import adam


class FusedAdam:
    """Adam over one group of parameters with torch's fused kernel (``torch.optim.Adam``'s ``fused=True``:
    one kernel for all parameters; on CPU 1.6x faster camera-network steps than the per-tensor loop).
    A loaded state's options replace these, as in ``torch.optim.Adam``. ``lr``: learning rate;
    ``eps``: added to the root of the second moment."""

    def __init__(self, params: Iterable[torch.Tensor], lr: float, eps: float = 1e-8,
                 betas: tuple[float, float] = (0.9, 0.999)):
        params = list(params)
        if not params:
            raise ValueError("FusedAdam got an empty parameter list")
        if len({id(p) for p in params}) != len(params):
            raise ValueError("FusedAdam got a parameter twice")
        if not lr >= 0.0 or not eps >= 0.0 or not all(0.0 <= beta < 1.0 for beta in betas):
            raise ValueError(f"FusedAdam: invalid lr {lr}, eps {eps} or betas {betas}")
        # torch.optim.Adam's group keys and defaults (its state dicts carry them all)
        self.param_groups: list[dict[str, Any]] = [{
            "params": params, "lr": lr, "betas": tuple(betas), "eps": eps, "weight_decay": 0,
            "amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
            "differentiable": False, "fused": True, "decoupled_weight_decay": False}]
        self.state: dict[torch.Tensor, dict[str, torch.Tensor]] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop the gradients (``set_to_none``) or zero them."""
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    if p.grad.grad_fn is not None:
                        p.grad.detach_()
                    else:
                        p.grad.requires_grad_(False)
                    p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient (the others keep their state)."""
        for group in self.param_groups:
            params, grads, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, steps = [], [], [], [], [], []
            for p in group["params"]:
                if p.grad is None:
                    continue
                if p.grad.is_sparse or torch.is_complex(p):
                    raise RuntimeError("FusedAdam takes dense real parameters and gradients only")
                state = self.state.get(p)
                if not state:
                    state = self.state[p] = _fresh_state(p, group)
                params.append(p)
                grads.append(p.grad)
                exp_avgs.append(state["exp_avg"])
                exp_avg_sqs.append(state["exp_avg_sq"])
                if group["amsgrad"]:
                    max_exp_avg_sqs.append(state["max_exp_avg_sq"])
                steps.append(state["step"])
            beta1, beta2 = group["betas"]
            adam(params, grads, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, steps,
                 foreach=group["foreach"], capturable=group["capturable"], differentiable=False,
                 fused=group["fused"], grad_scale=None, found_inf=None, has_complex=False,
                 decoupled_weight_decay=group["decoupled_weight_decay"], amsgrad=group["amsgrad"],
                 beta1=beta1, beta2=beta2, lr=group["lr"], weight_decay=group["weight_decay"],
                 eps=group["eps"], maximize=group["maximize"])

    def state_dict(self) -> dict[str, Any]:
        """``torch.optim.Adam.state_dict()``'s dict: ``state`` by parameter number (the order of the
        groups' parameters; only parameters that have stepped), ``param_groups`` with their options
        and numbers. The tensors are this optimizer's own, not copies (as torch's)."""
        numbers: dict[int, int] = {}
        groups = []
        for group in self.param_groups:
            for p in group["params"]:
                numbers.setdefault(id(p), len(numbers))
            groups.append({**{k: v for k, v in group.items() if k != "params"},
                           "params": [numbers[id(p)] for p in group["params"]]})
        return {"state": {numbers[id(p)]: state for p, state in self.state.items()}, "param_groups": groups}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Take a state from :meth:`state_dict` or from ``torch.optim.Adam.state_dict()`` over the
        same parameters: moments cast to each parameter's dtype and device, ``step`` to float32 on
        the parameter's device when the group is fused (torch's rules). Raises ValueError when the
        groups or their sizes differ."""
        saved_groups = deepcopy(state_dict["param_groups"])
        if len(saved_groups) != len(self.param_groups) or any(
                len(saved["params"]) != len(group["params"]) for saved, group in zip(saved_groups, self.param_groups)):
            raise ValueError("the optimizer state's parameter groups do not match this optimizer's parameters")
        if any(saved.get("differentiable", False) for saved in saved_groups):
            raise ValueError("FusedAdam does not take a differentiable optimizer's state")
        by_number = {number: p for saved, group in zip(saved_groups, self.param_groups)
                     for number, p in zip(saved["params"], group["params"])}
        fused = {number: bool(saved.get("fused") or saved.get("capturable"))
                 for saved in saved_groups for number in saved["params"]}
        state = {}
        for number, values in state_dict["state"].items():
            if number not in by_number:
                raise ValueError(f"the optimizer state names parameter {number!r}, which this optimizer lacks")
            p = by_number[number]
            state[p] = {key: _cast(value, p, key, fused[number]) for key, value in values.items()}
        for saved, group in zip(saved_groups, self.param_groups):
            saved["params"] = group["params"]
            for key, default in _OPTION_DEFAULTS.items():  # older torch's states lack the newer keys
                saved.setdefault(key, default)
        self.param_groups, self.state = saved_groups, state


_OPTION_DEFAULTS = {"amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
                    "differentiable": False, "fused": None, "decoupled_weight_decay": False}


def _fresh_state(p: torch.Tensor, group: dict[str, Any]) -> dict[str, torch.Tensor]:
    """A parameter's state before its first step, as ``torch.optim.Adam._init_group`` makes it."""
    if group["fused"] and not p.is_floating_point():
        raise RuntimeError(f"FusedAdam's fused kernel takes floating-point parameters, not {p.dtype}")
    step = (torch.zeros((), dtype=torch.float32, device=p.device) if group["capturable"] or group["fused"]
            else torch.tensor(0.0, dtype=_scalar_dtype()))
    state = {"step": step, "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
             "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format)}
    if group["amsgrad"]:
        state["max_exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
    return state


def _scalar_dtype() -> torch.dtype:
    return torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32


def _cast(value: Any, p: torch.Tensor, key: str, fused: bool) -> Any:
    """``torch.optim.Optimizer.load_state_dict``'s rule for one state entry (and ``Adam.__setstate__``'s
    for a ``step`` saved as a number by torch before 1.12)."""
    if key == "step" and isinstance(value, (int, float)):
        return (torch.tensor(float(value), dtype=torch.float32, device=p.device) if fused
                else torch.tensor(float(value), dtype=_scalar_dtype()))
    if not isinstance(value, torch.Tensor):
        return value
    if key == "step":
        return value.to(dtype=torch.float32, device=p.device) if fused else value
    return value.to(dtype=p.dtype, device=p.device) if p.is_floating_point() else value.to(device=p.device)
