"""An S3-compatible object store (AWS S3, MinIO, moto's server) seen as files under one bucket prefix.

``s3://bucket/prefix`` names where models live: model NAME is ``s3://bucket/prefix/NAME/`` in
deepracer-for-cloud's layout (the same layout as a local model folder, see layout.py). The endpoint
comes from ``AWS_ENDPOINT_URL`` (unset: AWS itself), the credentials from boto3's usual chain
(``AWS_ACCESS_KEY_ID`` / ``AWS_SECRET_ACCESS_KEY``, ``AWS_PROFILE``, ~/.aws, instance roles).

Why boto3 rather than fsspec/s3fs: boto3 is already what deepracer-utils reads buckets with, so one
client library and one credential chain serve both; it exposes S3's conditional writes
(``IfNoneMatch='*'``, ``IfMatch=etag``) that the model lock needs; and s3fs pins aiobotocore, which pins
botocore to a narrow range and would downgrade the botocore that boto3 and deepracer-utils use. The
store's needs (put, get, list, delete one prefix) are a few calls, so a filesystem layer buys nothing.

Every failure a user can cause (no server at the endpoint, no credentials, a missing bucket, a key
that is not there, a malformed URL) raises :class:`StoreError` with one paragraph naming the URL.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

STORE_ENV = "LAPLAB_STORE"
ENDPOINT_ENV = "AWS_ENDPOINT_URL"
_BUCKET_PATTERN = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")
_PREFIX_PART = re.compile(r"[A-Za-z0-9!_.*'()=+-]+")


class StoreError(Exception):
    """The object store cannot be used as asked; the message is one paragraph naming the URL or key.
    ``field``: the setting it is about (``"AWS_ENDPOINT_URL"``, ``"--store"``), when it is one."""

    def __init__(self, message: str = "", field: str | None = None):
        super().__init__(message)
        self.field = field


class PreconditionFailed(StoreError):
    """A conditional write lost: the object exists already (IfNoneMatch) or changed (IfMatch)."""


class ObjectMissing(StoreError):
    """The key does not exist in the bucket."""


@dataclass(frozen=True)
class S3Location:
    """``s3://bucket/prefix``; prefix without leading or trailing slash ('' for the bucket's root)."""

    bucket: str
    prefix: str = ""

    def key(self, *parts: str) -> str:
        """The object key of ``parts`` below the prefix, joined with '/'."""
        return "/".join(p.strip("/") for p in (self.prefix, *parts) if p.strip("/"))

    def url(self, *parts: str) -> str:
        return f"s3://{self.bucket}/{self.key(*parts)}".rstrip("/")

    def __str__(self) -> str:
        return self.url()


def parse_store_url(url: str) -> S3Location:
    """``s3://bucket[/prefix]`` -> :class:`S3Location`; anything else raises :class:`StoreError`."""
    example = "for example s3://my-bucket/laplab/models"
    if not isinstance(url, str) or not url.startswith("s3://"):
        raise StoreError(f"store URL {url!r} is not an s3:// URL; give --store s3://BUCKET/PREFIX ({example}), "
                         f"or leave --store and ${STORE_ENV} unset to keep models in local folders.")
    bucket, _, prefix = url[len("s3://"):].partition("/")
    if _BUCKET_PATTERN.fullmatch(bucket) is None or ".." in bucket:
        raise StoreError(f"store URL {url!r} has no valid bucket name ({bucket!r}): S3 bucket names are 3 to 63 "
                         f"lower-case letters, digits, dots and hyphens, starting and ending with a letter or a "
                         f"digit ({example}).")
    parts = [p for p in prefix.split("/") if p]
    bad = [p for p in parts if _PREFIX_PART.fullmatch(p) is None or p in (".", "..")]
    if bad or "//" in prefix.strip("/"):
        raise StoreError(f"store URL {url!r} has a prefix laplab cannot use ({prefix!r}): give folder names of "
                         f"letters, digits and -_.!*'()=+ separated by single slashes ({example}).")
    return S3Location(bucket, "/".join(parts))


def endpoint_url() -> str | None:
    """``$AWS_ENDPOINT_URL`` (a MinIO or moto server, e.g. http://127.0.0.1:9000), None for AWS;
    :class:`StoreError` when it is set to something that is not an http(s) URL."""
    return check_endpoint(os.environ.get(ENDPOINT_ENV) or None, f"${ENDPOINT_ENV}")


