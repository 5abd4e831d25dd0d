"""The DeepRacer console's import layout, as deepracer-for-cloud's ``dr-upload-model`` writes it.

``scripts/upload/upload-model.sh`` (deepracer-for-cloud) uploads, under the target prefix::

    model/<N>_Step-<steps>.ckpt.index, .data-00000-of-00001, .meta   rl_coach's TensorFlow checkpoint
    model/checkpoint                  TensorFlow's checkpoint state naming it (the simapp's "old" format)
    model/model_metadata.json
    model/model_<N>.pb                the frozen graph of checkpoint N (what the car and evaluation load)
    model/deepracer_checkpoints.json  best_checkpoint = last_checkpoint = the uploaded checkpoint
    model/.coach_checkpoint           the checkpoint's name (rl_coach's CheckpointStateFile)
    model_metadata.json
    reward_function.py
    ip/hyperparameters.json
    metrics/TrainingMetrics.json
    training_params.yaml              (scripts/upload/prepare-config.py)

laplab writes the same files into a local folder; the checkpoint holds laplab's weights under
rl_coach's variable names (``laplab.export.tensorflow_checkpoint``, docs/car.md).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from laplab.export.car import CONSOLE_SENSORS, PARITY_SAMPLES, PARITY_TOLERANCE, CarExportError, CarGraph, build_car_graph
from laplab.env.spec import uses_stereo_scheme


@dataclass(frozen=True)
class ConsoleExport:
    folder: Path
    files: tuple[str, ...]  # paths relative to ``folder``
    graph: CarGraph
    checkpoint_error: float  # max |restored checkpoint - model.pb| on random inputs
    limitations: tuple[str, ...] = ()  # what DeepRacer's simapp cannot do with the checkpoint (see below)


def simapp_limitations(metadata: dict, stereo_layout: str = "deepracer") -> tuple[str, ...]:
    """Why the simapp (console evaluation, resumed training) could not restore this model's
    checkpoint, though the car and the console's races run its model.pb (docs/car.md);
    ``stereo_layout``: the model's (laplab.json's), see :data:`laplab.env.spec.STEREO_LAYOUTS`."""
    notes = []
    if metadata.get("training_algorithm") == "sac":
        notes.append("SAC: DeepRacer's SAC networks differ from laplab's (a dense 256 layer in the policy "
                     "head, unless the model was imported from DeepRacer; critics without middleware and a V "
                     "network), so the checkpoint holds the policy and no critics; the simapp cannot evaluate or "
                     "resume it from the checkpoint")
    network = metadata.get("neural_network", "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")
    if stereo_layout != "deepracer" and uses_stereo_scheme(network, metadata.get("sensor", [])):
        notes.append(f"STEREO_CAMERAS with {network}: this model was trained by an older laplab with the camera "
                     "conv scheme (laplab.json stereo_layout 'laplab-1'), not DeepRacer's five-layer stereo scheme; "
                     "the simapp cannot restore the checkpoint (a model trained from scratch now has DeepRacer's)")
    return tuple(notes)


def console_checkpoint(graph: CarGraph) -> tuple[dict[str, bytes], float]:
    """rl_coach's TensorFlow checkpoint of ``graph``'s weights ({file name: bytes}, for ``model/``),
    checked by restoring it through its ``checkpoint`` state file and running it against the frozen
    ``model.pb``; refused when they differ by more than the export's tolerance."""
    import tempfile

    from laplab.export.tensorflow_checkpoint import checkpoint_files, random_feed, restore_checkpoint
    from laplab.export.tensorflow_graph import FrozenGraph, output_node_name

    files = checkpoint_files(graph.checkpoint, graph.layers, graph.value_layers).files
    with tempfile.TemporaryDirectory(prefix="laplab-ckpt-check-") as folder:
        for name, data in files.items():
            (Path(folder) / name).write_bytes(data)
        restored = restore_checkpoint(folder, graph.layers, graph.value_layers)
    feed = random_feed(graph.layers, PARITY_SAMPLES, seed=1)
    expected = FrozenGraph(graph.data, output_node_name(graph.layers.algorithm)).run(feed)
    error = float(abs(restored.run(feed) - expected).max())
    restored.session.close()
    if not error <= PARITY_TOLERANCE:
        raise CarExportError(f"the TensorFlow checkpoint of {graph.name!r} differs from its model.pb by {error:.3g} "
                             f"(> {PARITY_TOLERANCE}); nothing was written. Please report this as a bug.")
    return files, error


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
    checkpoint, checkpoint_error = console_checkpoint(graph)
    files: dict[str, bytes] = {f"model/{file}": data for file, data in checkpoint.items()}
    files.update({
        "model/model_metadata.json": metadata.encode(),
        f"model/model_{iteration}.pb": graph.data,
        "model/deepracer_checkpoints.json": (json.dumps({"last_checkpoint": entry, "best_checkpoint": entry},
                                                        indent=2) + "\n").encode(),
        "model/.coach_checkpoint": graph.checkpoint.encode(),  # as rl_coach writes it: no newline
        "model_metadata.json": metadata.encode(),
        "reward_function.py": source.reward_function.read_bytes(),
        "ip/hyperparameters.json": source.hyperparameters.read_bytes(),
        "training_params.yaml": training_params(config, prefix or name).encode(),
    })
    if source.training_metrics.is_file():
        files["metrics/TrainingMetrics.json"] = source.training_metrics.read_bytes()
    for relative, data in files.items():
        atomic_write_bytes(folder / relative, data)
    return ConsoleExport(folder, tuple(files), graph, checkpoint_error, simapp_limitations(graph.metadata, config.stereo_layout))
