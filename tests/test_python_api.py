"""laplab.api, the notebook's calls: model files, the metrics chart, command errors (a whole job with
Ray workers and the S3 store runs in tests/examples/test_notebook.py)."""

from __future__ import annotations

import json

import pytest

from laplab import api
from laplab.analysis.metrics_chart import training_metrics_figure
from laplab.errors import UserError

ACTIONS = [{"steering_angle": a, "speed": s} for a in (-20, 0, 20) for s in (1.0, 2.0)]
REWARD = "def reward_function(params):\n    return 1.0 if params['all_wheels_on_track'] else 1e-3\n"


def test_model_files_are_checked_as_laplab_train_checks_them(tmp_path):
    files = api.write_model_files(tmp_path, REWARD, ACTIONS, {"batch_size": 32}, sensor=["STATE"])
    assert json.loads(files.model_metadata.read_text())["action_space_type"] == "discrete"
    with pytest.raises(UserError, match="speed"):
        api.write_model_files(tmp_path / "bad", REWARD, [{"steering_angle": 0, "speed": -1}])
    with pytest.raises(UserError, match="batch_size"):
        api.write_model_files(tmp_path / "bad2", REWARD, ACTIONS, {"batch_size": "many"})


def test_chart_before_and_after_the_first_iteration():
    empty = training_metrics_figure([])
    assert "no episodes yet" in empty.axes[0].texts[0].get_text()
    rows = [{"phase": "training", "episode": e, "reward_score": e, "completion_percentage": 10 * e} for e in range(1, 5)]
    rows += [{"phase": "evaluation", "episode": 4, "reward_score": 0, "completion_percentage": p} for p in (50, 70)]
    figure = training_metrics_figure(rows, title="m")
    evaluation_line = [line for line in figure.axes[1].lines if "evaluation" in line.get_label()][0]
    assert list(evaluation_line.get_ydata()) == [60.0]


def test_a_failed_command_is_its_own_paragraph(tmp_path, monkeypatch):
    """(A whole job, Ray workers and the S3 store: tests/examples/test_notebook.py.)"""
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    with pytest.raises(UserError, match="evaluating 'api-nope' failed: no model named 'api-nope'") as refused:
        api.evaluate("api-nope")  # the command's own message, from its JSON outcome (not its printed lines)
    assert "\n" not in str(refused.value)
