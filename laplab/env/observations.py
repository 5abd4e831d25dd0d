"""Observations of a batch of cars, from the sensors that model_metadata.json lists.

An :class:`ObservationBuilder` owns the spaces and readers for one sensor set. A single sensor gives
a Box observation; several give a Dict keyed by DeepRacer's sensor names. ``STATE`` is computed by
the simulator's step kernel; lidar and cameras are computed from the cars' poses when observed, and
see each car's obstacles (boxes, bot cars, other models' cars) when the simulator has them
(:func:`obstacle_rows`).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

import gymnasium as gym
import numpy as np

from laplab.env.metadata import CAMERA_SENSORS, LIDAR_SENSORS, STATE_SENSOR
from laplab.env.spec import ModelSpec
from laplab.sim.simulator import Simulator

Reader = Callable[[np.ndarray], np.ndarray]  # car indices (K,) -> (K, *shape)


def obstacle_rows(sim, cars: np.ndarray):
    """The obstacles the sensors of ``cars`` see: the rows of ``sim.obstacles`` (an attribute or a method
    giving a ``laplab.sim.obstacles.Obstacles`` of (N, K) arrays, or None in a time trial) for those
    cars, as a tuple of seven (len(cars), K) arrays; None when the simulator has none (or K = 0)."""
    obstacles = getattr(sim, "obstacles", None)
    if callable(obstacles):
        obstacles = obstacles()
    if obstacles is None or np.shape(obstacles[6])[-1] == 0:  # a time trial: K = 0 slots
        return None
    return tuple(np.asarray(field)[cars] for field in obstacles)


def take_rows(observations: Any, index: np.ndarray | slice) -> Any:
    """Some rows of a batch of observations (an array or tensor, or a dict sensor -> one)."""
    if isinstance(observations, Mapping):
        return {key: value[index] for key, value in observations.items()}
    return observations[index]


class ObservationBuilder:
    """Builds the observation of the cars of a :class:`Simulator` for the sensors of a model.

    ``spec`` (a :class:`~laplab.env.spec.ModelSpec`) gives the sensors and the ``stack_size`` (that many
    consecutive camera frames stacked as channels, newest last); the spaces are the spec's own
    (:func:`laplab.env.spec.observation_space`). ``seed`` seeds the sensor noise (lidar's Gaussian
    noise); ``sensor_noise=False`` gives exact readings (evaluation of a deterministic policy, tests).

    Camera observations are ``(C, 120, 160)`` uint8, channels first: C = cameras x stack_size
    (stereo: left, right per frame). ``randomization`` (a
    :class:`laplab.sensors.randomize.RandomizationParams` with ``enabled=True``) applies domain
    randomisation to every camera frame: colour variants of the scene, brightness, contrast, gamma,
    noise, blur and camera-pose jitter, drawn per car and frame from the seeded generator.
    """

    def __init__(self, sim: Simulator, spec: ModelSpec, seed: int | None = None, sensor_noise: bool = True,
                 randomization=None):
        if not isinstance(spec, ModelSpec):
            raise TypeError(f"ObservationBuilder takes a ModelSpec (laplab.env.spec.model_spec(metadata, "
                            f"stack_size)), got {type(spec).__name__}")
        self.sim = sim
        self.spec = spec
        self.stack_size = spec.stack_size
        self.randomization = randomization if randomization is not None and randomization.enabled else None
        self._camera_rng = np.random.default_rng(seed)
        self.sensors = spec.sensors
        self.rng = np.random.default_rng(seed) if sensor_noise else None
        self.single_space: gym.Space = spec.observation_space
        spaces = self.single_space.spaces if isinstance(self.single_space, gym.spaces.Dict) else None
        self._parts: dict[str, tuple[gym.spaces.Box, Reader]] = {}
        for sensor in self.sensors:
            box = spaces[sensor] if spaces is not None else self.single_space
            if sensor == STATE_SENSOR:
                size = box.shape[0]
                if sim.obs.shape[1] != size and not (sim.obs.shape[1] > size and not spec.objects_summary):
                    raise ValueError(f"the simulator's STATE vector has {sim.obs.shape[1]} values, the model's "
                                     f"observation space {size}")
                # a model trained without objects (a time trial) drives among them without their summary
                # np.take: a fraction of the time of fancy indexing for a whole batch
                self._parts[sensor] = (box, (lambda cars: sim.obs.take(cars, axis=0)) if sim.obs.shape[1] == size
                                       else (lambda cars: sim.obs[:, :size].take(cars, axis=0)))
            elif sensor in LIDAR_SENSORS:
                self._parts[sensor] = (box, self._lidar_reader(sensor, spec.lidar_config))
            elif sensor in CAMERA_SENSORS:
                self._parts[sensor] = (box, self._camera_reader(sensor, box))

    def _lidar_reader(self, sensor: str, lidar_config: dict | None) -> Reader:
        from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, scan
        from laplab.sensors.lidar_observation import lidar_observation
        walls = LidarWalls.from_track(self.sim.track)
        poses = self.sim.poses

        def read(cars: np.ndarray) -> np.ndarray:
            ranges = scan(walls, poses()[cars], DEFAULT_LIDAR, rng=self.rng, parallel=False,
                          obstacles=obstacle_rows(self.sim, cars))
            return lidar_observation(sensor, ranges, lidar_config).astype(np.float32, copy=False)
        return read

    def _camera_reader(self, sensor: str, box: gym.spaces.Box) -> Reader:
        from laplab.sensors.camera import camera_for_sensor, render_cameras
        from laplab.sensors.randomize import build_randomized_texture, render_randomized, sample_randomization
        from laplab.sensors.look import announced_look, texture_for_track
        cameras = camera_for_sensor(sensor)
        rand, rng = self.randomization, self._camera_rng
        texture = (texture_for_track(self.sim.track) if rand is None
                   else build_randomized_texture(self.sim.track, announced_look(self.sim.track).params, rand, rng))

        def render(cars: np.ndarray) -> np.ndarray:  # (K, H, W, cameras) uint8
            poses_now, obstacles = poses()[cars], obstacle_rows(self.sim, cars)
            if rand is None:
                return render_cameras(texture, poses_now, cameras, obstacles=obstacles)
            draw = sample_randomization(rng, len(poses_now), rand, cameras[0], texture.num_variants)
            frames = render_randomized(texture, poses_now, cameras, draw, rng, obstacles=obstacles)
            return frames if frames.ndim == 4 else frames[..., None]

        per_frame = len(cameras)
        channels, height, width = box.shape
        st, poses = self.sim.state, self.sim.poses
        stack = np.zeros((self.sim.num_cars, channels, height, width), dtype=np.uint8)
        seen = np.full((self.sim.num_cars, 2), -1, dtype=np.int64)  # (episode, steps) of the newest frame

        def read(cars: np.ndarray) -> np.ndarray:
            now = np.stack([st.episode[cars], st.steps[cars]], axis=1)
            fresh = (now != seen[cars]).any(axis=1)
            if fresh.any():
                update = cars[fresh]
                frames = render(update).transpose(0, 3, 1, 2)
                new_episode = st.episode[update] != seen[update, 0]
                if self.stack_size > 1:
                    stack[update[~new_episode], :-per_frame] = stack[update[~new_episode], per_frame:]
                    stack[update[new_episode]] = np.tile(frames[new_episode], (1, self.stack_size, 1, 1))
                stack[update, -per_frame:] = frames
                seen[update] = now[fresh]
            return stack[cars]
        return read

    def observe(self, cars: np.ndarray | slice = slice(None)):
        """Observations of the selected cars: an array (or a dict of arrays) with a leading car axis.

        Always new arrays (every reader indexes with an integer array), which the caller may keep."""
        if isinstance(cars, slice):
            cars = np.arange(self.sim.num_cars)[cars]
        if len(self._parts) == 1:
            (_, read), = self._parts.values()
            return read(cars)
        return {name: read(cars) for name, (_, read) in self._parts.items()}
