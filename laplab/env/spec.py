"""A model's definition in one object: what it observes, how it acts, how it learns.

:class:`ModelSpec` is built in one place, :func:`model_spec`, from a model's ``model_metadata.json``
(:class:`~laplab.env.metadata.ModelMetadata`) and DeepRacer's ``stack_size`` hyperparameter. Training,
evaluation, the stored-model loader, export/import and the ONNX graph all take a ModelSpec, so a
setting one stage forgets (a camera model stacked 3 frames deep evaluated with 1) cannot happen:
the observation space follows from the spec alone.

:func:`observation_space` is pure: it needs no track and no Simulator. Torch-free.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import gymnasium as gym
import numpy as np

from laplab.env.action_space import ActionSpace, default_action_space
from laplab.env.metadata import (CAMERA_SENSORS, LIDAR_SENSORS, MAX_STACK_SIZE, NETWORKS, STATE_SENSOR,
                                 MetadataError, ModelMetadata, camera_sensor, lidar_sensor, validate_sensors)


#: ``stereo_layout`` of a model: ``"deepracer"`` builds deepracer-simapp's own STEREO_CAMERAS embedder
#: for the deeper networks (five 3x3 convolutions, ``laplab.agents.networks.STEREO_CONV_LAYERS``);
#: ``"laplab-1"`` the camera scheme, as laplab built stereo with those networks before laplab.json
#: version 3 (such model folders keep it, so their checkpoints load as they were).
STEREO_LAYOUTS = ("deepracer", "laplab-1")
DEEPER_STEREO_NETWORKS = ("DEEP_CONVOLUTIONAL_NETWORK", "DEEP_CONVOLUTIONAL_NETWORK_DEEP")
STEREO_SCHEME_SUFFIX = "+STEREO_CAMERAS"


def network_layout(network: str, sensors: Sequence[str], stereo_layout: str = "deepracer") -> str:
    """The name of the layers a model of ``network`` with ``sensors`` builds (a key of
    ``laplab.agents.networks.NETWORK_SCHEMES``): ``network``, or ``network + STEREO_SCHEME_SUFFIX`` for
    STEREO_CAMERAS with a deeper network in DeepRacer's ``stereo_layout``."""
    if stereo_layout not in STEREO_LAYOUTS:
        raise MetadataError(f"stereo_layout must be one of {', '.join(STEREO_LAYOUTS)}, got {stereo_layout!r}")
    if "STEREO_CAMERAS" in tuple(sensors) and network in DEEPER_STEREO_NETWORKS and stereo_layout == "deepracer":
        return network + STEREO_SCHEME_SUFFIX
    return network


def uses_stereo_scheme(network: str, sensors: Sequence[str]) -> bool:
    """Whether DeepRacer builds its own stereo embedder for this model (so ``stereo_layout`` matters)."""
    return network_layout(network, sensors) != network


@dataclass(frozen=True)
class ModelSpec:
    """Everything that fixes a model's networks and its observations.

    - ``sensors``: DeepRacer sensor names (model_metadata.json's ``sensor``), in file order.
    - ``stack_size``: camera frames stacked as channels, newest last (DeepRacer's hyperparameter).
    - ``network``: the ``neural_network`` scheme name; ``algorithm``: ``clipped_ppo`` or ``sac``.
    - ``action_space``: discrete list or continuous ranges; ``lidar_config``: DISCRETIZED_SECTOR_LIDAR's.
    - ``version``: model_metadata.json's ``version`` (kept so :attr:`metadata` round-trips).
    - ``objects_summary``: the race type puts objects on the track, so the ``STATE`` vector carries a
      summary of the nearest ones (:func:`laplab.sim.collision.summary_size` more values); time trials
      keep the STATE vector they always had.
    - ``policy_head_layers``: SAC only: relu dense layers of the policy head before its mean and
      log-std layers: () laplab's, (256,) deepracer-simapp's ``SACPolicyHead`` (imported DeepRacer models).
    - ``stereo_layout``: see :data:`STEREO_LAYOUTS`; :attr:`network_layout` is what the learner builds.
    """

    sensors: tuple[str, ...] = (STATE_SENSOR,)
    stack_size: int = 1
    network: str = NETWORKS[0]
    action_space: ActionSpace = field(default_factory=default_action_space)
    algorithm: str = "clipped_ppo"
    lidar_config: dict | None = None
    version: str = "5"
    objects_summary: bool = False
    policy_head_layers: tuple[int, ...] = ()
    stereo_layout: str = "deepracer"

    def __post_init__(self) -> None:
        if isinstance(self.stack_size, bool) or not isinstance(self.stack_size, (int, np.integer)) \
                or not 1 <= self.stack_size <= MAX_STACK_SIZE:
            raise MetadataError(f"stack_size must be an integer from 1 to {MAX_STACK_SIZE}, got {self.stack_size!r}")
        object.__setattr__(self, "stack_size", int(self.stack_size))
        object.__setattr__(self, "sensors", validate_sensors(list(self.sensors), "ModelSpec.sensors"))
        object.__setattr__(self, "policy_head_layers", validate_head_layers(self.policy_head_layers, self.algorithm))
        network_layout(self.network, self.sensors, self.stereo_layout)  # validates stereo_layout

    @property
    def network_layout(self) -> str:
        """The layers the learner builds (:func:`network_layout`)."""
        return network_layout(self.network, self.sensors, self.stereo_layout)

    @property
    def metadata(self) -> ModelMetadata:
        """The model_metadata.json half of the spec."""
        return ModelMetadata(self.action_space, self.sensors, self.network, self.algorithm, self.version,
                             self.lidar_config)

    @property
    def camera(self) -> str | None:
        return camera_sensor(self.sensors)

    @property
    def lidar(self) -> str | None:
        return lidar_sensor(self.sensors)

    @property
    def observation_space(self) -> gym.Space:
        return observation_space(self.metadata, self.stack_size, self.objects_summary)

    @property
    def gym_action_space(self) -> gym.Space:
        return self.action_space.gym_space()


