"""Policy checkpoints in a model folder, with DeepRacer's `deepracer_checkpoints.json`.

Each checkpoint is one file `model/<iteration>_Step-<steps>.ckpt` (the name rl_coach gives its
TensorFlow checkpoints in deepracer-for-cloud; `steps` = environment steps so far). Its bytes are
opaque here: the caller passes bytes, or a callable writing to a path (`lambda p:
torch.save(state, p)`), so this module needs no torch. As in the simapp (`NUM_MODELS_TO_KEEP`),
`keep` checkpoints are kept in all, the best among them: the newest `keep`, or the best and the
newest `keep - 1` when the best is older (the last is always kept); the rest are deleted after each save.

A checkpoint file holds the networks' weights. What resuming needs besides (optimizer state, target
networks) is written beside the *last* checkpoint only, as `model/<iteration>_Step-<steps>.ckpt.resume`
(`resume_path`), and deleted when a newer checkpoint takes over: the folder carries one copy of the
optimizer state, not one per checkpoint (docs/model-folder.md).

`model/deepracer_checkpoints.json` = `{"best_checkpoint": {"name", "avg_eval_metric",
"time_stamp"}, "last_checkpoint": {...}}`, rewritten atomically. The best is chosen as the
simapp does: a checkpoint whose metric is at least (for laptime: at most) the best's so far
takes over, ties going to the newer one; a checkpoint without a metric becomes best only
when there is none yet or the best has no metric either (more training beats none: a first
iteration cut short by the time limit replaces the untrained checkpoint 0). laplab adds one rule: on a tie, when both checkpoints carry the mean
lap time of their evaluation laps (`avg_eval_lap_time`, an extra key), the faster one wins, so
among checkpoints that all lap the best is the quickest rather than the newest.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from laplab.store.atomic import CorruptFileError, atomic_write_bytes, atomic_write_json, atomic_write_with, read_json
from laplab.store.layout import ModelFolder
from laplab.store.metrics import BEST_MODEL_METRICS

CHECKPOINT_NAME_PATTERN = re.compile(r"([0-9]+)_Step-([0-9]+)\.ckpt")
RESUME_SUFFIX = ".resume"


@dataclass(frozen=True)
class CheckpointParams:
    """keep: checkpoints kept in all, the best among them (the simapp's NUM_MODELS_TO_KEEP = 4);
    best_model_metric: 'progress' or 'reward' (higher is better) or 'laptime' (lower is better)."""

    keep: int = 4
    best_model_metric: str = "progress"

    def __post_init__(self) -> None:
        if isinstance(self.keep, bool) or not isinstance(self.keep, int) or self.keep < 1:
            raise ValueError(f"CheckpointParams.keep must be an int >= 1, got {self.keep!r}")
        if self.best_model_metric not in BEST_MODEL_METRICS:
            raise ValueError(f"CheckpointParams.best_model_metric must be one of {BEST_MODEL_METRICS}, "
                             f"got {self.best_model_metric!r}")


@dataclass(frozen=True)
class CheckpointRecord:
    """One entry of deepracer_checkpoints.json; time_stamp in Unix seconds."""

    name: str
    avg_eval_metric: float | None
    time_stamp: float
    avg_eval_lap_time: float | None = None  # s; laplab's tie-break (module docstring)

    def as_json(self) -> dict:
        out = {"name": self.name, "avg_eval_metric": self.avg_eval_metric, "time_stamp": self.time_stamp}
        if self.avg_eval_lap_time is not None:
            out["avg_eval_lap_time"] = self.avg_eval_lap_time
        return out


def checkpoint_name(iteration: int, steps: int) -> str:
    """`<iteration>_Step-<steps>.ckpt` for non-negative ints."""
    for label, value in (("iteration", iteration), ("steps", steps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"checkpoint {label} must be an int >= 0, got {value!r}")
    return f"{iteration}_Step-{steps}.ckpt"


def _order(name: str) -> tuple[int, int]:
    match = CHECKPOINT_NAME_PATTERN.fullmatch(name)
    return int(match.group(1)), int(match.group(2))


def _check_metric(metric: float | None) -> float | None:
    if metric is None:
        return None
    value = float(metric)
    if not math.isfinite(value):
        raise ValueError(f"checkpoint metric must be finite or None, got {metric!r}")
    return value


class CheckpointStore:
    """Saves, prunes and resolves the checkpoints of one model folder."""

    def __init__(self, folder: ModelFolder | str | os.PathLike, params: CheckpointParams = CheckpointParams()):
        self.folder = folder if isinstance(folder, ModelFolder) else ModelFolder(folder)
        self.params = params

    def names(self) -> list[str]:
        """Checkpoint file names present, oldest (lowest iteration) first."""
        if not self.folder.model_dir.is_dir():
            return []
        names = [p.name for p in self.folder.model_dir.iterdir() if CHECKPOINT_NAME_PATTERN.fullmatch(p.name)]
        return sorted(names, key=_order)

    def _records(self) -> tuple[CheckpointRecord | None, CheckpointRecord | None]:
        path = self.folder.deepracer_checkpoints
        if not path.exists():
            return None, None
        try:
            document = read_json(path)
        except CorruptFileError as error:
            available = ", ".join(self.names()) or "none"
            raise CorruptFileError(f"{error}. It names the model's best and last checkpoints; the checkpoint files "
                                   f"in {str(self.folder.model_dir)!r} are: {available} (give one by name, e.g. "
                                   f"--checkpoint {self.names()[-1] if self.names() else 'NAME'})") from None
        records = []
        for key in ("best_checkpoint", "last_checkpoint"):
            entry = document.get(key) if isinstance(document, dict) else None
            if entry is None:
                records.append(None)
                continue
            try:
                records.append(CheckpointRecord(str(entry["name"]), entry["avg_eval_metric"],
                                                float(entry["time_stamp"]), entry.get("avg_eval_lap_time")))
            except (KeyError, TypeError, ValueError) as error:
                raise CorruptFileError(f"{str(path)!r} is damaged: entry {key!r} must have name, avg_eval_metric "
                                       f"and time_stamp, got {entry!r}") from error
        return records[0], records[1]

    def best(self) -> CheckpointRecord | None:
        return self._records()[0]

    def last(self) -> CheckpointRecord | None:
        return self._records()[1]

    def _is_better(self, metric: float | None, best: CheckpointRecord | None, lap_time: float | None = None) -> bool:
        if best is None or not (self.folder.model_dir / best.name).exists():
            return True
        if best.avg_eval_metric is None:
            return True
        if metric is None:
            return False
        if metric == best.avg_eval_metric and lap_time is not None and best.avg_eval_lap_time is not None:
            return lap_time <= best.avg_eval_lap_time
        if self.params.best_model_metric == "laptime":
            return metric <= best.avg_eval_metric
        return metric >= best.avg_eval_metric

    def _write_records(self, best: CheckpointRecord | None, last: CheckpointRecord | None) -> None:
        atomic_write_json(self.folder.deepracer_checkpoints, {
            "best_checkpoint": None if best is None else best.as_json(),
            "last_checkpoint": None if last is None else last.as_json(),
        })

    def resume_path(self, name: str) -> Path:
        """Where the resume state of checkpoint ``name`` lives (present for the last one only)."""
        return self.folder.model_dir / (name + RESUME_SUFFIX)

    def save(self, payload: bytes | Callable[[Path], object], *, iteration: int, steps: int,
             metric: float | None = None, time_stamp: float | None = None,
             lap_time: float | None = None, resume: bytes | Callable[[Path], object] | None = None) -> Path:
        """Write a checkpoint atomically, update deepracer_checkpoints.json, prune old ones.

        payload: the checkpoint bytes, or a callable writing the checkpoint to the path it is
        given. metric: the checkpoint's mean evaluation metric (None if not evaluated yet; see
        `record_metric`). lap_time: the mean lap time of its evaluation laps, s, when they all
        lapped (breaks ties of the metric). resume: the state resuming needs besides (bytes or a
        writer, as payload), kept while this is the last checkpoint. Returns the checkpoint's path.
        """
        name = checkpoint_name(iteration, steps)
        value, lap_time = _check_metric(metric), _check_metric(lap_time)
        path = self.folder.model_dir / name
        if resume is not None:  # first, so the index never names a last checkpoint whose resume state is missing
            _write_payload(self.resume_path(name), resume)
        _write_payload(path, payload)
        record = CheckpointRecord(name, value, time.time() if time_stamp is None else float(time_stamp), lap_time)
        best, _ = self._records()
        self._write_records(record if self._is_better(value, best, lap_time) else best, record)
        self._prune()
        return path

    def record_metric(self, name: str, metric: float, time_stamp: float | None = None) -> None:
        """Set the evaluation metric of existing checkpoint `name` and reconsider the best."""
        self.resolve(name)
        value = _check_metric(metric)
        best, last = self._records()
        record = CheckpointRecord(name, value, time.time() if time_stamp is None else float(time_stamp))
        if last is not None and last.name == name:
            last = record
        if (best is not None and best.name == name) or self._is_better(value, best):
            best = record
        self._write_records(best, last)
        self._prune()

    def _prune(self) -> None:
        names = self.names()
        best, last = self._records()
        newest = names[-self.params.keep:]
        if best is not None and best.name not in newest and self.params.keep > 1:
            newest = names[-(self.params.keep - 1):]  # the best takes one of the places
        keep = set(newest) | ({best.name} if best is not None else set())
        for name in names:
            if name not in keep:
                (self.folder.model_dir / name).unlink(missing_ok=True)
        for path in self.folder.model_dir.glob("*" + RESUME_SUFFIX):
            if last is None or path.name != last.name + RESUME_SUFFIX:
                path.unlink(missing_ok=True)

    def resolve(self, which: str = "best") -> Path:
        """Path of the 'best' or 'last' checkpoint, or of the checkpoint named `which`."""
        if which in ("best", "last"):
            record = self.best() if which == "best" else self.last()
            if record is None:
                raise FileNotFoundError(f"model {self.folder.name!r} has no {which} checkpoint yet "
                                        f"({str(self.folder.deepracer_checkpoints)!r} is missing or empty)")
            name = record.name
        else:
            name = which
        path = self.folder.model_dir / name
        if CHECKPOINT_NAME_PATTERN.fullmatch(name) is None or not path.is_file():
            raise FileNotFoundError(f"checkpoint {name!r} not found in {str(self.folder.model_dir)!r}; "
                                    f"available: {self.names()} (or 'best', 'last')")
        return path


def _write_payload(path: Path, payload: bytes | Callable[[Path], object]) -> None:
    if isinstance(payload, (bytes, bytearray, memoryview)):
        atomic_write_bytes(path, payload)
    elif callable(payload):
        atomic_write_with(path, payload)
    else:
        raise TypeError(f"checkpoint payload must be bytes or a callable writing to a path, "
                        f"got {type(payload).__name__}")
