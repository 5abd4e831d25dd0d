"""A tiny car-side runtime: camera frame (or sensor vector) -> DeepRacer action, from an exported model.

Needs only numpy and onnxruntime (no torch, no other laplab module), so it runs on a car's compute
module. Load the folder written by ``laplab export MODEL --format onnx`` (``model.onnx`` +
``model_metadata.json``)::

    policy = OnnxPolicy("my-model-onnx")
    steering_angle_deg, speed_m_s = policy.act(frame)      # camera models: any size, grey or RGB
    steering_angle_deg, speed_m_s = policy.act_vector(obs)  # STATE / lidar models

Frames are ``(H, W)`` or ``(H, W, 1)`` grey or ``(H, W, 3)`` RGB, uint8 or float grey levels 0-255,
row 0 at the top. They are converted to grey with ITU-R 601 weights (0.299 R + 0.587 G + 0.114 B),
resized to the graph's size (160x120) with an area average (shrinking) or bilinear interpolation
(growing), and rounded to integer grey levels as laplab's camera renders them. Actions are greedy:
the most probable discrete action, or the continuous mean scaled onto the metadata's ranges.
"""

from __future__ import annotations

import json
from collections import deque
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np

CAMERA_SENSORS = ("FRONT_FACING_CAMERA", "STEREO_CAMERAS", "LEFT_CAMERA")
GREY_WEIGHTS = np.array([0.299, 0.587, 0.114], dtype=np.float32)  # ITU-R BT.601 luma
ONNX_FILE, METADATA_FILE = "model.onnx", "model_metadata.json"


class RuntimeModelError(ValueError):
    """An exported model folder, or an input frame / vector, this runtime cannot use."""


class CarAction(NamedTuple):
    """A DeepRacer action: steering angle in degrees (positive = left) and speed in m/s."""

    steering_angle: float
    speed: float


@lru_cache(maxsize=32)
def resize_weights(size_in: int, size_out: int) -> np.ndarray:
    """(size_out, size_in) matrix resampling one image axis: area average when shrinking (each
    output pixel averages the input span it covers, partial pixels weighted by overlap), bilinear
    with pixel centres at i + 0.5 when growing (cv2's INTER_LINEAR), identity when equal."""
    if size_in < 1 or size_out < 1:
        raise RuntimeModelError(f"cannot resize an image axis of {size_in} pixels to {size_out}")
    if size_in == size_out:
        return np.eye(size_out)
    if size_in > size_out:
        ratio = size_in / size_out
        lo = np.arange(size_out)[:, None] * ratio
        pixel = np.arange(size_in)[None, :]
        overlap = np.minimum(pixel + 1.0, lo + ratio) - np.maximum(pixel, lo)
        return np.clip(overlap, 0.0, None) / ratio
    source = np.clip((np.arange(size_out) + 0.5) * (size_in / size_out) - 0.5, 0.0, size_in - 1.0)
    left = np.minimum(np.floor(source).astype(np.int64), size_in - 2)
    fraction = source - left
    weights = np.zeros((size_out, size_in))
    rows = np.arange(size_out)
    weights[rows, left] = 1.0 - fraction
    weights[rows, left + 1] = fraction
    return weights


def to_grey(frame: Any) -> np.ndarray:
    """(H, W) float32 grey levels of a grey (H, W) / (H, W, 1) or RGB (H, W, 3) frame."""
    image = np.asarray(frame)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        red, green, blue = (image[:, :, k].astype(np.float32) for k in range(3))
        return red * GREY_WEIGHTS[0] + green * GREY_WEIGHTS[1] + blue * GREY_WEIGHTS[2]
    if image.ndim != 2 or image.shape[0] < 1 or image.shape[1] < 1:
        raise RuntimeModelError(f"a camera frame must be (H, W) or (H, W, 1) grey or (H, W, 3) RGB, "
                                f"got an array of shape {image.shape}")
    return image.astype(np.float32)


