"""``laplab import s3://BUCKET/PREFIX``: a model uploaded in the layout deepracer-for-cloud's
``dr-upload-model`` writes (laplab's own ``--out s3://`` upload of a console export), read from an
S3-compatible server (moto's, on 127.0.0.1); a prefix that does not exist is one paragraph."""

from __future__ import annotations

import secrets

import pytest

pytest.importorskip("torch", reason="the import writes a laplab (torch) checkpoint")
pytest.importorskip("tensorflow", reason="the console export writes model.pb with tensorflow-cpu")
pytest.importorskip("boto3", reason="S3 needs boto3")

from laplab.cli import main  # noqa: E402
from laplab.commands.export import _upload_console_folder  # noqa: E402
from laplab.errors import UserError  # noqa: E402
from laplab.export.deepracer_import import import_deepracer_model  # noqa: E402
from laplab.store.layout import models_root  # noqa: E402
from test_deepracer_import import assert_same_model  # noqa: E402

BUCKET = "laplab-import-test"


@pytest.fixture
def s3(s3_server, console_exports, monkeypatch):
    """Endpoint and credentials in the environment; $LAPLAB_HOME the exported models' home."""
    import boto3
    for name, value in (("AWS_ENDPOINT_URL", s3_server), ("AWS_ACCESS_KEY_ID", "testing"),
                        ("AWS_SECRET_ACCESS_KEY", "testing"), ("AWS_DEFAULT_REGION", "us-east-1"),
                        ("LAPLAB_HOME", str(console_exports["home"]))):
        monkeypatch.setenv(name, value)
    for name in ("LAPLAB_STORE", "AWS_PROFILE", "AWS_SESSION_TOKEN"):
        monkeypatch.delenv(name, raising=False)
    client = boto3.client("s3", endpoint_url=s3_server)
    if BUCKET not in {b["Name"] for b in client.list_buckets().get("Buckets", [])}:
        client.create_bucket(Bucket=BUCKET)
    return console_exports


def test_import_from_a_dr_upload_model_prefix(s3, capsys, monkeypatch):
    import boto3

    from laplab.store.s3 import ObjectStore
    url = f"s3://{BUCKET}/drfc-{secrets.token_hex(3)}/sac-model"
    assert _upload_console_folder(s3["sac-cam-sector"], url) >= 10
    simtrace = url.split("/", 3)[3] + "/training-simtrace/0-iteration.csv"  # a training prefix's other files
    boto3.client("s3").put_object(Bucket=BUCKET, Key=simtrace, Body=b"episode,steps")
    downloaded = []
    real_get_file = ObjectStore.get_file
    monkeypatch.setattr(ObjectStore, "get_file", lambda store, key, path: (downloaded.append(key),
                                                                            real_get_file(store, key, path)))
    assert main(["import", url]) == 0
    assert simtrace not in downloaded and any(key.endswith(".ckpt.index") for key in downloaded)
    assert "imported model 'sac-model'" in capsys.readouterr().out
    assert_same_model("sac-cam-sector", "sac-model")


def test_a_prefix_that_does_not_exist(s3):
    before = sorted(p.name for p in models_root().iterdir())
    with pytest.raises(UserError, match="no such prefix: the bucket holds no objects under nowhere/model/"):
        import_deepracer_model(f"s3://{BUCKET}/nowhere/model", "nowhere")
    assert sorted(p.name for p in models_root().iterdir()) == before
