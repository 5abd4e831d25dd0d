"""What a DeepRacer network sees of its lidar: simapp's observation filters on the beam ranges.

The ranges come from :func:`laplab.sensors.lidar.scan`; this module turns them into the observation
of each lidar sensor of ``model_metadata.json`` (``LIDAR``, ``SECTOR_LIDAR``,
``DISCRETIZED_SECTOR_LIDAR`` with its ``lidar_config``), as simapp's input filters make it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laplab.sensors.lidar import DEFAULT_LIDAR

LIDAR_SENSORS = ("LIDAR", "SECTOR_LIDAR", "DISCRETIZED_SECTOR_LIDAR")
LIDAR_CLIP = (0.15, 1.0)  # m: simapp's ObservationClippingFilter for LIDAR
SECTOR_LIDAR_SECTORS = 8
SECTOR_LIDAR_CLIPPING_DIST = 0.5  # m


@dataclass(frozen=True)
class LidarConfig:
    """``model_metadata.json``'s ``lidar_config`` for DISCRETIZED_SECTOR_LIDAR."""

    num_sectors: int = 8
    num_values_per_sector: int = 8
    clipping_dist: float = 2.0  # m


def parse_lidar_config(config: dict | LidarConfig | None, num_beams: int = 64) -> LidarConfig:
    """Read a ``lidar_config`` dict (missing keys take DeepRacer's defaults 8, 8, 2.0 m).

    Like simapp's ObservationSectorDiscretizeFilter, counts below 1 become 1 and ``clipping_dist``
    is clamped to [0.15, 12] m. Non-numbers and a sector count that does not divide the beam count
    raise ValueError.
    """
    if isinstance(config, LidarConfig):
        config = {"num_sectors": config.num_sectors, "num_values_per_sector": config.num_values_per_sector,
                  "clipping_dist": config.clipping_dist}
    config = dict(config or {})
    unknown = set(config) - {"num_sectors", "num_values_per_sector", "clipping_dist"}
    if unknown:
        raise ValueError(f"lidar_config: unknown key(s) {sorted(unknown)}; known keys are num_sectors, "
                         "num_values_per_sector and clipping_dist.")
    defaults = LidarConfig()
    values = {}
    for key, kind in (("num_sectors", int), ("num_values_per_sector", int), ("clipping_dist", float)):
        value = config.get(key, getattr(defaults, key))
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or (kind is int and int(value) != value):
            raise ValueError(f"lidar_config: {key} must be {'an integer' if kind is int else 'a number'}, "
                             f"got {value!r}.")
        values[key] = kind(value)
    sectors = max(values["num_sectors"], 1)
    if num_beams % sectors:
        raise ValueError(f"lidar_config: num_sectors={sectors} does not divide the {num_beams} lidar beams; "
                         "DeepRacer needs equal sectors (use 1, 2, 4, 8, 16, 32 or 64).")
    clip = min(max(values["clipping_dist"], LIDAR_CLIP[0]), DEFAULT_LIDAR.max_range)
    return LidarConfig(sectors, max(values["num_values_per_sector"], 1), clip)


def lidar_observation_shape(sensor_name: str, lidar_config: dict | LidarConfig | None = None,
                            num_beams: int = 64) -> tuple[int]:
    """Observation shape of a lidar sensor: (64,), (8,) or (num_sectors * num_values_per_sector,)."""
    if sensor_name == "LIDAR":
        return (num_beams,)
    if sensor_name == "SECTOR_LIDAR":
        return (SECTOR_LIDAR_SECTORS,)
    if sensor_name == "DISCRETIZED_SECTOR_LIDAR":
        config = parse_lidar_config(lidar_config, num_beams)
        return (config.num_sectors * config.num_values_per_sector,)
    raise ValueError(f"unknown lidar sensor {sensor_name!r}; model_metadata 'sensor' lidar names are "
                     f"{', '.join(LIDAR_SENSORS)}")


def lidar_observation(sensor_name: str, ranges: np.ndarray, lidar_config: dict | LidarConfig | None = None
                      ) -> np.ndarray:
    """What the network sees, from ranges (..., num_beams) m; float32, as simapp's input filters make it.

    - LIDAR: ranges clipped to [0.15, 1.0] m, shape (..., num_beams).
    - SECTOR_LIDAR: 8 sectors of consecutive beams (sector 0 starts at the car's right rear); 1.0 where
      the sector's nearest range is < 0.5 m, else 0.0; shape (..., 8).
    - DISCRETIZED_SECTOR_LIDAR: per sector, the nearest range clipped to ``clipping_dist`` falls into
      one of ``num_values_per_sector`` equal bins, one-hot encoded (bin 0 = nearest); a sector with
      nothing nearer than ``clipping_dist`` is all zeros; shape (..., num_sectors * num_values_per_sector).
    """
    ranges = np.asarray(ranges)
    if ranges.ndim == 0 or ranges.shape[-1] == 0:
        raise ValueError(f"lidar_observation: ranges must end in a beam axis (DeepRacer: 64), got shape {ranges.shape}")
    shape = lidar_observation_shape(sensor_name, lidar_config, ranges.shape[-1])
    lead = ranges.shape[:-1]
    if sensor_name == "LIDAR":
        return np.clip(ranges, *LIDAR_CLIP).astype(np.float32)
    if sensor_name == "SECTOR_LIDAR":
        if ranges.shape[-1] % SECTOR_LIDAR_SECTORS:
            raise ValueError(f"lidar_observation: SECTOR_LIDAR splits the beams into 8 sectors, but there are "
                             f"{ranges.shape[-1]} beams (DeepRacer: 64)")
        nearest = ranges.reshape(lead + (SECTOR_LIDAR_SECTORS, -1)).min(axis=-1)
        return (nearest < SECTOR_LIDAR_CLIPPING_DIST).astype(np.float32)
    config = parse_lidar_config(lidar_config, ranges.shape[-1])
    nearest = ranges.astype(np.float64).reshape(lead + (config.num_sectors, -1)).min(axis=-1)
    # Same float64 arithmetic as simapp, so bin edges fall exactly where DeepRacer puts them.
    bins = np.floor(np.minimum(nearest, config.clipping_dist) / (config.clipping_dist / config.num_values_per_sector))
    one_hot = bins[..., None] == np.arange(config.num_values_per_sector)
    return one_hot.reshape(lead + shape).astype(np.float32)
