"""model_metadata.json: valid files parse and round-trip; invalid ones raise MetadataError naming the key."""

from __future__ import annotations

import json

import pytest

from laplab.env import MetadataError, TimeTrialEnv, TimeTrialVectorEnv, load_model_metadata, metadata_from_dict
from laplab.env.action_space import DEFAULT_DISCRETE_ACTIONS
from laplab.env.metadata import ModelMetadata

CONTINUOUS = {"action_space": {"steering_angle": {"low": -20, "high": 25.5}, "speed": {"low": 1.0, "high": 3.5}},
              "action_space_type": "continuous", "sensor": ["STATE"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK",
              "training_algorithm": "sac", "version": "5"}
DISCRETE = {"action_space": [{"steering_angle": -30, "speed": 0.8}, {"steering_angle": 0, "speed": 4}],
            "sensor": ["FRONT_FACING_CAMERA", "LIDAR"], "action_space_type": "discrete",
            "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "training_algorithm": "clipped_ppo",
            "version": "4", "lidar_config": {"num_sectors": 8, "num_values_per_sector": 8, "clipping_dist": 2.0}}


def test_defaults():
    meta = ModelMetadata()
    assert meta.sensors == ("STATE",) and meta.training_algorithm == "clipped_ppo"
    assert meta.action_space.is_discrete and meta.action_space.actions == DEFAULT_DISCRETE_ACTIONS
    assert metadata_from_dict({}) == meta


def test_continuous_file_parses_and_round_trips(tmp_path):
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps(CONTINUOUS))
    meta = load_model_metadata(path)
    assert not meta.action_space.is_discrete
    assert meta.action_space.steering == (-20.0, 25.5) and meta.action_space.speed == (1.0, 3.5)
    assert meta.action_space.max_speed == 3.5
    assert meta.training_algorithm == "sac" and meta.neural_network == "DEEP_CONVOLUTIONAL_NETWORK"
    assert meta.to_dict() == CONTINUOUS
    assert metadata_from_dict(meta.to_dict()) == meta


def test_discrete_camera_lidar_parses_and_round_trips():
    meta = metadata_from_dict(DISCRETE)
    assert meta.action_space.actions == ((-30.0, 0.8), (0.0, 4.0))
    assert meta.camera == "FRONT_FACING_CAMERA" and meta.lidar == "LIDAR"
    assert meta.version == "4" and meta.lidar_config["num_sectors"] == 8
    assert meta.to_dict() == DISCRETE
    assert metadata_from_dict(json.loads(json.dumps(meta.to_dict()))) == meta


def test_action_space_type_is_inferred():
    data = {k: v for k, v in CONTINUOUS.items() if k != "action_space_type"}
    assert not metadata_from_dict(data).action_space.is_discrete
    assert metadata_from_dict({"action_space": DISCRETE["action_space"]}).action_space.is_discrete


def test_bad_json_names_the_file_and_position(tmp_path):
    path = tmp_path / "model_metadata.json"
    path.write_text('{"action_space": [\n  {"steering_angle": 0, "speed": 1,}\n]}')
    with pytest.raises(MetadataError, match=r"model_metadata\.json: not valid JSON: .* line 2"):
        load_model_metadata(path)
    with pytest.raises(MetadataError, match="no such file"):
        load_model_metadata(tmp_path / "absent.json")


def _with(**changes) -> dict:
    data = json.loads(json.dumps(CONTINUOUS))
    data.update(changes)
    return data


