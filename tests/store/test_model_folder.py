from datetime import datetime, timezone
from pathlib import Path

import pytest

from laplab.store.layout import (
    ModelFolder,
    ModelNameError,
    evaluation_stamp,
    list_evaluations,
    list_models,
    model_folder,
    models_root,
    validate_model_name,
)

METADATA = {"action_space": [{"steering_angle": 0, "speed": 1.0}], "sensor": ["FRONT_FACING_CAMERA"],
            "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "training_algorithm": "clipped_ppo",
            "action_space_type": "discrete", "version": "5"}


def test_paths_follow_the_deepracer_for_cloud_layout(tmp_path):
    folder = ModelFolder(tmp_path / "m")
    assert folder.model_metadata == tmp_path / "m/model/model_metadata.json"
    assert folder.hyperparameters == tmp_path / "m/ip/hyperparameters.json"
    assert folder.reward_function == tmp_path / "m/reward_function.py"
    assert folder.training_simtrace(3) == tmp_path / "m/training-simtrace/3-iteration.csv"
    assert folder.training_metrics == tmp_path / "m/metrics/TrainingMetrics.json"
    assert folder.deepracer_checkpoints == tmp_path / "m/model/deepracer_checkpoints.json"
    stamp = "20240102030405"
    assert folder.evaluation_simtrace(stamp) == tmp_path / f"m/evaluation-{stamp}/evaluation-simtrace/0-iteration.csv"
    assert folder.evaluation_metrics(stamp) == tmp_path / f"m/metrics/evaluation/evaluation-{stamp}.json"
    assert folder.laplab_config == tmp_path / "m/laplab.json"
    assert folder.error_file == tmp_path / "m/error.txt"
    assert not folder.exists()
    with pytest.raises(ValueError, match="iteration"):
        folder.training_simtrace(-1)
    with pytest.raises(ValueError, match="14 digits"):
        folder.evaluation_dir("2024-01-02")


@pytest.mark.parametrize("name", ["a", "My-Model-2", "x" * 64, "0-0"])
def test_accepts_deepracer_model_names(name):
    assert validate_model_name(name) == name


@pytest.mark.parametrize("name", ["", "x" * 65, "my_model", "my model", "model.v2", "../etc", "modèle", 7])
def test_rejects_other_model_names_with_a_clear_message(name):
    with pytest.raises(ModelNameError, match="letter, a digit or a hyphen"):
        validate_model_name(name)


def test_models_root_follows_laplab_home(monkeypatch, tmp_path):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    assert models_root() == tmp_path / "models"
    assert model_folder("abc").root == tmp_path / "models" / "abc"
    monkeypatch.delenv("LAPLAB_HOME")
    assert models_root() == Path("~/.laplab/models").expanduser()


def test_list_models_finds_folders_with_metadata_or_config(tmp_path):
    model_folder("b-model", tmp_path).create().write_model_metadata(METADATA)
    model_folder("a-model", tmp_path).create().write_laplab_config({"track": "reinvent"})
    model_folder("empty", tmp_path).create()
    (tmp_path / "not_valid").mkdir()
    (tmp_path / "not_valid" / "laplab.json").write_text("{}")
    assert list_models(tmp_path) == ["a-model", "b-model"]
    assert list_models(tmp_path / "nowhere") == []


def test_evaluations_get_unique_stamps_and_are_listed_in_order(tmp_path):
    folder = model_folder("m", tmp_path)
    moment = datetime(2024, 5, 6, 7, 8, 9, tzinfo=timezone.utc)
    first = folder.new_evaluation(moment)
    second = folder.new_evaluation(moment)
    assert (first, second) == ("20240506070809", "20240506070810")
    assert folder.evaluation_simtrace(first).parent.is_dir()
    folder.evaluation_metrics("20230101000000").parent.mkdir(parents=True)
    folder.evaluation_metrics("20230101000000").write_text('{"metrics": []}')
    assert list_evaluations("m", tmp_path) == ["20230101000000", first, second]
    assert evaluation_stamp(moment) == "20240506070809"


def test_documents_round_trip_and_metadata_keys_are_checked(tmp_path):
    folder = model_folder("m", tmp_path).create()
    folder.write_model_metadata(METADATA)
    folder.write_hyperparameters({"batch_size": 64})
    folder.write_reward_function("def reward_function(params):\n    return 1.0\n")
    assert folder.read_model_metadata() == METADATA
    assert folder.read_hyperparameters() == {"batch_size": 64}
    assert "reward_function" in folder.read_reward_function()
    with pytest.raises(ValueError, match="model_metadata.json lacks.*'sensor'"):
        folder.write_model_metadata({k: v for k, v in METADATA.items() if k != "sensor"})
    assert folder.read_error() is None
    folder.write_error("RewardFunctionError: division by zero at line 3")
    assert folder.read_error() == "RewardFunctionError: division by zero at line 3"
    assert folder.list_training_iterations() == []
    for iteration in (10, 2, 0):
        folder.training_simtrace(iteration).write_text("")
    assert folder.list_training_iterations() == [0, 2, 10]
