"""DeepRacer training hyperparameters (``hyperparameters.json``), loaded and validated.

The keys, valid ranges and defaults are the AWS DeepRacer console's (reference doc section 6).
This module must stay importable without torch: the CLI validates a job before training starts.
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Mapping

from laplab.env.metadata import MAX_STACK_SIZE
from laplab.errors import UserError

# The networks' arithmetic in training (laplab's option, not a DeepRacer hyperparameter): see
# ``laplab.agents.networks.set_compute_precision``.
PRECISIONS = ("auto", "float32", "bfloat16")

BATCH_SIZES = (32, 64, 128, 256, 512)
EXPLORATION_TYPES = ("categorical", "e-greedy")
LOSS_TYPES = ("huber", "mean squared error")


@dataclass(frozen=True)
class Hyperparameters:
    """One DeepRacer training configuration, console defaults.

    - ``batch_size``: minibatch size of a gradient step, one of 32, 64, 128, 256, 512.
    - ``num_epochs``: passes over an iteration's experience, 3..10.
    - ``lr``: Adam learning rate, 1e-5..1e-3.
    - ``exploration_type``: ``"categorical"`` (sample the policy) or ``"e-greedy"``
      (a uniform random action with probability epsilon).
    - ``e_greedy_value``, ``epsilon_steps``: epsilon decays linearly from 1 to ``e_greedy_value``
      over ``epsilon_steps`` environment steps.
    - ``beta_entropy``: weight of the entropy bonus, 1e-4..1e-2.
    - ``discount_factor``: gamma, 0..1.
    - ``loss_type``: value loss, ``"huber"`` or ``"mean squared error"``.
    - ``num_episodes_between_training``: episodes collected per iteration, 1..1000.
    - ``stack_size``: camera frames stacked into one observation, 1 to :data:`MAX_STACK_SIZE` (8).
    - ``term_cond_max_episodes``, ``term_cond_avg_score``: stop after this many episodes, or
      once the average episode reward reaches the score.
    - ``sac_alpha``: SAC's fixed entropy temperature, 0..1.
    """

    batch_size: int = 64
    num_epochs: int = 10
    lr: float = 3e-4
    exploration_type: str = "categorical"
    e_greedy_value: float = 0.05
    epsilon_steps: int = 10000
    beta_entropy: float = 0.01
    discount_factor: float = 0.99
    loss_type: str = "huber"
    num_episodes_between_training: int = 20
    stack_size: int = 1
    term_cond_max_episodes: int = 100_000  # laplab: time stops training (DRfC: 1000)
    term_cond_avg_score: float = 100_000.0  # laplab: time stops training (DRfC: 350)
    sac_alpha: float = 0.2

    def __post_init__(self) -> None:
        _validate(asdict(self), source="Hyperparameters(...)")

    def to_dict(self) -> dict[str, Any]:
        """DeepRacer's JSON form: the 14 keys, plain numbers and strings."""
        return asdict(self)

    def epsilon_at(self, steps: int) -> float:
        """The e-greedy epsilon after ``steps`` environment steps (linear decay, then constant)."""
        fraction = min(max(steps, 0) / self.epsilon_steps, 1.0)
        return 1.0 + fraction * (self.e_greedy_value - 1.0)


class HyperparameterError(UserError, ValueError):
    """A hyperparameters file or dict that DeepRacer would not accept."""

    default_field = "hyperparameters"


# key -> (kind, low, high, description of the valid values)
_RANGES: dict[str, tuple[str, float, float, str]] = {
    "batch_size": ("int", 32, 512, "one of 32, 64, 128, 256, 512"),
    "num_epochs": ("int", 3, 10, "an integer from 3 to 10"),
    "lr": ("float", 1e-5, 1e-3, "a number from 1e-05 to 0.001"),
    "e_greedy_value": ("float", 0.0, 1.0, "a number from 0 to 1"),
    "epsilon_steps": ("int", 1, math.inf, "an integer >= 1"),
    "beta_entropy": ("float", 1e-4, 1e-2, "a number from 0.0001 to 0.01"),
    "discount_factor": ("float", 0.0, 1.0, "a number from 0 to 1"),
    "num_episodes_between_training": ("int", 1, 1000, "an integer from 1 to 1000"),
    "stack_size": ("int", 1, MAX_STACK_SIZE, f"an integer from 1 to {MAX_STACK_SIZE}"),
    "term_cond_max_episodes": ("int", 1, math.inf, "an integer >= 1"),
    "term_cond_avg_score": ("float", -math.inf, math.inf, "a finite number"),
    "sac_alpha": ("float", 0.0, 1.0, "a number from 0 to 1"),
}
# names other RL libraries use for DeepRacer's keys, for the "did you mean" hint
_ALIASES = {
    "learning_rate": "lr", "gamma": "discount_factor", "entropy": "beta_entropy",
    "ent_coef": "beta_entropy", "epochs": "num_epochs", "n_epochs": "num_epochs",
    "minibatch_size": "batch_size", "alpha": "sac_alpha", "frame_stack": "stack_size",
}
_CHOICES: dict[str, tuple[str, ...]] = {
    "exploration_type": EXPLORATION_TYPES,
    "loss_type": LOSS_TYPES,
}


