"""Where a DeepRacer model comes from, made into a local folder that ``laplab import`` reads.

A source is a folder, a ``.tar.gz`` / ``.tgz`` / ``.tar`` or ``.zip`` archive, a bare ``model.pb``
(with its ``model_metadata.json`` beside it), or an ``s3://bucket/prefix`` (endpoint
``$AWS_ENDPOINT_URL``: the layout deepracer-for-cloud's ``dr-upload-model`` writes). Archives and
prefixes are unpacked into a temporary folder, removed afterwards, after checking every member:
regular files only (no links, devices, absolute paths or ``..``), in all at most ``max_bytes``
(DeepRacer on AWS imports models under 1 GB). Errors are :class:`ImportSourceError`, one paragraph
naming the source and the member at fault.
"""

from __future__ import annotations

import contextlib
import posixpath
import re
import shutil
import stat
import tarfile
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

from laplab.errors import UserError

MAX_IMPORT_BYTES = 1 << 30  # DeepRacer on AWS: "must be under 1GB"
ARCHIVE_SUFFIXES = (".tar.gz", ".tgz", ".tar", ".zip")
MODEL_PARTS = ("model", "ip", "agent")  # the folders of a prefix that hold the model (besides its root files)


class ImportSourceError(UserError, ValueError):
    """A model source that cannot be read or is refused; the message names the source and the member."""


def _check_name(source: str, name: str) -> str:
    """``name`` as a clean relative path, or :class:`ImportSourceError` for an absolute one or ``..``."""
    if (name.startswith(("/", "\\")) or "\\" in name or re.match(r"[A-Za-z]:", name)
            or ".." in name.split("/")):
        raise ImportSourceError(f"{source}: member {name!r} has an absolute path or '..'; refusing to import it "
                                "(an archive must not write outside its own folder). Nothing was imported.")
    return posixpath.normpath(name.removeprefix("./"))


def _too_large(source: str, total: int, max_bytes: int) -> ImportSourceError:
    return ImportSourceError(f"{source}: {total / 1e6:.1f} MB unpacked, over the import limit of "
                             f"{max_bytes / 1e6:.0f} MB (DeepRacer on AWS imports models under 1 GB). Remove old "
                             "checkpoints (keep the one .coach_checkpoint names) and import again. Nothing was imported.")


def _unpack_tar(path: Path, target: Path, max_bytes: int) -> None:
    source = str(path)
    try:
        with tarfile.open(path, "r:*") as tar:
            members, total = [], 0
            for info in tar.getmembers():
                name = _check_name(source, info.name)
                if info.isdir() or name == ".":
                    continue
                if not info.isfile():
                    kind = "a link" if info.issym() or info.islnk() else "a special file"
                    raise ImportSourceError(f"{source}: member {info.name!r} is {kind}; a model archive holds "
                                            "regular files only. Nothing was imported.")
                total += info.size
                if total > max_bytes:
                    raise _too_large(source, total, max_bytes)
                members.append(info)
            tar.extractall(target, members=members, filter="data")
    except (tarfile.TarError, EOFError, OSError) as exc:
        if isinstance(exc, ImportSourceError):
            raise
        raise ImportSourceError(f"{source}: not a readable tar archive, or truncated ({type(exc).__name__}: "
                                f"{' '.join(str(exc).split())[:200]}). Copy it again. Nothing was imported.") from None


def _unpack_zip(path: Path, target: Path, max_bytes: int) -> None:
    source = str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members, total = [], 0
            for info in archive.infolist():
                name = _check_name(source, info.filename)
                if info.is_dir() or name == ".":
                    continue
                mode = info.external_attr >> 16
                if stat.S_IFMT(mode) not in (0, stat.S_IFREG):  # 0: no Unix type recorded
                    raise ImportSourceError(f"{source}: member {info.filename!r} is a link or a special file; a "
                                            "model archive holds regular files only. Nothing was imported.")
                total += info.file_size
                if total > max_bytes:
                    raise _too_large(source, total, max_bytes)
                members.append((name, info))
            for name, info in members:
                destination = target / name
                destination.parent.mkdir(parents=True, exist_ok=True)
                with archive.open(info) as reader, open(destination, "wb") as writer:
                    shutil.copyfileobj(reader, writer, 1 << 20)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, ImportSourceError):
            raise
        raise ImportSourceError(f"{source}: not a readable zip archive, or truncated ({type(exc).__name__}: "
                                f"{' '.join(str(exc).split())[:200]}). Copy it again. Nothing was imported.") from None


