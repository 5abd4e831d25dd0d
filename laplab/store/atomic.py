"""Atomic file writes: a reader sees either the old file or the complete new one, never half.

Each write goes to a temporary file in the destination's own folder (same filesystem, so the
final `os.replace` is an atomic rename), is flushed and fsync'ed, then replaces the target; the
folder is fsync'ed afterwards so the rename itself survives a power cut (best effort: some
platforms cannot open a directory).
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from laplab.errors import UserError


def _fsync_directory(folder: Path) -> None:
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass
    finally:
        os.close(descriptor)


def _temporary_sibling(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(descriptor)
    return Path(temporary)


def atomic_write_with(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Atomically create or replace `path` with whatever `write(temporary_path)` writes.

    `write` receives a fresh, empty temporary file path in the same folder (for example
    `lambda p: torch.save(state, p)`); after it returns the file is fsync'ed and renamed onto
    `path`. If `write` raises, the temporary file is removed and `path` is left untouched.
    Parent folders are created. Returns `path` as a Path.
    """
    target = Path(path)
    temporary = _temporary_sibling(target)
    try:
        write(temporary)
        with open(temporary, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _fsync_directory(target.parent)
    return target


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Atomically create or replace `path` with `data`. Returns `path` as a Path."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"atomic_write_bytes({str(path)!r}) needs bytes, got {type(data).__name__}")

    def write(temporary: Path) -> None:
        with open(temporary, "wb") as handle:
            handle.write(data)
            handle.flush()

    return atomic_write_with(path, write)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Atomically create or replace `path` with `text` (newlines written as given)."""
    return atomic_write_bytes(path, text.encode(encoding))


def atomic_write_json(path: str | os.PathLike, obj: Any, indent: int | None = 2) -> Path:
    """Atomically create or replace `path` with `obj` as JSON (UTF-8, trailing newline).

    NaN and infinity are refused (they are not JSON and break other readers): the error
    names the file.
    """
    try:
        text = json.dumps(obj, indent=indent, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise ValueError(f"cannot write {str(path)!r} as JSON: {error}") from error
    return atomic_write_text(path, text + "\n")


class CorruptFileError(UserError, ValueError):
    """A file laplab wrote that is damaged (truncated, torn, edited); the message names it."""


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing file raises FileNotFoundError, a malformed one
    :class:`CorruptFileError`, each naming the path."""
    source = Path(path)
    try:
        text = source.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{str(source)!r} does not exist") from None
    except UnicodeDecodeError as error:
        raise CorruptFileError(f"{str(source)!r} is damaged: not UTF-8 text ({error.reason} at byte "
                               f"{error.start}); restore it or delete it") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise CorruptFileError(
            f"{str(source)!r} is damaged: not valid JSON (line {error.lineno}, column {error.colno}: "
            f"{error.msg}), for example cut short by a full disk or a copy that did not finish; restore it "
            f"or delete it"
        ) from None