MAX_HEAD_LAYERS, MAX_HEAD_WIDTH = 4, 4096


def validate_head_layers(layers, algorithm: str) -> tuple[int, ...]:
    """``policy_head_layers`` as a tuple of widths; :class:`MetadataError` unless they are up to
    ``MAX_HEAD_LAYERS`` integers in 1..``MAX_HEAD_WIDTH`` of a SAC model."""
    if isinstance(layers, (str, bytes)) or not all(isinstance(size, (int, np.integer)) and not isinstance(size, bool)
                                                   and 1 <= size <= MAX_HEAD_WIDTH for size in layers) \
            or len(layers) > MAX_HEAD_LAYERS:
        raise MetadataError(f"policy_head_layers must be up to {MAX_HEAD_LAYERS} layer widths within "
                            f"1..{MAX_HEAD_WIDTH}, got {layers!r}")
    if layers and algorithm != "sac":
        raise MetadataError(f"policy_head_layers belong to SAC's policy head; a {algorithm} model has none")
    return tuple(int(size) for size in layers)


def model_spec(metadata: ModelMetadata | None = None, stack_size: int = 1, objects_summary: bool = False,
               policy_head_layers: tuple[int, ...] = (), stereo_layout: str = "deepracer") -> ModelSpec:
    """The one constructor of a :class:`ModelSpec` from a model's metadata, its ``stack_size``,
    whether its race type has objects (``objects_summary``), its SAC ``policy_head_layers`` and its
    ``stereo_layout``."""
    metadata = metadata if metadata is not None else ModelMetadata()
    return ModelSpec(sensors=metadata.sensors, stack_size=stack_size, network=metadata.neural_network,
                     action_space=metadata.action_space, algorithm=metadata.training_algorithm,
                     lidar_config=metadata.lidar_config, version=metadata.version,
                     objects_summary=bool(objects_summary), policy_head_layers=tuple(policy_head_layers),
                     stereo_layout=stereo_layout)


def sensor_space(sensor: str, stack_size: int = 1, lidar_config: dict | None = None,
                 objects_summary: bool = False) -> gym.spaces.Box:
    """The observation Box of one sensor.

    ``STATE``: float32 (D,) (see :mod:`laplab.sensors.state_vector`); lidars: float32 (64,), (8,) or
    (sectors x values,); cameras: uint8 (cameras x stack_size, 120, 160), channels first.
    """
    if sensor == STATE_SENSOR:
        from laplab.sensors.state_vector import StateSensorParams
        from laplab.sim.collision import summary_size
        size = StateSensorParams().size + (summary_size() if objects_summary else 0)
        return gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
    if sensor in LIDAR_SENSORS:
        from laplab.sensors.lidar import DEFAULT_LIDAR
        from laplab.sensors.lidar_observation import lidar_observation_shape
        shape = lidar_observation_shape(sensor, lidar_config, DEFAULT_LIDAR.num_beams)
        high = np.inf if sensor == "LIDAR" else 1.0
        return gym.spaces.Box(0.0, high, shape=shape, dtype=np.float32)
    if sensor in CAMERA_SENSORS:
        from laplab.sensors.camera import camera_for_sensor
        cameras = camera_for_sensor(sensor)
        channels = len(cameras) * int(stack_size)
        return gym.spaces.Box(0, 255, shape=(channels, cameras[0].height, cameras[0].width), dtype=np.uint8)
    raise MetadataError(f"unknown sensor {sensor!r}")


def observation_space(metadata: ModelMetadata | ModelSpec, stack_size: int = 1,
                      objects_summary: bool = False) -> gym.Space:
    """The observation space of a model: one sensor gives its Box, several a Dict keyed by sensor
    name (in model_metadata.json's order). Pure: no track, no Simulator. A :class:`ModelSpec`
    brings its own ``stack_size``."""
    if isinstance(metadata, ModelSpec):
        metadata, stack_size, objects_summary = metadata.metadata, metadata.stack_size, metadata.objects_summary
    boxes = {name: sensor_space(name, stack_size, metadata.lidar_config, objects_summary) for name in metadata.sensors}
    return next(iter(boxes.values())) if len(boxes) == 1 else gym.spaces.Dict(boxes)


def sensor_spaces(observation_space: gym.Space, sensors: Sequence[str]) -> dict[str, gym.Space]:
    """Each sensor's space in an observation space as :func:`observation_space` makes it (a ``Box`` for
    one sensor, a ``Dict`` keyed by sensor names), in the order of ``sensors``; ValueError when the
    space does not belong to these sensors."""
    if isinstance(observation_space, gym.spaces.Dict):
        spaces = dict(observation_space.spaces)
        missing = [name for name in spaces if name not in sensors]
        if missing:
            raise ValueError(f"observation keys {missing} are not among the model's sensors {list(sensors)}")
        return {name: spaces[name] for name in sensors if name in spaces}
    if isinstance(observation_space, gym.spaces.Box):
        if len(sensors) != 1:
            raise ValueError(f"a Box observation space belongs to exactly one sensor, got sensors {list(sensors)}")
        return {sensors[0]: observation_space}
    raise ValueError(f"cannot export a network observing a {type(observation_space).__name__} space")
