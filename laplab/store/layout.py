"""Model folders in the deepracer-for-cloud single-worker layout (read by deepracer-utils).

    <models root>/<model name>/
        model/model_metadata.json          action space, sensors, network, algorithm
        model/<iteration>_Step-<steps>.ckpt  checkpoints (see checkpoints.py)
        model/deepracer_checkpoints.json   best and last checkpoint
        ip/hyperparameters.json            DeepRacer hyperparameters
        reward_function.py                 the user's reward function source
        laplab.json                        laplab's full training configuration
        error.txt                          why training died (a RewardFunctionError message)
        .laplab-job.lock                   the running job's lock (see lock.py)
        training-simtrace/<iteration>-iteration.csv     iterations count from 0
        <worker>/training-simtrace/<iteration>-iteration.csv   instead, when several rollout
                                           workers trained it (DRfC's multi-worker layout, 0-based)
        metrics/TrainingMetrics.json
        evaluation-<YYYYMMDDhhmmss>/evaluation-simtrace/0-iteration.csv
        metrics/evaluation/evaluation-<YYYYMMDDhhmmss>.json

The models root is `$LAPLAB_HOME/models` (default `~/.laplab/models`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from laplab.errors import UserError
from laplab.settings import current_settings
from laplab.store.atomic import atomic_write_json, atomic_write_text, read_json

MODEL_NAME_PATTERN = re.compile(r"[A-Za-z0-9-]{1,64}")
EVALUATION_STAMP_FORMAT = "%Y%m%d%H%M%S"
_EVALUATION_STAMP_PATTERN = re.compile(r"[0-9]{14}")
_ITERATION_FILE_PATTERN = re.compile(r"([0-9]+)-iteration\.csv")


class ModelNameError(UserError, ValueError):
    """A model name DeepRacer would refuse."""

    default_field = "name"


def validate_model_name(name: str) -> str:
    """Return `name` unchanged if DeepRacer accepts it (letters, digits, hyphens; 1-64 chars)."""
    if not isinstance(name, str) or MODEL_NAME_PATTERN.fullmatch(name) is None:
        raise ModelNameError(
            f"invalid model name {name!r}: DeepRacer model names are 1 to 64 characters, "
            "each an ASCII letter, a digit or a hyphen (no spaces, underscores or dots), "
            "for example 'my-model-2'"
        )
    return name


def evaluation_stamp(when: datetime | None = None) -> str:
    """The `YYYYMMDDhhmmss` stamp (UTC) naming an evaluation; `when` defaults to now."""
    moment = datetime.now(timezone.utc) if when is None else when.astimezone(timezone.utc)
    return moment.strftime(EVALUATION_STAMP_FORMAT)


def _check_stamp(stamp: str) -> str:
    if not isinstance(stamp, str) or _EVALUATION_STAMP_PATTERN.fullmatch(stamp) is None:
        raise ValueError(
            f"invalid evaluation stamp {stamp!r}: expected 14 digits YYYYMMDDhhmmss, "
            "as made by evaluation_stamp()"
        )
    return stamp


@dataclass(frozen=True)
class ModelFolder:
    """Paths of one model folder; creates nothing until asked (`create`, the write methods)."""

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root).expanduser())

    @property
    def name(self) -> str:
        return self.root.name

    @property
    def model_dir(self) -> Path:
        return self.root / "model"

    @property
    def model_metadata(self) -> Path:
        return self.model_dir / "model_metadata.json"

    @property
    def deepracer_checkpoints(self) -> Path:
        return self.model_dir / "deepracer_checkpoints.json"

    @property
    def hyperparameters(self) -> Path:
        return self.root / "ip" / "hyperparameters.json"

    @property
    def reward_function(self) -> Path:
        return self.root / "reward_function.py"

    @property
    def laplab_config(self) -> Path:
        return self.root / "laplab.json"

    @property
    def error_file(self) -> Path:
        return self.root / "error.txt"

    @property
    def training_simtrace_dir(self) -> Path:
        return self.root / "training-simtrace"

    @property
    def metrics_dir(self) -> Path:
        return self.root / "metrics"

    @property
    def training_metrics(self) -> Path:
        return self.metrics_dir / "TrainingMetrics.json"

    def training_simtrace(self, iteration: int) -> Path:
        """Simtrace CSV of training iteration `iteration` (0-based, as deepracer-utils needs)."""
        if isinstance(iteration, bool) or not isinstance(iteration, int) or iteration < 0:
            raise ValueError(f"training iteration must be an int >= 0, got {iteration!r}")
        return self.training_simtrace_dir / f"{iteration}-iteration.csv"

    def worker_training_simtrace_dir(self, worker: int) -> Path:
        """Training simtrace folder of rollout worker ``worker`` (deepracer-for-cloud's layout with
        several workers, which deepracer-utils reads as ``DRFC_MODEL_MULTIPLE_WORKERS``)."""
        if isinstance(worker, bool) or not isinstance(worker, int) or worker < 0:
            raise ValueError(f"worker must be an int >= 0, got {worker!r}")
        return self.root / str(worker) / "training-simtrace"

    def worker_training_simtrace(self, worker: int, iteration: int) -> Path:
        return self.worker_training_simtrace_dir(worker) / self.training_simtrace(iteration).name

    def simtrace_workers(self) -> list[int]:
        """Workers with a ``<worker>/training-simtrace/`` folder, ascending ([] in the single-worker layout)."""
        if not self.root.is_dir():
            return []
        return sorted(int(p.name) for p in self.root.iterdir()
                      if p.name.isdigit() and (p / "training-simtrace").is_dir())

    def training_simtrace_files(self, iteration: int) -> list[Path]:
        """Every existing simtrace file of training iteration ``iteration`` (0-based): the
        single-worker file and each worker's."""
        paths = [self.training_simtrace(iteration)]
        paths += [self.worker_training_simtrace(w, iteration) for w in self.simtrace_workers()]
        return [p for p in paths if p.is_file()]

    def evaluation_dir(self, stamp: str) -> Path:
        return self.root / f"evaluation-{_check_stamp(stamp)}"

    def evaluation_simtrace(self, stamp: str) -> Path:
        return self.evaluation_dir(stamp) / "evaluation-simtrace" / "0-iteration.csv"

    def evaluation_metrics(self, stamp: str) -> Path:
        return self.metrics_dir / "evaluation" / f"evaluation-{_check_stamp(stamp)}.json"

    def exists(self) -> bool:
        return self.root.is_dir()

    def create(self) -> "ModelFolder":
        """Create the folder skeleton (model/, ip/, metrics/, training-simtrace/); idempotent."""
        for folder in (self.model_dir, self.hyperparameters.parent, self.metrics_dir,
                       self.training_simtrace_dir):
            folder.mkdir(parents=True, exist_ok=True)
        return self

    def new_evaluation(self, when: datetime | None = None) -> str:
        """Create a fresh evaluation folder and return its stamp.

        If an evaluation already has this second's stamp, the next free second is taken, so two
        evaluations started in the same second do not share (and overwrite) a folder.
        """
        moment = datetime.now(timezone.utc) if when is None else when.astimezone(timezone.utc)
        while True:
            stamp = evaluation_stamp(moment)
            simtrace_dir = self.evaluation_simtrace(stamp).parent
            try:
                self.root.mkdir(parents=True, exist_ok=True)
                self.evaluation_dir(stamp).mkdir()
            except FileExistsError:
                moment += timedelta(seconds=1)
                continue
            simtrace_dir.mkdir()
            return stamp

    def list_training_iterations(self) -> list[int]:
        """Iterations that have a training simtrace file (of any worker), ascending."""
        folders = [self.training_simtrace_dir] + [self.worker_training_simtrace_dir(w) for w in self.simtrace_workers()]
        found: set[int] = set()
        for folder in folders:
            if folder.is_dir():
                matches = (_ITERATION_FILE_PATTERN.fullmatch(p.name) for p in folder.iterdir())
                found.update(int(m.group(1)) for m in matches if m is not None)
        return sorted(found)

    def list_evaluations(self) -> list[str]:
        """Stamps of evaluations with a folder or a metrics file, oldest first."""
        stamps = {
            p.name.removeprefix("evaluation-")
            for p in self.root.glob("evaluation-*") if p.is_dir()
        }
        metrics_files = (self.metrics_dir / "evaluation").glob("evaluation-*.json")
        stamps |= {p.stem.removeprefix("evaluation-") for p in metrics_files}
        return sorted(s for s in stamps if _EVALUATION_STAMP_PATTERN.fullmatch(s))

    def write_model_metadata(self, metadata: dict[str, Any]) -> Path:
        _require_keys(metadata, ("action_space", "sensor", "neural_network", "training_algorithm",
                                 "action_space_type", "version"), "model_metadata.json")
        return atomic_write_json(self.model_metadata, metadata)

    def read_model_metadata(self) -> dict[str, Any]:
        return read_json(self.model_metadata)

    def write_hyperparameters(self, hyperparameters: dict[str, Any]) -> Path:
        _require_keys(hyperparameters, (), "hyperparameters.json")
        return atomic_write_json(self.hyperparameters, hyperparameters)

    def read_hyperparameters(self) -> dict[str, Any]:
        return read_json(self.hyperparameters)

    def write_reward_function(self, source: str) -> Path:
        return atomic_write_text(self.reward_function, source)

    def read_reward_function(self) -> str:
        return self.reward_function.read_text(encoding="utf-8")

    def write_laplab_config(self, config: dict[str, Any]) -> Path:
        _require_keys(config, (), "laplab.json")
        return atomic_write_json(self.laplab_config, config)

    def read_laplab_config(self) -> dict[str, Any]:
        return read_json(self.laplab_config)

    def write_error(self, message: str) -> Path:
        """Record why training died (shown by the console and `laplab` commands)."""
        return atomic_write_text(self.error_file, message.rstrip("\n") + "\n")

    def read_error(self) -> str | None:
        """The recorded error message, or None when training did not die."""
        try:
            return self.error_file.read_text(encoding="utf-8").rstrip("\n")
        except FileNotFoundError:
            return None


