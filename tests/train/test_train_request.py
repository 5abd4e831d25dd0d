"""One TrainRequest for every door: one default max time, and a bad value gets the same message and
field from the CLI, laplab.api and the worker (the console's API: tests/console/test_request_fields.py)."""

from __future__ import annotations

import inspect
import json

import pytest

from laplab import api
from laplab.cli import build_parser
from laplab.commands.train import train_request
from laplab.errors import UserError
from laplab.train.config import TrainConfig
from laplab.train.request import (CLI_OPTIONS, DEFAULT_MAX_TIME_S, ExportRequest, RequestError, TrainRequest,
                                  as_cli_error)

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]
REWARD = "def reward_function(params):\n    return 1.0\n"


def _cli(*options: str):
    return train_request(build_parser().parse_args(["train", "--name", "m", *options]), "m")


@pytest.fixture
def model_files(tmp_path):
    return api.write_model_files(tmp_path, REWARD, ACTIONS, {"batch_size": 32}, sensor=["STATE"])


def test_one_default_max_time_everywhere(model_files):
    assert TrainRequest().max_time_s == DEFAULT_MAX_TIME_S == TrainConfig().max_time_s
    assert _cli().max_time_s == DEFAULT_MAX_TIME_S  # laplab train without --max-time
    train = next(a for a in build_parser()._subparsers._group_actions[0].choices["train"]._actions
                 if "--max-time" in a.option_strings)
    assert f"default {DEFAULT_MAX_TIME_S / 60:g}m" in train.help
    assert inspect.signature(api.TrainingJob.start).parameters["max_time"].default is None
    assert api.training_request("m", model_files).max_time_s == DEFAULT_MAX_TIME_S
    assert TrainRequest.from_mapping({"track": "oval", "workers": 1}).to_config().max_time_s == DEFAULT_MAX_TIME_S


def test_the_worker_builds_the_request_from_the_job_params(tmp_path, monkeypatch):
    import laplab.train.jobs as jobs
    from laplab.jobs import worker

    built = {}

    class Built(Exception):
        pass

    def capture(name, config, **kwargs):
        built[name] = config
        raise Built

    monkeypatch.setattr(jobs, "create_training_in_place", capture)
    params = {"track": "oval", "seed": 3, "physics": "5", "race_type": {"kind": "object_avoidance", "objects": 2}}
    with pytest.raises(Built):
        worker._train(worker.JobFiles(tmp_path), {"kind": "train", "model": "w", "params": params})
    config = built["w"]
    assert config.max_time_s == DEFAULT_MAX_TIME_S and config.seed == 3 and config.track == "oval"
    assert config.car == "deepracer-v5" and config.race_type.objects == 2
    assert config == TrainRequest.from_mapping({**params, "workers": 1}).to_config()
    with pytest.raises(RequestError) as error:
        worker._train(worker.JobFiles(tmp_path), {"kind": "train", "model": "w", "params": {"max_episodes": 0}})
    assert error.value.field == "max_episodes"


@pytest.mark.parametrize("field, option, value", [("workers", "--workers", 0), ("physics", "--physics", "seven")])
def test_a_bad_value_gets_the_same_message_and_field_from_every_door(model_files, field, option, value):
    with pytest.raises(UserError) as from_request:  # the console's API and the worker build this
        TrainRequest.from_mapping({field: value}).validate()
    with pytest.raises(UserError) as from_api:
        api.training_request("m", model_files, **{field: value})
    with pytest.raises(UserError) as from_cli:
        _cli(option, str(value))
    assert from_request.value.field == from_api.value.field == field
    assert from_cli.value.field == option == CLI_OPTIONS[field]
    assert str(from_request.value) == str(from_api.value)
    assert str(from_cli.value) == str(as_cli_error(from_request.value))  # the field's name -> the option's
    assert str(from_cli.value).replace(option, field, 1) == str(from_request.value)


def test_max_episodes_from_the_cli_and_a_mapping():
    with pytest.raises(UserError) as from_cli:
        _cli("--max-episodes", "0")
    with pytest.raises(UserError) as from_mapping:
        TrainRequest.from_mapping({"max_episodes": 0})
    assert (from_cli.value.field, from_mapping.value.field) == ("--max-episodes", "max_episodes")
    assert str(from_mapping.value) == "max episodes must be an integer >= 1, got 0"
    assert str(from_cli.value) == "--max-episodes: max episodes must be an integer >= 1, got 0"  # names the option


def test_max_time_errors_name_the_max_time(model_files):
    with pytest.raises(UserError) as from_cli:
        _cli("--max-time=-5m")
    with pytest.raises(UserError) as from_api:
        api.training_request("m", model_files, max_time="-5m")
    assert from_cli.value.field == "--max-time" and from_api.value.field == "max_time_s"
    assert str(from_cli.value) == f"--max-time: {from_api.value}" == str(as_cli_error(from_api.value))
    with pytest.raises(UserError) as number:
        api.training_request("m", model_files, max_time=-300)
    assert number.value.field == "max_time_s" and "max time must be a positive number" in str(number.value)


def test_errors_of_the_config_and_files_carry_the_request_field():
    cases = {"hyperparameters": {"hyperparameters": {"batch_size": -3}}, "track": {"track": "no-such-track"},
             "race_type": {"race_type": {"kind": "object_avoidance", "objects": "many"}},
             "model_metadata": {"model_metadata": {"action_space": 3}}, "precision": {"precision": "int3"},
             "name": {"name": "bad name!"}}
    for field, values in cases.items():
        with pytest.raises(UserError) as error:
            TrainRequest.from_mapping(values).validate()
        assert error.value.field == field, (field, str(error.value))
    with pytest.raises(RequestError, match="unknown training option 'sheep'"):
        TrainRequest.from_mapping({"sheep": 1})


