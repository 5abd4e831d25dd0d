"""The DeepRacer console's import layout, as deepracer-for-cloud's ``dr-upload-model`` writes it.

``scripts/upload/upload-model.sh`` (deepracer-for-cloud) uploads, under the target prefix::

    model/model_metadata.json
    model/model_<N>.pb                the frozen graph of checkpoint N (what the car and evaluation load)
    model/deepracer_checkpoints.json  best_checkpoint = last_checkpoint = the uploaded checkpoint
    model/.coach_checkpoint           the checkpoint's name
    model_metadata.json
    reward_function.py
    ip/hyperparameters.json
    metrics/TrainingMetrics.json
    training_params.yaml              (scripts/upload/prepare-config.py)

laplab writes the same files into a local folder. It does not write rl_coach's TensorFlow
checkpoint (``<N>_Step-<steps>.ckpt.index/.data/.meta``): laplab's weights are torch tensors in
its own network layout, see docs/car.md.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from laplab.export.car import CONSOLE_SENSORS, CarExportError, CarGraph, build_car_graph


@dataclass(frozen=True)
class ConsoleExport:
    folder: Path
    files: tuple[str, ...]  # paths relative to ``folder``
    graph: CarGraph


def training_params(config, prefix: str, bucket: str = "bucket") -> str:
    """``training_params.yaml`` as deepracer-for-cloud's prepare-config.py writes it (quoted YAML)."""
    track = Path(str(config.track)).stem if str(config.track).endswith(".npy") else str(config.track)
    values = {
        "AWS_REGION": "us-east-1", "JOB_TYPE": "TRAINING", "METRICS_S3_BUCKET": bucket,
        "METRICS_S3_OBJECT_KEY": f"{prefix}/TrainingMetrics.json",
        "MODEL_METADATA_FILE_S3_KEY": f"{prefix}/model/model_metadata.json",
        "REWARD_FILE_S3_KEY": f"{prefix}/reward_function.py", "SAGEMAKER_SHARED_S3_BUCKET": bucket,
        "SAGEMAKER_SHARED_S3_PREFIX": prefix, "BODY_SHELL_TYPE": "deepracer", "CAR_COLOR": "Red",
        "CAR_NAME": prefix, "RACE_TYPE": "TIME_TRIAL", "WORLD_NAME": track, "DISPLAY_NAME": prefix,
        "RACER_NAME": prefix,
        "ALTERNATE_DRIVING_DIRECTION": str(bool(getattr(config, "alternate_direction", False))).lower(),
        "CHANGE_START_POSITION": "true", "ROUND_ROBIN_ADVANCE_DIST": "0.05", "START_POSITION_OFFSET": "0.00",
        "ENABLE_DOMAIN_RANDOMIZATION": "false", "MIN_EVAL_TRIALS": "5",
    }
    quoted = (f"'{key}': '{str(value).replace(chr(39), chr(39) * 2)}'" for key, value in sorted(values.items()))
    return "---\n" + "\n".join(quoted) + "\n"


def export_console(name: str, checkpoint: str = "best", out: str | Path | None = None,
                   prefix: str | None = None) -> ConsoleExport:
    """``laplab export NAME --format console``: the import layout in folder ``out`` (default
    ``./NAME-console``), which must not exist or be empty. ``prefix`` names the model in
    training_params.yaml (default: the model's name)."""
    from laplab.store.atomic import atomic_write_bytes
    from laplab.store.checkpoints import CHECKPOINT_NAME_PATTERN, CheckpointStore
    from laplab.store.layout import model_folder
    from laplab.train.config import TrainConfig

    folder = Path(out) if out is not None else Path.cwd() / f"{name}-console"
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise CarExportError(f"{folder}: exists and is not an empty folder; give another --out.")
    graph = build_car_graph(name, checkpoint, CONSOLE_SENSORS, "the DeepRacer console")
    source = model_folder(name)
    config = TrainConfig.from_dict(source.read_laplab_config(), str(source.laplab_config))
    iteration = int(CHECKPOINT_NAME_PATTERN.fullmatch(graph.checkpoint).group(1))
    store = CheckpointStore(source)
    record = next((r for r in (store.best(), store.last()) if r is not None and r.name == graph.checkpoint), None)
    entry = {"name": graph.checkpoint, "time_stamp": time.time() if record is None else record.time_stamp,
             "avg_eval_metric": None if record is None else record.avg_eval_metric}
    metadata = json.dumps(graph.metadata, indent=2) + "\n"
    files: dict[str, bytes] = {
        "model/model_metadata.json": metadata.encode(),
        f"model/model_{iteration}.pb": graph.data,
        "model/deepracer_checkpoints.json": (json.dumps({"last_checkpoint": entry, "best_checkpoint": entry},
                                                        indent=2) + "\n").encode(),
        "model/.coach_checkpoint": (graph.checkpoint + "\n").encode(),
        "model_metadata.json": metadata.encode(),
        "reward_function.py": source.reward_function.read_bytes(),
        "ip/hyperparameters.json": source.hyperparameters.read_bytes(),
        "training_params.yaml": training_params(config, prefix or name).encode(),
    }
    if source.training_metrics.is_file():
        files["metrics/TrainingMetrics.json"] = source.training_metrics.read_bytes()
    for relative, data in files.items():
        atomic_write_bytes(folder / relative, data)
    return ConsoleExport(folder, tuple(files), graph)
