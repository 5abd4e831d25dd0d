"""One job per model in an object store: a lock object ``<prefix>/NAME/.laplab-job.lock``.

lock.py's ``flock`` guards a local folder only, and dies with its process; an object store has no
locks. So the job that trains NAME creates the lock object with a conditional write
(``If-None-Match: *``: the store refuses it when the object exists, atomically, on AWS S3 since
2024, MinIO and moto) holding who it is (pid, host, start time, command), and rewrites it every
``heartbeat_s`` seconds from a thread, each time only if it is still the object it wrote
(``If-Match: <etag>``). A second job that finds the lock fails with :class:`ModelBusyError` naming the
holder, unless the lock's last write is older than ``stale_after_s`` by the store's own clock (its
``Last-Modified`` against the ``Date`` of the same answer: no two machines' clocks are compared):
then the holder died without releasing it (SIGKILL, power cut) and the job takes it over, again with
``If-Match``, so of two jobs taking over the same stale lock only one wins.

Limits, said plainly: a holder that is alive but cut off from the store for longer than
``stale_after_s`` can lose its lock to another job and not know it until its next heartbeat (it then
logs that it lost the lock); a store without conditional writes (an old MinIO) would let two jobs in.
Readers (evaluate, export, report, leaderboard) take no lock, as locally.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
from email.utils import parsedate_to_datetime

from laplab.store.lock import LOCK_FILE_NAME, LockHolder, ModelBusyError
from laplab.store.s3 import ObjectMissing, ObjectStore, PreconditionFailed

HEARTBEAT_S = 30.0
STALE_AFTER_S = 120.0


class S3ModelLock:
    """The lock object at ``key`` of ``store``: ``acquire()`` / ``release()``."""

    def __init__(self, store: ObjectStore, key: str, model: str, what: str = "trained",
                 heartbeat_s: float = HEARTBEAT_S, stale_after_s: float = STALE_AFTER_S):
        self.store, self.key, self.model, self.what = store, key, model, what
        self.heartbeat_s, self.stale_after_s = heartbeat_s, stale_after_s
        self._etag: str | None = None
        self._document: dict | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.lost = False

    @property
    def held(self) -> bool:
        return self._etag is not None

    @property
    def url(self) -> str:
        return f"s3://{self.store.location.bucket}/{self.key}"

    def acquire(self, command: str | None = None) -> "S3ModelLock":
        if self._etag is not None:
            return self
        self._document = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                          "command": command if command is not None else " ".join(["laplab", *sys.argv[1:]])}
        body = self._body()
        try:
            self._etag = self.store.put_bytes(self.key, body, if_none_match=True)
        except PreconditionFailed:
            self._take_over_stale(body)
        self._thread = threading.Thread(target=self._beat, name=f"laplab-lock-{self.model}", daemon=True)
        self._thread.start()
        return self

    def _body(self) -> bytes:
        return (json.dumps({**self._document, "heartbeat": time.time()}) + "\n").encode()

    def _take_over_stale(self, body: bytes) -> None:
        answer = self.store.head(self.key)
        if answer is None:  # released meanwhile: try once more from scratch
            try:
                self._etag = self.store.put_bytes(self.key, body, if_none_match=True)
                return
            except PreconditionFailed:
                answer = self.store.head(self.key)
        holder = self._holder()
        age = _age_s(answer) if answer is not None else None
        if answer is not None and age is not None and age > self.stale_after_s:
            try:
                self._etag = self.store.put_bytes(self.key, body, if_match=answer["ETag"])
                return
            except (PreconditionFailed, ObjectMissing):
                holder = self._holder()
        silent = f"; its last heartbeat was {age:.0f} s ago" if age is not None else ""
        raise ModelBusyError(
            f"model {self.model!r} is being {self.what} by another job: {holder.describe()}{silent}. One job at a "
            f"time may write a model in the store (lock {self.url}); wait for that job to end or stop it. If it "
            f"died, its lock expires {self.stale_after_s:.0f} s after its last heartbeat (or delete {self.url}).")

    def _holder(self) -> LockHolder:
        try:
            data = json.loads(self.store.get_bytes(self.key))
            return LockHolder(int(data["pid"]), str(data["host"]), float(data["started"]), data.get("command"))
        except (ObjectMissing, ValueError, KeyError, TypeError):
            return LockHolder(None, None, None, None)

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            etag = self._etag
            if etag is None:
                return
            try:
                self._etag = self.store.put_bytes(self.key, self._body(), if_match=etag)
            except (PreconditionFailed, ObjectMissing):
                self.lost = True
                print(f"laplab: the lock {self.url} of model {self.model!r} was taken over by another job (this "
                      "job could not renew it in time); two jobs may now write the model.", file=sys.stderr)
                return
            except Exception:  # noqa: BLE001 - the store is unreachable for a while: beat again later
                continue

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=10)
        etag, self._etag = self._etag, None
        if etag is None or self.lost:
            return
        try:
            self.store.delete(self.key, if_match=etag)
        except (PreconditionFailed, ObjectMissing):
            pass

    def __enter__(self) -> "S3ModelLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def lock_key(store: ObjectStore, model: str) -> str:
    return store.location.key(model, LOCK_FILE_NAME)


def _age_s(answer: dict) -> float | None:
    """Seconds since the object was last written, by the store's clock (Last-Modified vs Date)."""
    try:
        date = parsedate_to_datetime(answer["ResponseMetadata"]["HTTPHeaders"]["date"])
        return (date - answer["LastModified"]).total_seconds()
    except (KeyError, TypeError, ValueError):
        return None
