"""What readers of the bucket see while and after a job publishes a model (moto's server on 127.0.0.1):
never an index naming a checkpoint whose data is missing; deepracer-utils reads the model as it is."""

from __future__ import annotations

import json
import shutil
import threading

import pytest

from laplab.cli import main
from laplab.store.layout import ModelFolder
from laplab.store.remote import INDEX_NAME, FolderSync, RemoteModels
from laplab.store.s3 import ObjectStore, parse_store_url
from tests.s3.conftest import BUCKET, keys


def _prefix(url: str) -> str:
    return url.split("/", 3)[3]


class IndexWatcher(threading.Thread):
    """Polls the bucket: each new deepracer_checkpoints.json it sees, then at once whether the
    checkpoints it names are there."""

    def __init__(self, client, key_base: str):
        super().__init__(daemon=True)
        self.client, self.base = client, key_base
        self.stop = threading.Event()
        self.seen: dict[str, dict[str, bool]] = {}  # index ETag -> {checkpoint name: object present}

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                answer = self.client.get_object(Bucket=BUCKET, Key=f"{self.base}/{INDEX_NAME}")
            except self.client.exceptions.NoSuchKey:
                continue
            etag = answer["ETag"]
            if etag in self.seen:
                continue
            index = json.loads(answer["Body"].read())
            present = {}
            for which in ("best_checkpoint", "last_checkpoint"):
                name = index[which]["name"]
                key = f"{self.base}/model/{name}"  # (the last checkpoint has a .ckpt.resume beside it)
                listed = self.client.list_objects_v2(Bucket=BUCKET, Prefix=key)
                present[name] = any(item["Key"] == key for item in listed.get("Contents", []))
            self.seen[etag] = present


@pytest.fixture(scope="module")
def published(s3_env, tiny_hp):
    """Model m1 trained into a fresh prefix (3 iterations) while an IndexWatcher polls the bucket."""
    url = f"s3://{BUCKET}/readers/models"
    watcher = IndexWatcher(s3_env, f"{_prefix(url)}/m1")
    watcher.start()
    try:
        code = main(["train", "--name", "m1", "--track", "oval", "--hyperparameters", str(tiny_hp),
                     "--max-episodes", "6", "--quiet", "--store", url])
    finally:
        watcher.stop.set()
        watcher.join()
    assert code == 0
    return url, watcher.seen


def test_a_reader_never_sees_an_index_naming_a_missing_checkpoint(published):
    _, seen = published
    assert len(seen) >= 2  # it saw the index change while the job ran
    assert all(all(present.values()) for present in seen.values()), seen


