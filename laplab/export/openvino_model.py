"""``model.pb`` through Intel's OpenVINO, as the car runs it: converted with the input names and shapes
the car's model optimizer passes, then run in OpenVINO's runtime on the CPU.

The car (aws-deepracer-model-optimizer-pkg) calls ``mo_tf.py --input_model model.pb --input
<names> --input_shape [1,120,160,1],...  --data_type FP16``; here ``openvino.convert_model`` (OVC)
does the same conversion in-process, with the same input nodes and shapes. OVC names a TensorFlow
input by its tensor (``NAME:0``) where the 2021 model optimizer took the node name ``NAME``; the
tensor name is passed first, the node name if OVC does not know the former. Precision stays FP32 unless
``fp16=True`` (the car's ``--data_type FP16`` compresses the weights to half precision).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np


@dataclass(frozen=True)
class OptimizerInput:
    """One ``--input`` / ``--input_shape`` pair of the car's model optimizer."""

    name: str
    shape: tuple[int, ...]


def car_optimizer_inputs(sensors: Sequence[str], algorithm: str, lidar_values: int | None = None,
                         height: int = 120, width: int = 160) -> tuple[OptimizerInput, ...]:
    """The inputs the car's model optimizer passes for model_metadata.json's ``sensors``: cameras
    ``[1, height, width, channels]`` (channels 1, stereo 2), lidars ``[1, num_sectors]`` (``lidar_values``;
    the car's defaults are 64 for LIDAR and 8 for SECTOR_LIDAR)."""
    from laplab.export.tensorflow_graph import input_node_name

    inputs = []
    for sensor in sensors:
        if sensor in ("LIDAR", "SECTOR_LIDAR"):
            count = lidar_values if lidar_values is not None else (64 if sensor == "LIDAR" else 8)
            inputs.append(OptimizerInput(input_node_name(sensor, algorithm), (1, count)))
        else:
            channels = 2 if sensor == "STEREO_CAMERAS" else 1
            inputs.append(OptimizerInput(input_node_name(sensor, algorithm), (1, height, width, channels)))
    return tuple(inputs)


class OpenVinoPolicy:
    """``model.pb`` converted by OpenVINO and compiled for the CPU. ``run({input_node: (1, ...)})``
    returns the first output (the car reads ``getOutputsInfo().begin()``) as a (1, n) array."""

    def __init__(self, pb_path: str | Path, inputs: Sequence[OptimizerInput], fp16: bool = False, threads: int = 1):
        try:
            import openvino as ov
        except ImportError:
            raise ImportError("OpenVINO is not installed: pip install 'laplab[deepracer]'") from None
        self.model = self._convert(ov, str(pb_path), inputs)
        if fp16:  # as the car's --data_type FP16: weights stored in half precision
            from openvino import save_model
            import tempfile
            with tempfile.TemporaryDirectory() as folder:
                save_model(self.model, f"{folder}/model.xml", compress_to_fp16=True)
                self.model = ov.Core().read_model(f"{folder}/model.xml")
        core = ov.Core()
        self.compiled = core.compile_model(self.model, "CPU", {"INFERENCE_NUM_THREADS": threads,
                                                               "INFERENCE_PRECISION_HINT": "f32"})
        self.request = self.compiled.create_infer_request()
        self.input_names = {spec.name: self._port_name(spec.name) for spec in inputs}

    @staticmethod
    def _convert(ov, path: str, inputs: Sequence[OptimizerInput]):
        # OVC names a TensorFlow input by its tensor (NODE:0); the 2021 optimizer took the node name
        try:
            return ov.convert_model(path, input=[(f"{spec.name}:0", list(spec.shape)) for spec in inputs])
        except Exception as exc:
            if "not found among model inputs" not in str(exc):
                raise
            return ov.convert_model(path, input=[(spec.name, list(spec.shape)) for spec in inputs])

    def _port_name(self, name: str) -> str:
        for port in self.compiled.inputs:
            names = port.get_names()
            if name in names or f"{name}:0" in names:
                return next(iter(n for n in (name, f"{name}:0") if n in names))
        raise KeyError(f"OpenVINO model has no input {name!r}")

    @property
    def output_names(self) -> set[str]:
        return set(self.compiled.outputs[0].get_names())

    def run(self, feed: Mapping[str, np.ndarray]) -> np.ndarray:
        result = self.request.infer({self.input_names[name]: np.ascontiguousarray(value, dtype=np.float32)
                                     for name, value in feed.items()})
        return np.array(result[self.compiled.outputs[0]])

    def run_batch(self, feed: Mapping[str, np.ndarray]) -> np.ndarray:
        """Row by row (the car's batch is 1): (B, ...) arrays -> (B, n)."""
        rows = next(iter(feed.values())).shape[0]
        return np.concatenate([self.run({k: v[i:i + 1] for k, v in feed.items()}) for i in range(rows)])
