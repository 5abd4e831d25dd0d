"""Models in an S3-compatible store (moto's server on 127.0.0.1): train, then every reader, from the bucket."""

from __future__ import annotations

import json
import tarfile


from laplab.cli import main
from tests.s3.conftest import keys


def laplab(*args) -> int:
    return main([str(a) for a in args])


def test_train_evaluate_report_export_clone_resume_leaderboard_from_the_store(store_url, s3_env, tiny_hp,
                                                                                tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert laplab("train", "--name", "m1", "--track", "oval", "--hyperparameters", tiny_hp, "--max-episodes", 4,
                  "--quiet", "--store", store_url) == 0
    stored = keys(s3_env, store_url)
    for required in ("m1/model/model_metadata.json", "m1/model/deepracer_checkpoints.json", "m1/ip/hyperparameters.json",
                     "m1/reward_function.py", "m1/laplab.json", "m1/metrics/TrainingMetrics.json",
                     "m1/training-simtrace/0-iteration.csv", "m1/training-simtrace/1-iteration.csv"):
        assert required in stored, sorted(stored)
    assert not any("/." in key or key.startswith(".") for key in stored)  # no lock, no temporaries left
    index = json.loads(s3_env.get_object(Bucket="laplab-test", Key=store_url.split("/", 3)[3] +
                                         "/m1/model/deepracer_checkpoints.json")["Body"].read())
    assert f"m1/model/{index['last_checkpoint']['name']}" in stored
    assert f"m1/model/{index['best_checkpoint']['name']}" in stored
    import os
    from pathlib import Path
    home = Path(os.environ["LAPLAB_HOME"])
    assert not (home / "models").exists()  # nothing in the local models folder
    assert not any((home / "cache" / "store").iterdir())  # the working copy is gone

    # evaluate: its evaluation lands in the bucket
    assert laplab("evaluate", "m1", "--trials", 1, "--store", store_url) == 0
    stored = keys(s3_env, store_url)
    stamps = {k.split("/")[1] for k in stored if k.startswith("m1/evaluation-")}
    assert len(stamps) == 1
    stamp = stamps.pop()
    assert f"m1/{stamp}/evaluation-simtrace/0-iteration.csv" in stored
    assert f"m1/{stamp}/summary.json" in stored
    assert f"m1/metrics/evaluation/{stamp}.json" in stored
    capsys.readouterr()
    assert laplab("evaluate", "m1", "--list", "--json", "--store", store_url) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [e["stamp"] for e in listed["evaluations"]] == [stamp.removeprefix("evaluation-")]

    # leaderboard from the bucket
    assert laplab("leaderboard", "--json", "--store", store_url) == 0
    boards = json.loads(capsys.readouterr().out)
    assert [e["model"] for board in boards for e in board["entries"]] == ["m1"]

    # report, written to ./m1-report by default
    assert laplab("report", "m1", "--iterations", 1, "--store", store_url) == 0
    assert (tmp_path / "m1-report" / "index.html").is_file()

    # export the archive straight from the bucket
    assert laplab("export", "m1", "--out", tmp_path / "m1.tar.gz", "--store", store_url) == 0
    with tarfile.open(tmp_path / "m1.tar.gz") as archive:
        assert any(name.endswith(".ckpt") for name in archive.getnames())

    # clone: source and new model both in the store
    assert laplab("clone", "m1", "m2", "--max-episodes", 2, "--quiet", "--store", store_url) == 0
    stored = keys(s3_env, store_url)
    assert "m2/model/deepracer_checkpoints.json" in stored and "m2/training-simtrace/0-iteration.csv" in stored

    # resume m1 for two more episodes: the iteration count continues in the bucket
    monkeypatch.setenv("LAPLAB_STORE", store_url)  # the environment variable works like --store
    assert laplab("train", "--resume", "m1", "--max-episodes", 6, "--quiet") == 0
    stored = keys(s3_env, store_url)
    assert "m1/training-simtrace/2-iteration.csv" in stored
    index = json.loads(s3_env.get_object(Bucket="laplab-test", Key=store_url.split("/", 3)[3] +
                                         "/m1/model/deepracer_checkpoints.json")["Body"].read())
    assert index["last_checkpoint"]["name"].startswith("3_Step-")
    checkpoints = sorted(k for k in stored if k.startswith("m1/model/") and k.endswith(".ckpt"))
    assert f"m1/model/{index['last_checkpoint']['name']}" in checkpoints
    assert len(checkpoints) <= 4  # 4 in all, the best among them: pruned checkpoints are deleted from the bucket too
