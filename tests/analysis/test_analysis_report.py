"""`laplab report`: a tiny trained model's report has every section's PNG, referenced by the page;
evaluations (hand-made in the store layout, and a real one when laplab.evaluate is present) are
drawn with their trial table and video; a model without evaluations still reports."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from laplab.analysis.evaluations import load_evaluations
from laplab.analysis.loaders import load_training_traces, traced_iterations
from laplab.analysis.plots import _episode_segments
from laplab.analysis.report import build_report
from laplab.cli import main
from laplab.env.metadata import ModelMetadata
from laplab.store.layout import model_folder
from laplab.store.metrics import EvaluationMetricsWriter
from laplab.store.simtrace import SimtraceWriter, read_simtrace
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training

TRAINING_PNGS = ("training.png", "losses.png", "trajectories.png", "actions.png", "reward_map.png")


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """$LAPLAB_HOME holding model 'tiny': 3 iterations of 4 episodes (PPO, discrete)."""
    root = tmp_path_factory.mktemp("home")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LAPLAB_HOME", str(root))
        hyper = {**TrainConfig().hyper().to_dict(), "num_episodes_between_training": 4, "batch_size": 32,
                 "num_epochs": 3}
        config = replace(TrainConfig(), hyperparameters=hyper, model_metadata=ModelMetadata().to_dict(),
                         max_time_s=120, max_episodes=12)
        result = create_training("tiny", config).run()
        assert result.iterations == 3
        yield root


def _png_ok(path: Path) -> None:
    assert path.is_file(), f"{path.name} was not written"
    with Image.open(path) as image:
        assert image.format == "PNG" and image.width > 300 and image.height > 200
        pixels = np.asarray(image.convert("L"))
    assert pixels.std() > 5, f"{path.name} is blank"


def _hand_made_evaluation(folder) -> str:
    """An evaluation written with the store's writers: two trials replayed from training episodes,
    a summary.json in laplab evaluate's format naming a GIF video."""
    stamp = folder.new_evaluation()
    trace = read_simtrace(folder.training_simtrace(2))
    episodes = np.unique(trace["episode"])[:2]
    keep = np.isin(trace["episode"], episodes)
    columns = {name: values[keep] for name, values in trace.items()}
    columns["episode"] = np.searchsorted(episodes, columns["episode"])
    # read_simtrace returns statuses as StringDType, which the writer cannot take back (yet).
    columns["episode_status"] = columns["episode_status"].astype(object)
    with SimtraceWriter(folder.evaluation_simtrace(stamp), fsync=False) as writer:
        writer.write_rows(columns)
    EvaluationMetricsWriter(folder.evaluation_metrics(stamp)).append_trials(
        completion_percentage=[100.0, 42.0], start_time=[0.0, 12.5], metric_time=[12.5, 20.0],
        episode_status=["lap_complete", "off_track"], crash_count=[0, 0], immobilized_count=[0, 0],
        off_track_count=[1, 1], reversed_count=[0, 0])
    frames = [Image.new("RGB", (64, 48), colour) for colour in ((200, 30, 30), (30, 30, 200))]
    frames[0].save(folder.evaluation_dir(stamp) / "trial-1.gif", save_all=True, append_images=frames[1:])
    summary = {
        "version": 1, "model": folder.name, "track": {"name": "classic_2018", "direction": "ccw"},
        "settings": {"track": None, "trials": 2},
        "trials": [{"index": 0, "status": "lap_complete", "lap_time": 12.5, "completion": 100.0, "off_track_count": 1},
                   {"index": 1, "status": "off_track", "lap_time": None, "completion": 42.0, "off_track_count": 1}],
        "summary": {"trials": 2, "completed": 1, "best_lap": 12.5, "optimal_lap_time": 5.0, "gap_to_optimal": 2.5,
                    "standing_start_lap_time": 5.5},
        "video": "trial-1.gif",
    }
    (folder.evaluation_dir(stamp) / "summary.json").write_text(json.dumps(summary))
    return stamp