def test_the_request_round_trips_through_its_mapping_and_reaches_the_config():
    request = TrainRequest(name="m", tracks=("oval", "classic_2018@reversed"), physics="4", seed=7, workers=2,
                           race_type={"kind": "head_to_bot", "bots": 2}, max_episodes=8)
    assert TrainRequest.from_mapping(request.to_mapping()) == request
    assert TrainRequest.from_mapping({"vehicle": "deepracer-v6"}).physics == "deepracer-v6"  # older job params
    config = request.to_config()
    assert config.tracks == ("oval", "classic_2018@reversed") and config.car == "deepracer-v4"
    assert (config.seed, config.workers, config.max_episodes, config.race_type.bots) == (7, 2, 8, 2)


def test_the_python_api_passes_the_request_to_laplab_train(model_files):
    from laplab.api import _train_args
    request = api.training_request("m", model_files, track=["oval", "classic_2018"], max_time=90, physics="5",
                                   race_type={"kind": "object_avoidance", "objects": 2})
    args = build_parser().parse_args(["train", *_train_args(request, model_files)])
    again = train_request(args, args.name)
    assert again.max_time_s == 90 and again.tracks == ("oval", "classic_2018") and again.physics == "deepracer-v5"
    assert again.race_type["kind"] == "object_avoidance" and again.race_type["objects"] == 2


def test_export_request_ranges():
    assert ExportRequest().format == "car"
    with pytest.raises(RequestError) as error:
        ExportRequest.from_mapping({"format": "zip"})
    assert error.value.field == "format"
    with pytest.raises(RequestError) as error:
        ExportRequest(format="onnx").as_job()
    assert error.value.field == "format"
    with pytest.raises(RequestError) as error:
        ExportRequest(checkpoint="")
    assert error.value.field == "checkpoint"


def test_evaluate_request_errors_carry_their_field_from_laplab_api():
    from laplab.evaluate.trials import EvaluateRequest, EvaluationSettings
    assert EvaluateRequest is EvaluationSettings
    with pytest.raises(UserError) as from_api:  # checked before any process starts
        api.evaluate("no-such-model", trials=9)
    with pytest.raises(UserError) as from_request:
        EvaluateRequest.from_mapping({"trials": 9})
    assert from_api.value.field == from_request.value.field == "trials"
    assert str(from_api.value) == str(from_request.value)
    with pytest.raises(UserError) as unknown:
        EvaluateRequest.from_mapping({"laps": 2})
    assert unknown.value.field == "laps"


def test_laplab_export_checks_the_export_request(capsys):
    from laplab.cli import main
    assert main(["export", "any-model", "--checkpoint", ""]) == 2
    assert "--checkpoint must be 'best', 'last' or a checkpoint file name" in capsys.readouterr().err


def test_a_console_resume_trusts_the_reward_only_inside_the_sandbox(tmp_path, monkeypatch):
    """An imported model's reward runs on resume where the console confines every reward (bubblewrap),
    and stays untrusted in an unconfined console job."""
    import laplab.train.jobs as jobs
    from laplab.jobs import worker
    from laplab.jobs.db import Job
    from laplab.jobs.runner import write_spec

    asked = []

    class Built(Exception):
        pass

    def capture(name, max_time_s=None, **kwargs):
        asked.append(kwargs.get("trust_reward"))
        raise Built

    monkeypatch.setattr(jobs, "resume_training", capture)
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    for sandboxed in (True, False):
        job = Job(7, "resume", "imported", 1, "queued", 0.0, {}, 0.0, None, None, None, None, None, None)
        spec = json.loads(write_spec(job, sandboxed=sandboxed).read_text())
        assert spec["sandboxed"] is sandboxed
        with pytest.raises(Built):
            worker._train(worker.JobFiles(tmp_path), spec)
    assert asked == [True, False]


def test_domain_randomization_without_a_camera_is_refused_alike_at_every_door(model_files):
    with pytest.raises(UserError) as from_request:  # the console's API and the worker build this
        TrainRequest.from_mapping({"domain_randomization": True}).validate()
    with pytest.raises(UserError) as from_api:
        api.training_request("m", model_files, domain_randomization=True)
    with pytest.raises(UserError) as from_cli:
        _cli("--domain-randomization")
    assert from_request.value.field == from_api.value.field == "domain_randomization"
    assert "no camera (sensors: STATE)" in str(from_request.value) and str(from_request.value) == str(from_api.value)
    assert from_cli.value.field == "--domain-randomization"
    assert str(from_cli.value) == f"--domain-randomization: {from_request.value}"


def test_domain_randomization_of_a_camera_model_reaches_the_config_from_every_door(tmp_path):
    files = api.write_model_files(tmp_path, REWARD, ACTIONS, {"batch_size": 32}, sensor=["FRONT_FACING_CAMERA"])
    request = api.training_request("m", files, domain_randomization=True)
    assert request.domain_randomization and request.to_config().domain_randomization
    from laplab.api import _train_args
    again = train_request(build_parser().parse_args(["train", *_train_args(request, files)]), "m")
    assert again.domain_randomization and again.to_config().domain_randomization
    plain = api.training_request("m", files)
    assert "--domain-randomization" not in _train_args(plain, files) and not plain.to_config().domain_randomization
