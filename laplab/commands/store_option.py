"""``--store s3://bucket/prefix`` (or ``$LAPLAB_STORE``): the commands that read or write models use an
S3-compatible object store instead of ``$LAPLAB_HOME/models`` (docs/store.md).

A command with a store works on a private local copy (``$LAPLAB_HOME/cache/store/<command>-<pid>-<hex>``,
the models folder of the settings it runs with: laplab.settings.use_settings, ``os.environ`` untouched):
it pulls what it needs from
the bucket first (laplab.store.remote), runs exactly as on local folders, publishes what it wrote
(a job: as it writes it, after every iteration; evaluate: its evaluation at the end) and removes the
copy. A copy whose upload failed is kept, and the error says where. Jobs also hold the model's lock
object in the bucket (laplab.store.s3_lock). Store errors are one paragraph (UserError), no traceback.
"""

from __future__ import annotations

import argparse
import os
import secrets
import shutil
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from laplab.errors import UserError
from laplab.settings import Settings, current_settings, use_settings
from laplab.store.layout import ModelFolder, validate_model_name
from laplab.store.lock import ModelBusyError
from laplab.store.remote import FolderSync, RemoteModels
from laplab.store.s3 import STORE_ENV, ObjectStore, StoreError, parse_store_url
from laplab.store.s3_lock import S3ModelLock, lock_key


def add_store_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--store", default=None, metavar="s3://BUCKET/PREFIX",
                        help=f"models in an S3-compatible object store (model NAME at s3://BUCKET/PREFIX/NAME/; "
                             f"endpoint from AWS_ENDPOINT_URL; default ${STORE_ENV}, else local folders)")


def evaluations_only(rel: str) -> bool:
    """What ``evaluate --list`` and the leaderboard read: the model's markers and its evaluation summaries."""
    return (rel in ("laplab.json", "model/model_metadata.json") or rel.startswith("metrics/evaluation/")
            or (rel.startswith("evaluation-") and rel.endswith("/summary.json")))


def without_traces(rel: str) -> bool:
    """What evaluate, export and clone read: all but simtrace, logs, videos and reports (the bulk of a
    model besides its checkpoints); evaluation summaries stay, so a new evaluation gets a fresh stamp."""
    parts = rel.split("/")
    return not ("training-simtrace" in parts or "evaluation-simtrace" in parts or parts[0] in ("logs", "report")
                or rel.endswith(".mp4"))


class StoreSession:
    """One command's use of the store at ``url``: pulls, jobs' locks and syncs, the local copy."""

    def __init__(self, url: str, command: str, settings: Settings | None = None):
        self.store = ObjectStore(parse_store_url(url))
        self.store.check()
        self.remote = RemoteModels(self.store)
        base = current_settings() if settings is None else settings
        self.root = base.cache_dir / "store" / f"{command}-{os.getpid()}-{secrets.token_hex(4)}"
        self.root.mkdir(parents=True)
        self.settings = base.with_models_dir(self.root)  # what the command runs with: models in the copy
        self.syncs: list[FolderSync] = []
        self.locks: list[S3ModelLock] = []
        self.keep = False

    @property
    def url(self) -> str:
        return self.store.location.url()

    def folder(self, name: str) -> ModelFolder:
        return ModelFolder(self.root / validate_model_name(name))

    def pull(self, name: str, checkpoints: tuple[str, ...] = (), include: Callable[[str], bool] | None = None,
             publish: bool = False) -> ModelFolder:
        """Fetch model ``name`` (see RemoteModels.pull); ``publish``: upload what the command adds."""
        folder = self.remote.pull(name, self.root, checkpoints, include)
        if publish:
            self.syncs.append(FolderSync(self.remote, name, folder, FolderSync.baseline(folder)))
        return folder

    def pull_all(self, include: Callable[[str], bool]) -> list[str]:
        """Fetch the files ``include`` accepts of every model in the store; returns the names."""
        names = self.remote.list_models()
        for name in names:
            self.remote.pull(name, self.root, (), include)
        return names

    def _lock(self, name: str) -> None:
        lock = S3ModelLock(self.store, lock_key(self.store, name), name)
        lock.acquire()
        self.locks.append(lock)

    def create_job(self, name: str) -> tuple[FolderSync]:
        """Lock model ``name`` in the store for a new job (refused if it exists); its listeners."""
        validate_model_name(name)
        self._lock(name)
        if self.remote.exists(name):
            raise UserError(f"a model named {name!r} already exists in the store ({self.remote.url(name)}); "
                            f"models are immutable: pick another name, `laplab clone {name} NEW --store "
                            f"{self.url}`, or `laplab train --resume {name} --store {self.url}`.")
        sync = FolderSync(self.remote, name, self.folder(name), delete=True, background=True)
        self.syncs.append(sync)
        return (sync,)

    def resume_job(self, name: str) -> tuple[FolderSync]:
        """Lock model ``name``, fetch it with its best and last checkpoints; its listeners."""
        validate_model_name(name)
        self._lock(name)
        folder = self.remote.pull(name, self.root, ("best", "last"))
        sync = FolderSync(self.remote, name, folder, FolderSync.baseline(folder), delete=True, background=True)
        self.syncs.append(sync)
        return (sync,)

    def finish(self) -> None:
        """Publish what the command wrote (raises StoreError, keeping the local copy, if it fails)."""
        for sync in self.syncs:
            try:
                sync.finish()
            except StoreError:
                self.keep = True
                raise

    def close(self) -> None:
        for lock in self.locks:
            lock.release()
        if not self.keep:
            shutil.rmtree(self.root, ignore_errors=True)


@contextmanager
def store_session(args: argparse.Namespace, command: str) -> Iterator[StoreSession | None]:
    """The command's :class:`StoreSession` when ``--store`` or ``$LAPLAB_STORE`` is set, else None.

    While it is open, model names resolve to its local copy (``session.settings`` are in force, see
    laplab.settings.use_settings); on a normal exit what the command wrote is published. Store errors
    and a model locked by another job become one-paragraph UserErrors."""
    url = getattr(args, "store", None) or os.environ.get(STORE_ENV)
    if not url:
        yield None
        return
    session = None
    try:
        session = StoreSession(url, command)
        finished = False
        try:
            with use_settings(session.settings):
                yield session
            finished = True
            session.finish()
        finally:
            if not finished:  # the command failed or was interrupted: keep what it wrote, if we can
                try:
                    session.finish()
                except StoreError as exc:
                    print(f"laplab {command}: {exc}", file=sys.stderr)
    except (StoreError, ModelBusyError) as exc:
        raise UserError(str(exc), field=getattr(exc, "field", None) or "--store") from None
    finally:
        if session is not None:
            session.close()
