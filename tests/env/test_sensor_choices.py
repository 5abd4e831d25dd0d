"""The sensor sets the console offers are exactly the ones a model may have."""

from __future__ import annotations

import itertools

import pytest

from laplab.env.metadata import ALL_SENSORS, SENSOR_CHOICES, MetadataError, validate_sensors


def test_every_offered_sensor_set_validates_and_camera_with_lidar_is_offered():
    for choice in SENSOR_CHOICES:
        assert validate_sensors(list(choice), "test") == choice
    assert ("FRONT_FACING_CAMERA", "LIDAR") in SENSOR_CHOICES and ("STEREO_CAMERAS", "SECTOR_LIDAR") in SENSOR_CHOICES


def test_no_valid_camera_set_is_left_out():
    for size in (1, 2):
        for sensors in itertools.permutations(ALL_SENSORS, size):
            try:
                validate_sensors(list(sensors), "test")
            except MetadataError:
                assert sensors not in SENSOR_CHOICES
                continue
            # LEFT_CAMERA is DeepRacer's older name of the front camera: offered alone, not with a lidar
            if "STATE" not in sensors and "LEFT_CAMERA" not in sensors:
                assert sensors in SENSOR_CHOICES or sensors[::-1] in SENSOR_CHOICES, sensors


def test_a_lidar_alone_is_not_a_model():
    with pytest.raises(MetadataError, match="needs one camera"):
        validate_sensors(["LIDAR"], "test")
