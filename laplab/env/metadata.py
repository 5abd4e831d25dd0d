"""``model_metadata.json``: action space, sensors, network and algorithm of a model."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from laplab.env.action_space import (
    MAX_DISCRETE_ACTIONS, ActionSpace, ActionSpaceError, default_action_space, parse_action_space,
)
from laplab.errors import UserError
from laplab.sensors.lidar_observation import LIDAR_SENSORS
from laplab.vehicle.physics import DEFAULT_VERSION, PhysicsError, car_for_version

CAMERA_SENSORS = ("FRONT_FACING_CAMERA", "STEREO_CAMERAS", "LEFT_CAMERA")
STATE_SENSOR = "STATE"  # laplab's own vector sensor (see laplab.sensors.state_vector)
ALL_SENSORS = CAMERA_SENSORS + LIDAR_SENSORS + (STATE_SENSOR,)
#: The sensor sets a model may have, as the console offers them: STATE, or a camera, or a camera with a lidar
#: (DeepRacer's "camera" / "stereo camera" + "LiDAR" choices; validate_sensors accepts exactly these and
#: STATE with a lidar).
SENSOR_CHOICES = ((STATE_SENSOR,),) + tuple((camera,) for camera in CAMERA_SENSORS) + tuple(
    (camera, lidar) for camera in ("FRONT_FACING_CAMERA", "STEREO_CAMERAS") for lidar in LIDAR_SENSORS)
NETWORKS = ("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "DEEP_CONVOLUTIONAL_NETWORK", "DEEP_CONVOLUTIONAL_NETWORK_DEEP")
ALGORITHMS = ("clipped_ppo", "sac")
#: The most camera frames one observation may stack (DeepRacer trains with 1; the memory of every
#: observation and of a replay buffer grows with it).
MAX_STACK_SIZE = 8
MAX_METADATA_BYTES = 256 << 10  # a model_metadata.json of 64 actions and every sensor is ~5 KiB


class MetadataError(UserError, ValueError):
    """A model_metadata.json that DeepRacer (or laplab) would not accept."""

    default_field = "model_metadata"


@dataclass(frozen=True)
class ModelMetadata:
    """A parsed model_metadata.json. laplab's default sensor is ``STATE`` (trains in seconds);
    DeepRacer's is ``FRONT_FACING_CAMERA``."""

    action_space: ActionSpace = field(default_factory=default_action_space)
    sensors: tuple[str, ...] = (STATE_SENSOR,)
    neural_network: str = NETWORKS[0]
    training_algorithm: str = "clipped_ppo"
    version: str = DEFAULT_VERSION  # DeepRacer's physics generation (laplab.vehicle.physics)
    lidar_config: dict | None = None

    @property
    def camera(self) -> str | None:
        return camera_sensor(self.sensors)

    @property
    def lidar(self) -> str | None:
        return lidar_sensor(self.sensors)

    def to_dict(self) -> dict:
        out = {"action_space": self.action_space.to_json(), "sensor": list(self.sensors),
               "neural_network": self.neural_network, "training_algorithm": self.training_algorithm,
               "action_space_type": self.action_space.kind, "version": self.version}
        if self.lidar_config is not None:
            out["lidar_config"] = dict(self.lidar_config)
        return out


def camera_sensor(sensors: tuple[str, ...]) -> str | None:
    """The model's camera sensor name, or None."""
    return next((s for s in sensors if s in CAMERA_SENSORS), None)


def lidar_sensor(sensors: tuple[str, ...]) -> str | None:
    """The model's lidar sensor name, or None."""
    return next((s for s in sensors if s in LIDAR_SENSORS), None)


