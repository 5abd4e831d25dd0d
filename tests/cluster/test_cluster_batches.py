"""Merging the workers' episodes, the on-policy check and the job checks (no Ray needed)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from laplab.cluster.batches import merge_batches, tag
from laplab.cluster.collector import StalePolicyError, check_reachable, require_policy_version
from laplab.cluster.launch import check_workers, worker_setups
from laplab.cluster.worker import split_cars
from laplab.train.collect import EpisodeBatch
from laplab.train.config import ConfigError, TrainConfig, parse_track_spec
from laplab.train.errors import JobError


def fake_batch(steps: int, cars: int, obs_dim: int = 3) -> EpisodeBatch:
    rng = np.random.default_rng(steps * 10 + cars)
    t = lambda dtype=np.float32: rng.random((steps, cars)).astype(dtype)  # noqa: E731
    valid = np.ones((steps, cars), bool)
    trace = {"episode": np.repeat(np.arange(cars), steps), "X": rng.random(steps * cars)}
    return EpisodeBatch(observations=rng.random((steps, cars, obs_dim)).astype(np.float32),
                        actions=rng.integers(0, 5, (steps, cars)), log_probs=t(), values=t(), rewards=t(),
                        terminated=np.zeros((steps, cars), bool), truncated=np.zeros((steps, cars), bool),
                        valid=valid, bootstrap_values=t(), total_reward=rng.random(cars),
                        progress=rng.random(cars) * 100, status=np.full(cars, 3), steps=np.full(cars, steps),
                        lap_time=np.full(cars, np.nan), duration=np.full(cars, steps / 15), trace=trace,
                        wall_seconds=0.5)


def test_merge_pads_to_the_longest_episode_with_invalid_steps():
    a, b = tag(fake_batch(5, 2), 0, "A", 3), tag(fake_batch(8, 3), 1, "B@reversed", 3)
    merged = merge_batches([a, b])
    assert merged.valid.shape == (8, 5) and merged.observations.shape == (8, 5, 3)
    assert merged.valid[:5, :2].all() and not merged.valid[5:, :2].any() and merged.valid[:, 2:].all()
    assert np.array_equal(merged.rewards[:5, :2], a.rewards) and (merged.rewards[5:, :2] == 0).all()
    assert merged.env_steps == 5 * 2 + 8 * 3
    assert merged.worker.tolist() == [0, 0, 1, 1, 1]
    assert merged.track.tolist() == ["A", "A", "B@reversed", "B@reversed", "B@reversed"]
    assert sorted(set(merged.trace["episode"].tolist())) == [0, 1, 2, 3, 4]  # numbered across workers
    merged.rewards[0, 0] = 99.0  # a copy: pieces from Ray's object store are read-only


def test_merge_of_dict_observations():
    pieces = []
    for steps, cars in ((2, 1), (4, 2)):
        piece = fake_batch(steps, cars)
        piece.observations = {"CAMERA": np.ones((steps, cars, 2, 2), np.uint8), "STATE": piece.observations}
        pieces.append(piece)
    merged = merge_batches(pieces)
    assert merged.observations["CAMERA"].shape == (4, 3, 2, 2)
    assert merged.observations["CAMERA"][2:, 0].sum() == 0


def test_a_stale_policy_version_is_refused():
    merged = merge_batches([tag(fake_batch(3, 2), 0, "A", 4), tag(fake_batch(3, 2), 1, "A", 3)])
    with pytest.raises(StalePolicyError, match="version"):
        require_policy_version(merged, 4)
    require_policy_version(merge_batches([tag(fake_batch(3, 2), 0, "A", 4)]), 4)


def test_cars_are_shared_and_tracks_given_round_robin():
    assert split_cars(20, 3) == [7, 7, 6]
    config = replace(TrainConfig(), tracks=("classic_2018", "reInvent2019_track@reversed"), workers=3)
    assert config.track == "classic_2018" and config.reverse is False
    setups = worker_setups(config, "def reward_function(params):\n    return 1.0\n", "r.py", 3)
    assert [(s.track, s.reverse) for s in setups] == [("classic_2018", False), ("reInvent2019_track", True),
                                                      ("classic_2018", False)]
    assert [s.start_offset for s in setups] == [0, 7, 14]
    assert len({s.seed for s in setups}) == 3
    with pytest.raises(JobError, match="--workers 2"):
        check_workers(replace(config, workers=1), 1)


def test_config_with_tracks_round_trips_and_old_configs_load():
    config = replace(TrainConfig(), tracks=("a", "b@reversed"), workers=2)
    again = TrainConfig.from_dict(config.to_dict())
    assert again.tracks == ("a", "b@reversed") and again.workers == 2
    assert again.training_tracks() == [("a", False), ("b", True)]
    old = TrainConfig().to_dict()
    del old["tracks"], old["workers"]
    assert TrainConfig.from_dict(old).training_tracks() == [("classic_2018", False)]
    with pytest.raises(ConfigError, match="@reversed"):
        parse_track_spec("a@backwards")
    with pytest.raises(ConfigError, match="workers"):
        TrainConfig(workers=0)


def test_an_unreachable_cluster_is_a_clear_error():
    import socket
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(JobError, match="cannot reach the Ray cluster at 127.0.0.1"):
        check_reachable(f"127.0.0.1:{port}", timeout_s=2)
    with pytest.raises(JobError, match="HOST:PORT"):
        check_reachable("nonsense")


def test_device_cuda_without_a_gpu_is_a_clear_error():
    from laplab.cluster.launch import resolve_device
    torch = pytest.importorskip("torch")
    assert resolve_device("cpu") == "cpu"
    with pytest.raises(JobError, match="cpu or cuda"):
        resolve_device("tpu")
    if torch.cuda.is_available():
        assert resolve_device("cuda") == "cuda"
    else:
        with pytest.raises(JobError, match="no usable GPU"):
            resolve_device("cuda")


def test_a_folder_resumed_with_several_workers_moves_to_the_multi_worker_layout(tmp_path):
    from laplab.store.layout import ModelFolder
    from laplab.train.recorder import ModelFolderRecorder
    folder = ModelFolder(tmp_path / "m").create()
    for k in (0, 1):
        folder.training_simtrace(k).write_text("episode\n")
    ModelFolderRecorder(folder, iteration=2, episodes=40, workers=1)
    assert folder.simtrace_workers() == [] and folder.list_training_iterations() == [0, 1]
    ModelFolderRecorder(folder, iteration=2, episodes=40, workers=3)
    assert not folder.training_simtrace_dir.exists()  # else deepracer-utils reads it as single-worker
    assert folder.simtrace_workers() == [0] and folder.list_training_iterations() == [0, 1]
    assert folder.training_simtrace_files(1) == [folder.worker_training_simtrace(0, 1)]
    folder.worker_training_simtrace(2, 1).parent.mkdir(parents=True)
    folder.worker_training_simtrace(2, 1).write_text("episode\n")
    ModelFolderRecorder(folder, iteration=1, episodes=20, workers=1)  # resumed from checkpoint 1
    assert folder.list_training_iterations() == [0]  # iteration 1 of every worker dropped


def test_a_multi_track_job_without_enough_workers_writes_nothing(tmp_path, monkeypatch, capsys):
    from laplab.cli import main
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    code = main(["train", "--name", "mt", "--track", "classic_2018", "--track", "classic_2018@reversed"])
    assert code == 2 and "add --workers 2" in capsys.readouterr().err
    assert not (tmp_path / "home" / "models" / "mt").exists()
