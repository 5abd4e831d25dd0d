"""Every sensor combination of model_metadata.json builds the right observation spaces, in the single
Env and the VectorEnv; bad combinations fail with a clear error; camera frames stack and randomise."""

import itertools

import gymnasium as gym
import numpy as np
import pytest

from laplab.env import MetadataError, TimeTrialEnv, TimeTrialVectorEnv
from laplab.sensors.randomize import RandomizationParams

CAMERAS = {"FRONT_FACING_CAMERA": 1, "LEFT_CAMERA": 1, "STEREO_CAMERAS": 2}
LIDARS = {"LIDAR": (64,), "SECTOR_LIDAR": (8,), "DISCRETIZED_SECTOR_LIDAR": (16,)}
LIDAR_CONFIG = {"num_sectors": 4, "num_values_per_sector": 4, "clipping_dist": 2.0}


def expected_shapes(sensors, stack=1):
    shapes = {}
    for s in sensors:
        if s in CAMERAS:
            shapes[s] = (CAMERAS[s] * stack, 120, 160)
        elif s in LIDARS:
            shapes[s] = LIDARS[s]
        else:
            shapes[s] = (27,)
    return shapes


COMBINATIONS = ([[c] for c in CAMERAS] + [["STATE"]]
                + [[c, l] for c, l in itertools.product(CAMERAS, LIDARS)]
                + [["STATE", l] for l in LIDARS] + [["FRONT_FACING_CAMERA", "STATE", "LIDAR"]])


@pytest.mark.parametrize("sensors", COMBINATIONS, ids=lambda s: "+".join(s))
def test_every_sensor_combination_builds_its_spaces(sensors):
    meta = {"sensor": sensors, "lidar_config": LIDAR_CONFIG}
    shapes = expected_shapes(sensors)
    single = TimeTrialEnv(track="oval", model_metadata=meta)
    vector = TimeTrialVectorEnv(3, track="oval", model_metadata=meta)
    if len(sensors) == 1:
        assert single.observation_space.shape == shapes[sensors[0]]
        assert vector.single_observation_space.shape == shapes[sensors[0]]
    else:
        assert isinstance(single.observation_space, gym.spaces.Dict)
        assert set(single.observation_space.spaces) == set(sensors)
        assert {k: v.shape for k, v in vector.single_observation_space.spaces.items()} == shapes
    obs, _ = single.reset(seed=0)
    assert single.observation_space.contains(obs)
    obs, *_ = single.step(single.action_space.sample())
    assert single.observation_space.contains(obs)
    batch, _ = vector.reset(seed=0)
    batch, *_ = vector.step(np.full(3, 2))
    assert vector.observation_space.contains(batch)
    for sensor in sensors:
        part = batch[sensor] if isinstance(batch, dict) else batch
        assert part.shape == (3,) + shapes[sensor]
        if sensor in CAMERAS:
            assert part.dtype == np.uint8 and part.std() > 5  # a rendered picture


@pytest.mark.parametrize("sensors,message", [
    (["FRONT_FACING_CAMERA", "STEREO_CAMERAS"], "2 cameras .* exactly one"),
    (["STATE", "LIDAR", "SECTOR_LIDAR"], "2 lidars .* at most one"),
    (["LIDAR"], "camera sensor"),
    (["FRONT_FACING_CAMERA", "RADAR"], "unknown sensor 'RADAR'"),
    ([], "non-empty"),
])
def test_bad_sensor_combinations_fail_clearly(sensors, message):
    with pytest.raises(MetadataError, match=message) as info:
        TimeTrialEnv(model_metadata={"sensor": sensors})
    assert "sensor" in str(info.value)


def test_camera_frames_stack_newest_last_and_restart_with_each_episode():
    env = TimeTrialVectorEnv(2, track="oval", model_metadata={"sensor": ["FRONT_FACING_CAMERA"]}, stack_size=3)
    assert env.single_observation_space.shape == (3, 120, 160)
    obs, _ = env.reset(seed=0)
    assert (obs[:, 0] == obs[:, 1]).all() and (obs[:, 1] == obs[:, 2]).all()  # a new episode: one frame, 3 times
    previous = obs
    for _ in range(3):
        obs, *_ = env.step(np.array([0, 4]))  # full lock: the view changes every step
        np.testing.assert_array_equal(obs[:, :2], previous[:, 1:])  # shifted by one frame
        assert (obs[:, 2] != previous[:, 2]).any()
        previous = obs


def test_domain_randomization_changes_frames_and_is_seeded():
    meta = {"sensor": ["FRONT_FACING_CAMERA"]}
    plain = TimeTrialVectorEnv(4, track="oval", model_metadata=meta)
    rand = [TimeTrialVectorEnv(4, track="oval", model_metadata=meta, seed=7,
                               randomization=RandomizationParams(enabled=True)) for _ in range(2)]
    clean, _ = plain.reset(seed=0)
    first, _ = rand[0].reset(seed=0)
    second, _ = rand[1].reset(seed=0)
    np.testing.assert_array_equal(first, second)
    assert np.abs(first.astype(int) - clean.astype(int)).mean() > 2