def _download_prefix(url: str, target: Path, max_bytes: int) -> None:
    from laplab.store.s3 import ObjectStore, StoreError, parse_store_url
    try:
        store = ObjectStore(parse_store_url(url))
        store.check()
        prefix = store.location.key()
        base = prefix + "/" if prefix else ""
        objects = store.list(base)
        if not objects:
            raise ImportSourceError(f"{url}: no such prefix: the bucket holds no objects under {base or '/'} (is "
                                    "the prefix spelled as dr-upload-model wrote it, and $AWS_ENDPOINT_URL the right "
                                    "server?). Nothing was imported.")
        wanted = {}
        for key, (size, _) in objects.items():
            relative = _check_name(url, key[len(base):])
            # the model's files only: a training prefix also holds simtraces, metrics and logs
            if relative not in (".", "") and not key.endswith("/") and (
                    "/" not in relative or relative.split("/")[0] in MODEL_PARTS):
                wanted[key] = (relative, size)
        total = sum(size for _, size in wanted.values())
        if total > max_bytes:
            raise _too_large(url, total, max_bytes)
        for key, (relative, _) in sorted(wanted.items()):
            store.get_file(key, target / relative)
    except StoreError as exc:
        raise ImportSourceError(str(exc), field="source") from None


def _copy_bare_graph(path: Path, target: Path) -> None:
    """A bare ``model.pb``: it and the ``model_metadata.json`` beside it."""
    metadata = path.parent / "model_metadata.json"
    if not metadata.is_file():
        raise ImportSourceError(f"{path}: a bare model.pb needs its model_metadata.json beside it ({metadata} is "
                                "missing): the graph alone does not say the action space. Nothing was imported.")
    shutil.copyfile(path, target / "model.pb")
    shutil.copyfile(metadata, target / "model_metadata.json")


def model_root(folder: Path) -> Path:
    """The folder holding the model: ``folder``, or its one subfolder when the archive wrapped the
    files in a folder of their own (as a download of the whole model folder does)."""
    markers = ("model_metadata.json", "model", "agent", "model.pb")
    current = folder
    for _ in range(3):
        if any((current / marker).exists() for marker in markers):
            return current
        entries = [entry for entry in current.iterdir() if not entry.name.startswith(".")]
        if len(entries) != 1 or not entries[0].is_dir():
            return current
        current = entries[0]
    return current


@contextlib.contextmanager
def staged_source(source: str | Path, max_bytes: int = MAX_IMPORT_BYTES) -> Iterator[Path]:
    """The model folder of ``source`` (a folder is used in place; anything else is unpacked into a
    temporary folder, removed when the block ends)."""
    text = str(source)
    if text.startswith("s3://"):
        kind = "s3"
    else:
        path = Path(source)
        if not path.exists():
            raise ImportSourceError(f"{path}: no such file or folder (give a model folder, a .tar.gz or .zip, a "
                                    "model.pb, or s3://BUCKET/PREFIX).", field="source")
        if path.is_dir():
            yield model_root(path)
            return
        name = path.name.lower()
        kind = ("tar" if name.endswith((".tar.gz", ".tgz", ".tar")) else "zip" if name.endswith(".zip")
                else "pb" if name.endswith(".pb") else "")
        if not kind:
            raise ImportSourceError(f"{path}: not a model folder, .tar.gz, .tgz, .tar, .zip or model.pb; laplab "
                                    "cannot tell how to read it.", field="source")
        if kind != "pb" and path.stat().st_size > max_bytes:
            raise _too_large(text, path.stat().st_size, max_bytes)
    with tempfile.TemporaryDirectory(prefix="laplab-import-") as temporary:
        target = Path(temporary)
        if kind == "s3":
            _download_prefix(text, target, max_bytes)
        elif kind == "tar":
            _unpack_tar(path, target, max_bytes)
        elif kind == "zip":
            _unpack_zip(path, target, max_bytes)
        else:
            _copy_bare_graph(path, target)
        yield model_root(target)
