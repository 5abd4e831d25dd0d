import json

import pytest

from laplab.store.checkpoints import CheckpointParams, CheckpointStore, checkpoint_name
from laplab.store.layout import ModelFolder


def _store(tmp_path, **params):
    return CheckpointStore(ModelFolder(tmp_path / "m"), CheckpointParams(**params))


def test_keeps_four_in_all_the_best_among_them(tmp_path):
    """As the simapp's NUM_MODELS_TO_KEEP: an older best takes one of the 4 places; a best among
    the newest 4 takes none."""
    store = _store(tmp_path)
    metrics = [10.0, 80.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    for iteration, metric in enumerate(metrics):
        store.save(f"weights {iteration}".encode(), iteration=iteration, steps=1000 * iteration, metric=metric)
    assert store.names() == ["1_Step-1000.ckpt", "4_Step-4000.ckpt", "5_Step-5000.ckpt", "6_Step-6000.ckpt"]
    store.save(b"weights 7", iteration=7, steps=7000, metric=90.0)
    assert store.names() == ["4_Step-4000.ckpt", "5_Step-5000.ckpt", "6_Step-6000.ckpt", "7_Step-7000.ckpt"]
    store.save(b"weights 8", iteration=8, steps=8000, metric=5.0)
    assert store.names() == ["5_Step-5000.ckpt", "6_Step-6000.ckpt", "7_Step-7000.ckpt", "8_Step-8000.ckpt"]
    store.save(b"weights 9", iteration=9, steps=9000, metric=5.0)
    assert store.names() == ["6_Step-6000.ckpt", "7_Step-7000.ckpt", "8_Step-8000.ckpt", "9_Step-9000.ckpt"]
    store.save(b"weights 10", iteration=10, steps=10000, metric=5.0)
    assert store.names() == ["7_Step-7000.ckpt", "8_Step-8000.ckpt", "9_Step-9000.ckpt", "10_Step-10000.ckpt"]
    store.save(b"weights 11", iteration=11, steps=11000, metric=5.0)
    assert store.names() == ["7_Step-7000.ckpt", "9_Step-9000.ckpt", "10_Step-10000.ckpt", "11_Step-11000.ckpt"]
    assert store.best().name == "7_Step-7000.ckpt"
    store = _store(tmp_path / "again")
    for iteration, metric in enumerate(metrics):
        store.save(f"weights {iteration}".encode(), iteration=iteration, steps=1000 * iteration, metric=metric)
    assert store.resolve("best").read_bytes() == b"weights 1"
    assert store.resolve("last").name == "6_Step-6000.ckpt"
    assert store.resolve("4_Step-4000.ckpt").read_bytes() == b"weights 4"
    document = json.loads(store.folder.deepracer_checkpoints.read_text())
    assert set(document) == {"best_checkpoint", "last_checkpoint"}
    assert document["best_checkpoint"]["name"] == "1_Step-1000.ckpt"
    assert document["best_checkpoint"]["avg_eval_metric"] == 80.0
    assert set(document["last_checkpoint"]) == {"name", "avg_eval_metric", "time_stamp"}


def test_ties_go_to_the_newer_and_laptime_prefers_lower(tmp_path):
    progress = _store(tmp_path / "p")
    progress.save(b"a", iteration=0, steps=0, metric=50.0)
    progress.save(b"b", iteration=1, steps=5, metric=50.0)
    assert progress.best().name == "1_Step-5.ckpt"
    laptime = _store(tmp_path / "t", best_model_metric="laptime")
    for iteration, seconds in enumerate([12.0, 9.5, 11.0]):
        laptime.save(b"x", iteration=iteration, steps=iteration, metric=seconds)
    assert laptime.best().name == "1_Step-1.ckpt"


def test_metric_recorded_after_saving_can_make_a_checkpoint_best(tmp_path):
    store = _store(tmp_path, keep=1)
    store.save(b"first", iteration=0, steps=10)
    assert store.best().name == "0_Step-10.ckpt" and store.best().avg_eval_metric is None
    store.record_metric("0_Step-10.ckpt", 40.0)
    store.save(b"second", iteration=1, steps=20)
    assert store.best().name == "0_Step-10.ckpt"
    store.record_metric("1_Step-20.ckpt", 45.0, time_stamp=123.0)
    assert store.best().name == "1_Step-20.ckpt" and store.last().avg_eval_metric == 45.0
    assert store.names() == ["1_Step-20.ckpt"]


def test_callable_payload_and_failed_save(tmp_path):
    store = _store(tmp_path)
    store.save(lambda path: path.write_bytes(b"torch bytes"), iteration=2, steps=7, metric=1.0)
    assert store.resolve("last").read_bytes() == b"torch bytes"

    def crashes(path):
        path.write_bytes(b"half")
        raise OSError("no space left")

    with pytest.raises(OSError, match="no space"):
        store.save(crashes, iteration=3, steps=9, metric=99.0)
    assert store.names() == ["2_Step-7.ckpt"] and store.last().name == "2_Step-7.ckpt"
    assert sorted(p.name for p in store.folder.model_dir.iterdir()) == ["2_Step-7.ckpt", "deepracer_checkpoints.json"]


def test_errors_are_clear(tmp_path):
    store = _store(tmp_path)
    with pytest.raises(FileNotFoundError, match="no best checkpoint yet"):
        store.resolve("best")
    store.save(b"x", iteration=0, steps=0)
    with pytest.raises(FileNotFoundError, match=r"'9_Step-1.ckpt' not found.*\['0_Step-0.ckpt'\]"):
        store.resolve("9_Step-1.ckpt")
    with pytest.raises(ValueError, match="finite"):
        store.save(b"x", iteration=1, steps=1, metric=float("nan"))
    with pytest.raises(TypeError, match="bytes or a callable"):
        store.save("text", iteration=1, steps=1)
    with pytest.raises(ValueError, match="steps must be an int"):
        checkpoint_name(1, -5)
    with pytest.raises(ValueError, match="keep"):
        CheckpointParams(keep=0)


def test_lap_time_breaks_ties_among_checkpoints_that_lap(tmp_path):
    store = _store(tmp_path)
    runs = [(90.0, None), (100.0, 7.5), (100.0, 6.9), (100.0, 8.2), (100.0, None), (99.0, None)]
    for iteration, (progress, lap) in enumerate(runs):
        store.save(b"w", iteration=iteration, steps=iteration, metric=progress, lap_time=lap)
    best = json.loads(store.folder.deepracer_checkpoints.read_text())["best_checkpoint"]
    # the 6.9 s checkpoint stays best: slower laps lose the tie; a tie without a lap time goes to the newer
    assert best["name"] == "4_Step-4.ckpt" and "avg_eval_lap_time" not in best
    store = _store(tmp_path / "again")
    for iteration, (progress, lap) in enumerate(runs[:4]):
        store.save(b"w", iteration=iteration, steps=iteration, metric=progress, lap_time=lap)
    best = store.best()
    assert (best.name, best.avg_eval_lap_time) == ("2_Step-2.ckpt", 6.9)
