"""Model archives: one model and one checkpoint packed as ``.tar.gz``, and their safe import.

An archive holds a subset of the model folder, at the same paths (see docs/car.md)::

    laplab-export.json                 manifest: format, version, model name, checkpoint, sha256 per file
    model/model_metadata.json
    model/<iteration>_Step-<steps>.ckpt  the exported checkpoint (the networks' weights)
    model/<...>.ckpt.resume            only with full_state: optimizer state and target networks, so
                                       `laplab train --resume` continues exactly (the last checkpoint only)
    model/deepracer_checkpoints.json   best and last both name that checkpoint
    ip/hyperparameters.json
    reward_function.py
    laplab.json
    metrics/TrainingMetrics.json       (when present)
    metrics/laplab-iterations.json     (when present)

Import checks every member before anything is written (regular files at the paths above only: no
absolute names, ``..``, links or devices; sizes and sha256 as the manifest says), extracts into a
hidden temporary folder beside the models, checks the files there (JSON, reward source, checkpoint
index) and runs the caller's validation (:mod:`laplab.train.archive` checks metadata,
hyperparameters, laplab.json and that the checkpoint loads into the model's network), then renames
the folder into place: a model appears complete or not at all. This module imports nothing above
``laplab.store``.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import posixpath
import re
import shutil
import tarfile
import secrets
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from laplab import __version__
from laplab.store.atomic import atomic_write_with
from laplab.store.checkpoints import CHECKPOINT_NAME_PATTERN, CheckpointStore
from laplab.store.layout import ModelFolder, model_folder, models_root, validate_model_name

ARCHIVE_FORMAT = "laplab-model"
ARCHIVE_VERSION = 1
MANIFEST = "laplab-export.json"
_FIXED_MEMBERS = ("model/model_metadata.json", "model/deepracer_checkpoints.json", "ip/hyperparameters.json",
                  "reward_function.py", "laplab.json")
_OPTIONAL_MEMBERS = ("metrics/TrainingMetrics.json", "metrics/laplab-iterations.json")
_CHECKPOINT_MEMBER = re.compile(r"model/[0-9]+_Step-[0-9]+\.ckpt")
_RESUME_MEMBER = re.compile(r"model/[0-9]+_Step-[0-9]+\.ckpt\.resume")


class ArchiveError(ValueError):
    """A model archive that cannot be written or imported; the message names the file and the reason."""


@dataclass(frozen=True)
class ImportedModel:
    name: str
    folder: ModelFolder
    checkpoint: str  # file name of the checkpoint, now the model's best and last


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _tar_info(name: str, size: int, mtime: float) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = size, int(mtime), 0o644
    return info


def export_model_archive(name: str, checkpoint: str = "best", out: str | os.PathLike | None = None,
                         verify: Callable[[BinaryIO, str], None] | None = None, full_state: bool = False) -> Path:
    """Pack model ``name`` at ``checkpoint`` ('best', 'last' or a file name) into the file ``out``
    (default, or when ``out`` is a folder: ``<name>.tar.gz`` in it / here), written atomically.
    The archive carries the checkpoint's weights; ``full_state`` adds its resume state (optimizers,
    target networks: the last checkpoint has one), for moving a job between machines.

    Every member is read once and packed from those bytes, so a job training the model meanwhile
    cannot make the manifest disagree with the archive. ``verify(handle, where)`` checks the opened
    checkpoint before anything is written (it raises on a damaged one). Returns the archive's path."""
    folder = model_folder(name)
    if not folder.exists():
        raise FileNotFoundError(f"no model named {name!r} (looked in {folder.root}).")
    store = CheckpointStore(folder)
    checkpoint_name, handle = _open_checkpoint(store, checkpoint)
    with handle:
        if verify is not None:
            verify(handle, str(folder.model_dir / checkpoint_name))
        handle.seek(0)
        checkpoint_bytes = handle.read()
    if not checkpoint_bytes:
        raise ArchiveError(f"checkpoint {folder.model_dir / checkpoint_name} is empty; nothing was written.")
    record = next((r for r in (store.best(), store.last()) if r is not None and r.name == checkpoint_name), None)
    now = time.time()
    records = {"name": checkpoint_name, "avg_eval_metric": None if record is None else record.avg_eval_metric,
               "time_stamp": now if record is None else record.time_stamp}
    members = {"model/deepracer_checkpoints.json": json.dumps(
        {"best_checkpoint": records, "last_checkpoint": records}, indent=2).encode() + b"\n"}
    for member in _FIXED_MEMBERS + _OPTIONAL_MEMBERS:
        if member not in members:
            try:
                members[member] = (folder.root / member).read_bytes()
            except FileNotFoundError:
                pass
    missing = [m for m in _FIXED_MEMBERS if m not in members]
    if missing:
        raise ArchiveError(f"model {name!r} lacks {missing} in {folder.root}; it cannot be exported "
                           "(was it created by laplab train?)")
    members[f"model/{checkpoint_name}"] = checkpoint_bytes
    if full_state:
        try:
            members[f"model/{checkpoint_name}.resume"] = store.resume_path(checkpoint_name).read_bytes()
        except FileNotFoundError:
            last = store.last()
            raise ArchiveError(f"checkpoint {checkpoint_name} of model {name!r} has no resume state (optimizers, "
                               f"target networks): only the last checkpoint has one "
                               f"({last.name if last else 'none yet'}); export --checkpoint last, or leave out "
                               f"the full state. Nothing was written.") from None
    manifest = {"format": ARCHIVE_FORMAT, "version": ARCHIVE_VERSION, "name": name,
                "checkpoint": checkpoint_name, "laplab_version": __version__, "exported_at": now,
                "files": {m: {"sha256": hashlib.sha256(b).hexdigest(), "size": len(b)} for m, b in members.items()}}
    manifest_bytes = json.dumps(manifest, indent=2).encode() + b"\n"
    target = Path(out) if out is not None else Path.cwd()
    if target.is_dir():
        target = target / f"{name}.tar.gz"

    def write(temporary: Path) -> None:
        with tarfile.open(temporary, "w:gz", format=tarfile.PAX_FORMAT) as tar:
            tar.addfile(_tar_info(MANIFEST, len(manifest_bytes), now), io.BytesIO(manifest_bytes))
            for member in sorted(members):
                tar.addfile(_tar_info(member, len(members[member]), now), io.BytesIO(members[member]))

    return atomic_write_with(target, write)