def _require_keys(document: Any, keys: tuple[str, ...], file_name: str) -> None:
    if not isinstance(document, dict):
        raise TypeError(f"{file_name} must be a JSON object (dict), got {type(document).__name__}")
    missing = [key for key in keys if key not in document]
    if missing:
        raise ValueError(f"{file_name} lacks required key(s) {missing}; present keys: {sorted(document)}")


def models_root() -> Path:
    """The settings' models folder (laplab/settings.py): `$LAPLAB_HOME/models`, default
    `~/.laplab/models`, or a `--store` command's local working copy (not created here)."""
    return current_settings().models_dir


def model_folder(name: str, root: str | os.PathLike | None = None) -> ModelFolder:
    """The folder of model `name` (validated) under `root` (default `models_root()`)."""
    base = models_root() if root is None else Path(root)
    return ModelFolder(base / validate_model_name(name))


def list_models(root: str | os.PathLike | None = None) -> list[str]:
    """Names of the models under `root` (folders with a valid name holding
    model/model_metadata.json or laplab.json), sorted."""
    base = models_root() if root is None else Path(root)
    if not base.is_dir():
        return []
    names = []
    for entry in base.iterdir():
        if not entry.is_dir() or MODEL_NAME_PATTERN.fullmatch(entry.name) is None:
            continue
        folder = ModelFolder(entry)
        if folder.model_metadata.is_file() or folder.laplab_config.is_file():
            names.append(entry.name)
    return sorted(names)


def list_evaluations(name: str, root: str | os.PathLike | None = None) -> list[str]:
    """Evaluation stamps of model `name`, oldest first."""
    return model_folder(name, root).list_evaluations()