def _fail(source: str, key: str, value: Any, valid: str) -> HyperparameterError:
    return HyperparameterError(
        f"{source}: hyperparameter {key!r} has the invalid value {value!r}; "
        f"valid values are {valid} (AWS DeepRacer console ranges)."
    )


def _coerce(source: str, key: str, value: Any) -> Any:
    """Turn a JSON value (number, or a number written as a string, as SageMaker passes them)
    into the field's type, or raise an error naming key and value."""
    if key in _CHOICES:
        if not isinstance(value, str) or value.strip().lower() not in _CHOICES[key]:
            raise _fail(source, key, value, " or ".join(repr(c) for c in _CHOICES[key]))
        return value.strip().lower()
    kind, _, _, valid = _RANGES[key]
    number = value
    if isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            raise _fail(source, key, value, valid) from None
    if isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number):
        raise _fail(source, key, value, valid)
    if kind == "int":
        if float(number) != int(number):
            raise _fail(source, key, value, valid)
        return int(number)
    return float(number)


def _validate(values: Mapping[str, Any], source: str) -> None:
    """Raise ``HyperparameterError`` for the first value of the full key set out of range."""
    for key, (kind, low, high, valid) in _RANGES.items():
        value = values[key]
        numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not numeric or (kind == "int" and not isinstance(value, int)) or not math.isfinite(value):
            raise _fail(source, key, value, valid)
        if not low <= value <= high:
            raise _fail(source, key, value, valid)
    if values["batch_size"] not in BATCH_SIZES:
        raise _fail(source, "batch_size", values["batch_size"], _RANGES["batch_size"][3])
    for key, choices in _CHOICES.items():
        if values[key] not in choices:
            raise _fail(source, key, values[key], " or ".join(repr(c) for c in choices))


def from_dict(values: Mapping[str, Any], source: str = "hyperparameters") -> Hyperparameters:
    """Build validated ``Hyperparameters`` from a DeepRacer-style dict; missing keys take the
    console defaults. ``source`` names the origin (a file path) in error messages."""
    if not isinstance(values, Mapping):
        raise HyperparameterError(
            f"{source}: expected a JSON object of hyperparameters, got {type(values).__name__}."
        )
    known = [f.name for f in fields(Hyperparameters)]
    clean: dict[str, Any] = {}
    for key, value in values.items():
        if key not in known:
            close = [_ALIASES[key]] if key in _ALIASES else difflib.get_close_matches(
                str(key), known, n=1, cutoff=0.6)
            hint = f" Did you mean {close[0]!r}?" if close else ""
            raise HyperparameterError(
                f"{source}: unknown hyperparameter {key!r}.{hint} Known keys: {', '.join(known)}."
            )
        clean[key] = _coerce(source, key, value)
    merged = {**asdict(Hyperparameters()), **clean}
    _validate(merged, source)
    return Hyperparameters(**merged)


def load_hyperparameters(path: str | Path) -> Hyperparameters:
    """Read and validate a DeepRacer ``hyperparameters.json``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise HyperparameterError(f"{path}: cannot read the hyperparameters file ({error}).") from None
    return parse_hyperparameters(text, str(path))


def parse_hyperparameters(text: str, source: str) -> Hyperparameters:
    """Read and validate hyperparameters from JSON ``text``; errors name ``source`` (a file, an option)."""
    try:
        values = json.loads(text)
    except json.JSONDecodeError as error:
        raise HyperparameterError(
            f"{source}: not valid JSON at line {error.lineno}, column {error.colno}: {error.msg}."
        ) from None
    return from_dict(values, source=source)


def save_hyperparameters(hyperparameters: Hyperparameters, path: str | Path) -> None:
    """Write ``hyperparameters.json`` in DeepRacer's form (sorted keys, indented)."""
    Path(path).write_text(json.dumps(hyperparameters.to_dict(), indent=4, sort_keys=True) + "\n")