def _open_checkpoint(store: CheckpointStore, which: str) -> tuple[str, BinaryIO]:
    """Open checkpoint ``which``; re-resolve 'best'/'last' if a training job pruned it meanwhile."""
    for attempt in range(5):
        path = store.resolve(which)
        try:
            return path.name, open(path, "rb")  # noqa: SIM115 - closed by the caller
        except FileNotFoundError:
            if attempt == 4 or which not in ("best", "last"):
                raise
    raise AssertionError("unreachable")


def _check_members(archive: Path, tar: tarfile.TarFile) -> dict[str, tarfile.TarInfo]:
    """Every member is a regular file at an allowed relative path (directories are ignored)."""
    members: dict[str, tarfile.TarInfo] = {}
    for info in tar.getmembers():
        name = info.name
        clean = posixpath.normpath(name.removeprefix("./")) if name not in ("", ".") else "."
        if (name.startswith(("/", "\\")) or "\\" in name or re.match(r"[A-Za-z]:", name)
                or ".." in name.split("/") or clean.startswith("..")):
            raise ArchiveError(f"{archive}: member {name!r} has an absolute path or '..'; refusing to import.")
        if info.isdir():
            continue
        if not info.isfile():
            raise ArchiveError(f"{archive}: member {name!r} is a link or a special file; a model archive holds "
                               "regular files only.")
        if (clean not in _FIXED_MEMBERS + _OPTIONAL_MEMBERS + (MANIFEST,) and not _CHECKPOINT_MEMBER.fullmatch(clean)
                and not _RESUME_MEMBER.fullmatch(clean)):
            raise ArchiveError(f"{archive}: unexpected member {name!r}; a laplab model archive holds only "
                               f"{MANIFEST}, {', '.join(_FIXED_MEMBERS + _OPTIONAL_MEMBERS)} and one model/*.ckpt.")
        if clean in members:
            raise ArchiveError(f"{archive}: member {clean!r} appears twice.")
        members[clean] = info
    return members


def _read_manifest(archive: Path, tar: tarfile.TarFile, members: dict[str, tarfile.TarInfo]) -> dict:
    if MANIFEST not in members:
        raise ArchiveError(f"{archive}: no {MANIFEST}; this is not an archive written by `laplab export`.")
    try:
        manifest = json.loads(tar.extractfile(members[MANIFEST]).read())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ArchiveError(f"{archive}: {MANIFEST} is not valid JSON ({exc}).") from None
    if not isinstance(manifest, dict) or manifest.get("format") != ARCHIVE_FORMAT:
        raise ArchiveError(f"{archive}: {MANIFEST} does not describe a {ARCHIVE_FORMAT!r} archive.")
    if manifest.get("version") != ARCHIVE_VERSION:
        raise ArchiveError(f"{archive}: archive version {manifest.get('version')!r} is not supported "
                           f"(this laplab reads version {ARCHIVE_VERSION}).")
    listed = manifest.get("files")
    checkpoint = manifest.get("checkpoint")
    if not (isinstance(listed, dict) and isinstance(checkpoint, str) and CHECKPOINT_NAME_PATTERN.fullmatch(checkpoint)):
        raise ArchiveError(f"{archive}: {MANIFEST} lacks a valid 'files' table or 'checkpoint' name.")
    present = set(members) - {MANIFEST}
    stray = [m for m in present if _RESUME_MEMBER.fullmatch(m) and m != f"model/{checkpoint}.resume"]
    if stray:
        raise ArchiveError(f"{archive}: {stray[0]} is the resume state of another checkpoint than {checkpoint}.")
    expected = set(_FIXED_MEMBERS) | {f"model/{checkpoint}"}
    missing, unlisted = sorted((set(listed) | expected) - present), sorted(present - set(listed))
    if missing or unlisted:
        raise ArchiveError(f"{archive}: the archive lacks {missing} and holds unlisted {unlisted} compared with "
                           f"its {MANIFEST}; it is incomplete or was altered.")
    for member, entry in listed.items():
        if not isinstance(entry, dict) or members[member].size != entry.get("size"):
            raise ArchiveError(f"{archive}: {member} has {members[member].size} bytes, the manifest says "
                               f"{entry.get('size') if isinstance(entry, dict) else entry!r}; the archive is damaged.")
    return manifest


