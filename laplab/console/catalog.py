"""The console's view of model folders: one summary per folder (track, sensors, best lap, race type),
re-read only when one of the folder's files changed (:class:`ModelCatalog`)."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from laplab.jobs.runner import models_dir
from laplab.store.layout import ModelFolder


def iso_time(timestamp: float | None) -> str | None:
    return None if timestamp is None else datetime.fromtimestamp(timestamp, timezone.utc).isoformat(timespec="seconds")


def read_json(path: Path) -> Any:
    """The JSON document at ``path``; None when it is missing or not JSON (a file being written)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


class ModelCatalog:
    """Summaries of model folders, re-read only when one of their files changed."""

    def __init__(self):
        self._cache: dict[str, tuple[tuple, dict]] = {}

    @staticmethod
    def _files(folder: ModelFolder) -> tuple[Path, ...]:
        return (folder.laplab_config, folder.model_metadata, folder.metrics_dir / "laplab-iterations.json",
                folder.deepracer_checkpoints, folder.error_file, folder.metrics_dir / "evaluation")

    def summary(self, name: str) -> dict:
        folder = ModelFolder(models_dir() / name)
        key = tuple(p.stat().st_mtime_ns if p.exists() else 0 for p in self._files(folder))
        hit = self._cache.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        config = read_json(folder.laplab_config) or {}
        metadata = read_json(folder.model_metadata) or config.get("model_metadata") or {}
        iterations = (read_json(folder.metrics_dir / "laplab-iterations.json") or {}).get("iterations", [])
        training_best = None
        for row in iterations:
            if row.get("best_lap_time") is not None:
                training_best = row["best_lap_time"] if training_best is None else min(training_best, row["best_lap_time"])
        best = _best_evaluated_lap(folder, config)
        created = folder.root.stat().st_mtime if folder.root.exists() else None
        if folder.laplab_config.exists():
            created = folder.laplab_config.stat().st_mtime
        summary = {"name": name, "track": config.get("track"), "sensor": metadata.get("sensor"),
                   "algorithm": metadata.get("training_algorithm"),
                   "action_space_type": metadata.get("action_space_type"),
                   "created": iso_time(created), "best_lap_time": best, "best_training_lap": training_best,
                   "iteration_count": len(iterations),
                   "max_time_s": config.get("max_time_s"), "error": folder.read_error(),
                   "race_type": _race_summary(config.get("race_type")),
                   "evaluations": len(folder.list_evaluations()) if folder.exists() else 0,
                   "exists": folder.laplab_config.exists() or folder.model_metadata.exists()}
        self._cache[name] = (key, summary)
        return summary

    @staticmethod
    def iterations(name: str) -> list[dict]:
        folder = ModelFolder(models_dir() / name)
        rows = (read_json(folder.metrics_dir / "laplab-iterations.json") or {}).get("iterations", [])
        keep = ("iteration", "episodes", "env_steps", "mean_reward", "mean_progress", "completion_rate",
                "eval_progress", "best_lap_time", "eval_lap_time", "steps_per_second", "elapsed_s", "time_left_s")
        return [{k: r.get(k) for k in keep} for r in rows]


def _best_evaluated_lap(folder: ModelFolder, config: dict) -> float | None:
    """The model's best lap, as laplab defines it everywhere (:func:`laplab.evaluate.leaderboard.
    best_evaluated_lap`): evaluations under the standard rules on its training track and race."""
    if not folder.exists():
        return None
    from laplab.evaluate.leaderboard import best_evaluated_lap, load_records_of
    try:
        records = load_records_of(folder.name, folder.root.parent)
    except Exception:  # noqa: BLE001 - a damaged summary: no best lap rather than a broken list
        return None
    return best_evaluated_lap(folder.name, config.get("track"), _race_summary(config.get("race_type")) or "time trial",
                              records)


def _race_summary(data) -> str:
    """A model's race type in one line (``laplab.json``'s ``race_type``; none: a time trial)."""
    from laplab.sim.race_type import RaceType, RaceTypeError
    try:
        return RaceType.from_dict(data).summary()
    except (RaceTypeError, TypeError):
        return "unreadable race type"