@pytest.mark.parametrize("data, named", [
    ({"action_space": [{"steering_angle": 0, "speed": 1.0}, {"steering_angle": 10, "speed": 4.5}]},
     r"action_space\[1\]\.speed = 4\.5 m/s is outside"),
    ({"action_space": [{"steering_angle": 0, "speed": 0.05}]}, r"action_space\[0\]\.speed = 0\.05"),
    ({"action_space": [{"steering_angle": 31, "speed": 1.0}]}, r"action_space\[0\]\.steering_angle = 31"),
    ({"action_space": [{"steering_angle": 0, "speed": "fast"}]}, r"action_space\[0\]\.speed must be a finite number"),
    ({"action_space": [{"steering_angle": 0}]}, r"action_space\[0\] must be an object with keys"),
    ({"action_space": []}, "non-empty list"),
    (_with(action_space={"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 5}}),
     r"action_space\.speed\.high = 5"),
    (_with(action_space={"steering_angle": {"low": -45, "high": 30}, "speed": {"low": 0.5, "high": 4}}),
     r"action_space\.steering_angle\.low = -45"),
    (_with(action_space={"steering_angle": {"low": 10, "high": -10}, "speed": {"low": 0.5, "high": 4}}),
     r"action_space\.steering_angle: low \(10\.0\) must be smaller than high"),
    (_with(action_space={"steering_angle": {"low": -30, "high": 30}}), "continuous action_space must be"),
    (_with(action_space_type="continuous", action_space=[{"steering_angle": 0, "speed": 1}]),
     "continuous action_space must be"),
    (_with(action_space_type="hybrid"), "action_space_type must be"),
    (_with(sensor=["FRONT_FACING_CAMERA", "STEREO_CAMERAS"]), r"'sensor'.*FRONT_FACING_CAMERA.*STEREO_CAMERAS"),
    (_with(sensor=["STATE", "SONAR"]), r"unknown sensor 'SONAR' in 'sensor'"),
    (_with(sensor=["LIDAR", "SECTOR_LIDAR", "STATE"]), r"'sensor'.*LIDAR.*SECTOR_LIDAR"),
    (_with(sensor=["STATE", "STATE"]), "'sensor' lists a sensor twice"),
    (_with(sensor=["LIDAR"]), r"needs one camera sensor.*'sensor' lists only \['LIDAR'\]"),
    (_with(sensor=[]), "'sensor' must be a non-empty list"),
    (_with(neural_network="RESNET"), "neural_network 'RESNET'"),
    (_with(training_algorithm="dqn"), "training_algorithm 'dqn'"),
    ({"training_algorithm": "sac", "action_space": [{"steering_angle": 0, "speed": 1.0}]},
     "training_algorithm 'sac' needs a continuous action space"),
    ({"training_algorithm": "sac"}, "training_algorithm 'sac' needs a continuous"),  # default actions are discrete
    (_with(lidar_config={"num_sectors": 0}), r"lidar_config\.num_sectors must be a positive number"),
    (_with(lidar_config=[8]), "lidar_config must be an object"),
    (_with(unexpected_key=1), "unknown key 'unexpected_key'"),
])
def test_invalid_metadata_names_the_key(data, named):
    with pytest.raises(MetadataError, match=named) as info:
        metadata_from_dict(data, "models/m1/model_metadata.json")
    assert str(info.value).startswith("models/m1/model_metadata.json: ")


def test_not_an_object():
    with pytest.raises(MetadataError, match="must hold a JSON object, got list"):
        metadata_from_dict([1, 2])


def test_envs_reject_invalid_metadata(tmp_path):
    with pytest.raises(MetadataError, match=r"action_space\[0\]\.speed"):
        TimeTrialEnv(track="oval", model_metadata={"action_space": [{"steering_angle": 0, "speed": 9}]})
    path = tmp_path / "model_metadata.json"
    path.write_text("{not json")
    with pytest.raises(MetadataError, match="not valid JSON"):
        TimeTrialVectorEnv(2, track="oval", model_metadata=str(path))
    path.write_text(json.dumps({"sensor": ["STATE"], "training_algorithm": "sac",
                                "action_space": [{"steering_angle": 0, "speed": 1}]}))
    with pytest.raises(MetadataError, match="training_algorithm"):
        TimeTrialEnv(track="oval", model_metadata=path)


def test_env_action_space_follows_the_file(tmp_path):
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": DISCRETE["action_space"], "sensor": ["STATE"]}))
    env = TimeTrialEnv(track="oval", model_metadata=path)
    assert env.action_space.n == 2
    env.reset()
    assert env.step(1)[4]["params"]["speed"] == 4.0
