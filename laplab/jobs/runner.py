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
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Protocol

from laplab.jobs.db import Job
from laplab.jobs.confinement import SANDBOX_HOME, JobLimits, Mounts, bubblewrap_works, clean_environment, start_confined
from laplab.jobs.priority import job_priority
from laplab.jobs.supervisor import ENV_LIMITS
from laplab.settings import Settings, current_settings

CRASH_LOG = "crash.txt"  # faulthandler's dump of a job that crashed, in its folder


@dataclass(frozen=True)
class Finished:
    """A job that ended: its exit status, and the runner's reason when the runner ended it."""

    job_id: int
    returncode: int
    error: str | None = None


class JobRunner(Protocol):
    def start(self, job: Job) -> int:
        """Start ``job``; returns its process id (or another handle)."""

    def stop(self, job: Job) -> None:
        """Ask ``job`` to stop; it keeps its model (as Ctrl-C does on the CLI)."""

    def poll(self) -> list[Finished]:
        """Jobs that ended since the last call (the runner ends those past their wall-clock limit)."""

    def running(self) -> list[int]:
        """Ids of the jobs this runner has started and that have not ended."""


def wall_limit_s(job: Job, margin_s: float) -> float:
    """The most wall-clock seconds ``job`` may run: its own budget plus ``margin_s`` (start-up,
    the last checkpoint and evaluation). ``params["wall_limit_s"]`` sets it for one job."""
    if job.params.get("wall_limit_s"):
        return float(job.params["wall_limit_s"])
    if job.kind == "evaluate":  # simulated time runs faster than the wall clock
        budget = float(job.params.get("trials") or 3) * float(job.params.get("max_trial_time") or 600.0)
    elif job.kind == "export":
        budget = 0.0
    elif job.kind == "duel":  # simulated seconds: the wall clock runs slower only when the machine is busy
        budget = float(job.params.get("max_time_s") or 180.0)
    else:
        budget = float(job.params.get("max_time_s") or 0.0)
        if budget <= 0 or not math.isfinite(budget):
            return math.inf  # a resume with its saved budget, unknown here: the CPU limit still applies
    return budget + margin_s


def overtime_message(limit_s: float, margin_s: float) -> str:
    return (f"the job was still running {limit_s:.0f} s after it started, past its wall-clock limit (its own time "
            f"budget + {margin_s:.0f} s), and was ended. A job that uses no CPU for that long is usually "
            "blocked: a reward function sleeping or waiting on a lock, or reading from something that never "
            "answers. The model keeps its last checkpoint: fix the reward function and train a clone, or resume it.")


def job_folder(job_id: int) -> Path:
    return current_settings().jobs_dir / str(job_id)


def models_dir() -> Path:
    return current_settings().models_dir


def owner_cache(owner: int) -> Path:
    return current_settings().sandbox_dir / f"user-{owner}" / "cache"


READ_ONLY_KINDS = ("export", "duel")
# the jobs that yield the CPU to trainings (JobLimits.evaluation_priority, `laplab serve --evaluation-priority`):
# an evaluation (the model page's or a race submission's) and a head-to-model race
EVALUATION_KINDS = ("evaluate", "duel")


def job_mounts(job: Job) -> Mounts:
    """What the job may see (real path -> path inside the sandbox)."""
    folder = job_folder(job.id)
    target = models_dir() / job.model
    target.mkdir(parents=True, exist_ok=True)  # train/clone start in an empty, pre-made folder
    writable = {str(folder): f"{SANDBOX_HOME}/job"}
    readonly = {}
    model_view = readonly if job.kind in READ_ONLY_KINDS else writable  # an export or a race only reads its model
    model_view[str(target.resolve())] = f"{SANDBOX_HOME}/models/{job.model}"
    if job.kind == "duel":  # a head-to-model race: its opponents, read-only (the console checked who may race them)
        for opponent in job.params.get("models", [])[1:]:  # one deleted since: the race says it is missing
            if (models_dir() / opponent).is_dir():
                readonly[str((models_dir() / opponent).resolve())] = f"{SANDBOX_HOME}/models/{opponent}"
    cache = owner_cache(job.owner)
    cache.mkdir(parents=True, exist_ok=True)
    from laplab.jobs.warmup import seed
    seed(cache / "numba", current_settings().home)
    writable[str(cache)] = f"{SANDBOX_HOME}/cache"
    source = job.params.get("source")
    if source:
        readonly[str((models_dir() / source).resolve())] = f"{SANDBOX_HOME}/models/{source}"
    tracks = current_settings().tracks_dir
    if tracks.is_dir():
        readonly[str(tracks)] = f"{SANDBOX_HOME}/tracks"
    return Mounts(writable, readonly)


STOP_FILE = "stop"


def request_stop(job_id: int) -> None:
    """The worker polls for this file and stops after the current step, keeping its model."""
    folder = job_folder(job_id)
    if folder.is_dir():
        (folder / STOP_FILE).touch()


def write_spec(job: Job, cluster: dict | None = None, sandboxed: bool = False) -> Path:
    """The job's ``spec.json``; ``cluster`` (address, workers) when its rollout workers run on Ray;
    ``sandboxed``: the job runs inside bubblewrap (where the console runs every reward, whoever wrote it)."""
    folder = job_folder(job.id)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spec.json"
    spec = {"id": job.id, "kind": job.kind, "model": job.model, "params": job.params, "sandboxed": bool(sandboxed)}
    if cluster is not None:
        spec["cluster"] = cluster
    path.write_text(json.dumps(spec))
    return path