def _referenced(page: str) -> set[str]:
    return set(re.findall(r'src="([^"]+)"', page))


def test_report_with_evaluations_has_every_section(home, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    folder = model_folder("tiny")
    stamps = [_hand_made_evaluation(folder)]
    try:
        from laplab.evaluate.trials import EvaluationSettings, evaluate_model
    except ImportError:
        evaluate_model = None
    if evaluate_model is not None:
        stamps.append(evaluate_model("tiny", EvaluationSettings(trials=2))[1])

    index = build_report(folder)
    assert index == folder.root / "report" / "index.html"
    page = index.read_text()
    out = index.parent
    expected = set(TRAINING_PNGS) | {f"evaluation-{stamp}.png" for stamp in stamps}
    for name in expected:
        _png_ok(out / name)
    video = f"evaluation-{stamps[0]}-video.gif"
    assert (out / video).is_file()
    assert expected | {video} <= _referenced(page)
    assert all((out / name).is_file() for name in _referenced(page)), "the page links a missing file"
    for heading in ("Training", "Trajectories", "Action usage", "Reward by track position", "Evaluations"):
        assert f"<h2>{heading}</h2>" in page
    # The hand-made trial table: lap 12.5 s, gap 12.5 / 5.0, the off-track trial without a lap time.
    assert "<td>12.500</td>" in page and "<td>x2.500</td>" in page and "<td>off track</td>" in page
    assert "the race line driven from rest takes 5.500 s (x1.100)" in page  # trials start at rest
    assert "No evaluation yet" not in page


def test_report_without_evaluations_through_the_cli(home, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    source = model_folder("tiny").root
    copy = tmp_path / "copy"
    shutil.copytree(source, copy, ignore=shutil.ignore_patterns("evaluation*", "report"))
    out = tmp_path / "out"
    assert main(["report", str(copy), "--out", str(out), "--iterations", "2"]) == 0
    assert capsys.readouterr().out.strip() == str(out / "index.html")
    page = (out / "index.html").read_text()
    for name in TRAINING_PNGS:
        _png_ok(out / name)
    assert _referenced(page) == set(TRAINING_PNGS)
    assert "No evaluation yet" in page
    assert "iterations 2-3" in page


def test_report_cli_refuses_unknown_models(home, monkeypatch, capsys):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    assert main(["report", "no-such-model"]) == 2
    assert "no model named 'no-such-model'" in capsys.readouterr().err


def test_trajectory_segments_join_only_consecutive_steps_of_one_episode(home, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    folder = model_folder("tiny")
    trace = load_training_traces(folder, traced_iterations(folder))
    segments, speeds, _ = _episode_segments(trace, max_points=10**6)
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    # One decision at 15 Hz moves the car a few cm; a segment across episodes would span metres.
    assert segments.shape[0] == trace.size - len(np.unique(trace.episode))
    assert lengths.max() < 0.35  # 4 m/s for 1/15 s is 0.27 m
    # mean commanded speed of the segment's two steps: within the default action space's 1.33..4 m/s
    assert speeds.min() >= 1.33 - 1e-9 and speeds.max() <= 4.0 + 1e-9


def test_a_broken_summary_is_reported_not_fatal(home, monkeypatch, tmp_path):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    copy = tmp_path / "broken"
    shutil.copytree(model_folder("tiny").root, copy, ignore=shutil.ignore_patterns("evaluation*", "report"))
    from laplab.store.layout import ModelFolder
    folder = ModelFolder(copy)
    stamp = folder.new_evaluation()
    (folder.evaluation_dir(stamp) / "summary.json").write_text("{not json")
    evaluation = load_evaluations(folder)[0]
    assert evaluation.trace is None and evaluation.trials == ()
    assert "summary.json: not valid JSON" in evaluation.problems[0]
    page = build_report(folder, tmp_path / "out").read_text()
    assert "not valid JSON" in page and "This evaluation has no simtrace" in page
