"""One job per model folder: an exclusive ``fcntl.flock`` on ``<model>/.laplab-job.lock``.

The lock is held on an open file for the job's lifetime and released by the operating system when
the process ends, however it ends (a SIGKILL included), so a dead job never leaves a stale lock.
The holder writes who it is (pid, host, start time, command) into the file; a second job that
cannot take the lock reads that and fails at once with :class:`ModelBusyError` naming the holder.
Readers (evaluate, export) take no lock: checkpoints and JSON files are replaced atomically.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

LOCK_FILE_NAME = ".laplab-job.lock"


class ModelBusyError(RuntimeError):
    """Another job holds the model folder's lock; the message names the holder."""


@dataclass(frozen=True)
class LockHolder:
    """Who holds a model lock: process id, host name, start time (Unix s) and command line."""

    pid: int | None
    host: str | None
    started: float | None
    command: str | None

    def describe(self) -> str:
        if self.pid is None:
            return "another job (it has not written its details yet)"
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started)) if self.started else "?"
        text = f"process {self.pid} on host {self.host} since {when}"
        return text + (f" ({self.command})" if self.command else "")


def lock_path(model_root: str | os.PathLike) -> Path:
    return Path(model_root) / LOCK_FILE_NAME


def read_holder(model_root: str | os.PathLike) -> LockHolder:
    """The details the current (or last) holder wrote; fields are None when unreadable."""
    try:
        data = json.loads(lock_path(model_root).read_text(encoding="utf-8"))
        return LockHolder(int(data["pid"]), str(data["host"]), float(data["started"]), data.get("command"))
    except (OSError, ValueError, KeyError, TypeError):
        return LockHolder(None, None, None, None)


class ModelLock:
    """The exclusive job lock of one model folder. ``acquire()`` or ``with ModelLock(root):``."""

    def __init__(self, model_root: str | os.PathLike, what: str = "trained"):
        self.root = Path(model_root)
        self.what = what
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, command: str | None = None, wait_s: float = 1.0) -> "ModelLock":
        """Take the lock; raises :class:`ModelBusyError` naming the holder if it is still taken after
        ``wait_s`` seconds (a short wait lets a job that is being killed finish dying)."""
        if self._fd is not None:
            return self
        fd = os.open(lock_path(self.root), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() < deadline:
                    time.sleep(0.05)
                    continue
            os.close(fd)
            holder = read_holder(self.root)
            raise ModelBusyError(
                f"model {self.root.name!r} is being {self.what} by another job: {holder.describe()}. "
                f"One job at a time may write a model folder ({self.root}); wait for that job to end or stop "
                f"it (Ctrl-C in its terminal, or `kill {holder.pid if holder.pid else 'PID'}`).") from None
        info = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                           "command": command if command is not None else " ".join(["laplab", *sys.argv[1:]])})
        os.ftruncate(fd, 0)
        os.pwrite(fd, info.encode() + b"\n", 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)  # closing the last descriptor releases the flock

    def __del__(self) -> None:
        try:
            self.release()
        except Exception:  # noqa: BLE001 - interpreter shutdown: the OS releases the lock anyway
            pass

    def __enter__(self) -> "ModelLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def is_locked(model_root: str | os.PathLike) -> bool:
    """Whether a job holds the folder's lock right now (probes with a non-blocking shared lock)."""
    path = lock_path(model_root)
    if not path.exists():
        return False
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False
