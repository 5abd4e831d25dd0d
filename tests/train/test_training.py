"""Tiny-budget training runs: folder layout, learning moved the numbers, immutability, clone, errors, resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest

from laplab.cli import main
from laplab.env.metadata import ModelMetadata
from laplab.store.checkpoints import CheckpointStore
from laplab.store.layout import model_folder
from laplab.store.simtrace import SIMTRACE_HEADER, read_simtrace
from laplab.train.config import TrainConfig
from laplab.train.jobs import JobError, clone_config, create_training
from laplab.train.trainer import load_checkpoint

SMALL_HP = {"num_episodes_between_training": 4, "batch_size": 32, "num_epochs": 3}
CONTINUOUS = {"action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 1.5}},
              "action_space_type": "continuous"}


pytestmark = pytest.mark.usefixtures("laplab_home")  # tests/train/conftest.py


def small_config(**changes) -> TrainConfig:
    hyper = {**TrainConfig().hyper().to_dict(), **SMALL_HP, **changes.pop("hyper", {})}
    meta = {**ModelMetadata().to_dict(), **changes.pop("meta", {})}
    return replace(TrainConfig(), hyperparameters=hyper, model_metadata=meta, max_time_s=120, **changes)


def check_layout(name: str, iterations: int) -> None:
    folder = model_folder(name)
    assert json.loads(folder.model_metadata.read_text())["sensor"]
    assert json.loads(folder.hyperparameters.read_text())["num_episodes_between_training"] == 4
    assert "def reward_function" in folder.reward_function.read_text()
    assert json.loads(folder.laplab_config.read_text())["track"] == "classic_2018"
    assert folder.list_training_iterations() == list(range(iterations))
    first = folder.training_simtrace(0).read_text().splitlines()
    assert first[0] == SIMTRACE_HEADER
    trace = read_simtrace(folder.training_simtrace(0))
    assert set(trace["episode"].tolist()) == {0, 1, 2, 3}
    metrics = json.loads(folder.training_metrics.read_text())["metrics"]
    training = [m for m in metrics if m["phase"] == "training"]
    assert len(training) == 4 * iterations
    assert [m["episode"] for m in training] == list(range(1, 4 * iterations + 1))
    checkpoints = json.loads(folder.deepracer_checkpoints.read_text())
    assert checkpoints["last_checkpoint"]["name"].startswith(f"{iterations}_Step-")
    assert len(CheckpointStore(folder).names()) <= 5  # the last 4 plus the best


@pytest.mark.parametrize("algorithm,meta,sensors", [
    ("clipped_ppo", {}, ("STATE",)),
    ("clipped_ppo", CONTINUOUS, ("STATE",)),
    ("sac", CONTINUOUS, ("STATE",)),
    ("clipped_ppo", {}, ("STATE", "SECTOR_LIDAR")),
    ("clipped_ppo", {}, ("FRONT_FACING_CAMERA",)),
    ("sac", CONTINUOUS, ("FRONT_FACING_CAMERA", "LIDAR")),
])
def test_tiny_training_runs_write_the_deepracer_layout(algorithm, meta, sensors):
    config = small_config(max_episodes=12, meta={**meta, "training_algorithm": algorithm, "sensor": list(sensors)})
    trainer = create_training("tiny", config)
    weights_before = [p.detach().clone() for p in _parameters(trainer.learner)]
    result = trainer.run()
    assert result.stop_reason == "max_episodes" and result.iterations == 3 and result.episodes == 12
    check_layout("tiny", 3)
    moved = [not np.allclose(a.numpy(), b.detach().numpy()) for a, b in zip(weights_before, _parameters(trainer.learner))]
    assert any(moved), "training did not change the network"


def _parameters(learner):
    module = learner.model if hasattr(learner, "model") else learner.actor
    return list(module.parameters())


def test_learning_improves_progress():
    hyper = {"num_episodes_between_training": 10, "num_epochs": 10, "batch_size": 64}
    trainer = create_training("learner", small_config(max_episodes=10**6, hyper=hyper))
    reports = []
    trainer.run(callbacks=(reports.append,), should_stop=lambda: len(reports) >= 20)
    first, last = reports[0], reports[-1]
    assert max(r.mean_progress for r in reports[-3:]) > first.mean_progress + 15, [r.mean_progress for r in reports]
    assert last.episodes == 200


def test_a_model_name_is_immutable():
    create_training("taken", small_config(max_episodes=4)).run()
    with pytest.raises(JobError, match="already exists"):
        create_training("taken", small_config())
    assert main(["train", "--name", "taken", "--max-time", "5s"]) == 2


def test_clone_keeps_action_space_and_starts_from_the_weights(tmp_path):
    source = create_training("source", small_config(max_episodes=4))
    source.run()
    config, weights = clone_config("source", {"max_episodes": 4, "track": "oval"})
    clone = create_training("clone", config, init_weights=weights)
    for a, b in zip(_parameters(source.learner), _parameters(clone.learner)):
        assert np.allclose(a.detach().numpy(), b.detach().numpy())
    assert clone.config.track == "oval"
    other = ModelMetadata().to_dict() | {"action_space": [{"steering_angle": 0, "speed": 1.0}]}
    with pytest.raises(JobError, match="action space"):
        clone_config("source", {"model_metadata": other})
    meta_file = tmp_path / "meta.json"
    meta_file.write_text(json.dumps(other))
    assert main(["clone", "source", "clone2", "--model-metadata", str(meta_file)]) == 2


def test_reward_function_failing_mid_training_stops_and_keeps_checkpoints(tmp_path):
    # fails 2000 calls into training: the validation sweep runs in a forked child (multiprocessing's),
    # whose calls this process's counter does not see
    reward = tmp_path / "reward_function.py"
    reward.write_text("import multiprocessing\nCALLS = [0]\ndef reward_function(params):\n"
                      "    if multiprocessing.parent_process() is None:\n        CALLS[0] += 1\n"
                      "    if CALLS[0] > 2000:\n        raise ValueError('boom at call %d' % CALLS[0])\n    return 1.0\n")
    trainer = create_training("faulty", small_config(reward_path=str(reward), max_episodes=10**6))
    result = trainer.run()
    assert result.stop_reason == "reward_error"
    assert "reward_function.py, line 7" in result.error and "boom" in result.error
    folder = model_folder("faulty")
    assert "boom" in folder.error_file.read_text()
    state = load_checkpoint(CheckpointStore(folder).resolve("last"))
    assert "learner" in state


def test_bad_reward_function_is_refused_before_anything_is_written(tmp_path):
    reward = tmp_path / "bad.py"
    reward.write_text("def reward_function(params):\n    return params['speeed']\n")
    assert main(["train", "--name", "bad", "--reward", str(reward), "--max-time", "5s"]) == 2
    assert not model_folder("bad").exists()


def test_bad_hyperparameters_name_the_key(tmp_path, capsys):
    hp = tmp_path / "hyperparameters.json"
    hp.write_text(json.dumps({"batch_size": 100}))
    assert main(["train", "--name", "hp", "--hyperparameters", str(hp)]) == 2
    assert "batch_size" in capsys.readouterr().err
    assert not model_folder("hp").exists()


def test_resume_after_sigkill_continues_the_iteration_count(laplab_home, tmp_path):
    hp = tmp_path / "hyperparameters.json"
    hp.write_text(json.dumps({**TrainConfig().hyper().to_dict(), **SMALL_HP}))
    env = {**os.environ, "LAPLAB_HOME": str(laplab_home)}
    cmd = [sys.executable, "-m", "laplab.cli", "train", "--name", "killed", "--hyperparameters", str(hp),
           "--max-time", "10m", "--quiet"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    folder = model_folder("killed")
    deadline = time.time() + 120
    while time.time() < deadline and len(folder.list_training_iterations()) < 2:
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    done = CheckpointStore(folder).last()
    assert done is not None and not done.name.startswith("0_"), proc.stderr.read().decode()
    iteration = int(done.name.split("_")[0])
    assert main(["train", "--resume", "killed", "--max-episodes", str(4 * (iteration + 2)), "--quiet"]) == 0
    last = CheckpointStore(folder).last()
    assert int(last.name.split("_")[0]) == iteration + 2
    assert folder.list_training_iterations() == list(range(iteration + 2))
    assert load_checkpoint(CheckpointStore(folder).resolve("last"))["iteration"] == iteration + 2


def test_sigterm_stops_gracefully_with_a_complete_model(laplab_home, tmp_path):
    env = {**os.environ, "LAPLAB_HOME": str(laplab_home)}
    proc = subprocess.Popen([sys.executable, "-m", "laplab.cli", "train", "--name", "termed", "--max-time", "10m"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    folder = model_folder("termed")
    deadline = time.time() + 120
    while time.time() < deadline and not folder.list_training_iterations():
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()
    assert b"stopped on request" in out
    assert load_checkpoint(CheckpointStore(folder).resolve("last"))["iteration"] >= 1


def test_deepracer_utils_reads_a_freshly_trained_model():
    logs = pytest.importorskip("deepracer.logs")
    create_training("utils", small_config(max_episodes=8)).run()
    folder = model_folder("utils")
    log = logs.DeepRacerLog(model_folder=str(folder.root))
    log.load()
    df = log.dataframe()
    assert set(df["iteration"].unique()) == {0, 1}
    assert df["episode"].nunique() == 8
    assert len(df) == sum(len(read_simtrace(folder.training_simtrace(i))["episode"]) for i in (0, 1))
    metrics = logs.TrainingMetrics(bucket=None, fname=str(folder.training_metrics))
    summary = metrics.getSummary()
    assert len(summary) >= 1


def test_default_hyperparameters_follow_the_sensor():
    from laplab.env.metadata import ModelMetadata
    state, camera = TrainConfig(), replace(TrainConfig(), model_metadata=replace(
        ModelMetadata(), sensors=("FRONT_FACING_CAMERA",)).to_dict())
    assert state.hyperparameters is None and state.hyper().num_epochs == 10  # the console's
    assert camera.hyper().num_epochs == 5  # deepracer-for-cloud's, for camera networks
    # laplab.json writes the values out, so a resumed job keeps them
    assert TrainConfig.from_dict(camera.to_dict()).hyperparameters.num_epochs == 5
    given = replace(camera, hyperparameters={**camera.hyper().to_dict(), "num_epochs": 8})
    assert given.hyper().num_epochs == 8
