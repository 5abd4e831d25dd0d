"""Job runners: how a queued job becomes a running process, and how it is stopped.

The console talks to one small interface, :class:`JobRunner` (``start`` / ``stop`` / ``poll``);
:class:`LocalProcessRunner` runs each job as its own confined process on this machine
(``python -m laplab.jobs.worker JOB_FOLDER``). A Ray runner or a supervisor with per-job cgroups
plugs in here without touching the scheduler or the API.

A job talks back only through files in its folder ``$LAPLAB_HOME/jobs/<id>/``: ``spec.json`` (what
to do, written by the server), ``log.txt``, ``events.jsonl`` (one JSON line per iteration),
``poses.json`` (the cars now, rewritten at 15 Hz) and ``result.json`` (how it ended).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from laplab.jobs.db import Job, laplab_home
from laplab.jobs.confinement import SANDBOX_HOME, JobLimits, Mounts, bubblewrap_works, clean_environment, start_confined


@dataclass(frozen=True)
class Finished:
    job_id: int
    returncode: int


class JobRunner(Protocol):
    def start(self, job: Job) -> int:
        """Start ``job``; returns its process id (or another handle)."""

    def stop(self, job: Job) -> None:
        """Ask ``job`` to stop; it keeps its model (as Ctrl-C does on the CLI)."""

    def poll(self) -> list[Finished]:
        """Jobs that ended since the last call."""

    def running(self) -> list[int]:
        """Ids of the jobs this runner has started and that have not ended."""


def job_folder(job_id: int) -> Path:
    return laplab_home() / "jobs" / str(job_id)


def models_dir() -> Path:
    return laplab_home() / "models"


def owner_cache(owner: int) -> Path:
    return laplab_home() / "sandbox" / f"user-{owner}" / "cache"


def job_mounts(job: Job) -> Mounts:
    """What the job may see (real path -> path inside the sandbox)."""
    folder = job_folder(job.id)
    target = models_dir() / job.model
    target.mkdir(parents=True, exist_ok=True)  # train/clone start in an empty, pre-made folder
    writable = {str(folder): f"{SANDBOX_HOME}/job", str(target.resolve()): f"{SANDBOX_HOME}/models/{job.model}"}
    cache = owner_cache(job.owner)
    cache.mkdir(parents=True, exist_ok=True)
    from laplab.jobs.warmup import seed
    seed(cache / "numba", laplab_home())
    writable[str(cache)] = f"{SANDBOX_HOME}/cache"
    readonly = {}
    source = job.params.get("source")
    if source:
        readonly[str((models_dir() / source).resolve())] = f"{SANDBOX_HOME}/models/{source}"
    tracks = laplab_home() / "tracks"
    if tracks.is_dir():
        readonly[str(tracks)] = f"{SANDBOX_HOME}/tracks"
    return Mounts(writable, readonly)


STOP_FILE = "stop"


def request_stop(job_id: int) -> None:
    """The worker polls for this file and stops after the current step, keeping its model."""
    folder = job_folder(job_id)
    if folder.is_dir():
        (folder / STOP_FILE).touch()


def write_spec(job: Job) -> Path:
    folder = job_folder(job.id)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spec.json"
    path.write_text(json.dumps({"id": job.id, "kind": job.kind, "model": job.model, "params": job.params}))
    return path


class LocalProcessRunner:
    """Each job a confined child process of the server (bubblewrap when it works, else limits only)."""

    def __init__(self, limits: JobLimits = JobLimits(), sandbox: bool | None = None):
        self.limits = limits
        self.sandbox = bubblewrap_works() if sandbox is None else sandbox
        self._processes: dict[int, subprocess.Popen] = {}

    def start(self, job: Job) -> int:
        write_spec(job)
        folder = job_folder(job.id)
        inside = f"{SANDBOX_HOME}/job" if self.sandbox else str(folder)
        home = SANDBOX_HOME if self.sandbox else str(laplab_home())
        env = clean_environment({"LAPLAB_HOME": home,
                                 "NUMBA_CACHE_DIR": f"{home}/cache/numba" if self.sandbox
                                 else str(owner_cache(job.owner) / "numba")}, sandboxed=self.sandbox)
        mounts = job_mounts(job)
        command = [sys.executable, "-m", "laplab.jobs.worker", inside]
        process = start_confined(command, mounts, self._limits_for(job), folder / "log.txt", env, self.sandbox)
        self._processes[job.id] = process
        return process.pid

    def _limits_for(self, job: Job) -> JobLimits:
        """CPU time: the job's wall budget on every core, plus a margin for start-up and evaluation."""
        budget = float(job.params.get("max_time_s") or 0) * (os.cpu_count() or 1) * 1.5 + 600
        return JobLimits(self.limits.memory_bytes, int(min(self.limits.cpu_seconds, budget)), self.limits.file_bytes)

    def stop(self, job: Job) -> None:
        """Ask through the job's folder (a signal would end bubblewrap, and with it the job, at once)."""
        request_stop(job.id)

    def kill(self, job_id: int) -> None:
        process = self._processes.get(job_id)
        if process is not None and process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)

    def poll(self) -> list[Finished]:
        done = [Finished(job_id, p.returncode) for job_id, p in self._processes.items() if p.poll() is not None]
        for item in done:
            del self._processes[item.job_id]
        return done

    def running(self) -> list[int]:
        return [job_id for job_id, p in self._processes.items() if p.poll() is None]

    def shutdown(self, grace_s: float = 5.0) -> None:
        """Stop every job (a stop request, then SIGKILL after ``grace_s``): each keeps its last checkpoint."""
        for job_id, process in list(self._processes.items()):
            if process.poll() is None:
                request_stop(job_id)
        for job_id, process in list(self._processes.items()):
            try:
                process.wait(grace_s)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
