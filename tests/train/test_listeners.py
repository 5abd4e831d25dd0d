"""The trainer reports to listeners and writes nothing itself; learners share one interface."""

from __future__ import annotations

import inspect
from dataclasses import replace

import numpy as np
import pytest

from laplab.agents.learner import Learner, build_learner
from laplab.env.metadata import metadata_from_dict
from laplab.env.spec import model_spec
from laplab.reward.loader import load_reward_function
from laplab.track.registry import load_track
from laplab.train import policy as policy_module
from laplab.train import trainer as trainer_module
from laplab.train.config import TrainConfig
from laplab.train.events import CheckpointReady, IterationEpisodes, IterationReport, PosesFrame
from laplab.train.trainer import Trainer

CONTINUOUS = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 1.5}},
              "action_space_type": "continuous", "training_algorithm": "sac"}


class Recorder:
    def __init__(self):
        self.events = []

    def on_poses(self, frame):
        self.events.append(("poses", frame))

    def on_episodes(self, episodes):
        self.events.append(("episodes", episodes))

    def on_checkpoint(self, checkpoint):
        self.events.append(("checkpoint", checkpoint))

    def on_iteration(self, report):
        self.events.append(("iteration", report))


class IterationsOnly:  # a listener may implement any subset
    def __init__(self):
        self.reports = []

    def on_iteration(self, report):
        self.reports.append(report.iteration)


def test_a_trainer_without_a_folder_reports_everything_to_its_listeners(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    base = TrainConfig(track="oval", max_episodes=4)
    config = replace(base, hyperparameters=replace(base.hyper(), num_episodes_between_training=2, batch_size=32,
                                                   num_epochs=3))
    track = load_track("oval")
    recorder, iterations = Recorder(), IterationsOnly()  # given when it is built, heard in that order
    trainer = Trainer(config, load_reward_function(config_reward()), track, listeners=(recorder, iterations))
    assert trainer.folder is None and trainer.lock is None and trainer.collector is None
    trainer.save_initial_checkpoint()
    result = trainer.run()
    assert result.iterations == 2 and iterations.reports == [1, 2]
    kinds = [kind for kind, _ in recorder.events]
    assert kinds[0] == "checkpoint" and recorder.events[0][1].iteration == 0
    per_iteration = [k for k in kinds[1:] if k != "poses"]
    assert per_iteration == ["episodes", "checkpoint", "iteration"] * 2
    poses = [event for kind, event in recorder.events if kind == "poses"]
    laps = [p for p in poses if p.evaluation]  # the evaluation laps are shown too, marked as such
    poses = [p for p in poses if not p.evaluation]
    assert all(isinstance(p, PosesFrame) and p.poses.shape == (2, 3) for p in poses)
    assert {p.iteration for p in laps} == {1, 2} and all(p.poses.shape == (config.eval_episodes, 3) for p in laps)
    first = [p for p in poses if p.iteration == 1]
    assert len(first) > 0 and np.allclose(np.diff([p.sim_time for p in first]), 1 / 15)
    episodes = [e for kind, e in recorder.events if kind == "episodes"]
    assert isinstance(episodes[1], IterationEpisodes) and episodes[1].first_episode == 2
    assert set(episodes[1].training_trace()["episode"].tolist()) == {2, 3}
    checkpoint = [e for kind, e in recorder.events if kind == "checkpoint"][-1]
    assert isinstance(checkpoint, CheckpointReady) and checkpoint.iteration == 2
    checkpoint.write(tmp_path / "c.ckpt")
    assert (tmp_path / "c.ckpt").stat().st_size > 0
    assert isinstance([e for kind, e in recorder.events if kind == "iteration"][0], IterationReport)
    assert not (tmp_path / "home").exists()  # the trainer itself wrote no file


def config_reward():
    from laplab.env.vector import DEFAULT_REWARD
    return DEFAULT_REWARD


@pytest.mark.parametrize("metadata", [{}, CONTINUOUS])
def test_learners_share_one_interface(metadata):
    spec = model_spec(metadata_from_dict(metadata))
    learner = build_learner(spec, TrainConfig().hyper(), seed=0)
    assert isinstance(learner, Learner) and learner.algorithm == spec.algorithm
    obs = np.zeros((3, *spec.observation_space.shape), np.float32)
    step = learner.act(obs, deterministic=True)
    assert len(step.env_action) == 3 and learner.values(obs).shape == (3,)
    other = build_learner(spec, TrainConfig().hyper(), seed=1)
    other.load_weights(learner.state_dict())
    np.testing.assert_allclose(other.act(obs, True).env_action, step.env_action)


def test_trainer_and_policy_loader_hold_no_algorithm_branches():
    for module in (trainer_module, policy_module):
        source = inspect.getsource(module)
        for word in ("PPOLearner", "SACLearner", "isinstance(", "hasattr("):
            assert word not in source, f"{module.__name__} mentions {word}"
