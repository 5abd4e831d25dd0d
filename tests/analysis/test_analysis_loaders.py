"""Loaders and plot helpers on hand-made logs with known answers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from laplab.analysis.evaluations import load_evaluation
from laplab.analysis.loaders import ReportDataError, Trace, load_episode_log, load_training_history
from laplab.analysis.plots import PlotStyle, moving_average, plot_action_usage, reward_grid, reward_map_cell
from laplab.store.layout import ModelFolder


def _row(phase, trial, reward, progress, status="Off track", elapsed=1000):
    return {"phase": phase, "trial": trial, "episode": 0, "reward_score": reward, "completion_percentage": progress,
            "episode_status": status, "elapsed_time_in_milliseconds": elapsed, "metric_time": 0, "start_time": 0}


def _write_metrics(folder: ModelFolder, rows) -> None:
    folder.create()
    folder.training_metrics.write_text(json.dumps({"metrics": rows, "version": 2.0}))


def test_iterations_are_recovered_from_trial_numbers(tmp_path):
    folder = ModelFolder(tmp_path / "m")
    _write_metrics(folder, [
        _row("training", 1, 10, 20), _row("training", 2, 30, 40, "Lap complete"),
        _row("evaluation", 2, 0, 50), _row("evaluation", 2, 0, 100, "Lap complete"),
        _row("training", 1, 50, 60), _row("training", 2, 70, 80),
        _row("training", 3, 90, 100, "Lap complete"),
        _row("training", 2, 5, 10),  # a trial that does not follow on starts iteration 3
    ])
    log = load_episode_log(folder.training_metrics)
    np.testing.assert_array_equal(log.iteration, [1, 1, 1, 1, 2, 2, 2, 3])
    history = load_training_history(folder)
    np.testing.assert_array_equal(history.iteration, [1, 2, 3])
    np.testing.assert_allclose(history.mean_reward, [20, 70, 5])
    np.testing.assert_allclose(history.mean_progress, [30, 80, 10])
    np.testing.assert_allclose(history.completion_rate, [0.5, 1 / 3, 0])
    np.testing.assert_allclose(history.eval_progress, [75, np.nan, np.nan])
    np.testing.assert_allclose(history.eval_completion_rate, [0.5, np.nan, np.nan])
    assert history.losses == {}


def test_losses_and_fallback_means_come_from_the_iteration_log(tmp_path):
    folder = ModelFolder(tmp_path / "m").create()
    rows = [{"iteration": i, "mean_reward": 10.0 * i, "mean_progress": 5.0 * i, "completion_rate": 0.25,
             "eval_progress": 50.0, "eval_completed": 1, "eval_episodes": 4, "env_steps": 100 * i,
             "losses": {"entropy": 1.0 / i, "policy_loss": -0.01, "num_steps": 999}} for i in (1, 2)]
    (folder.metrics_dir / "laplab-iterations.json").write_text(json.dumps({"iterations": rows}))
    history = load_training_history(folder)
    np.testing.assert_allclose(history.mean_reward, [10, 20])
    np.testing.assert_allclose(history.eval_completion_rate, [0.25, 0.25])
    np.testing.assert_allclose(history.env_steps, [100, 200])
    assert sorted(history.losses) == ["entropy", "policy_loss"]  # counters are not curves
    np.testing.assert_allclose(history.losses["entropy"], [1.0, 0.5])


def test_a_metrics_row_without_a_key_is_named(tmp_path):
    folder = ModelFolder(tmp_path / "m")
    row = _row("training", 1, 1, 1)
    del row["reward_score"]
    _write_metrics(folder, [row])
    with pytest.raises(ReportDataError, match="row 0 lacks the key 'reward_score'"):
        load_training_history(folder)


def test_moving_average_is_a_trailing_nan_aware_mean():
    values = np.array([1.0, 2.0, np.nan, 4.0, 6.0])
    np.testing.assert_allclose(moving_average(values, 2), [1.0, 1.5, 2.0, 4.0, 5.0])
    np.testing.assert_allclose(moving_average(values, 10), [1.0, 1.5, 1.5, 7 / 3, 13 / 4])


def test_summary_trials_take_precedence_and_count_from_one(tmp_path):
    folder = ModelFolder(tmp_path / "m").create()
    stamp = folder.new_evaluation()
    summary = {"track": {"name": "oval@reversed"}, "settings": {"track": None},
               "trials": [{"index": 0, "status": "lap_complete", "lap_time": 9.5, "completion": 100.0,
                           "off_track_count": 2},
                          {"index": 1, "status": "off_track", "lap_time": None, "completion": 30.0}],
               "summary": {"optimal_lap_time": 4.75}, "video": "missing.mp4"}
    (folder.evaluation_dir(stamp) / "summary.json").write_text(json.dumps(summary))
    evaluation = load_evaluation(folder, stamp)
    assert [t.trial for t in evaluation.trials] == [1, 2]
    assert evaluation.trials[0].lap_time_s == 9.5 and evaluation.trials[0].off_track_count == 2
    assert evaluation.trials[1].lap_time_s is None and evaluation.trials[1].off_track_count is None
    assert evaluation.track == "oval@reversed" and evaluation.optimal_lap_time == 4.75
    assert evaluation.video is None and evaluation.trace is None and evaluation.problems == ()


def _trace(x, y, reward, steer=None, throttle=None, action=None) -> Trace:
    n = len(x)
    steer = np.zeros(n) if steer is None else steer
    throttle = np.ones(n) if throttle is None else throttle
    return Trace(np.ones(n, np.int64), np.zeros(n, np.int64), np.asarray(x, float), np.asarray(y, float), steer,
                 throttle, np.asarray(reward, float), np.zeros(n), np.zeros(n, np.int64) if action is None else action,
                 np.array(["in_progress"] * n, dtype=np.dtypes.StringDType()), np.ones(n, bool))


def test_reward_grid_means_per_cell(stadium_track):
    style = PlotStyle(heat_min_visits=2)
    cell = reward_map_cell(stadium_track, style)
    assert cell == pytest.approx(stadium_track.nominal_width / style.heat_cells_across)
    xs, ys, mean = reward_grid(stadium_track, _trace([0.01, 0.02, 0.03, 2.0], [-2.0, -2.0, -2.0, -2.0],
                                                     [1.0, 2.0, 6.0, 5.0]), style)
    assert mean.shape == (len(ys) - 1, len(xs) - 1)
    column, row = np.searchsorted(xs, 0.02) - 1, np.searchsorted(ys, -2.0) - 1
    assert mean[row, column] == pytest.approx(3.0)
    assert mean.count() == 1  # the single step at x = 2 is below heat_min_visits


def test_continuous_action_usage_is_a_2d_histogram(tmp_path):
    rng = np.random.default_rng(0)
    steer, speed = rng.uniform(-30, 30, 500), rng.uniform(0.5, 3.0, 500)
    trace = _trace(np.zeros(500), np.zeros(500), np.zeros(500), steer, speed, np.column_stack([steer, speed]))
    space = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 3.0}}
    path = plot_action_usage(trace, space, "continuous", tmp_path / "a.png", "continuous")
    with Image.open(path) as image:
        assert image.width > 300 and np.asarray(image.convert("L")).std() > 5
