"""laplab's writers produce model folders that the community's deepracer-utils reads."""

import numpy as np
import pytest

pytest.importorskip("pandas")
logs = pytest.importorskip("deepracer.logs")
from deepracer.logs import AnalysisUtils, DeepRacerLog, LogFolderType, TrainingMetrics  # noqa: E402

from laplab.store import (  # noqa: E402
    CheckpointStore,
    EvaluationMetricsWriter,
    SimtraceWriter,
    TrainingMetricsWriter,
    model_folder,
)

DISCRETE = {"action_space": [{"steering_angle": -30, "speed": 1.0}, {"steering_angle": 0, "speed": 2.0},
                             {"steering_angle": 30, "speed": 1.0}, {"steering_angle": 15, "speed": 1.5},
                             {"steering_angle": -15, "speed": 1.5}],
            "sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
            "training_algorithm": "clipped_ppo", "action_space_type": "discrete", "version": "5"}
CONTINUOUS = {**DISCRETE, "action_space_type": "continuous",
              "action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}}}
HYPERPARAMETERS = {"batch_size": 64, "num_epochs": 10, "lr": 3e-4, "num_episodes_between_training": 4}
EPISODE_LENGTHS = [[6, 9, 4, 7], [5, 12, 8, 3], [10, 6, 6, 9]]  # 3 iterations x 4 episodes


def _write_model(tmp_path, name, metadata, simtrace_columns):
    folder = model_folder(name, tmp_path).create()
    folder.write_model_metadata(metadata)
    folder.write_hyperparameters(HYPERPARAMETERS)
    continuous = metadata["action_space_type"] == "continuous"
    metrics = TrainingMetricsWriter(folder.training_metrics)
    first_episode = 0
    for iteration, lengths in enumerate(EPISODE_LENGTHS):
        columns = simtrace_columns(first_episode, lengths, continuous, seed=iteration)
        with SimtraceWriter(folder.training_simtrace(iteration), fsync=False) as writer:
            writer.write_rows({k: v[:20] for k, v in columns.items()})  # two batches per iteration
            writer.write_rows({k: v[20:] for k, v in columns.items()})
        ends = columns["done"]
        metrics.append_training(reward_score=np.bincount(columns["episode"] - first_episode, columns["reward"]),
                                start_time=columns["tstamp"][np.r_[True, ends[:-1]]],
                                metric_time=columns["tstamp"][ends], completion_percentage=columns["progress"][ends],
                                episode_status=columns["episode_status"][ends])
        metrics.append_evaluation(reward_score=[5.0], start_time=[0.0], metric_time=[3.0],
                                  completion_percentage=[40.0], episode_status=["off_track"])
        CheckpointStore(folder).save(b"w", iteration=iteration, steps=int(sum(lengths)), metric=40.0)
        first_episode += len(lengths)
    stamp = folder.new_evaluation()
    with SimtraceWriter(folder.evaluation_simtrace(stamp), fsync=False) as writer:
        writer.write_rows(simtrace_columns(0, [11, 13, 12], continuous, seed=7))
    EvaluationMetricsWriter(folder.evaluation_metrics(stamp)).append_trials(
        completion_percentage=[100, 100, 100], start_time=[0, 20, 40], metric_time=[11, 32, 52],
        episode_status=["lap_complete"] * 3, crash_count=[0] * 3, immobilized_count=[0] * 3,
        off_track_count=[1, 0, 2], reversed_count=[0] * 3)
    return folder, stamp


@pytest.mark.parametrize("metadata", [DISCRETE, CONTINUOUS], ids=["discrete", "continuous"])
def test_deepracer_log_loads_training_and_evaluation_traces(tmp_path, simtrace_columns, metadata):
    folder, stamp = _write_model(tmp_path, "compat-model", metadata, simtrace_columns)
    log = DeepRacerLog(model_folder=str(folder.root))
    assert log.fh.type == LogFolderType.DRFC_MODEL_SINGLE_WORKERS
    log.load()
    df = log.dataframe()
    assert len(df) == sum(map(sum, EPISODE_LENGTHS))
    assert sorted(df["iteration"].unique()) == [0, 1, 2]
    assert df["unique_episode"].nunique() == 12 and df["episode"].nunique() == 12
    assert df.groupby("unique_episode")["steps"].max().tolist() == [n for it in EPISODE_LENGTHS for n in it]
    assert df["done"].dtype == bool and int(df["done"].sum()) == 12
    assert {"x", "y", "steering_angle", "speed", "on_track", "wall_clock"} <= set(df.columns)
    if metadata is DISCRETE:
        assert df["action"].between(0, 4).all()  # numeric indices kept
    else:
        assert (df["action"] == -1).all()  # deepracer-utils' documented value for "[steer speed]" strings
    assert log.action_space() == metadata["action_space"]
    assert log.hyperparameters() == HYPERPARAMETERS
    aggregates = AnalysisUtils.simulation_agg(df)
    assert len(aggregates) == 12 and aggregates["complete"].sum() == 3  # the longest episode of each iteration

    evaluation = DeepRacerLog(model_folder=str(folder.root))
    evaluation.load_evaluation_trace()
    eval_df = evaluation.dataframe()
    assert len(eval_df) == 36 and eval_df["stream"].unique().tolist() == [stamp]
    assert eval_df["episode"].nunique() == 3


def test_training_metrics_loads_the_json(tmp_path, simtrace_columns):
    folder, _ = _write_model(tmp_path, "metrics-model", DISCRETE, simtrace_columns)
    metrics = TrainingMetrics(bucket=None, fname=str(folder.training_metrics)).metrics
    training = metrics[metrics["phase"] == "training"]
    assert len(training) == 12 and len(metrics) == 15
    assert training["iteration"].tolist() == [0] * 4 + [1] * 4 + [2] * 4
    assert metrics[metrics["phase"] == "evaluation"]["iteration"].tolist() == [0, 1, 2]
    assert training["complete"].sum() == 3
    assert (training["time"] > 0).all()
