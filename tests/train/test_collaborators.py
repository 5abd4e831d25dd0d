"""A trainer is given its collaborators (folder, lock, listeners, collector, evaluator) when it is
built, owns the lock and the collector (``close``), and a job's worker launcher is asked before
anything is written and started before the trainer exists."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from laplab.cluster.evaluate import MultiTrackEvaluator
from laplab.reward.loader import load_reward_function
from laplab.store.layout import model_folder
from laplab.store.lock import is_locked
from laplab.track.registry import load_track
from laplab.train.collect import collect_episodes
from laplab.train.config import TrainConfig
from laplab.train.errors import JobError
from laplab.train.jobs import create_training, create_training_in_place, resume_training
from laplab.train.trainer import Trainer

REPO = Path(__file__).resolve().parents[2]
REWARD = str(REPO / "laplab/reward/examples/follow_centerline.py")


pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py


def _config(**changes) -> TrainConfig:
    base = TrainConfig(track="oval", max_episodes=2, reward_path=REWARD)
    hyper = replace(base.hyper(), num_episodes_between_training=2, batch_size=32, num_epochs=3)
    return replace(base, hyperparameters=hyper, **changes)


class InProcessCollector:
    """A collector doing what the trainer would, counting its calls; ``close_fails``: its close raises."""

    def __init__(self, close_fails: bool = False):
        self.calls, self.closed, self.close_fails = [], 0, close_fails

    def collect(self, trainer, should_abort, on_progress=None, on_poses=None):
        self.calls.append((trainer.iteration, trainer.episodes))

        def act(obs):
            step = trainer.learner.act(obs, False)
            return step.action, step.env_action, step.log_prob, step.value
        return collect_episodes(trainer.stepper, trainer.observations, act, trainer.learner.values,
                                should_abort=should_abort)

    def close(self) -> None:
        self.closed += 1
        if self.close_fails:
            raise RuntimeError("the workers would not stop")


class CountingEvaluator(MultiTrackEvaluator):
    def __init__(self, *args):
        super().__init__(*args)
        self.calls = 0

    def evaluate(self, policy):
        self.calls += 1
        return super().evaluate(policy)


class Lock:
    def __init__(self, events: list):
        self.events = events

    def release(self) -> None:
        self.events.append("lock released")


def test_a_trainer_uses_the_collector_and_evaluator_it_was_given_and_closes_what_it_owns():
    config = _config()
    reward_fn = load_reward_function(REWARD)
    collector = InProcessCollector()
    evaluator = CountingEvaluator(config, reward_fn, [("oval", False)])
    events: list = []
    with Trainer(config, reward_fn, load_track("oval"), lock=Lock(events), collector=collector,
                 evaluator=evaluator) as trainer:
        reports = []
        result = trainer.run(callbacks=(reports.append,))
        assert events == [] and collector.closed == 0  # nothing is closed while the job runs
    assert result.error is None and result.iterations == 1 and result.episodes == 2
    assert collector.calls == [(0, 0)] and evaluator.calls == 1
    assert reports[0].eval_progress_by_track.keys() == {"oval"}  # the evaluator's tagged laps
    assert collector.closed == 1 and events == ["lock released"]
    trainer.close()  # once only
    assert collector.closed == 1 and events == ["lock released"]


def test_the_lock_is_released_even_when_the_collector_fails_to_close():
    config = _config()
    events: list = []
    trainer = Trainer(config, load_reward_function(REWARD), load_track("oval"), lock=Lock(events),
                      collector=InProcessCollector(close_fails=True))
    with pytest.raises(RuntimeError, match="would not stop"):
        trainer.close()
    assert events == ["lock released"]


class Launcher:
    """A worker launcher recording when it is asked and what it is given."""

    def __init__(self, refuse: bool = False, fail: bool = False):
        self.refuse, self.fail = refuse, fail
        self.checked, self.started, self.collector = [], [], InProcessCollector()

    def check(self, config, reward_fn) -> None:
        self.checked.append((config.workers, reward_fn.path, model_folder("m").exists()))
        if self.refuse:
            raise JobError("--workers 9 is more than the 2 episodes of an iteration")

    def start(self, config, reward_fn, folder, iteration):
        self.started.append((folder.root, iteration, folder.model_metadata.is_file(), is_locked(folder.root)))
        if self.fail:
            raise JobError("the rollout workers could not start: no cluster")
        return self.collector, None


def test_a_job_checks_its_workers_before_writing_and_starts_them_before_its_trainer():
    launcher = Launcher()
    with create_training("m", _config(), launcher=launcher) as trainer:
        assert launcher.checked == [(1, REWARD, False)]  # nothing written when it was asked
        assert launcher.started == [(model_folder("m").root, 0, True, True)]  # the folder written and locked
        assert trainer.collector is launcher.collector and trainer.folder.root == model_folder("m").root
        assert trainer.run().iterations == 1 and launcher.collector.calls == [(0, 0)]
    assert launcher.collector.closed == 1 and not is_locked(model_folder("m").root)
    again = Launcher()
    with resume_training("m", max_episodes=4, workers=2, launcher=again) as resumed:
        assert again.checked == [(2, str(model_folder("m").reward_function), True)]
        assert again.started == [(model_folder("m").root, 1, True, True)]  # at the iteration it resumes
        assert resumed.run().iterations == 2 and again.collector.calls == [(1, 2)]
    assert again.collector.closed == 1 and json.loads(model_folder("m").laplab_config.read_text())["workers"] == 2


def test_workers_that_are_refused_or_fail_to_start_leave_no_model_and_no_lock():
    with pytest.raises(JobError, match="more than the 2 episodes"):
        create_training("m", _config(), launcher=Launcher(refuse=True))
    assert not model_folder("m").exists() and not list(model_folder("m").root.parent.glob(".create-*"))
    with pytest.raises(JobError, match="could not start"):
        create_training("m", _config(), launcher=Launcher(fail=True))
    assert not model_folder("m").exists()  # a folder is whole (checkpoint 0) or absent: the name stays free
    model_folder("m").root.mkdir(parents=True)  # the console's confined job: a folder made empty for it
    with pytest.raises(JobError, match="could not start"):
        create_training_in_place("m", _config(), launcher=Launcher(fail=True))
    assert [p.name for p in model_folder("m").root.iterdir()] == [".laplab-job.lock"]
    assert not is_locked(model_folder("m").root)
    with create_training_in_place("m", _config()) as trainer:  # and the next job can use it
        assert trainer.collector is None and np.isfinite(trainer.run().elapsed_s)


def test_nothing_sets_a_trainers_collaborators_from_outside_or_probes_for_them():
    assigned = re.compile(r"\b\w*trainer\.(folder|lock|collector|evaluator|location|recorder)\s*=[^=]"
                          r"|getattr\(\s*\w*trainer\b")
    sources = [p for d in ("laplab", "bench", "tests") for p in (REPO / d).rglob("*.py") if p != Path(__file__)]
    offenders = [f"{p.relative_to(REPO)}:{n}" for p in sources
                 for n, line in enumerate(p.read_text().splitlines(), 1) if assigned.search(line)]
    assert not offenders, offenders
    assert assigned.search("trainer.folder = Folder()") and assigned.search("getattr(trainer, 'lock', None)")
