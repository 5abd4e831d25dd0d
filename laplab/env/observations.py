"""Observations of a batch of cars, from the sensors that model_metadata.json lists.

An :class:`ObservationBuilder` owns the spaces and readers for one sensor set. A single sensor gives
a Box observation; several give a Dict keyed by DeepRacer's sensor names. ``STATE`` is computed by
the simulator's step kernel; lidar and cameras are computed from the cars' poses when observed.
"""

from __future__ import annotations

from typing import Callable

import gymnasium as gym
import numpy as np

from laplab.env.metadata import CAMERA_SENSORS, LIDAR_SENSORS, STATE_SENSOR, ModelMetadata
from laplab.sim.simulator import Simulator

Reader = Callable[[np.ndarray], np.ndarray]  # car indices (K,) -> (K, *shape)


class ObservationBuilder:
    """Builds the observation of the cars of a :class:`Simulator` for the sensors of a model.

    ``seed`` seeds the sensor noise (lidar's Gaussian noise); ``sensor_noise=False`` gives exact
    readings (evaluation of a deterministic policy, tests). ``stack_size`` (DeepRacer's hyperparameter)
    stacks that many consecutive camera frames as channels, newest last.

    Camera observations are ``(C, 120, 160)`` uint8, channels first: C = cameras x stack_size
    (stereo: left, right per frame). ``randomization`` (a
    :class:`laplab.sensors.randomize.RandomizationParams` with ``enabled=True``) applies domain
    randomisation to every camera frame: colour variants of the scene, brightness, contrast, gamma,
    noise, blur and camera-pose jitter, drawn per car and frame from the seeded generator.
    """

    def __init__(self, sim: Simulator, metadata: ModelMetadata, seed: int | None = None, sensor_noise: bool = True,
                 stack_size: int = 1, randomization=None):
        if int(stack_size) < 1:
            raise ValueError(f"stack_size must be >= 1, got {stack_size!r}")
        self.sim = sim
        self.stack_size = int(stack_size)
        self.randomization = randomization if randomization is not None and randomization.enabled else None
        self._camera_rng = np.random.default_rng(seed)
        self.sensors = metadata.sensors
        self.rng = np.random.default_rng(seed) if sensor_noise else None
        self._parts: dict[str, tuple[gym.spaces.Box, Reader]] = {}
        for sensor in self.sensors:
            if sensor == STATE_SENSOR:
                box = gym.spaces.Box(-np.inf, np.inf, shape=(sim.obs.shape[1],), dtype=np.float32)
                self._parts[sensor] = (box, lambda cars: sim.obs[cars])
            elif sensor in LIDAR_SENSORS:
                self._parts[sensor] = self._lidar_part(sensor, metadata.lidar_config)
            elif sensor in CAMERA_SENSORS:
                self._parts[sensor] = self._camera_part(sensor)
        boxes = {name: box for name, (box, _) in self._parts.items()}
        self.single_space: gym.Space = next(iter(boxes.values())) if len(boxes) == 1 else gym.spaces.Dict(boxes)

    def _lidar_part(self, sensor: str, lidar_config: dict | None) -> tuple[gym.spaces.Box, Reader]:
        from laplab.sensors.lidar import DEFAULT_LIDAR, LidarWalls, lidar_observation, lidar_observation_shape, scan
        walls = LidarWalls.from_track(self.sim.track)
        shape = lidar_observation_shape(sensor, lidar_config, DEFAULT_LIDAR.num_beams)
        low, high = (0.0, np.inf) if sensor == "LIDAR" else (0.0, 1.0)
        box = gym.spaces.Box(low, high, shape=shape, dtype=np.float32)
        poses = self.sim.poses

        def read(cars: np.ndarray) -> np.ndarray:
            ranges = scan(walls, poses()[cars], DEFAULT_LIDAR, rng=self.rng, parallel=False)
            return lidar_observation(sensor, ranges, lidar_config).astype(np.float32, copy=False)
        return box, read

    def _camera_part(self, sensor: str) -> tuple[gym.spaces.Box, Reader]:
        from laplab.sensors.camera import camera_for_sensor, render_cameras
        from laplab.sensors.randomize import build_randomized_texture, render_randomized, sample_randomization
        from laplab.sensors.texture import TextureParams, build_track_texture
        cameras = camera_for_sensor(sensor)
        rand, rng = self.randomization, self._camera_rng
        texture = (build_track_texture(self.sim.track) if rand is None
                   else build_randomized_texture(self.sim.track, TextureParams(), rand, rng))

        def render(poses_now: np.ndarray) -> np.ndarray:  # (K, H, W, cameras) uint8
            if rand is None:
                return render_cameras(texture, poses_now, cameras)
            draw = sample_randomization(rng, len(poses_now), rand, cameras[0], texture.num_variants)
            frames = render_randomized(texture, poses_now, cameras, draw, rng)
            return frames if frames.ndim == 4 else frames[..., None]

        height, width, per_frame = cameras[0].height, cameras[0].width, len(cameras)
        channels = per_frame * self.stack_size
        box = gym.spaces.Box(0, 255, shape=(channels, height, width), dtype=np.uint8)
        st, poses = self.sim.state, self.sim.poses
        stack = np.zeros((self.sim.num_cars, channels, height, width), dtype=np.uint8)
        seen = np.full((self.sim.num_cars, 2), -1, dtype=np.int64)  # (episode, steps) of the newest frame

        def read(cars: np.ndarray) -> np.ndarray:
            now = np.stack([st.episode[cars], st.steps[cars]], axis=1)
            fresh = (now != seen[cars]).any(axis=1)
            if fresh.any():
                update = cars[fresh]
                frames = render(poses()[update]).transpose(0, 3, 1, 2)
                new_episode = st.episode[update] != seen[update, 0]
                if self.stack_size > 1:
                    stack[update[~new_episode], :-per_frame] = stack[update[~new_episode], per_frame:]
                    stack[update[new_episode]] = np.tile(frames[new_episode], (1, self.stack_size, 1, 1))
                stack[update, -per_frame:] = frames
                seen[update] = now[fresh]
            return stack[cars]
        return box, read

    def observe(self, cars: np.ndarray | slice = slice(None)):
        """Observations of the selected cars: an array (or a dict of arrays) with a leading car axis.

        Always new arrays (every reader indexes with an integer array), which the caller may keep."""
        if isinstance(cars, slice):
            cars = np.arange(self.sim.num_cars)[cars]
        if len(self._parts) == 1:
            (_, read), = self._parts.values()
            return read(cars)
        return {name: read(cars) for name, (_, read) in self._parts.items()}