def import_model_archive(path: str | os.PathLike, name: str | None = None,
                         validate: Callable[[ModelFolder, str, str], None] | None = None) -> ImportedModel:
    """Restore an archive as model ``name`` (default: the exported model's name); see the module
    docstring for the checks. ``validate(staging folder, checkpoint name, archive)`` checks the
    model before it is moved into place (laplab.train.archive passes one that loads the checkpoint).
    Refuses a name that is taken. A truncated or damaged archive raises :class:`ArchiveError`."""
    try:
        return _import(Path(path), name, validate)
    except (EOFError, zlib.error, tarfile.TarError) as exc:
        raise ArchiveError(f"{path}: the archive is damaged or truncated ({type(exc).__name__}: {exc}); "
                           "nothing was imported. Export it again or copy it again.") from None
    except OSError as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise ArchiveError(f"{path}: cannot read the archive ({exc}); nothing was imported.") from None


def _import(archive: Path, name: str | None, validate) -> ImportedModel:
    if not archive.is_file():
        raise FileNotFoundError(f"{archive}: no such archive file.")
    try:
        tar = tarfile.open(archive, "r:gz")
    except (tarfile.TarError, OSError) as exc:
        raise ArchiveError(f"{archive}: not a gzip-compressed tar archive ({exc}).") from None
    with tar:
        members = _check_members(archive, tar)
        manifest = _read_manifest(archive, tar, members)
        if name is None and not isinstance(manifest.get("name"), str):
            raise ArchiveError(f"{archive}: {MANIFEST} names no model; give one with --name NEW.")
        new_name = validate_model_name(name if name is not None else manifest["name"])
        target = model_folder(new_name)
        if target.exists():
            raise ArchiveError(f"a model named {new_name!r} already exists at {target.root}; models are "
                               "immutable: import under another name with --name NEW.")
        root = models_root()
        root.mkdir(parents=True, exist_ok=True)
        staging = root / f".import-{new_name}-{secrets.token_hex(6)}"  # hidden: list_models skips it
        staging.mkdir()
        try:
            tar.extractall(staging, members=[members[m] for m in manifest["files"]], filter="data")
            for member, entry in manifest["files"].items():
                if _sha256(staging / member) != entry.get("sha256"):
                    raise ArchiveError(f"{archive}: {member} does not match its sha256 in {MANIFEST}; "
                                       "the archive is damaged or was altered.")
            check_model_files(ModelFolder(staging), manifest["checkpoint"], str(archive))
            if validate is not None:
                validate(ModelFolder(staging), manifest["checkpoint"], str(archive))
            try:
                os.rename(staging, target.root)
            except OSError as exc:
                raise ArchiveError(f"cannot create {target.root}: {exc}.") from None
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
    return ImportedModel(new_name, target, manifest["checkpoint"])


def check_model_files(folder: ModelFolder, checkpoint: str, source: str) -> None:
    """What the store can check without the layers above it: the JSON files parse, the reward
    source compiles, and deepracer_checkpoints.json names ``checkpoint``."""
    for member in ("model/model_metadata.json", "ip/hyperparameters.json", "laplab.json"):
        try:
            json.loads((folder.root / member).read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ArchiveError(f"{source}: {member} is not valid JSON ({exc}).") from None
    try:
        compile(folder.read_reward_function(), f"{source}: reward_function.py", "exec")
    except (SyntaxError, UnicodeDecodeError, ValueError) as exc:
        raise ArchiveError(f"{source}: reward_function.py does not compile: {exc}") from None
    store = CheckpointStore(folder)
    try:
        names = store.resolve("best").name, store.resolve("last").name
    except (ValueError, FileNotFoundError) as exc:
        raise ArchiveError(f"{source}: model/deepracer_checkpoints.json: {exc}") from None
    if names != (checkpoint, checkpoint):
        raise ArchiveError(f"{source}: model/deepracer_checkpoints.json does not name {checkpoint}.")
