"""Observations of a batch of cars, from the sensors that model_metadata.json lists.

An :class:`ObservationBuilder` owns the spaces and preallocated buffers for one sensor set. A single
sensor gives a Box observation; several give a Dict keyed by DeepRacer's sensor names.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from laplab.env.metadata import STATE_SENSOR, ModelMetadata
from laplab.sim.simulator import Simulator


class ObservationBuilder:
    """Builds the observation of every car of a :class:`Simulator` for the sensors of a model."""

    def __init__(self, sim: Simulator, metadata: ModelMetadata):
        self.sim = sim
        self.sensors = metadata.sensors
        self._parts: dict[str, tuple[gym.spaces.Box, callable]] = {}
        for sensor in self.sensors:
            if sensor == STATE_SENSOR:
                size = sim.obs.shape[1]
                box = gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
                self._parts[sensor] = (box, lambda cars: sim.obs[cars])
            else:
                raise NotImplementedError(
                    f"sensor {sensor!r} is not available in this build of laplab yet; use STATE.")
        boxes = {name: box for name, (box, _) in self._parts.items()}
        self.single_space: gym.Space = (next(iter(boxes.values())) if len(boxes) == 1 else gym.spaces.Dict(boxes))

    def observe(self, cars: np.ndarray | slice = slice(None)):
        """Observations of the selected cars: an array (or a dict of arrays) with a leading car axis."""
        if len(self._parts) == 1:
            (_, read), = self._parts.values()
            return read(cars)
        return {name: read(cars) for name, (_, read) in self._parts.items()}
