"""A model is evaluated with the car it trained with, unless told otherwise; a folder from before
DeepRacer's cars keeps laplab's classic car and says so."""

from __future__ import annotations

import json
import pytest

from laplab.cli import main
from laplab.evaluate import EvaluationSettings, evaluate_model
from laplab.store.layout import model_folder
from tests.evaluate.conftest import train_tiny_model

QUICK = dict(trials=1, max_trial_time=8.0)


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("home")
        patch.setenv("LAPLAB_HOME", str(root))
        for name, car in (("v4-model", "deepracer-v4"), ("old-model", "deepracer-v6")):
            train_tiny_model(name, max_episodes=4, max_time_s=60, vehicle=car)
        # a folder written before DeepRacer's cars: config version 1, where "deepracer" was laplab's car
        path = model_folder("old-model").laplab_config
        document = json.loads(path.read_text())
        path.write_text(json.dumps({**document, "version": 1, "vehicle": "deepracer"}))
        yield root


def test_the_model_folder_records_its_car_and_the_version_that_chooses_it(home):
    folder = model_folder("v4-model")
    assert json.loads(folder.laplab_config.read_text())["vehicle"] == "deepracer-v4"
    assert json.loads(folder.model_metadata.read_text())["version"] == "4"


def test_evaluation_drives_the_training_car_unless_told(home):
    result, stamp = evaluate_model("v4-model", EvaluationSettings(**QUICK))
    assert result.vehicle.name == "deepracer-v4" and result.trained_car == "deepracer-v4"
    summary = json.loads((model_folder("v4-model").evaluation_dir(stamp) / "summary.json").read_text())
    assert summary["car"] == "deepracer-v4"
    other, _ = evaluate_model("v4-model", EvaluationSettings(**QUICK, physics="6"))
    assert other.vehicle.name == "deepracer-v6" and other.trained_car == "deepracer-v4"


def test_a_folder_from_before_deepracers_cars_keeps_the_classic_car_and_says_so(home, capsys):
    assert main(["evaluate", "old-model", "--trials", "1", "--max-trial-time", "8"]) == 0
    out = capsys.readouterr().out
    assert "car: laplab-classic" in out and "trained before laplab drove DeepRacer's cars" in out
    assert "--physics 6" in out
    assert main(["evaluate", "old-model", "--trials", "1", "--max-trial-time", "8", "--physics", "5"]) == 0
    assert "car: deepracer-v5" in capsys.readouterr().out


def test_a_bad_physics_choice_is_one_clear_error(home, capsys):
    assert main(["evaluate", "v4-model", "--physics", "7b"]) == 2
    err = capsys.readouterr().err
    assert "--physics '7b'" in err and "Traceback" not in err
    assert main(["train", "--name", "x", "--physics", "nine", "--max-time", "5s"]) == 2
    assert "--physics 'nine'" in capsys.readouterr().err
    assert not model_folder("x").exists()
