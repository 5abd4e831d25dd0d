"""Model folders in the deepracer-for-cloud layout: paths, simtrace and metrics files,
checkpoints, atomic writes. See docs/model-folder.md."""

from laplab.store.atomic import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    atomic_write_with,
    read_json,
)
from laplab.store.checkpoints import (
    CheckpointParams,
    CheckpointRecord,
    CheckpointStore,
    checkpoint_name,
)
from laplab.store.layout import (
    ModelFolder,
    ModelNameError,
    evaluation_stamp,
    list_evaluations,
    list_models,
    model_folder,
    models_root,
    validate_model_name,
)
from laplab.store.metrics import (
    EPISODE_STATUS_LABELS,
    EvaluationMetricsWriter,
    TrainingMetricsWriter,
    episode_status_labels,
    read_metrics,
)
from laplab.store.simtrace import (
    EPISODE_STATUSES,
    SIMTRACE_COLUMNS,
    SIMTRACE_HEADER,
    SimtraceWriter,
    format_rows,
    read_simtrace,
)

__all__ = [
    "CheckpointParams", "CheckpointRecord", "CheckpointStore", "EPISODE_STATUSES",
    "EPISODE_STATUS_LABELS", "EvaluationMetricsWriter", "ModelFolder", "ModelNameError",
    "SIMTRACE_COLUMNS", "SIMTRACE_HEADER", "SimtraceWriter", "TrainingMetricsWriter",
    "atomic_write_bytes", "atomic_write_json", "atomic_write_text", "atomic_write_with",
    "checkpoint_name", "episode_status_labels", "evaluation_stamp", "format_rows",
    "list_evaluations", "list_models", "model_folder", "models_root", "read_json",
    "read_metrics", "read_simtrace", "validate_model_name",
]
