"""Honest time limits (learning and evaluation stop at the limit, the model stays whole), phase
progress events and the terminal lines they make, compact checkpoints with one resume state."""

from __future__ import annotations

import io
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from rich.console import Console

from laplab.reward.loader import load_reward_function
from laplab.store.checkpoints import CheckpointStore
from laplab.track.registry import load_track
from laplab.train.config import ConfigError, TrainConfig, parse_duration
from laplab.train.events import PhaseProgress
from laplab.train.jobs import create_training, resume_training
from laplab.train.trainer import Trainer

REWARD = "laplab/reward/examples/follow_centerline.py"


pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py


def _config(**hyper) -> TrainConfig:
    base = TrainConfig(track="oval", max_episodes=8, reward_path=REWARD)
    return replace(base, hyperparameters=replace(base.hyper(), **{
        "num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3, **hyper}))


class Progress:
    def __init__(self):
        self.events: list[PhaseProgress] = []

    def on_progress(self, progress):
        self.events.append(progress)


def _trainer(config: TrainConfig, **collaborators) -> Trainer:
    return Trainer(config, load_reward_function(config.reward_path), load_track(config.track), **collaborators)


def test_progress_events_cover_collection_learning_and_evaluation(monkeypatch):
    monkeypatch.setattr("laplab.train.trainer.PROGRESS_INTERVAL_S", 0.0)  # every event, for the test
    trainer = _trainer(_config())
    progress = Progress()
    trainer.subscribe(progress)
    trainer.run()
    first = [p for p in progress.events if p.iteration == 1]
    assert [p.phase for p in first][0] == "collect" and first[0].done == 0 and first[0].total == 2
    phases = [p.phase for p in first]
    assert phases.index("learn") > max(i for i, p in enumerate(phases) if p == "collect")
    assert phases[-1] == "evaluate"
    collected = [p.done for p in first if p.phase == "collect"]
    assert collected == sorted(collected) and collected[-1] == 2  # episodes done / num_episodes_between_training
    learned = [p for p in first if p.phase == "learn" and p.total]
    assert learned and learned[-1].done == learned[-1].total  # minibatches done / planned
    assert all(p.env_steps > 0 for p in first if p.phase == "collect" and p.done)


def test_progress_events_are_throttled_to_about_one_a_second():
    trainer = _trainer(_config())
    progress = Progress()
    trainer.subscribe(progress)
    started = time.perf_counter()
    trainer.run()
    elapsed = time.perf_counter() - started
    forced = 3 * 4  # each iteration forces one event per phase start (collect, learn, evaluate)
    assert len(progress.events) <= forced + elapsed + 1


def test_the_time_limit_stops_learning_midway_and_keeps_the_partly_trained_model(monkeypatch):
    monkeypatch.setattr("laplab.train.trainer.PROGRESS_INTERVAL_S", 0.0)
    trainer = _trainer(_config(num_epochs=10, batch_size=32))
    stop_now = []

    class StopWhenLearning:
        def on_progress(self, progress):
            if progress.phase == "learn" and progress.done >= 2:
                stop_now.append(True)

    checkpoints = []
    trainer.subscribe(StopWhenLearning())
    trainer.subscribe(type("C", (), {"on_checkpoint": lambda self, c: checkpoints.append(c)})())
    reports = []
    result = trainer.run(callbacks=(reports.append,), should_stop=lambda: bool(stop_now))
    assert result.stop_reason == "stopped" and result.iterations == 1
    assert reports[0].partial and reports[0].eval_episodes == 0
    assert reports[0].eval_progress is None  # not evaluated: no 0 % plunge at the end of the graph
    assert reports[0].to_dict()["eval_progress"] is None
    assert reports[0].losses["num_minibatches"] == 2  # stopped after 2 of 10 x ceil(steps / 32)
    assert checkpoints[-1].iteration == 1 and checkpoints[-1].metric is None


def test_a_small_max_time_is_kept_with_a_complete_model(laplab_home):
    # a STATE job whose iteration takes longer than the whole budget (many episodes, 10 epochs)
    config = replace(_config(num_episodes_between_training=40, num_epochs=10, batch_size=32),
                     max_time_s=2.0, max_episodes=10_000)
    trainer = create_training("limit", config)
    started = time.perf_counter()
    result = trainer.run()
    elapsed = time.perf_counter() - started
    assert result.stop_reason == "max_time"
    assert elapsed <= 2.0 + 15  # the last gradient step or simulation step (the issue allows 15 s), not the iteration
    trainer.close()
    store = CheckpointStore(trainer.folder)
    state = torch.load(store.resolve("last"), weights_only=True)
    assert "learner" in state and "optimizer" not in state["learner"]
    resumed = resume_training("limit", max_time_s=1.0)
    assert resumed.iteration == result.iterations
    resumed.close()


def test_only_the_last_checkpoint_carries_the_resume_state(laplab_home):
    config = replace(_config(), max_episodes=6)
    trainer = create_training("compact", config)
    trainer.run()
    trainer.close()
    store = CheckpointStore(trainer.folder)
    names = store.names()
    assert len(names) == 4  # 0, 1, 2, 3
    resume_files = sorted(p.name for p in trainer.folder.model_dir.glob("*.resume"))
    assert resume_files == [store.last().name + ".resume"]
    for name in names:
        learner = torch.load(trainer.folder.model_dir / name, weights_only=True)["learner"]
        assert "optimizer" not in learner and "model" in learner
    extra = torch.load(store.resume_path(store.last().name), weights_only=True)["learner"]
    assert set(extra) == {"optimizer"}
    resumed = resume_training("compact", max_episodes=8)
    optimizer = resumed.learner.optimizer.state_dict()
    assert optimizer["state"]  # Adam's moments came back from the resume state, bit for bit
    saved = trainer.learner.optimizer.state_dict()["state"]
    assert saved.keys() == optimizer["state"].keys()
    for index, moments in saved.items():
        for key, value in moments.items():
            assert torch.equal(optimizer["state"][index][key], value), (index, key)
    resumed.run()
    resumed.close()
    assert resumed.iteration == 4


def test_the_printer_shows_the_phase_within_seconds():
    from laplab.train.progress import ProgressPrinter
    class Folder:
        name = "m"
        root = "."
    trainer = _trainer(_config(), folder=Folder())
    out = io.StringIO()
    printer = ProgressPrinter(Console(file=out, width=200), trainer)
    printer.on_progress(PhaseProgress(1, "collect", 0, 20, 0, 0.1))
    printer.on_progress(PhaseProgress(1, "collect", 3, 20, 400, 2.0))  # within 5 s of the last line: quiet
    text = out.getvalue()
    assert "iteration 1: collecting, episodes 0/20" in text and "3/20" not in text
    printer._last_line -= 6
    printer.on_progress(PhaseProgress(1, "learn", 120, 800, 5000, 9.0))
    assert "iteration 1: learning, gradient steps 120/800, 5000 env steps" in out.getvalue()


def test_a_stop_before_the_first_minibatch_still_writes_the_iteration_log_and_report(laplab_home, tmp_path):
    # the limit cut learning before any gradient step: the losses are not numbers, written as JSON null
    from laplab.analysis.loaders import load_training_history
    from laplab.analysis.report import build_report
    from laplab.console.catalog import ModelCatalog
    from laplab.store.atomic import read_json

    trainer = create_training("cut", _config())
    stop_now = []

    class StopAtLearning:
        def on_progress(self, progress):
            if progress.phase == "learn":
                stop_now.append(True)

    trainer.subscribe(StopAtLearning())
    reports = []
    result = trainer.run(callbacks=(reports.append,), should_stop=lambda: bool(stop_now))
    trainer.close()
    assert result.error is None and result.iterations == 1 and reports[0].partial
    assert reports[0].losses["num_minibatches"] == 0
    row = read_json(trainer.folder.metrics_dir / "laplab-iterations.json")["iterations"][0]
    assert row["losses"]["policy_loss"] is None and row["mean_reward"] == reports[0].mean_reward
    assert row["eval_progress"] is None  # "not evaluated", never 0 %
    from laplab.train.progress import ProgressPrinter
    out = io.StringIO()
    ProgressPrinter(Console(file=out, width=200), trainer)(reports[0])
    assert "  0/0   -% " in out.getvalue() and "not evaluated" in out.getvalue()
    history = load_training_history(trainer.folder)
    assert history.size == 1 and np.isnan(history.losses.get("policy_loss", [np.nan])[0])
    assert build_report(trainer.folder, out_dir=tmp_path / "report").is_file()
    assert ModelCatalog.iterations("cut")[0]["iteration"] == 1


def test_durations_read_as_the_cli_writes_them():
    assert [parse_duration(text) for text in ("90s", "20m", "1.5h", "45", " 2 min ")] == [90, 1200, 5400, 45, 120]
    for text, message in (("-5", "must be positive"), ("0m", "must be positive"), ("abc", "write e.g. 90s"),
                          ("5 days", "write e.g. 90s")):
        with pytest.raises(ConfigError, match=message):
            parse_duration(text)
