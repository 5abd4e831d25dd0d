import json

import numpy as np
import pytest

from laplab.store.metrics import (
    EvaluationMetricsWriter,
    TrainingMetricsWriter,
    episode_status_labels,
    read_metrics,
)


def _iteration(n, start=0.0):
    return dict(reward_score=np.linspace(10.4, 20.6, n), start_time=start + 10.0 * np.arange(n),
                metric_time=start + 10.0 * np.arange(n) + 7.25, completion_percentage=np.linspace(12.9, 100.0, n),
                episode_status=["off_track"] * (n - 1) + ["lap_complete"])


def test_training_rows_follow_the_simapp_numbering(tmp_path):
    path = tmp_path / "metrics" / "TrainingMetrics.json"
    writer = TrainingMetricsWriter(path)
    writer.append_training(**_iteration(3))
    writer.append_evaluation(**_iteration(2, start=100.0))
    writer.append_training(**_iteration(3, start=200.0))
    document = json.loads(path.read_text())
    assert document["version"] == 2.0 and document["best_model_metric"] == "progress"
    rows = document["metrics"]
    assert [(r["phase"], r["episode"], r["trial"]) for r in rows] == [
        ("training", 1, 1), ("training", 2, 2), ("training", 3, 3),
        ("evaluation", 3, 3), ("evaluation", 3, 3),
        ("training", 4, 1), ("training", 5, 2), ("training", 6, 3)]
    first = rows[0]
    assert set(first) == {"reward_score", "metric_time", "start_time", "elapsed_time_in_milliseconds",
                          "episode", "trial", "phase", "completion_percentage", "episode_status"}
    assert (first["reward_score"], first["start_time"], first["metric_time"]) == (10, 0, 7250)
    assert first["elapsed_time_in_milliseconds"] == 7250
    assert first["completion_percentage"] == 12 and first["episode_status"] == "Off track"
    assert rows[2]["episode_status"] == "Lap complete" and rows[2]["completion_percentage"] == 100


def test_training_writer_resumes_an_existing_file(tmp_path):
    path = tmp_path / "TrainingMetrics.json"
    TrainingMetricsWriter(path).append_training(**_iteration(4))
    resumed = TrainingMetricsWriter(path, best_model_metric="reward")
    resumed.append_training(**_iteration(4))
    rows = read_metrics(path)
    assert [r["episode"] for r in rows] == list(range(1, 9))
    assert json.loads(path.read_text())["best_model_metric"] == "reward"


def test_evaluation_rows_sum_resets_and_number_trials(tmp_path):
    path = tmp_path / "evaluation-20240101000000.json"
    writer = EvaluationMetricsWriter(path)
    for _ in range(2):
        writer.append_trials(completion_percentage=[100.0, 55.5], start_time=[0.0, 20.0], metric_time=[15.5, 31.0],
                             episode_status=["Lap complete", "time_up"], crash_count=[0, 1],
                             immobilized_count=[0, 0], off_track_count=[2, 3], reversed_count=[0, 1])
    document = json.loads(path.read_text())
    assert set(document) == {"metrics"}
    rows = document["metrics"]
    assert [r["trial"] for r in rows] == [1, 2, 3, 4]
    assert [r["reset_count"] for r in rows] == [2, 5, 2, 5]
    assert rows[0]["elapsed_time_in_milliseconds"] == 15500 and rows[1]["episode_status"] == "Time Up"
    assert set(rows[0]) == {"completion_percentage", "metric_time", "start_time", "elapsed_time_in_milliseconds",
                            "episode_status", "crash_count", "immobilized_count", "off_track_count",
                            "reversed_count", "reset_count", "trial"}


def test_bad_input_is_refused_before_anything_is_written(tmp_path):
    path = tmp_path / "TrainingMetrics.json"
    writer = TrainingMetricsWriter(path)
    with pytest.raises(ValueError, match="unknown episode_status.*'flying'"):
        writer.append_training(**{**_iteration(2), "episode_status": ["flying", "off_track"]})
    with pytest.raises(ValueError, match="'metric_time'.*2 rows"):
        writer.append_training(**{**_iteration(2), "metric_time": [1.0]})
    with pytest.raises(ValueError, match="'reward_score'.*finite"):
        writer.append_training(**{**_iteration(2), "reward_score": [1.0, np.nan]})
    with pytest.raises(ValueError, match="best_model_metric"):
        TrainingMetricsWriter(path, best_model_metric="speed")
    assert not path.exists()
    path.write_text('{"rows": []}')
    with pytest.raises(ValueError, match="TrainingMetrics.json.*'metrics' list"):
        TrainingMetricsWriter(path)


def test_status_codes_and_labels_both_map_to_labels():
    assert episode_status_labels(np.array(["off_track", "Crashed", "reversed"])) == ["Off track", "Crashed", "Reversed"]