def preprocess_frame(frame: Any, height: int = 120, width: int = 160) -> np.ndarray:
    """A camera frame -> (height, width) float32 integer grey levels 0-255 (see the module docstring)."""
    grey = to_grey(frame)
    if not np.isfinite(grey).all():
        raise RuntimeModelError("the camera frame contains NaN or infinite values")
    if grey.shape != (height, width):  # float32 products: ~1 ms for 640x480 -> 160x120
        rows = resize_weights(grey.shape[0], height).astype(np.float32)
        grey = rows @ grey @ resize_weights(grey.shape[1], width).T.astype(np.float32)
    return np.clip(np.rint(grey), 0.0, 255.0).astype(np.float32)


def _action_table(metadata: Mapping[str, Any], source: str) -> tuple[bool, np.ndarray]:
    """(discrete, table): discrete (A, 2) rows of (steering deg, speed m/s), or continuous
    [[steer_low, steer_high], [speed_low, speed_high]]."""
    space = metadata.get("action_space")
    kind = metadata.get("action_space_type", "discrete" if isinstance(space, list) else "continuous")
    try:
        if kind == "discrete":
            return True, np.array([[float(a["steering_angle"]), float(a["speed"])] for a in space]).reshape(-1, 2)
        if kind == "continuous":
            return False, np.array([[float(space[key]["low"]), float(space[key]["high"])]
                                    for key in ("steering_angle", "speed")])
    except (TypeError, KeyError, ValueError):
        pass
    raise RuntimeModelError(f"{source}: cannot read action_space {space!r:.120} of action_space_type {kind!r}; "
                            "expected a list of {steering_angle, speed} (discrete) or "
                            "{steering_angle: {low, high}, speed: {low, high}} (continuous)")