class LocalProcessRunner:
    """Each job a confined child process of the server (bubblewrap when it works, else limits only)."""

    def __init__(self, limits: JobLimits | None = None, sandbox: bool | None = None, cluster=None,
                 threads_per_job: int = 1):
        self.limits = limits if limits is not None else JobLimits.console()
        self.sandbox = bubblewrap_works() if sandbox is None else sandbox
        self.cluster = cluster  # a laplab.cluster.console.RayCluster: training jobs' workers run there
        # a job's OpenMP threads: its camera learner's torch threads and its simulator's numba threads
        # (vector networks use one torch thread whatever this says); the server's $OMP_NUM_THREADS wins
        self.threads_per_job = max(1, int(threads_per_job))
        self._processes: dict[int, subprocess.Popen] = {}
        self._deadlines: dict[int, tuple[float, float]] = {}  # job id -> (monotonic deadline, limit s)
        self._overtime: dict[int, str] = {}

    def start(self, job: Job) -> int:
        from laplab.cluster.console import CLUSTER_KINDS
        on_cluster = self.cluster is not None and job.kind in CLUSTER_KINDS
        write_spec(job, self.cluster.to_spec() if on_cluster else None, self.sandbox)
        folder = job_folder(job.id)
        inside = f"{SANDBOX_HOME}/job" if self.sandbox else str(folder)
        limits = self._limits_for(job)
        env = self.environment(job, on_cluster)
        # the worker enters the job as `laplab train`'s supervised child does (laplab.jobs.supervisor.enter_job):
        # the same limits, the reward watchdog, the os._exit guard, the output cap and a crash log
        env[ENV_LIMITS] = json.dumps({**asdict(limits), "status_fd": None, "crash_log": f"{inside}/{CRASH_LOG}"})
        mounts = job_mounts(job)
        if on_cluster:  # the network, to reach the cluster; the same files as any job
            mounts = replace(mounts, network=True)
        command = [sys.executable, "-m", "laplab.jobs.worker", inside]
        process = start_confined(command, mounts, limits, folder / "log.txt", env, self.sandbox)
        self._processes[job.id] = process
        limit = wall_limit_s(job, self.limits.wall_margin_s)
        self._deadlines[job.id] = (time.monotonic() + limit, limit)
        return process.pid

    def environment(self, job: Job, on_cluster: bool = False) -> dict[str, str]:
        """The variables a job's process sees (:func:`clean_environment`, plus its home, numba cache,
        torch threads and, on a Ray cluster, the cluster's address)."""
        where = (Settings.at(SANDBOX_HOME) if self.sandbox else current_settings()).to_env()
        return clean_environment({**where,
                                  "NUMBA_CACHE_DIR": f"{SANDBOX_HOME}/cache/numba" if self.sandbox
                                  else str(owner_cache(job.owner) / "numba"),
                                  "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS") or str(self.threads_per_job),
                                  **(self.cluster.job_environment() if on_cluster else {})}, sandboxed=self.sandbox)

    def _limits_for(self, job: Job) -> JobLimits:
        """CPU time: the job's wall budget on every core, plus a margin for start-up and evaluation;
        CPU priority: an evaluation's ``evaluation_priority`` levels below the server (where trainings run)."""
        budget = float(job.params.get("max_time_s") or 0) * (os.cpu_count() or 1) * 1.5 + 600
        cpu = budget if self.limits.cpu_seconds is None else min(self.limits.cpu_seconds, budget)
        priority = (job_priority(self.limits.evaluation_priority) if job.kind in EVALUATION_KINDS
                    else self.limits.cpu_priority)
        return replace(self.limits, cpu_seconds=int(cpu), cpu_priority=priority)

    def stop(self, job: Job) -> None:
        """Ask through the job's folder (a signal would end bubblewrap, and with it the job, at once)."""
        request_stop(job.id)

    def kill(self, job_id: int) -> None:
        process = self._processes.get(job_id)
        if process is not None and process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)

    def poll(self) -> list[Finished]:
        now = time.monotonic()
        for job_id, (deadline, limit) in list(self._deadlines.items()):
            if now > deadline and job_id not in self._overtime and self._processes[job_id].poll() is None:
                self._overtime[job_id] = overtime_message(limit, self.limits.wall_margin_s)
                self.kill(job_id)
        done = [Finished(job_id, p.returncode, self._overtime.pop(job_id, None))
                for job_id, p in self._processes.items() if p.poll() is not None]
        for item in done:
            del self._processes[item.job_id]
            self._deadlines.pop(item.job_id, None)
        return done

    def running(self) -> list[int]:
        return [job_id for job_id, p in self._processes.items() if p.poll() is None]

    def shutdown(self, grace_s: float = 5.0) -> None:
        """Stop every job (a stop request, then SIGKILL ``grace_s`` after it): each keeps its last
        checkpoint. The jobs share the grace period: the server stops within ``grace_s`` however many run."""
        for job_id, process in list(self._processes.items()):
            if process.poll() is None:
                request_stop(job_id)
        deadline = time.monotonic() + grace_s
        for job_id, process in list(self._processes.items()):
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
