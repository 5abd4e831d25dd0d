"""A real S3-compatible server for the store tests: moto's standalone server on 127.0.0.1 (a free
port), one per test module, with a bucket; each test gets its own LAPLAB_HOME and store prefix."""

from __future__ import annotations

import json
import secrets
from pathlib import Path

import pytest

from laplab.train.config import TrainConfig

TINY_HP = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
BUCKET = "laplab-test"


@pytest.fixture(scope="module")
def bucket(s3_server):
    import boto3
    client = boto3.client("s3", endpoint_url=s3_server, region_name="us-east-1",
                          aws_access_key_id="testing", aws_secret_access_key="testing")
    client.create_bucket(Bucket=BUCKET)
    return BUCKET


@pytest.fixture(scope="module")
def s3_env(s3_server, bucket, tmp_path_factory):
    """Endpoint and credentials in the environment, a private LAPLAB_HOME (for the module); returns a
    boto3 client of the server."""
    import boto3
    with pytest.MonkeyPatch.context() as patch:
        for name, value in (("AWS_ENDPOINT_URL", s3_server), ("AWS_ACCESS_KEY_ID", "testing"),
                            ("AWS_SECRET_ACCESS_KEY", "testing"), ("AWS_DEFAULT_REGION", "us-east-1"),
                            ("LAPLAB_HOME", str(tmp_path_factory.mktemp("home")))):
            patch.setenv(name, value)
        for name in ("LAPLAB_STORE", "LAPLAB_MODELS", "AWS_PROFILE", "AWS_SESSION_TOKEN"):
            patch.delenv(name, raising=False)
        yield boto3.client("s3", endpoint_url=s3_server)


@pytest.fixture
def store_url(s3_env, bucket) -> str:
    """A fresh prefix in the test bucket for each test."""
    return f"s3://{bucket}/runs-{secrets.token_hex(3)}/models"


@pytest.fixture(scope="module")
def tiny_hp(tmp_path_factory) -> Path:
    """A hyperparameters.json with 2 episodes per iteration and three epochs (iterations of ~1 s)."""
    path = tmp_path_factory.mktemp("hp") / "hyperparameters.json"
    path.write_text(json.dumps({**TrainConfig().hyper().to_dict(), **TINY_HP}))
    return path


def keys(client, url: str) -> set[str]:
    """Keys below an s3:// URL, relative to it."""
    bucket, _, prefix = url[len("s3://"):].partition("/")
    prefix = prefix.rstrip("/") + "/"
    pages = client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix)
    return {item["Key"][len(prefix):] for page in pages for item in page.get("Contents", [])}