def check_endpoint(endpoint: str | None, what: str = "the endpoint") -> str | None:
    """``endpoint`` when None or an ``http(s)://host[:port][/path]`` URL, else :class:`StoreError`."""
    if endpoint is None:
        return None
    from urllib.parse import urlsplit
    try:
        parts = urlsplit(endpoint)
        port_ok = parts.port is None or parts.port > 0
    except ValueError:
        parts, port_ok = None, False
    if parts is None or parts.scheme not in ("http", "https") or not parts.hostname or not port_ok:
        raise StoreError(f"{what} is {endpoint!r}, which is not the URL of an S3-compatible server: give "
                         f"http://HOST:PORT or https://HOST (for example http://127.0.0.1:9000 for MinIO), or "
                         f"unset {ENDPOINT_ENV} to use AWS S3 itself.")
    return endpoint


class ObjectStore:
    """Files under one bucket prefix: put, get, list, delete, conditional writes (boto3's S3 client)."""

    def __init__(self, location: S3Location, endpoint: str | None = None):
        try:
            import boto3
            from botocore.config import Config
        except ImportError:
            raise StoreError(f"--store {location.url()} needs boto3, which is not installed: "
                             "`pip install 'laplab[store]'` (or `pip install boto3`).") from None
        self.location = location
        self.endpoint = check_endpoint(endpoint) if endpoint is not None else endpoint_url()
        where = self.endpoint or "AWS S3"
        self._where = f"{location.url()} (endpoint {where})"
        # Few retries and short timeouts: a wrong endpoint fails in seconds, not minutes.
        config = Config(retries={"max_attempts": 3, "mode": "standard"}, connect_timeout=5, read_timeout=60,
                        s3={"addressing_style": "path"} if self.endpoint else None)
        # A session of its own: boto3's default session keeps the credentials it found first.
        self.client = boto3.session.Session().client("s3", endpoint_url=self.endpoint, config=config)

    # -- errors --------------------------------------------------------------------------------

    def explain(self, exc: Exception, key: str | None = None) -> StoreError:
        """A :class:`StoreError` paragraph for a boto3/botocore exception raised on ``key``."""
        from botocore.exceptions import (ClientError, EndpointConnectionError, NoCredentialsError,
                                         PartialCredentialsError)
        from botocore.exceptions import ConnectionError as BotoConnectionError
        from botocore.exceptions import ConnectTimeoutError, ReadTimeoutError
        what = f"s3://{self.location.bucket}/{key}" if key else self._where
        endpoint = self.endpoint or "AWS S3"
        if isinstance(exc, (NoCredentialsError, PartialCredentialsError)):
            return StoreError(f"no AWS credentials to read or write {what}: set AWS_ACCESS_KEY_ID and "
                              f"AWS_SECRET_ACCESS_KEY (or AWS_PROFILE) for the endpoint {endpoint}.")
        if isinstance(exc, (EndpointConnectionError, ConnectTimeoutError, BotoConnectionError, ReadTimeoutError)):
            return StoreError(f"cannot reach the object store at {endpoint} for {what} ({type(exc).__name__}); "
                              f"check that the server runs and that ${ENDPOINT_ENV} is its address "
                              f"(e.g. http://127.0.0.1:9000 for a local MinIO).")
        if isinstance(exc, ClientError):
            code = str(exc.response.get("Error", {}).get("Code", ""))
            status = exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode")
            if code in ("NoSuchBucket",) or (code in ("404", "NotFound") and key is None):
                return StoreError(f"bucket {self.location.bucket!r} does not exist at {endpoint} (store "
                                  f"{self.location.url()}); create it (`aws s3 mb s3://{self.location.bucket}"
                                  f"{' --endpoint-url ' + endpoint if self.endpoint else ''}`) or fix --store.")
            if code in ("NoSuchKey", "404", "NotFound"):
                return ObjectMissing(f"{what} does not exist in the store (endpoint {endpoint}).")
            if code in ("PreconditionFailed", "412", "ConditionalRequestConflict") or status == 412:
                return PreconditionFailed(f"{what} was written by someone else meanwhile (conditional write "
                                          f"refused by {endpoint}).")
            if code in ("AccessDenied", "403", "Forbidden", "InvalidAccessKeyId", "SignatureDoesNotMatch"):
                return StoreError(f"the object store at {endpoint} refused access to {what} ({code}): check the "
                                  f"credentials (AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY) and the bucket's policy.")
            message = exc.response.get("Error", {}).get("Message", "")
            return StoreError(f"the object store at {endpoint} failed on {what}: {code} {message}".rstrip())
        return StoreError(f"the object store at {endpoint} failed on {what}: {type(exc).__name__}: {exc}")

    def _call(self, key: str | None, method: str, **kwargs):
        from botocore.exceptions import BotoCoreError, ClientError
        try:
            return getattr(self.client, method)(**kwargs)
        except (BotoCoreError, ClientError) as exc:
            raise self.explain(exc, key) from None

    # -- operations ----------------------------------------------------------------------------

    def check(self) -> None:
        """Fail with one paragraph unless the bucket is reachable with the current credentials."""
        self._call(None, "head_bucket", Bucket=self.location.bucket)

    def put_bytes(self, key: str, data: bytes, if_none_match: bool = False, if_match: str | None = None) -> str:
        """Write ``data`` at ``key``; returns the new ETag. ``if_none_match``: only if ``key`` does not
        exist; ``if_match``: only if its ETag is still that (else :class:`PreconditionFailed`)."""
        extra = {"IfNoneMatch": "*"} if if_none_match else {}
        if if_match is not None:
            extra["IfMatch"] = if_match
        answer = self._call(key, "put_object", Bucket=self.location.bucket, Key=key, Body=data, **extra)
        return answer.get("ETag", "")

    def put_file(self, key: str, path: Path) -> None:
        """Upload the file at ``path`` (multipart above 8 MB) to ``key``."""
        from boto3.exceptions import S3UploadFailedError
        from botocore.exceptions import BotoCoreError, ClientError
        try:
            self.client.upload_file(str(path), self.location.bucket, key)
        except S3UploadFailedError as exc:
            cause = exc.__context__
            raise (self.explain(cause, key) if isinstance(cause, (BotoCoreError, ClientError))
                   else StoreError(f"upload of {path} to s3://{self.location.bucket}/{key} failed: {exc}")) from None
        except (BotoCoreError, ClientError) as exc:
            raise self.explain(exc, key) from None

    def get_bytes(self, key: str) -> bytes:
        answer = self._call(key, "get_object", Bucket=self.location.bucket, Key=key)
        return answer["Body"].read()

    def get_file(self, key: str, path: Path) -> None:
        """Download ``key`` to ``path`` (through a temporary sibling: a reader never sees half a file)."""
        from laplab.store.atomic import atomic_write_with
        from botocore.exceptions import BotoCoreError, ClientError

        def download(temporary: Path) -> None:
            try:
                self.client.download_file(self.location.bucket, key, str(temporary))
            except (BotoCoreError, ClientError) as exc:
                raise self.explain(exc, key) from None
        atomic_write_with(path, download)

    def head(self, key: str) -> dict | None:
        """The object's metadata (ETag, ContentLength, ...) or None when it does not exist."""
        try:
            return self._call(key, "head_object", Bucket=self.location.bucket, Key=key)
        except ObjectMissing:
            return None

    def list(self, prefix: str) -> dict[str, tuple[int, str]]:
        """``{key: (size in bytes, ETag)}`` of every object whose key starts with ``prefix``."""
        out: dict[str, tuple[int, str]] = {}
        token = None
        while True:
            kwargs = {"Bucket": self.location.bucket, "Prefix": prefix}
            if token:
                kwargs["ContinuationToken"] = token
            answer = self._call(None, "list_objects_v2", **kwargs)
            for item in answer.get("Contents", []):
                out[item["Key"]] = (int(item["Size"]), str(item.get("ETag", "")))
            if not answer.get("IsTruncated"):
                return out
            token = answer.get("NextContinuationToken")

    def folders(self, prefix: str) -> list[str]:
        """Names of the 'folders' directly below ``prefix`` (keys ``prefix/NAME/...``), sorted."""
        base = prefix.rstrip("/") + "/" if prefix else ""
        names, token = set(), None
        while True:
            kwargs = {"Bucket": self.location.bucket, "Prefix": base, "Delimiter": "/"}
            if token:
                kwargs["ContinuationToken"] = token
            answer = self._call(None, "list_objects_v2", **kwargs)
            names |= {p["Prefix"][len(base):].rstrip("/") for p in answer.get("CommonPrefixes", [])}
            if not answer.get("IsTruncated"):
                return sorted(names)
            token = answer.get("NextContinuationToken")

    def delete(self, key: str, if_match: str | None = None) -> None:
        extra = {"IfMatch": if_match} if if_match is not None else {}
        self._call(key, "delete_object", Bucket=self.location.bucket, Key=key, **extra)
