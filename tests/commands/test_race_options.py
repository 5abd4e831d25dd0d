"""laplab train's race-type options and the Python API's race_type: parsed into a RaceType, bad ones named."""

from __future__ import annotations

import pytest

from laplab.api import race_type_args
from laplab.cli import build_parser
from laplab.commands.race_options import race_type_from_args
from laplab.sim.race_type import RaceType, RaceTypeError


def parse(*options: str):
    return race_type_from_args(build_parser().parse_args(["train", "--name", "m", *options]))


def test_no_race_options_is_a_time_trial():
    assert parse() is None


def test_object_avoidance_options():
    race = parse("--race-type", "object_avoidance", "--objects", "3", "--randomize-objects")
    assert race == RaceType("object_avoidance", objects=3, randomize_objects=True)
    fixed = parse("--race-type", "object_avoidance", "--object-positions", "0.2,1;0.6,-1")
    assert fixed.object_positions == ((0.2, 1), (0.6, -1)) and fixed.objects == 2


def test_head_to_bot_options():
    race = parse("--race-type", "head_to_bot", "--bots", "2", "--bot-speed", "1.0", "--lane-change")
    assert race == RaceType("head_to_bot", bots=2, bot_speed=1.0, lane_change=True)


@pytest.mark.parametrize("options, field", [
    (("--bots", "2"), "--bots"),
    (("--race-type", "head_to_bot", "--bot-speed", "0.01"), "--bot-speed"),
    (("--race-type", "head_to_bot", "--bot-lane", "fast"), "--bot-lane"),
    (("--race-type", "object_avoidance", "--object-positions", "0.2,3"), "--object-positions"),
    (("--race-type", "head_to_model"), "--race-type"),
])
def test_bad_race_options_are_named(options, field):
    with pytest.raises(RaceTypeError) as error:
        race = parse(*options)
        from laplab.train.config import TrainConfig
        TrainConfig(race_type=race)
    assert error.value.field == field


def test_api_race_type_becomes_train_options():
    assert race_type_args({"kind": "time_trial"}) == []
    args = race_type_args({"kind": "head_to_bot", "bots": 2, "bot_speed": 1.0, "lane_change": True})
    assert args == ["--race-type", "head_to_bot", "--bots", "2", "--bot-speed", "1.0", "--lane-change"]
    race = RaceType("object_avoidance", object_positions=((0.25, 1), (0.5, -1)))
    back = parse(*race_type_args(race))
    assert back == race


def test_config_round_trips_its_race_and_old_files_are_time_trials():
    from laplab.train.config import TrainConfig
    config = TrainConfig(race_type={"kind": "object_avoidance", "objects": 3})
    data = config.to_dict()
    assert TrainConfig.from_dict(data).race_type == config.race_type
    del data["race_type"]
    assert TrainConfig.from_dict(data).race_type.kind == "time_trial"
    assert config.spec.observation_space.shape[0] == TrainConfig().spec.observation_space.shape[0] + 12


def test_reward_validate_puts_the_race_objects_on_the_track(tmp_path, capsys):
    from laplab.cli import main
    from tests.sim.test_race_types import DEEPRACER_OA_EXAMPLE
    path = tmp_path / "reward_function.py"
    path.write_text(DEEPRACER_OA_EXAMPLE)
    assert main(["reward", "validate", str(path)]) == 1  # a time trial has no objects: objects_distance[0] fails
    assert "IndexError" in capsys.readouterr().out
    assert main(["reward", "validate", str(path), "--race-type", "object_avoidance", "--objects", "3"]) == 0
    assert "PASS" in capsys.readouterr().out
