"""Exports carry weights only unless the full state is asked for; both kinds import and resume."""

from __future__ import annotations

import tarfile
from dataclasses import replace

import pytest
import torch

from laplab.store.archive import ArchiveError
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.train.archive import export_model_archive, import_model_archive
from laplab.train.config import TrainConfig
from laplab.train.jobs import create_training, resume_training


def _names(path) -> set[str]:
    with tarfile.open(path, "r:gz") as tar:
        return set(tar.getnames())


def test_weights_only_and_full_state_exports(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    base = TrainConfig(track="oval")
    config = replace(base, max_episodes=4, hyperparameters=replace(
        base.hyper(), num_episodes_between_training=2, batch_size=32, num_epochs=3))
    trainer = create_training("src", config)
    trainer.run()
    trainer.close()
    last = CheckpointStore(model_folder("src")).last().name

    plain = export_model_archive("src", "last", tmp_path / "plain.tar.gz")
    assert f"model/{last}" in _names(plain) and not any(n.endswith(".resume") for n in _names(plain))
    full = export_model_archive("src", "last", tmp_path / "full.tar.gz", full_state=True)
    assert f"model/{last}.resume" in _names(full)
    assert full.stat().st_size > plain.stat().st_size
    with pytest.raises(ArchiveError, match="only the last checkpoint"):
        export_model_archive("src", "0_Step-0.ckpt", tmp_path / "x.tar.gz", full_state=True)
    assert not (tmp_path / "x.tar.gz").exists()

    import_model_archive(full, "moved")
    moved = resume_training("moved", max_episodes=6, trust_reward=True)
    assert moved.learner.optimizer.state_dict()["state"]  # Adam's moments travelled
    moved.close()
    import_model_archive(plain, "copied")
    copied = resume_training("copied", max_episodes=6, trust_reward=True)
    assert not copied.learner.optimizer.state_dict()["state"]  # weights only: a fresh optimizer
    for a, b in zip(copied.learner.model.parameters(), moved.learner.model.parameters()):
        assert torch.equal(a, b)
    copied.run()
    copied.close()
    assert copied.iteration == 3