class OrderCheckingStore(ObjectStore):
    """The real store client; when the index is written it checks, on the server, that every
    checkpoint the index names is there already."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.index_writes, self.problems = 0, []

    def put_bytes(self, key, data, **kwargs):
        if key.endswith(INDEX_NAME):
            self.index_writes += 1
            index = json.loads(data)
            folder = key[: -len(INDEX_NAME)]
            for which in ("best_checkpoint", "last_checkpoint"):
                if self.head(folder + "model/" + index[which]["name"]) is None:
                    self.problems.append((which, index[which]["name"]))
        return super().put_bytes(key, data, **kwargs)


def test_checkpoint_data_is_uploaded_before_the_index_that_names_it(published, tmp_path):
    url, _ = published
    store = OrderCheckingStore(parse_store_url(url))
    remote = RemoteModels(store)
    source = remote.pull("m1", tmp_path / "pulled", ("best", "last"))
    # Publish it under a new name from scratch, then add a checkpoint and prune one, as a job does.
    copy = ModelFolder(tmp_path / "copy" / "m1-copy")
    shutil.copytree(source.root, copy.root)
    sync = FolderSync(remote, "m1-copy", copy, delete=True)
    sync.sync()
    from laplab.store.checkpoints import CheckpointParams, CheckpointStore
    checkpoints = CheckpointStore(copy, CheckpointParams(keep=1))
    checkpoints.save(b"new weights", iteration=9, steps=999, metric=100.0)
    sync.sync()
    assert store.index_writes == 2 and not store.problems
    stored = keys(store.client, url)
    assert "m1-copy/model/9_Step-999.ckpt" in stored
    remaining = {k for k in stored if k.startswith("m1-copy/model/") and k.endswith(".ckpt")}
    assert remaining == {f"m1-copy/model/{n}" for n in checkpoints.names()}  # pruned ones deleted


def test_deepracer_utils_reads_the_model_from_the_bucket(published, s3_server):
    pytest.importorskip("deepracer.logs")
    from deepracer.logs import DeepRacerLog, S3FileHandler
    from deepracer.logs.metrics import TrainingMetrics
    from deepracer.logs.misc import LogFolderType
    url, _ = published
    handler = S3FileHandler(bucket=BUCKET, prefix=f"{_prefix(url)}/m1", s3_endpoint_url=s3_server)
    log = DeepRacerLog(filehandler=handler)
    assert handler.type == LogFolderType.DRFC_MODEL_SINGLE_WORKERS
    log.load_training_trace()
    frame = log.dataframe()
    assert sorted(frame["iteration"].unique()) == [0, 1, 2]
    assert frame["episode"].nunique() == 6
    assert log.hyperparameters()["num_episodes_between_training"] == 2
    assert log.action_space()
    metrics = TrainingMetrics(BUCKET, model_name=f"{_prefix(url)}/m1", s3_endpoint_url=s3_server)
    training = metrics.getTraining()
    assert len(training) == 6 and set(training["iteration"]) == {0, 1, 2}


def test_per_worker_simtrace_folders_are_published_as_drfc_writes_them(published, s3_server, tmp_path):
    """DR_WORKERS > 1 layout: <worker>/training-simtrace/<k>-iteration.csv (and TrainingMetrics_<w>.json):
    the sync uploads whatever the folder holds, and deepracer-utils sees the workers."""
    pytest.importorskip("deepracer.logs")
    from deepracer.logs import DeepRacerLog, S3FileHandler
    from deepracer.logs.misc import LogFolderType
    url, _ = published
    remote = RemoteModels(ObjectStore(parse_store_url(url)))
    # every checkpoint the index names (the best and the last differ when a later iteration evaluated worse)
    source = remote.pull("m1", tmp_path / "pulled", ("best", "last"))
    folder = ModelFolder(tmp_path / "multi" / "mw")
    shutil.copytree(source.root, folder.root)
    simtrace = folder.root / "training-simtrace"
    for worker in ("0", "1"):
        shutil.copytree(simtrace, folder.root / worker / "training-simtrace")
    shutil.rmtree(simtrace)
    shutil.copy(folder.training_metrics, folder.metrics_dir / "TrainingMetrics_1.json")
    FolderSync(remote, "mw", folder, delete=True).sync()
    stored = keys(remote.store.client, url)
    assert {"mw/0/training-simtrace/0-iteration.csv", "mw/1/training-simtrace/2-iteration.csv",
            "mw/metrics/TrainingMetrics_1.json"} <= stored
    handler = S3FileHandler(bucket=BUCKET, prefix=f"{_prefix(url)}/mw", s3_endpoint_url=s3_server)
    log = DeepRacerLog(filehandler=handler)
    assert handler.type == LogFolderType.DRFC_MODEL_MULTIPLE_WORKERS
    log.load_training_trace()
    assert sorted(log.dataframe()["worker"].unique()) == [0, 1]


def test_background_publication_keeps_the_order_while_checkpoints_are_saved_and_pruned(s3_env, tmp_path):
    """A job saving (and pruning) checkpoints faster than they upload: every index written to the
    bucket names checkpoints already there, and the last state is published at finish()."""
    from laplab.store.checkpoints import CheckpointParams, CheckpointStore
    url = f"s3://{BUCKET}/background/models"
    store = OrderCheckingStore(parse_store_url(url))
    folder = ModelFolder(tmp_path / "bg").create()
    folder.write_laplab_config({"track": "oval"})
    sync = FolderSync(RemoteModels(store), "bg", folder, delete=True, background=True)
    checkpoints = CheckpointStore(folder, CheckpointParams(keep=2))
    for iteration in range(12):
        checkpoints.save(bytes(200_000), iteration=iteration, steps=10 * iteration, metric=float(iteration % 5))
        sync.on_checkpoint(None)
    sync.finish()
    assert store.index_writes >= 1 and not store.problems
    stored = keys(store.client, url)
    assert {k for k in stored if k.endswith(".ckpt")} == {f"bg/model/{n}" for n in checkpoints.names()}
    index = json.loads(store.get_bytes(store.location.key("bg", INDEX_NAME)))
    assert index["last_checkpoint"]["name"] == "11_Step-110.ckpt"