class OnnxPolicy:
    """An exported policy: ``path`` is the export folder or its ``model.onnx`` (with
    ``model_metadata.json`` beside it, else the copy embedded in the graph).

    ``threads``: onnxruntime intra-op threads (1 suits a car's small CPU). Models that stack frames
    (``stack_size`` > 1) keep the last frames between calls; ``reset()`` forgets them.
    """

    def __init__(self, path: str | Path, threads: int = 1):
        import onnxruntime

        path = Path(path)
        onnx_path = path / ONNX_FILE if path.is_dir() else path
        if not onnx_path.is_file():
            raise RuntimeModelError(f"{onnx_path}: no such file; give the folder written by "
                                    "`laplab export MODEL --format onnx` or its model.onnx")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
        self.metadata, source = self._read_metadata(onnx_path)
        self.discrete, self.actions = _action_table(self.metadata, source)
        self.inputs = {i.name: tuple(int(d) for d in i.shape[1:]) for i in self.session.get_inputs()}
        self.output_name = self.session.get_outputs()[0].name
        self.camera = next((name for name in self.inputs if name in CAMERA_SENSORS), None)
        self.vector_names = tuple(name for name in self.inputs if name != self.camera)
        self.cameras = 2 if self.camera == "STEREO_CAMERAS" else 1
        if self.camera is not None:
            height, width, channels = self.inputs[self.camera]
            self.frame_size, self.stack = (height, width), channels // self.cameras
            self._frames: deque[np.ndarray] = deque(maxlen=self.stack)
            recorded = self.session.get_modelmeta().custom_metadata_map.get("stack_size")
            if recorded is not None and (not recorded.isdigit() or int(recorded) * self.cameras != channels):
                raise RuntimeModelError(f"{onnx_path}: the graph's {self.camera} input has {channels} channels, "
                                        f"but the model was exported with stack_size {recorded} "
                                        f"({self.cameras} camera(s) per frame)")
        width = self.session.get_outputs()[0].shape[-1]
        expected = len(self.actions) if self.discrete else 2
        if isinstance(width, int) and width != expected:
            raise RuntimeModelError(f"{onnx_path}: the graph outputs {width} values but {source} describes "
                                    f"{expected} ({'actions' if self.discrete else 'continuous dimensions'})")

    def _read_metadata(self, onnx_path: Path) -> tuple[dict, str]:
        beside = onnx_path.parent / METADATA_FILE
        if beside.is_file():
            text, source = beside.read_text(encoding="utf-8"), str(beside)
        else:
            text = self.session.get_modelmeta().custom_metadata_map.get("model_metadata")
            source = f"{onnx_path} (embedded model_metadata)"
            if text is None:
                raise RuntimeModelError(f"{beside}: no such file, and {onnx_path} embeds no model_metadata")
        try:
            metadata = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RuntimeModelError(f"{source}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
        if not isinstance(metadata, dict):
            raise RuntimeModelError(f"{source}: must hold a JSON object")
        return metadata, source

    def reset(self) -> None:
        """Forget stacked frames (call at the start of a new run)."""
        if self.camera is not None:
            self._frames.clear()

    def _camera_feed(self, frame: Any) -> np.ndarray:
        """(1, H, W, C): the frame(s) of every camera (stereo: a (left, right) pair), stacked
        oldest first with the newest frame last (a fresh stack repeats the first frame)."""
        frames = list(frame) if self.cameras > 1 else [frame]
        if len(frames) != self.cameras:
            raise RuntimeModelError(f"{self.camera} needs {self.cameras} frames per step (left, right), "
                                    f"got {len(frames)}")
        now = np.stack([preprocess_frame(f, *self.frame_size) for f in frames], axis=-1)
        if not self._frames:
            self._frames.extend([now] * self.stack)
        self._frames.append(now)
        return np.concatenate(list(self._frames), axis=-1)[None]

    def _vector_feed(self, vectors: Any) -> dict[str, np.ndarray]:
        if not self.vector_names:
            if vectors is not None:
                raise RuntimeModelError(f"this model has no vector sensor; its inputs are {list(self.inputs)}")
            return {}
        if not isinstance(vectors, Mapping):
            if len(self.vector_names) != 1:
                raise RuntimeModelError(f"this model takes several vectors {list(self.vector_names)}: pass a dict")
            vectors = {self.vector_names[0]: vectors}
        feed = {}
        for name in self.vector_names:
            if name not in vectors:
                raise RuntimeModelError(f"missing the {name} vector; this model takes {list(self.vector_names)}")
            value = np.asarray(vectors[name], dtype=np.float32)
            if value.shape != self.inputs[name]:
                raise RuntimeModelError(f"{name} must have shape {self.inputs[name]}, got {value.shape}")
            feed[name] = value[None]
        return feed

    def policy_output(self, frame: Any = None, vectors: Any = None) -> np.ndarray:
        """The graph's output for one step: (A,) action probabilities or the (2,) action in [-1, 1]."""
        if self.camera is not None and frame is None:
            raise RuntimeModelError(f"this model drives from its {self.camera}: pass a frame (act(frame))")
        if self.camera is None and frame is not None:
            raise RuntimeModelError(f"this model has no camera (inputs {list(self.inputs)}); use act_vector")
        feed = self._vector_feed(vectors)
        if self.camera is not None:
            feed[self.camera] = self._camera_feed(frame)
        return self.session.run([self.output_name], feed)[0][0]

    def probabilities(self, frame: Any = None, vectors: Any = None) -> np.ndarray:
        """(A,) probabilities of the discrete actions, in model_metadata.json's order."""
        if not self.discrete:
            raise RuntimeModelError("a continuous model has no action probabilities; use policy_output or act")
        return self.policy_output(frame, vectors)

    def to_action(self, output: np.ndarray) -> CarAction:
        """Greedy action from ``policy_output``: argmax (discrete) or the mean scaled onto the ranges."""
        if self.discrete:
            steer, speed = self.actions[int(np.argmax(output))]
            return CarAction(float(steer), float(speed))
        low, high = self.actions[:, 0], self.actions[:, 1]
        steer, speed = low + (np.clip(output, -1.0, 1.0) + 1.0) * 0.5 * (high - low)
        return CarAction(float(steer), float(speed))

    def act(self, frame: Any, vectors: Any = None) -> CarAction:
        """Camera frame (plus lidar vector for camera+lidar models) -> (steering deg, speed m/s)."""
        return self.to_action(self.policy_output(frame, vectors))

    def act_vector(self, vectors: Any) -> CarAction:
        """STATE / lidar observation (an array, or a dict by sensor name) -> (steering deg, speed m/s)."""
        return self.to_action(self.policy_output(None, vectors))
