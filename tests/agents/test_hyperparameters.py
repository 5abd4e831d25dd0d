"""Hyperparameters: console defaults, DeepRacer JSON round trip, and clear error messages."""

import json
import sys

import pytest

from laplab.agents.hyperparameters import (HyperparameterError, Hyperparameters, from_dict,
                                           load_hyperparameters, save_hyperparameters)


def test_console_defaults():
    hp = Hyperparameters()
    assert (hp.batch_size, hp.num_epochs, hp.lr, hp.beta_entropy) == (64, 10, 3e-4, 0.01)
    assert (hp.exploration_type, hp.loss_type, hp.discount_factor) == ("categorical", "huber", 0.99)
    assert (hp.e_greedy_value, hp.epsilon_steps, hp.num_episodes_between_training) == (0.05, 10000, 20)
    # laplab's stop conditions default to "never" (the max time stops a job), not DRfC's 1000 / 350
    assert (hp.stack_size, hp.term_cond_max_episodes, hp.term_cond_avg_score, hp.sac_alpha) == (1, 100_000, 100_000.0, 0.2)


def test_module_does_not_import_torch():
    assert "laplab.agents.hyperparameters" in sys.modules
    # hyperparameters.py itself has no torch import (the CLI validates jobs without torch)
    source = open(sys.modules["laplab.agents.hyperparameters"].__file__).read()
    assert "import torch" not in source


def test_round_trip_through_deepracer_json(tmp_path):
    hp = Hyperparameters(batch_size=128, lr=1e-4, loss_type="mean squared error", exploration_type="e-greedy")
    path = tmp_path / "hyperparameters.json"
    save_hyperparameters(hp, path)
    written = json.loads(path.read_text())
    assert written["batch_size"] == 128 and written["loss_type"] == "mean squared error"
    assert set(written) == set(Hyperparameters().to_dict())
    assert load_hyperparameters(path) == hp


def test_deepracer_file_forms_are_accepted():
    # older console exports capitalise the loss type; SageMaker passes numbers as strings
    hp = from_dict({"loss_type": "Mean squared error", "batch_size": "32", "lr": "0.0001",
                    "num_epochs": 3.0, "exploration_type": "E-Greedy"})
    assert (hp.loss_type, hp.batch_size, hp.lr, hp.num_epochs, hp.exploration_type) == (
        "mean squared error", 32, 1e-4, 3, "e-greedy")


def test_malformed_json_names_file_line_and_column(tmp_path):
    path = tmp_path / "hyperparameters.json"
    path.write_text('{\n  "batch_size": 64,\n  "lr": 0.0003,,\n}\n')
    with pytest.raises(HyperparameterError) as error:
        load_hyperparameters(path)
    message = str(error.value)
    # line 3 is '  "lr": 0.0003,,': the stray second comma is its 16th character
    assert str(path) in message and "line 3" in message and "column 16" in message


def test_unknown_key_names_it_with_a_hint(tmp_path):
    path = tmp_path / "hp.json"
    path.write_text(json.dumps({"num_epoch": 5}))
    expected = r"hp\.json.*unknown hyperparameter 'num_epoch'.*Did you mean 'num_epochs'"
    with pytest.raises(HyperparameterError, match=expected):
        load_hyperparameters(path)
    with pytest.raises(HyperparameterError, match="'learning_rate'.*Did you mean 'lr'"):
        from_dict({"learning_rate": 1e-4})


@pytest.mark.parametrize("key, value, valid", [
    ("batch_size", 100, "32, 64, 128, 256, 512"),
    ("num_epochs", 11, "from 3 to 10"),
    ("lr", 0.01, "from 1e-05 to 0.001"),
    ("beta_entropy", 0.5, "from 0.0001 to 0.01"),
    ("discount_factor", 1.5, "from 0 to 1"),
    ("num_episodes_between_training", 0, "from 1 to 1000"),
    ("stack_size", 0, "from 1 to 8"),
    ("stack_size", 1_000_000, "from 1 to 8"),
    ("loss_type", "mse", "'huber' or 'mean squared error'"),
    ("exploration_type", "greedy", "'categorical' or 'e-greedy'"),
    ("num_epochs", 4.5, "integer"),
    ("lr", True, "number"),
    ("lr", "fast", "number"),
])
def test_out_of_range_names_key_value_and_range(key, value, valid):
    with pytest.raises(HyperparameterError) as error:
        from_dict({key: value}, source="job/hyperparameters.json")
    message = str(error.value)
    assert "job/hyperparameters.json" in message and repr(key) in message and valid in message
    assert repr(value) in message or str(value) in message


def test_constructor_validates_too():
    with pytest.raises(HyperparameterError, match="'num_epochs'.*2"):
        Hyperparameters(num_epochs=2)


def test_not_an_object(tmp_path):
    path = tmp_path / "hp.json"
    path.write_text("[1, 2]")
    with pytest.raises(HyperparameterError, match="expected a JSON object"):
        load_hyperparameters(path)


def test_epsilon_schedule_is_linear_then_constant():
    hp = Hyperparameters(e_greedy_value=0.1, epsilon_steps=100)
    # 1 + (steps / 100) * (0.1 - 1): 0 -> 1, 50 -> 0.55, 100 and beyond -> 0.1
    assert hp.epsilon_at(0) == 1.0
    assert hp.epsilon_at(50) == pytest.approx(0.55)
    assert hp.epsilon_at(100) == pytest.approx(0.1)
    assert hp.epsilon_at(10_000) == pytest.approx(0.1)