def validate_sensors(sensors: object, source: str) -> tuple[str, ...]:
    """Exactly one camera or the STATE sensor, at most one lidar, no unknown or repeated names."""
    if isinstance(sensors, str):
        sensors = [sensors]
    if not isinstance(sensors, list) or not sensors or not all(isinstance(s, str) for s in sensors):
        raise MetadataError(f"{source}: 'sensor' must be a non-empty list of sensor names, got {sensors!r}.")
    unknown = [s for s in sensors if s not in ALL_SENSORS]
    if unknown:
        raise MetadataError(f"{source}: unknown sensor {unknown[0]!r} in 'sensor'; known: {', '.join(ALL_SENSORS)}.")
    if len(set(sensors)) != len(sensors):
        raise MetadataError(f"{source}: 'sensor' lists a sensor twice: {sensors}.")
    cameras = [s for s in sensors if s in CAMERA_SENSORS]
    lidars = [s for s in sensors if s in LIDAR_SENSORS]
    if len(cameras) > 1:
        raise MetadataError(f"{source}: 'sensor' lists {len(cameras)} cameras {cameras}; a model has exactly one.")
    if len(lidars) > 1:
        raise MetadataError(f"{source}: 'sensor' lists {len(lidars)} lidars {lidars}; a model has at most one.")
    if not cameras and STATE_SENSOR not in sensors:
        raise MetadataError(f"{source}: a model needs one camera sensor ({', '.join(CAMERA_SENSORS)}) "
                            f"or laplab's STATE sensor; 'sensor' lists only {sensors}.")
    return tuple(sensors)


def metadata_from_dict(data: object, source: str = "model_metadata.json") -> ModelMetadata:
    """Validate a model_metadata.json object; errors name the file and the key."""
    if not isinstance(data, dict):
        raise MetadataError(f"{source}: must hold a JSON object, got {type(data).__name__}.")
    known = {"action_space", "sensor", "neural_network", "training_algorithm", "action_space_type",
             "version", "lidar_config", "preprocess_type", "regional_parameters"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise MetadataError(f"{source}: unknown key {unknown[0]!r}; known keys: {', '.join(sorted(known))}.")
    try:
        action_space = (parse_action_space(data["action_space"], data.get("action_space_type"), source)
                        if "action_space" in data else default_action_space())
    except ActionSpaceError as exc:
        raise MetadataError(str(exc)) from None
    sensors = validate_sensors(data.get("sensor", [STATE_SENSOR]), source)
    network = data.get("neural_network", NETWORKS[0])
    if network not in NETWORKS:
        raise MetadataError(f"{source}: neural_network {network!r} is not one of {', '.join(NETWORKS)}.")
    algorithm = data.get("training_algorithm", "clipped_ppo")
    if algorithm not in ALGORITHMS:
        raise MetadataError(f"{source}: training_algorithm {algorithm!r} is not one of {', '.join(ALGORITHMS)}.")
    if algorithm == "sac" and action_space.is_discrete:
        raise MetadataError(f"{source}: training_algorithm 'sac' needs a continuous action space "
                            "(action_space_type 'continuous').")
    lidar_config = data.get("lidar_config")
    if lidar_config is not None:
        if not isinstance(lidar_config, dict):
            raise MetadataError(f"{source}: lidar_config must be an object, got {lidar_config!r}.")
        for key in ("num_sectors", "num_values_per_sector", "clipping_dist"):
            if key in lidar_config and not (isinstance(lidar_config[key], (int, float)) and lidar_config[key] > 0):
                raise MetadataError(f"{source}: lidar_config.{key} must be a positive number, got {lidar_config[key]!r}.")
    version = str(data.get("version", DEFAULT_VERSION))
    try:
        car_for_version(version)
    except PhysicsError as error:
        raise MetadataError(f"{source}: {error}.") from None
    return ModelMetadata(action_space, sensors, network, algorithm, version, lidar_config)


def load_model_metadata(path: str | Path) -> ModelMetadata:
    """Read and validate a model_metadata.json file."""
    path = Path(path)
    if not path.is_file():
        raise MetadataError(f"{path}: no such file.")
    size = path.stat().st_size
    if size > MAX_METADATA_BYTES:
        raise MetadataError(f"{path}: the file is {size / 2**20:.1f} MiB; a model_metadata.json is at most "
                            f"{MAX_METADATA_BYTES // 2**10} KiB ({MAX_DISCRETE_ACTIONS} actions and the sensors "
                            "take a few KiB). Is it the right file?")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise MetadataError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}.") from None
    except UnicodeDecodeError as exc:
        raise MetadataError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start}).") from None
    if isinstance(data, dict) and "action_space" not in data:
        # The default grid applies only when no file is given: a file without one is a mistake.
        raise MetadataError(f"{path}: has no 'action_space'. A model_metadata.json names the actions the car "
                            "may take, e.g. \"action_space\": [{\"steering_angle\": 0, \"speed\": 1.0}, ...] (or a "
                            "continuous range with \"action_space_type\": \"continuous\"); leave out "
                            "--model-metadata to train laplab's default grid.")
    return metadata_from_dict(data, str(path))
