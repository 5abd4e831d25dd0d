"""Store errors are one paragraph naming the URL or key, never a traceback; the lock object in the
bucket keeps one job per model (moto's server on 127.0.0.1)."""

from __future__ import annotations

import socket
import time

import pytest

from laplab.cli import main
from laplab.store.lock import ModelBusyError
from laplab.store.s3 import ObjectStore, StoreError, parse_store_url
from laplab.store.s3_lock import S3ModelLock, lock_key
from tests.s3.conftest import BUCKET


def run_error(capsys, *args) -> str:
    capsys.readouterr()
    assert main([str(a) for a in args]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and "\n\n" not in err and err.count("\n") == 0, err
    return err


def _closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize("url, names", [
    ("http://bucket/models", "is not an s3:// URL"),
    ("s3://", "no valid bucket name"),
    ("s3://Bad_Bucket/models", "'Bad_Bucket'"),
    ("s3://good-bucket/a//b", "prefix"),
])
def test_a_malformed_store_url_is_named(s3_env, capsys, url, names):
    err = run_error(capsys, "evaluate", "m1", "--store", url)
    assert url in err and names in err


def test_the_environment_variable_is_checked_too(s3_env, capsys, monkeypatch):
    monkeypatch.setenv("LAPLAB_STORE", "s3:/typo/models")
    err = run_error(capsys, "leaderboard")
    assert "s3:/typo/models" in err and "s3://BUCKET/PREFIX" in err


def test_an_unreachable_endpoint(s3_env, capsys, monkeypatch):
    endpoint = f"http://127.0.0.1:{_closed_port()}"
    monkeypatch.setenv("AWS_ENDPOINT_URL", endpoint)
    err = run_error(capsys, "evaluate", "m1", "--store", f"s3://{BUCKET}/models")
    assert f"cannot reach the object store at {endpoint}" in err and "AWS_ENDPOINT_URL" in err


def test_a_missing_bucket(s3_env, capsys):
    err = run_error(capsys, "export", "m1", "--store", "s3://no-such-bucket/models")
    assert "bucket 'no-such-bucket' does not exist" in err and "s3://no-such-bucket/models" in err


def test_missing_credentials(s3_env, capsys, monkeypatch, tmp_path):
    for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.delenv(name)
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    err = run_error(capsys, "report", "m1", "--store", f"s3://{BUCKET}/models")
    assert "no AWS credentials" in err and f"s3://{BUCKET}/models" in err and "AWS_ACCESS_KEY_ID" in err


def test_a_model_not_in_the_store(s3_env, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    url = f"s3://{BUCKET}/empty/models"
    for command in (("evaluate", "ghost"), ("report", "ghost"), ("export", "ghost"), ("clone", "ghost", "new"),
                    ("train", "--resume", "ghost")):
        err = run_error(capsys, *command, "--store", url)
        assert f"no model named 'ghost' in the store {url}" in err and f"{url}/ghost/" in err, err


def test_the_lock_object_keeps_one_job_per_model(s3_env):
    store = ObjectStore(parse_store_url(f"s3://{BUCKET}/locks"))
    first = S3ModelLock(store, lock_key(store, "m1"), "m1", heartbeat_s=0.2).acquire(command="laplab train A")
    try:
        etag = first._etag
        with pytest.raises(ModelBusyError, match=r"process \d+ on host .*laplab train A.*s3://laplab-test/locks/m1/"
                                                 r"\.laplab-job\.lock"):
            S3ModelLock(store, lock_key(store, "m1"), "m1").acquire()
        deadline = time.monotonic() + 10
        while first._etag == etag and time.monotonic() < deadline:
            time.sleep(0.05)
        assert first._etag != etag  # the heartbeat rewrote it
        S3ModelLock(store, lock_key(store, "m2"), "m2").acquire().release()  # other models are free
    finally:
        first.release()
    assert store.head(lock_key(store, "m1")) is None
    S3ModelLock(store, lock_key(store, "m1"), "m1").acquire().release()  # free again after release


def test_a_stale_lock_is_taken_over_once(s3_env):
    store = ObjectStore(parse_store_url(f"s3://{BUCKET}/stale"))
    dead = S3ModelLock(store, lock_key(store, "m1"), "m1", heartbeat_s=3600).acquire()
    dead._stop.set()  # a job killed with SIGKILL: no heartbeat, no release
    time.sleep(2.1)  # Last-Modified has a resolution of one second
    heir = S3ModelLock(store, lock_key(store, "m1"), "m1", stale_after_s=1.0).acquire()
    with pytest.raises(ModelBusyError):
        S3ModelLock(store, lock_key(store, "m1"), "m1", stale_after_s=60.0).acquire()
    dead.release()  # the dead job's late release does not remove the heir's lock (If-Match)
    assert store.head(lock_key(store, "m1")) is not None
    heir.release()
    assert store.head(lock_key(store, "m1")) is None


def test_a_job_on_a_locked_model_and_an_existing_name_are_refused(s3_env, capsys, tiny_hp):
    url = f"s3://{BUCKET}/busy/models"
    store = ObjectStore(parse_store_url(url))
    holder = S3ModelLock(store, lock_key(store, "m1"), "m1").acquire(command="laplab train --name m1")
    try:
        err = run_error(capsys, "train", "--name", "m1", "--hyperparameters", tiny_hp, "--store", url)
        assert "being trained by another job" in err and f"{url}/m1/.laplab-job.lock" in err
    finally:
        holder.release()
    store.put_bytes(store.location.key("m1", "laplab.json"), b"{}")
    err = run_error(capsys, "train", "--name", "m1", "--hyperparameters", tiny_hp, "--store", url)
    assert f"a model named 'm1' already exists in the store ({url}/m1/)" in err
    assert store.head(lock_key(store, "m1")) is None  # the refused job released its lock


def test_store_errors_name_the_key(s3_env):
    store = ObjectStore(parse_store_url(f"s3://{BUCKET}/x"))
    with pytest.raises(StoreError, match=f"s3://{BUCKET}/x/nothing.json does not exist"):
        store.get_bytes("x/nothing.json")


def test_a_failing_upload_is_reported_once_retried_and_the_copy_kept(s3_env, tmp_path):
    """The bucket disappears under a job: its events keep going (training is not stopped), the failure
    is logged once, and the final publication fails with a paragraph naming the kept local copy."""
    from laplab.store.layout import ModelFolder
    from laplab.store.remote import FolderSync, RemoteModels
    s3_env.create_bucket(Bucket="vanishing")
    remote = RemoteModels(ObjectStore(parse_store_url("s3://vanishing/models")))
    folder = ModelFolder(tmp_path / "m1").create()
    folder.write_laplab_config({"track": "oval"})
    messages = []
    sync = FolderSync(remote, "m1", folder, delete=True, log=messages.append)
    sync.on_checkpoint(None)
    assert remote.exists("m1")
    s3_env.delete_object(Bucket="vanishing", Key="models/m1/laplab.json")
    s3_env.delete_bucket(Bucket="vanishing")
    for _ in range(2):
        folder.write_error("boom")
        sync.on_iteration(None)  # no exception: the job goes on
    assert len(messages) == 1 and "retried after the next iteration" in messages[0] and "vanishing" in messages[0]
    with pytest.raises(StoreError, match=f"kept in {folder.root}"):
        sync.finish()
