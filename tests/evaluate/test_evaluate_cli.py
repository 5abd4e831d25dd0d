"""``laplab evaluate`` on a freshly trained tiny model, in process: files in the deepracer-for-cloud
layout (read back by deepracer-utils), the listing, the trial limit, video, determinism."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from laplab.cli import main
from laplab.evaluate import EvaluationSettings, evaluate_model
from laplab.store.layout import model_folder
from laplab.store.metrics import read_metrics
from laplab.store.simtrace import read_simtrace
from tests.evaluate.conftest import train_tiny_model

MODEL = "eval-me"
QUICK = ["--max-trial-time", "12"]  # s: the tiny model may never finish; keep trials short


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("home")
        patch.setenv("LAPLAB_HOME", str(root))
        train_tiny_model(MODEL)
        yield root


def _last_stamp():
    return model_folder(MODEL).list_evaluations()[-1]


def test_evaluate_writes_simtrace_metrics_and_summary(home, capsys):
    assert main(["evaluate", MODEL, "--trials", "2", "--off-track-penalty", "5", *QUICK]) == 0
    out = capsys.readouterr().out
    assert "status" in out and "gap to optimal" in out and "evaluation " in out
    folder, stamp = model_folder(MODEL), _last_stamp()
    document = json.loads((folder.evaluation_dir(stamp) / "summary.json").read_text())
    assert document["track"]["name"] == "classic_2018" and document["settings"]["off_track_penalty"] == 5.0
    assert len(document["trials"]) == 2 and document["summary"]["optimal_lap_time"] > 0
    trace = read_simtrace(folder.evaluation_simtrace(stamp))
    assert set(trace["episode"].tolist()) == {0, 1}
    assert trace["done"].sum() == 2
    metrics = read_metrics(folder.evaluation_metrics(stamp))
    assert [row["trial"] for row in metrics] == [1, 2]
    for row, trial in zip(metrics, document["trials"]):
        assert row["off_track_count"] == trial["off_track_count"]
        assert row["elapsed_time_in_milliseconds"] == pytest.approx(1000 * trial["duration"], abs=1)


def test_deepracer_utils_reads_the_evaluation(home):
    logs = pytest.importorskip("deepracer.logs")
    assert main(["evaluate", MODEL, "--trials", "3", *QUICK]) == 0
    folder, stamp = model_folder(MODEL), _last_stamp()
    log = logs.DeepRacerLog(model_folder=str(folder.root))
    log.load_evaluation_trace()
    df = log.dataframe()
    df = df[df["stream"] == stamp]
    document = json.loads((folder.evaluation_dir(stamp) / "summary.json").read_text())
    assert len(df) == len(read_simtrace(folder.evaluation_simtrace(stamp))["episode"])
    assert sorted(df["episode"].unique().tolist()) == [0, 1, 2]
    aggregates = logs.AnalysisUtils.simulation_agg(df.copy(), "stream", is_eval=True)
    assert aggregates["off_track"].tolist() == [t["off_track_count"] for t in document["trials"]]


def test_list_json_and_trial_limit(home, capsys):
    assert main(["evaluate", MODEL, "--trials", "1", "--json", *QUICK]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["stamp"] == _last_stamp() and len(printed["trials"]) == 1
    assert main(["evaluate", MODEL, "--list"]) == 0
    assert _last_stamp() in capsys.readouterr().out
    assert main(["evaluate", MODEL, "--list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["evaluations"]
    assert [row["stamp"] for row in listed] == model_folder(MODEL).list_evaluations()
    assert main(["evaluate", MODEL, "--trials", "6", *QUICK]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["evaluate", MODEL, "--trials", "6", "--force", "--max-trial-time", "2"]) == 0
    assert len(read_metrics(model_folder(MODEL).evaluation_metrics(_last_stamp()))) == 6
    assert main(["evaluate", "no-such-model"]) == 2
    with pytest.raises(SystemExit):
        main(["evaluate", MODEL, "--resets", "-1"])


def test_video_of_the_first_trial(home, capsys):
    assert main(["evaluate", MODEL, "--trials", "1", "--video", "--max-trial-time", "2"]) == 0
    out = capsys.readouterr().out
    document = json.loads((model_folder(MODEL).evaluation_dir(_last_stamp()) / "summary.json").read_text())
    video = document["video"]
    assert video and video in out and video.endswith((".mp4", ".gif"))
    from pathlib import Path
    assert Path(video).stat().st_size > 1000


def test_stochastic_evaluation_repeats_with_its_seed(home):
    settings = EvaluationSettings(trials=2, stochastic=True, seed=11, max_trial_time=8.0)
    first, _ = evaluate_model(MODEL, settings)
    second, _ = evaluate_model(MODEL, settings)
    other, _ = evaluate_model(MODEL, replace(settings, seed=12))
    assert first.trials == second.trials
    assert np.array_equal(first.trace["X"], second.trace["X"])
    assert not (len(first.trace["X"]) == len(other.trace["X"]) and np.array_equal(first.trace["X"], other.trace["X"]))


def test_domain_randomization_of_a_model_without_a_camera_is_refused_and_writes_nothing(home, capsys):
    before = model_folder(MODEL).list_evaluations()
    assert main(["evaluate", MODEL, "--domain-randomization", *QUICK]) == 2
    error = capsys.readouterr().err
    assert "--domain-randomization" in error and "no camera (sensors: STATE)" in error
    assert model_folder(MODEL).list_evaluations() == before
