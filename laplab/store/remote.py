"""Model folders in an object store: the models under ``s3://bucket/prefix``, fetched into a local
working copy and published back as a job writes them.

A model NAME is the objects under ``<prefix>/NAME/`` with the keys of a local model folder's files
(deepracer-for-cloud's layout, layout.py), so deepracer-utils' ``S3FileHandler`` reads it as it is.
Jobs and readers work on a local copy (the caller picks its folder, see laplab/commands/store.py):

- :meth:`RemoteModels.pull` downloads what a command needs: every file of the model but the
  checkpoints, and of those only the ones asked for ('best', 'last' or file names), resolved through
  ``model/deepracer_checkpoints.json``; a checkpoint pruned between reading that index and
  downloading it makes the pull read the index again (as checkpoint_read.py does locally).
- :class:`FolderSync` publishes a local model folder: new and changed files are uploaded; the
  checkpoint files before ``deepracer_checkpoints.json`` (which names them), so a reader of the
  bucket never finds an index naming a checkpoint whose data is not there yet; files a job removed
  (pruned checkpoints, simtrace of an iteration redone after a resume) are deleted after the index.
  Object stores have no append: a file that grows (metrics, the robomaker log) is uploaded again.
  Hidden files (the local lock, atomic-write temporaries) are never uploaded.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from laplab.store.layout import MODEL_NAME_PATTERN, ModelFolder, validate_model_name
from laplab.store.s3 import ObjectMissing, ObjectStore, StoreError

INDEX_NAME = "model/deepracer_checkpoints.json"
_MARKERS = ("model/model_metadata.json", "laplab.json")
_ATTEMPTS = 5


def is_checkpoint(rel: str) -> bool:
    """Whether ``rel`` (a path inside a model folder) is a checkpoint file ``model/*.ckpt``."""
    return rel.startswith("model/") and rel.endswith(".ckpt") and rel.count("/") == 1


def checkpoint_of(rel: str) -> str | None:
    """The checkpoint (``<i>_Step-<n>.ckpt``) that ``rel`` belongs to: the checkpoint file itself or the
    resume state beside the last one (``model/<name>.ckpt.resume``); None for other files."""
    rel = rel.removesuffix(".resume")
    return rel.removeprefix("model/") if is_checkpoint(rel) else None


def _hidden(rel: str) -> bool:
    return any(part.startswith(".") for part in rel.split("/"))


class RemoteModels:
    """The models under one bucket prefix (``store.location``)."""

    def __init__(self, store: ObjectStore):
        self.store = store
        self.location = store.location

    def model_key(self, name: str, rel: str = "") -> str:
        return self.location.key(validate_model_name(name), rel) + ("" if rel else "/")

    def url(self, name: str, rel: str = "") -> str:
        return self.location.url(name, rel) + ("" if rel else "/")

    def list_models(self) -> list[str]:
        """Names of the models in the store (folders holding model_metadata.json or laplab.json)."""
        names = [n for n in self.store.folders(self.location.prefix) if MODEL_NAME_PATTERN.fullmatch(n)]
        return [n for n in names if self.exists(n)]

    def exists(self, name: str) -> bool:
        return any(self.store.head(self.model_key(name, marker)) is not None for marker in _MARKERS)

    def missing(self, name: str, what: str = "") -> StoreError:
        """The error for a model ``name`` that is not in the store (lists the ones that are)."""
        known = self.list_models()
        shown = ", ".join(known[:20]) + (" ..." if len(known) > 20 else "") if known else "none"
        return ObjectMissing(f"no model named {name!r} in the store {self.location.url()} (looked for "
                             f"{self.url(name)}{what}; models there: {shown}).")

    def read(self, name: str, rel: str) -> bytes:
        """The bytes of ``rel`` in model ``name``'s folder (ObjectMissing when it is not there)."""
        return self.store.get_bytes(self.model_key(name, rel))

    def listing(self, name: str) -> dict[str, tuple[int, str]]:
        """``{path inside the model folder: (size, ETag)}`` of the model's objects."""
        base = self.model_key(name)
        return {key[len(base):]: info for key, info in self.store.list(base).items() if key != base}

    def pull(self, name: str, root: Path, checkpoints: Iterable[str] = ("best",),
             include: Callable[[str], bool] | None = None) -> ModelFolder:
        """Download model ``name`` into ``root/name`` and return that folder.

        Every file but the checkpoints, which ``include(rel)`` accepts (default all); of the checkpoints,
        those named in ``checkpoints`` ('best', 'last' or ``<i>_Step-<n>.ckpt``; empty: none).
        Raises :class:`StoreError` when the model is not in the store.
        """
        folder = ModelFolder(Path(root) / validate_model_name(name))
        wanted = tuple(checkpoints)
        for attempt in range(_ATTEMPTS):
            # The index before the listing: a checkpoint it names was uploaded before it, so the
            # listing has it unless it was pruned meanwhile (then look again).
            index = self._read_index(name) if wanted else None
            files = self.listing(name)
            if not any(marker in files for marker in _MARKERS):
                raise self.missing(name)
            names = self._checkpoint_names(index, wanted)
            indexed = self._checkpoint_names(index, tuple(w for w in wanted if w in ("best", "last")))
            if any(f"model/{n}" not in files for n in indexed) and attempt < _ATTEMPTS - 1:
                continue
            try:
                for rel in sorted(files, key=lambda r: (r == INDEX_NAME, r)):  # the index last
                    if rel.endswith("/") or _hidden(rel) or (include is not None and not include(rel)):
                        continue
                    owner = checkpoint_of(rel)
                    if owner is not None and owner not in names:
                        continue  # another checkpoint, or its resume state (only --resume reads one)
                    if rel == INDEX_NAME and index is not None:
                        (folder.root / rel).parent.mkdir(parents=True, exist_ok=True)
                        (folder.root / rel).write_bytes(index)  # the index that named what was pulled
                        continue
                    self.store.get_file(self.model_key(name, rel), folder.root / rel)
                return folder
            except ObjectMissing:  # pruned (or rewritten) meanwhile by a running job: look again
                if attempt == _ATTEMPTS - 1:
                    raise
        raise AssertionError("unreachable")

    def _read_index(self, name: str) -> bytes | None:
        try:
            return self.store.get_bytes(self.model_key(name, INDEX_NAME))
        except ObjectMissing:
            return None

    @staticmethod
    def _checkpoint_names(index: bytes | None, wanted: tuple[str, ...]) -> set[str]:
        names = {w for w in wanted if w not in ("best", "last")}
        if index is None:
            return names
        try:
            document = json.loads(index)
        except ValueError:
            return names  # a damaged index: the local reader reports it, naming the file
        for which in ("best", "last"):
            entry = document.get(f"{which}_checkpoint") if isinstance(document, dict) else None
            if which in wanted and isinstance(entry, dict) and isinstance(entry.get("name"), str):
                names.add(entry["name"])
        return names


class FolderSync:
    """Publishes the local model folder ``folder`` to model ``name`` of ``remote`` (see module doc).

    ``known``: the files the bucket holds already ({path inside the folder: (size, mtime_ns)} of the
    local copies, as :meth:`baseline` makes after a pull). ``delete``: remove the objects of known files
    the job removed (a job that owns the model; readers never delete). Also a trainer listener: it
    publishes after every event, so subscribe it after the recorder that writes the folder. An upload
    that fails is retried at the next event and at :meth:`finish`, which raises if it still fails.

    ``background``: publish from a thread of its own, so the job does not wait for the network (an
    event only wakes it; passes do not overlap; :meth:`finish` waits for the last one). A log file the
    job is appending to may then go up half-written and is uploaded again by the next pass; the
    checkpoints and their index keep their order (each pass snapshots the index and uploads it only
    once every checkpoint it names is in the bucket).
    """

    def __init__(self, remote: RemoteModels, name: str, folder: ModelFolder,
                 known: dict[str, tuple[int, int]] | None = None, delete: bool = False,
                 log: Callable[[str], None] | None = None, background: bool = False):
        self.remote, self.name, self.folder = remote, name, folder
        self.known = dict(known or {})
        self.delete = delete
        self._wake = threading.Event()
        self._closing = False
        self.log = log or (lambda text: print(f"laplab: {text}", file=sys.stderr))
        self.failure: StoreError | None = None
        self.uploads = 0  # files uploaded so far
        self.seconds = 0.0  # wall time spent publishing, s
        self._thread: threading.Thread | None = None
        if background:
            self._thread = threading.Thread(target=self._publish_in_background, name=f"laplab-sync-{name}",
                                            daemon=True)
            self._thread.start()

    @staticmethod
    def baseline(folder: ModelFolder) -> dict[str, tuple[int, int]]:
        """{path: (size, mtime_ns)} of the files now in ``folder`` (what a pull just downloaded)."""
        return dict(_scan(folder.root))

    def sync(self) -> int:
        """Publish what changed since the last call; returns the number of files uploaded."""
        started = time.perf_counter()
        try:
            for _ in range(_ATTEMPTS):
                done = self._pass()
                if done is not None:
                    return done
        finally:
            self.seconds += time.perf_counter() - started
        raise StoreError(f"the checkpoints of {self.folder.root} kept changing while they were uploaded to "
                         f"{self.remote.url(self.name)}; try again.")

    def _pass(self) -> int | None:
        current = dict(_scan(self.folder.root))
        index_path = self.folder.root / INDEX_NAME
        changed = [rel for rel, stat in current.items() if self.known.get(rel) != stat and rel != INDEX_NAME]
        index_bytes = None
        if INDEX_NAME in current and self.known.get(INDEX_NAME) != current[INDEX_NAME]:
            index_bytes = _read(index_path)  # snapshot: the checkpoints it names exist locally now
        # Checkpoint data first, then the other files, the index last (it names the checkpoints).
        changed.sort(key=lambda rel: (checkpoint_of(rel) is None, rel))
        uploaded = 0
        for rel in changed:
            path = self.folder.root / rel
            try:
                self.remote.store.put_file(self.remote.model_key(self.name, rel), path)
            except (StoreError, OSError) as exc:
                if not path.is_file():
                    continue  # removed meanwhile (a pruned checkpoint): a later scan sees it gone
                if isinstance(exc, StoreError):
                    raise
                raise StoreError(f"cannot upload {path}: {exc}") from None
            self.known[rel] = current[rel]
            uploaded += 1
        if index_bytes is not None:
            named = _named_checkpoints(index_bytes)
            if any(f"model/{n}" not in self.known for n in named):
                return None  # the index names a checkpoint not uploaded (pruned meanwhile): scan again
            self.remote.store.put_bytes(self.remote.model_key(self.name, INDEX_NAME), index_bytes)
            self.known[INDEX_NAME] = current[INDEX_NAME]
            uploaded += 1
        if self.delete:
            for rel in [rel for rel in self.known if rel not in current]:
                try:
                    self.remote.store.delete(self.remote.model_key(self.name, rel))
                except ObjectMissing:
                    pass
                del self.known[rel]
        self.uploads += uploaded
        return uploaded

    def _safe_sync(self, _event=None) -> None:
        try:
            self.sync()
        except StoreError as exc:
            if self.failure is None:
                self.log(f"upload to {self.remote.url(self.name)} failed, training goes on and the upload is "
                         f"retried after the next iteration: {exc}")
            self.failure = exc
        else:
            if self.failure is not None:
                self.log(f"upload to {self.remote.url(self.name)} works again")
            self.failure = None

    def _publish_in_background(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            if self._closing:
                return
            self._safe_sync()

    def _request(self, _event=None) -> None:
        if self._thread is None:
            self._safe_sync()
        else:
            self._wake.set()

    on_checkpoint = on_episodes = on_iteration = on_error = _request

    def finish(self) -> None:
        """The last publication, after the background pass under way (raises :class:`StoreError` if it
        still fails)."""
        if self._thread is not None:
            self._closing = True
            self._wake.set()
            self._thread.join()
            self._thread = None
        try:
            self.sync()
        except StoreError as exc:
            raise StoreError(f"{exc} The model's files are kept in {self.folder.root}; they were not all "
                             f"uploaded to {self.remote.url(self.name)}.") from None


def _scan(root: Path) -> Iterable[tuple[str, tuple[int, int]]]:
    for directory, subdirs, files in os.walk(root):
        subdirs[:] = [d for d in subdirs if not d.startswith(".")]
        for file_name in files:
            if file_name.startswith("."):
                continue
            path = Path(directory) / file_name
            try:
                stat = path.stat()
            except FileNotFoundError:
                continue
            yield path.relative_to(root).as_posix(), (stat.st_size, stat.st_mtime_ns)


def _read(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None


def _named_checkpoints(index: bytes | None) -> set[str]:
    try:
        document = json.loads(index or b"")
    except ValueError:
        return set()
    if not isinstance(document, dict):
        return set()
    return {entry["name"] for entry in (document.get("best_checkpoint"), document.get("last_checkpoint"))
            if isinstance(entry, dict) and isinstance(entry.get("name"), str)}
